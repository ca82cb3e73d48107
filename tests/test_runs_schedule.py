"""The cool-downs of the training schedule (``runs.idle_training``) on continuous logs whose
schedule is built with the role each piece must get."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rafi.method.runs import find_runs, run_rules
from rafi.method.windows import schedule_cooldowns
from rafi.twin.synthetic_logs import FIND_RUNS_KWARGS, schedule_log

H = 3600.0
TRAINING_SPEEDS = (3000, 6000, 9000, 12000, 15000, 18000)
#: Constant speeds at least 1500 r/min from every training speed.
VALIDATION_SPEEDS = (4500, 7500, 10500, 13500, 16500)


def continuous_schedule(seed: int, *, validation: bool = True):
    """A continuous log's schedule and the role of each of its pieces, by its place in the
    schedule: ``[(speed_rpm, duration_s, role), ...]``.

    Optionally a long rest first (the start of the training schedule: training); 2-4 training
    runs with cool-downs between them (training), sometimes a stop too short to be a run
    (excluded) between two of them; then, with ``validation``, a cool-down after the last
    training run (validation), 1-2 validation runs with cool-downs (validation), sometimes a run
    at a training speed after them (validation: the leak guard) and a last cool-down; without,
    a last cool-down after the last training run (validation: no training run follows it).
    """
    rng = np.random.default_rng(seed)

    def hours(*choices):
        return float(rng.choice(choices)) * H

    pieces = []
    if rng.random() < 0.5:
        pieces.append((0, hours(0.5, 1, 2), "training"))
    for k, speed in enumerate(rng.choice(TRAINING_SPEEDS, size=rng.integers(2, 5), replace=False)):
        if k:
            pieces.append((0, hours(1, 2, 3, 4), "training"))
            if rng.random() < 0.3:  # a short stop and a restart at the same speed: two runs
                pieces += [(int(speed), hours(1, 2), "training"), (0, 900.0, "excluded")]
        pieces.append((int(speed), hours(1, 2, 4), "training"))
    pieces.append((0, hours(1, 2, 4), "validation_idle"))
    if not validation:
        return pieces
    for k, speed in enumerate(rng.choice(VALIDATION_SPEEDS, size=rng.integers(1, 3), replace=False)):
        if k:
            pieces.append((0, hours(1, 3), "validation_idle"))
        pieces.append((int(speed), hours(1, 3), "validation_single"))
    if rng.random() < 0.5:
        pieces += [(0, H, "validation_idle"), (int(rng.choice(TRAINING_SPEEDS)), H, "validation_single")]
    pieces.append((0, hours(1, 2), "validation_idle"))
    return pieces


def runs_of(schedule, **over):
    frame, truth = schedule_log([(s, d) for s, d, _ in schedule], speed_noise_rpm=20.0)
    table, _ = find_runs({"log": frame}, {"log": "sha"}, **{**FIND_RUNS_KWARGS, **over})
    return table, truth


@pytest.mark.parametrize("seed", range(12))
def test_cool_downs_between_training_runs_train_and_the_rest_stay_validation(seed):
    schedule = continuous_schedule(seed)
    table, truth = runs_of(schedule)  # the default: runs.idle_training: schedule
    assert len(table) == len(schedule)
    np.testing.assert_allclose(table["start_s"], truth["start_s"])
    assert table["role"].tolist() == [role for _, _, role in schedule]
    assert table["kind"].tolist() == ["idle" if s == 0 else "constant" for s, _, _ in schedule]
    idle = table[(table["kind"] == "idle") & (table["role"] != "excluded")]
    trained = idle["role"] == "training"
    assert idle.loc[trained, "role_reason"].str.contains("in the training schedule: training run").all()
    assert idle.loc[~trained, "role_reason"].str.contains("not in the training schedule").all()
    assert set(idle["role_source"]) == {"auto"}
    # no training data after the first validation run
    first_validation = table.loc[table["role"].str.startswith("validation") & (table["kind"] != "idle")]
    assert table.loc[table["role"] == "training", "end_s"].max() < first_validation["start_s"].min()


@pytest.mark.parametrize("seed", range(4))
def test_a_log_of_training_runs_only_validates_its_last_cool_down(seed):
    schedule = continuous_schedule(seed, validation=False)
    table, _ = runs_of(schedule)
    assert table["role"].tolist() == [role for _, _, role in schedule]
    assert table["role"].iloc[-1] == "validation_idle"


def test_idle_training_false_and_true_keep_their_meaning():
    schedule = continuous_schedule(3)
    roles = [role for _, _, role in schedule]
    idle = [s == 0 and role != "excluded" for s, _, role in schedule]
    first_validation = next(k for k, (s, _, role) in enumerate(schedule) if role == "validation_single")
    # false: no cool-down trains (RAFI as published, and the behaviour before issue 25)
    table, _ = runs_of(schedule, idle_training=False)
    expected = ["validation_idle" if i else r for i, r in zip(idle, roles)]
    assert table["role"].tolist() == expected
    # true: every automatic cool-down before the first validation run trains, the one after
    # the last training run too; those after it are demoted by the leak guard
    table, _ = runs_of(schedule, idle_training=True)
    expected = [
        ("training" if k < first_validation else "validation_idle") if i else r
        for k, (i, r) in enumerate(zip(idle, roles))
    ]
    assert table["role"].tolist() == expected


def test_idle_runs_in_a_training_window_train_by_default():
    schedule = [(3000, 2 * H, ""), (0, 2 * H, ""), (6000, 2 * H, ""), (0, 2 * H, ""), (4500, 2 * H, "")]
    windows = [
        {"role": "training", "end": 8 * H, "unit": "elapsed_s"},
        {"role": "validation", "start": 8 * H, "unit": "elapsed_s"},
    ]
    table, _ = runs_of(schedule, windows=windows)
    # the window says what is training: its last cool-down too (as with true)
    assert table["role"].tolist() == ["training"] * 4 + ["validation_single"]
    assert set(table["role_source"]) == {"window"}
    table, _ = runs_of(schedule, windows=windows, idle_training=False)
    assert table["role"].tolist() == ["training", "excluded", "training", "excluded", "validation_single"]


def _table(*rows):
    columns = ["run_id", "start_s", "end_s", "kind", "role", "role_source", "role_reason"]
    return pd.DataFrame(
        [(f"log#{k}", k * H, (k + 1) * H - 5, *row, "why") for k, row in enumerate(rows, start=1)],
        columns=columns,
    )


def test_schedule_cooldowns_looks_past_excluded_runs_and_stops_at_configured_validation():
    table = _table(
        ("constant", "training", "auto"),
        ("idle", "validation_idle", "auto"),  # -> training: #4 follows, #3 is excluded
        ("varying", "excluded", "auto"),
        ("constant", "training", "auto"),
        ("idle", "validation_idle", "auto"),  # the next run is configured validation: stays
        ("idle", "validation_idle", "window"),  # configured: never changed, and validation data
        ("idle", "validation_idle", "auto"),  # after validation data: stays
        ("constant", "training", "window"),  # a training window after validation (allowed)
    )
    out = schedule_cooldowns(table)
    assert out["role"].tolist() == [
        "training",
        "training",
        "excluded",
        "training",
        "validation_idle",
        "validation_idle",
        "validation_idle",
        "training",
    ]
    assert "training run log#4 starts from it" in out.loc[1, "role_reason"]
    assert out.loc[5, "role_reason"] == "why"  # the configured run keeps its reason
    # in any row order, the table comes back in its own order
    shuffled = table.iloc[::-1]
    pd.testing.assert_frame_equal(schedule_cooldowns(shuffled), out.iloc[::-1])
    assert schedule_cooldowns(table.iloc[:0]).empty


def test_run_rules_refuse_an_unknown_idle_training():
    kw = {**FIND_RUNS_KWARGS, "windows": [], "allow_training_after_validation": False}
    for value in (False, True, "schedule"):
        assert run_rules(**kw, idle_training=value).idle_training == value
    for value in ("yes", 1, None):
        with pytest.raises(ValueError, match="idle_training"):
            run_rules(**kw, idle_training=value)


def test_config_refuses_an_unknown_idle_training_naming_the_key():
    from rafi.errors import SettingsError
    from rafi.settings import machine_settings, validate_config

    assert machine_settings({"machines": {"m": {}}}, "m")["runs"]["idle_training"] == "schedule"
    for value in (False, "schedule", True):
        validate_config({"machines": {"m": {"runs": {"idle_training": value}}}})
    with pytest.raises(SettingsError, match=r"machines\.m\.runs\.idle_training: 'yes' is not one of"):
        validate_config({"machines": {"m": {"runs": {"idle_training": "yes"}}}})
