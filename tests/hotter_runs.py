"""A machine run hotter than ever in training, shared by the envelope tests: the twin's logs trained
at 3000 and 6000 r/min and a 5 h test run at 9000 r/min (rafi.twin.synthetic_logs), and the
streaming compensator stepped through a frame of it."""

from __future__ import annotations

import json

from rafi.deploy.compensator import Compensator
from rafi.twin.synthetic_logs import schedule_log
from rafi.twin.synthetic_runs import runs_of_logs


def hotter_than_ever_runs():
    """``(table, frame)`` of the two training logs and the hotter test log (``test.csv``)."""
    rest = (0, 180)
    logs = {
        f"train{i}.csv": schedule_log([rest, (speed, 2 * 3600), (0, 3600)], period_s=20, seed=i)[0]
        for i, speed in enumerate((3000, 6000))
    }
    logs["test.csv"] = schedule_log([rest, (9000, 5 * 3600)], period_s=20, seed=9)[0]
    return runs_of_logs(logs, training_speeds_rpm=[3000, 6000], reference_window_s=60)


def streamed(model, frame) -> list:
    """The compensator of ``model``'s artefact (through JSON, as a machine reads it) stepped through
    every row of ``frame``: one ``Step`` per row."""
    comp = Compensator.from_artefact(json.loads(json.dumps(model.to_dict())))
    sensors = [c for c in frame.columns if c.startswith("T") and c[1:].isdigit()]
    cols = (frame["log_t_s"].to_numpy(), frame["speed_rpm"].to_numpy(), frame[sensors].to_numpy(dtype=float))
    return [comp.step(t, n, row) for t, n, row in zip(*cols)]
