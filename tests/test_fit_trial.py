"""fit_trial as a whole: a trial with every kind of segment, bad segments that must not stop the
others, no mutation of inputs, the damping matrix layout, and documented public functions."""

from __future__ import annotations

import copy
import math
import time

import numpy as np
import pandas as pd
import pytest

import pipeline.fit as fit
from pipeline.fit import fit_trial
from pipeline.records import DOFS, Segment, Segments, Trial
from pipeline.vessel import parse_vessel

AAUSHIP = {"name": "aauship", "rigid_body": {"mass": 13.0, "inertia": [0.0654, 1.089, 1.107]},
           "restoring": {"roll": 6.97, "pitch": 131.8}}
# AAUSHIP damping diagonal (u v p q r).
D_TRUE = np.array([2.86, 32.5, 0.1094, 7.203, 0.26285])
FS = 50.0


def aauship_trial(seed):
    """Coast-downs in surge, sway and yaw, and roll and pitch free decays, one after the other.

    Sway and yaw use the rigid-body M[i, i] (no added mass in the config): T = M/D.
    """
    rng = np.random.default_rng(seed)
    vessel = parse_vessel(AAUSHIP)
    t = np.arange(0.0, 100.0, 1.0 / FS)
    cols = {c: np.zeros(t.size) for c in ("u", "v", "r", "phi", "theta")}
    segs = []
    for ch, dof, y0, t0 in (("u", "surge", 1.0, 0.0), ("v", "sway", 0.3, 20.0),
                             ("r", "yaw", 0.5, 40.0)):
        i = DOFS.index(ch)
        T = vessel.effective_mass(dof) / D_TRUE[i]
        s = t - t0
        cols[ch] = np.where((s >= 0) & (s < 20), y0 * np.exp(-np.clip(s, 0, None) / T), 0.0)
        segs.append(Segment("coast_down", dof, t0, t0 + min(19.9, 6 * T)))
    decays = (("phi", "roll", math.radians(10), 60.0, 0.2), ("theta", "pitch", math.radians(8), 80.0, 0.02))
    for ch, dof, a0, t0, noise in decays:
        i = DOFS.index({"roll": "p", "pitch": "q"}[dof])
        inertia, c = vessel.effective_mass(dof), AAUSHIP["restoring"][dof]
        wn = math.sqrt(c / inertia)
        zeta = D_TRUE[i] / (2 * math.sqrt(c * inertia))
        wd = wn * math.sqrt(1 - zeta**2)
        s = np.clip(t - t0, 0, None)
        x = a0 * np.exp(-zeta * wn * s) * (np.cos(wd * s) + zeta * wn / wd * np.sin(wd * s))
        cols[ch] = np.where((t >= t0) & (t < t0 + 20), x, 0.0) + rng.normal(0, math.radians(noise), t.size)
        segs.append(Segment("free_decay", dof, t0, t0 + 10.0))
    for ch, sd in (("u", 0.01), ("v", 0.005), ("r", 0.005)):
        cols[ch] = cols[ch] + rng.normal(0, sd, t.size)
    return Trial("aauship", pd.DataFrame({"t": t, **cols}), FS), Segments("aauship", tuple(segs))


def test_whole_aauship_diagonal_is_recovered_within_three_sigma():
    trial, segs = aauship_trial(seed=1)
    t0 = time.perf_counter()
    fits = fit_trial(trial, segs, parse_vessel(AAUSHIP), extend=False)
    elapsed = time.perf_counter() - t0
    assert elapsed < 0.2 * len(segs.items)  # single-DOF fits: well under a second per segment
    diag, se = np.diag(fits.damping_matrix), np.diag(fits.damping_stderr)
    assert np.all(np.abs(diag - D_TRUE) < 3 * se), (diag, se)
    joint = fit_trial(trial, segs, parse_vessel(AAUSHIP))
    jdiag, jse = np.diag(joint.damping_matrix), np.diag(joint.damping_stderr)
    assert np.all(np.abs(jdiag - D_TRUE) < np.maximum(3 * jse, 3 * se)), (jdiag, jse)
    assert np.all(np.abs(diag - D_TRUE) < 0.05 * D_TRUE)  # and within 5% of truth
    assert list(fits.estimates)[:5] == ["X_u", "Y_v", "K_p", "M_q", "N_r"]
    for name, unit in (("X_u", "kg/s"), ("Y_v", "kg/s"), ("K_p", "kg m^2/s"), ("M_q", "kg m^2/s"),
                       ("N_r", "kg m^2/s")):
        e = fits.estimates[name]
        assert e.success and e.value < 0 and e.unit == unit, (name, e.message)
    off = ~np.eye(5, dtype=bool)
    assert np.isnan(fits.damping_matrix[off]).all() and np.isnan(fits.damping_stderr[off]).all()
    assert "X_u = -D[0,0]" in fits.convention
    assert all(sf.success for sf in fits.segment_fits)


