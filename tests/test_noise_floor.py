"""The noise floor estimated from a run's own displacement (rafi.method.noise; issue 12 item 8).

Known truth: synthetic runs with a smooth polynomial truth plus white noise of known sigma
(rafi.twin.synthetic_runs.make_runs) and the digital twin's logger, whose white displacement
noise is ``0.85 * disp_noise_um`` (rafi.twin.simulate) and whose noise-free truth gives the
real max |noise| of a run. Outside oracles: sigma * sqrt(2 / pi) for one sample, Monte Carlo
for many.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from rafi.method.noise import expected_max_abs_noise, noise_floor, white_noise_sigma
from rafi.twin.machines import MACHINES
from rafi.twin.recipes import shipped_specs, simulate_spec
from rafi.twin.synthetic_runs import make_runs


def test_expected_max_of_one_sample_is_the_half_normal_mean():
    assert expected_max_abs_noise(1.0, 1) == pytest.approx(math.sqrt(2 / math.pi), rel=1e-5)
    assert expected_max_abs_noise(0.3, 1) == pytest.approx(0.3 * math.sqrt(2 / math.pi), rel=1e-5)


@pytest.mark.parametrize("n", [20, 500, 3000])
def test_expected_max_matches_monte_carlo(n):
    rng = np.random.default_rng(n)
    draws = np.abs(rng.standard_normal((4000, n))).max(axis=1)
    assert expected_max_abs_noise(1.0, n) == pytest.approx(draws.mean(), rel=0.01)
    assert expected_max_abs_noise(2.0, n) == pytest.approx(2.0 * expected_max_abs_noise(1.0, n))


def test_expected_max_edge_cases():
    assert np.isnan(expected_max_abs_noise(np.nan, 100))
    assert np.isnan(expected_max_abs_noise(1.0, 0))
    assert expected_max_abs_noise(0.0, 100) == 0.0


@pytest.mark.parametrize("sigma", [0.3, 1.0])
def test_sigma_of_synthetic_runs_with_known_noise(sigma):
    """make_runs adds ``sigma`` to dz and 0.01 K to the rises the truth is computed from (about
    0.025 um more white noise in dz): below 0.3 um that part shows, above it is < 0.5 %."""
    syn = make_runs((3000, 9000), sigma=sigma, seed=4, duration_s=7200, validation_speeds=(6000,))
    for run_id, g in syn.runs_frame.groupby("run_id"):
        dz = g.sort_values("t_s")["dz_um"].to_numpy()
        assert white_noise_sigma(dz) == pytest.approx(sigma, rel=0.1), run_id
        s, floor = noise_floor(dz)
        assert floor == pytest.approx(expected_max_abs_noise(s, len(dz)))
        # 1440 samples: the max of |N(0, 1)| is about 3.8
        assert 3.4 * sigma < floor < 4.3 * sigma


def test_sigma_ignores_jumps_spikes_and_missing_samples():
    rng = np.random.default_rng(8)
    t = np.arange(3000) * 5.0
    truth = 20.0 * (1 - np.exp(-t / 3000.0)) + np.where(t > 7000, 3.0, 0.0)  # a draw-in jump
    dz = truth + rng.normal(0.0, 0.2, t.size)  # the MAD's own scatter at n = 3000: ~4 %
    dz[[100, 900, 2000]] += 8.0  # spikes
    dz[1500:1510] = np.nan
    assert white_noise_sigma(dz) == pytest.approx(0.2, rel=0.1)
    _, floor = noise_floor(dz)
    assert floor == pytest.approx(expected_max_abs_noise(white_noise_sigma(dz), 2990))


def test_short_or_quantised_series():
    assert np.isnan(white_noise_sigma([1.0, 2.0, 3.0]))
    assert np.isnan(noise_floor([np.nan] * 50)[1])
    rng = np.random.default_rng(1)
    q = np.round(rng.normal(0.0, 0.3, 2000))  # 1 um resolution: MAD of d2 may be 0
    assert white_noise_sigma(q) > 0.0


def test_twin_logger_noise_is_found_from_the_log_alone():
    """The twin's validation runs: the estimate from the logged displacement matches the white
    noise the twin adds, and the floor is close to the max |noise| the noise-free truth shows
    (which also holds the twin's slow, correlated part: the floor is a bit lower)."""
    white = 0.85 * MACHINES["tapping-center-a"]().disp_noise_um
    specs = [s for s in shipped_specs("tapping-center-a") if s.file.startswith(("valid", "multi"))]
    assert specs
    for spec in specs[:3]:
        run = simulate_spec(spec, defects=False)
        logged = run.log["disp_um"].to_numpy()
        true_noise = logged - run.truth["disp_um"].to_numpy()
        sigma, floor = noise_floor(logged)
        assert sigma == pytest.approx(white, rel=0.1), spec.run_id
        real = float(np.max(np.abs(true_noise)))
        assert 0.7 * real < floor < 1.2 * real, spec.run_id
