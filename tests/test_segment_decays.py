"""Heeling tests and pool decays: a roll or pitch free decay is segmented from the release (not
from the heel ramp or the hold) and fitted, K_p and M_q with their uncertainty."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pipeline.fit import fit_trial
from pipeline.flow import load_trial, segment_trial
from pipeline.records import Trial
from pipeline.segment import detect_segments
from pipeline.segment.decays import release_index
from pipeline.sim import simulate
from pipeline.sim.manoeuvres import chain, step_and_coast
from pipeline.sim.writers import write_log
from pipeline.vessel import load_vessel

ROOT = Path(__file__).resolve().parents[1]
VESSEL = load_vessel(ROOT / "vessel_configs" / "aauship.toml")
D = np.diag(VESSEL.damping)


def _decay(t, a0, wn, zeta):
    wd = wn * math.sqrt(1 - zeta**2)
    s = np.clip(t, 0, None)
    return a0 * np.exp(-zeta * wn * s) * (np.cos(wd * s) + zeta * wn / wd * np.sin(wd * s))


def test_hand_heel_ramp_hold_release_starts_at_the_release():
    """A hull heeled by hand over 8 s, held 25 s, let go at 40 s: the decay starts at 40 s."""
    fs = 50.0
    t = np.arange(0.0, 60.0, 1 / fs)
    a0 = math.radians(8)
    phi = np.interp(t, [0, 7, 15, 40], [0, 0, a0, a0])
    phi = np.where(t >= 40, _decay(t - 40, a0, 10.3, 0.08), phi)
    phi += np.random.default_rng(1).normal(0, math.radians(0.05), t.size)
    trial = Trial("pool", pd.DataFrame({"t": t, "phi": phi}), fs)
    (seg,) = [s for s in detect_segments(trial).items if s.kind == "free_decay"]
    assert seg.dof == "roll" and abs(seg.t_start - 40.0) <= 2 / fs, seg
    assert seg.t_end > 43.0


def test_release_index_on_an_instantaneous_release_is_the_peak():
    dev = _decay(np.arange(0, 5, 0.01), 0.2, 10.0, 0.1)
    # Within 2 % of the peak: cos(wn t) > 0.98 for wn t < 0.2 rad, i.e. 0.02 s at 10 rad/s.
    assert release_index(dev, 0, 1e-4) <= 2


@pytest.mark.parametrize("seed", [1, 2])
def test_heeling_test_with_a_logged_moment_gives_k_p_and_m_q(seed, tmp_path):
    """tau_k held 30 s then released (and tau_m for pitch), written to CSV and read back."""
    sched = chain(step_and_coast("roll", VESSEL.restoring["roll"] * math.radians(10), 30.0, 20.0),
                  step_and_coast("pitch", VESSEL.restoring["pitch"] * math.radians(3), 30.0, 20.0), rest_s=5.0)
    res = simulate(VESSEL, sched, seed=seed)
    trial = load_trial([write_log(res.log, tmp_path / "heel.csv", vessel=VESSEL)], VESSEL)
    segs = segment_trial(trial)
    decays = segs.of("free_decay")
    releases = [s for s in decays if s.label.startswith("release")]
    assert {s.dof for s in releases} == {"roll", "pitch"}
    for s in releases:
        expected = 35.0 if s.dof == "roll" else 90.0  # rest 5 s, hold 30 s (then 20 s + rest 5 s)
        assert abs(s.t_start - expected) <= 1.0 / trial.fs, s
    # No segment starts on the heel ramp or hold as a free decay of its own.
    assert len(decays) == 4
    fits = fit_trial(trial, segs, VESSEL, extend=False)
    for name, truth in (("K_p", -D[2]), ("M_q", -D[3])):
        est = fits.estimates[name]
        assert est.success, est.message
        assert abs(est.value - truth) < 3 * est.stderr, (name, est.value, est.stderr, truth)
        assert abs(est.value - truth) < 0.06 * abs(truth)