def test_bad_segments_do_not_stop_the_good_ones():
    trial, segs = aauship_trial(seed=2)
    bad = (Segment("coast_down", "surge", 10.0, 10.1),           # 6 samples
           Segment("zigzag", "yaw", 0.0, 50.0),                   # whole-record fit, but no rudder logged
           Segment("coast_down", "roll", 0.0, 10.0),              # wrong DOF for a coast-down
           Segment("step", "surge", 5.0, 4.0),                    # reversed bounds
           Segment("coast_down", "heave", 0.0, 10.0))
    fits = fit_trial(trial, Segments("aauship", segs.items + bad), parse_vessel(AAUSHIP))
    assert len(fits.segment_fits) == len(segs.items) + len(bad)
    failed = fits.segment_fits[len(segs.items):]
    assert not any(sf.success for sf in failed)
    msgs = [sf.message for sf in failed]
    assert "found 6 samples" in msgs[0]
    assert "zigzag yaw [0.00-50.00 s]: expected channel delta" in msgs[1]
    assert "expected a coast_down in surge, sway or yaw, found DOF 'roll'" in msgs[2]
    assert "expected t_end > t_start" in msgs[3]
    x_u = fits.estimates["X_u"]
    assert x_u.success and x_u.n_segments == 1 and "left out" in x_u.message
    assert np.isfinite(np.diag(fits.damping_matrix)).all()


def test_inputs_are_not_mutated():
    trial, segs = aauship_trial(seed=3)
    data_before = trial.data.copy(deep=True)
    segs_before = copy.deepcopy(segs)
    vessel = parse_vessel(AAUSHIP)
    fit_trial(trial, segs, vessel)
    pd.testing.assert_frame_equal(trial.data, data_before)
    assert segs == segs_before
    assert vessel.mass == 13.0 and vessel.restoring == AAUSHIP["restoring"]


def test_added_mass_enters_m_eff():
    trial, segs = aauship_trial(seed=4)
    doc = {**AAUSHIP, "added_mass": {"surge": 1.3}}
    x_u = fit_trial(trial, Segments("a", segs.items[:1]), parse_vessel(doc)).estimates["X_u"]
    x_u0 = fit_trial(trial, Segments("a", segs.items[:1]), parse_vessel(AAUSHIP)).estimates["X_u"]
    assert x_u.value == pytest.approx(1.1 * x_u0.value) and "m_eff = 14.3 kg" in x_u.method


def test_empty_segments_give_empty_fits():
    trial, _ = aauship_trial(seed=5)
    fits = fit_trial(trial, Segments("aauship", ()), parse_vessel(AAUSHIP), extend=False)
    assert fits.estimates == {} and fits.segment_fits == () and fits.damping_matrix.shape == (5, 5)
    assert np.isnan(fits.damping_matrix).all()
    # With the joint stage the coupled terms are listed as not identified, each with its reason.
    joint = fit_trial(trial, Segments("aauship", ()), parse_vessel(AAUSHIP))
    assert np.isnan(joint.damping_matrix).all()
    assert all(not e.success and e.message for e in joint.estimates.values())


def test_greybox_and_structures_as_units_match_the_serial_steps(monkeypatch):
    # fit_trial runs the grey-box fit and each DOF's structure choice as units of one ordered_map (in
    # worker processes when the cores allow): the result is the serial composition, bit for bit.
    from pipeline.fit.extend import extend_fits
    from pipeline.fit.structure import apply_structures

    trial, segs = aauship_trial(seed=3)
    vessel = parse_vessel(AAUSHIP)
    single = fit_trial(trial, segs, vessel, extend=False)
    serial = apply_structures(extend_fits(single, trial, segs, vessel), trial, segs.items, vessel)
    assert serial.structures  # the structure step ran
    for jobs in ("1", "2"):
        monkeypatch.setenv("VESSELID_JOBS", jobs)
        units = fit_trial(trial, segs, vessel)
        assert list(units.estimates) == list(serial.estimates)
        for name, e in serial.estimates.items():
            u = units.estimates[name]
            assert (repr(u.value), repr(u.stderr), u.message, u.success) == (
                repr(e.value), repr(e.stderr), e.message, e.success), name
        assert np.array_equal(units.damping_matrix, serial.damping_matrix, equal_nan=True)
        assert np.array_equal(units.damping_stderr, serial.damping_stderr, equal_nan=True)
        assert list(units.structures) == list(serial.structures)
        assert [c.selected for c in units.structures.values()] == [c.selected for c in serial.structures.values()]


def test_bad_model_is_refused_before_any_joint_fit():
    from pipeline.errors import FitError

    trial, segs = aauship_trial(seed=1)
    with pytest.raises(FitError, match="--model: expected one of"):
        fit_trial(trial, segs, parse_vessel(AAUSHIP), model="cubic")
