"""Every analysed DOF has a noise unit and a held-out floor.

- A DOF faster than the log, cut into windows of a few samples, with no noise stated in the vessel
  config: its noise is measured over the whole log (:func:`pipeline.diagnose.problem.block_noise`);
  before, it had no noise unit (gaps in scale units) and no floor (randomised seed 43 r008, the twin
  at 1.92 Hz: yaw 0.065 in scale units).
- Roll and pitch get a held-out floor like the first-order DOFs
  (:func:`pipeline.diagnose.floor.oscillatory_floor`); before, their channels were tested against 1.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.diagnose import problem
from pipeline.diagnose.problem import block_noise
from test_diagnose_stated_noise import _short_windows


@pytest.mark.parametrize("m", [1, 2])
def test_the_whole_log_gives_the_noise_where_the_windows_are_too_short_and_none_is_stated(m):
    rng = np.random.default_rng(7)
    w = _short_windows(12, 7)  # no block of 8 samples in any window
    sigma = 0.004
    x = rng.normal(0.0, sigma, 400)
    # A manoeuvre of 20 sigma inside the log but outside the windows' blocks: the robust spread ignores it.
    x[200:230] += 20 * sigma * np.sin(np.linspace(0, np.pi, 30))
    got = block_noise(x, w, m, trapezoid=True)
    assert got == pytest.approx(sigma * np.sqrt(m - 0.5) / m, rel=0.25)
    assert problem.noise_source(x, w, m) == "whole log"
    assert not np.isfinite(block_noise(x, w, m, trapezoid=True, whole_log=False))
    # A stated noise still comes first where the windows cannot measure it; measurable windows first of all.
    assert problem.noise_source(x, w, m, stated=sigma) == "stated"
    assert block_noise(x, w, m, stated=sigma) == pytest.approx(sigma / np.sqrt(m), rel=1e-9)
    assert problem.noise_source(rng.normal(0.0, sigma, 1000), _short_windows(20, 40), m) == "windows"
    # A log too short for the whole-log contrasts: none.
    assert problem.noise_source(x[:40], _short_windows(3, 7), m) == "none"
    assert not np.isfinite(block_noise(x[:40], _short_windows(3, 7), m))


def test_roll_and_pitch_have_a_heldout_floor(tmp_path):
    from diagnose_synthetic import simulated_trial
    from pipeline.diagnose import diagnose
    from pipeline.sim import Effects
    from pipeline.sim.manoeuvres import chain, free_decay
    from pipeline.vessel import load_vessel

    aauship = load_vessel(Path(__file__).resolve().parents[1] / "vessel_configs" / "aauship.toml")
    decays = chain(*(free_decay("roll", np.radians(a), 3.0) for a in (20, -15, 25, 10)),
                   *(free_decay("pitch", np.radians(a), 3.0) for a in (5, -4)), rest_s=2.0)
    trial, _ = simulated_trial(aauship, decays, Effects(), tmp_path, "rollfloor", seed=5)
    rep = diagnose(trial, aauship)
    for dof, chans in (("roll", {"p", "phi"}), ("pitch", {"q", "theta"})):
        d = next(x for x in rep.dofs if x.dof == dof)
        assert set(d.heldout_floor) == chans, (dof, d.heldout_floor)
        assert all(np.isfinite(f) and 1.0 <= f < 3.0 for f in d.heldout_floor.values()), d.heldout_floor
    assert rep.effects == () and rep.unexplained == ()


@pytest.mark.slow
def test_the_twins_fast_yaw_without_stated_noise_is_in_noise_units_with_a_floor():
    """Randomised seed 43 r008 (twin_clean at 1.92 Hz, r and psi noise 0.004 and 0.006 per sample, not
    stated): the yaw's noise from the whole log, a held-out floor, null, nothing unexplained."""
    import tempfile

    from pipeline.diagnose import diagnose
    from pipeline.diagnose.gridfit import grid_data
    from pipeline.diagnose.verdict import _stated_noise_notes
    from pipeline.flow import load_trial
    from test_diagnose_floor_start import _bench, random_problem

    _, p = random_problem(43, 18, ("clean", "pvs_clean", "twin_clean"), 8)
    assert not p.stated_noise
    d = grid_data(p)
    # Per sample (m = 1, trapezoid weights sqrt(1/2)): within 30 % of the simulator's noise.
    assert d.sigma_y / np.sqrt(0.5) == pytest.approx(0.004, rel=0.3)
    assert d.sigma_angle / np.sqrt(0.5) == pytest.approx(0.006, rel=0.3)
    assert any("whole log" in n and " r " in n for n in _stated_noise_notes(p))
    b = _bench()
    case = b.random_cases(18, 43, ("clean", "pvs_clean", "twin_clean"))[8]
    with tempfile.TemporaryDirectory() as tmp:
        files, vessel, truth = b.make_random_trial(case, Path(tmp))
        vessel = b.stated_noise(case, truth, vessel)
        rep = diagnose(load_trial(files, vessel), vessel)
    yaw = next(x for x in rep.dofs if x.dof == "yaw")
    assert set(yaw.heldout_floor) == {"r", "psi"}
    assert 0.3 < yaw.gap < 3.0  # noise units (0.065 in scale units before)
    assert rep.effects == () and rep.unexplained == ()
    assert any("whole log" in n for n in rep.notes)
