"""Extinction-curve analysis of roll decays: linear and quadratic damping, wn, effective inertia,
per direction and combined, checked against the simulated truth."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from pipeline.fit.decay_analysis import analyse_decays, extinction_curve, extrema
from pipeline.model.vessel5dof import simulate_dof
from pipeline.records import Segment, Trial
from pipeline.vessel import parse_vessel

I, C, B1, B2 = 0.0654, 6.97, 0.1094, 0.05
FS = 100.0
VESSEL = parse_vessel({"name": "aauship", "rigid_body": {"mass": 13.0, "inertia": [I, 1.089, 1.107], "cg": [0, 0, 0]},
                       "restoring": {"roll": C, "pitch": 131.8}})


def roll_trial(seed: int, b2: float = B2, noise: float = 2e-4) -> tuple[Trial, list[Segment]]:
    rng = np.random.default_rng(seed)
    n = int(8 * FS)
    rows, segs, t0 = [], [], 0.0
    for phi0 in (0.35, -0.35, 0.3, -0.3):
        x = simulate_dof(np.array([[0.0, phi0]]), np.zeros((1, n)), 1 / FS, B1 / I, b2 / I, C / I)[0]
        t = t0 + np.arange(n) / FS
        rows.append(pd.DataFrame({"t": t, "phi": x[:, 1] + rng.normal(0, noise, n), "p": x[:, 0]}))
        segs.append(Segment("free_decay", "roll", t[0], t[-1]))
        t0 = t[-1] + 1 / FS
    return Trial("roll", pd.concat(rows, ignore_index=True), FS), segs


def test_extinction_recovers_linear_and_quadratic_damping():
    trial, segs = roll_trial(1)
    a = analyse_decays(trial, segs, VESSEL, "roll")
    assert set(a.curves) == {"starboard down", "port down", "combined"}
    c = a.curves["combined"]
    assert abs(c.B1 - B1) < 3 * c.B1_se and abs(c.B1 - B1) < 0.15 * B1
    assert abs(c.B2 - B2) < 3 * c.B2_se and abs(c.B2 - B2) < 0.25 * B2
    wn = math.sqrt(C / I)
    assert abs(c.wn - wn) < max(3 * c.wn_se, 0.005 * wn)
    assert abs(c.inertia_fit - I) < 0.02 * I and "effective inertia" in a.message
    # Same truth both ways: the directions agree.
    assert a.consistency_p > 0.01
    # B_eq between B1 and B1 + the quadratic share at the stated amplitude.
    assert c.B1 < c.B_eq < c.B1 + 8 / (3 * math.pi) * c.wn * c.amplitude * c.B2 * 1.0001


def test_linear_decay_gives_quadratic_term_near_zero():
    trial, segs = roll_trial(2, b2=0.0)
    c = analyse_decays(trial, segs, VESSEL, "roll").curves["combined"]
    assert abs(c.B2) < 3 * c.B2_se
    assert abs(c.B1 - B1) < 3 * c.B1_se


def test_extrema_alternate_and_no_decay_returns_none():
    t = np.arange(0, 5, 0.01)
    times, vals, off = extrema(t, 0.1 * np.exp(-0.3 * t) * np.cos(2 * math.pi * t) + 0.02)
    assert np.all(np.sign(vals[1:]) != np.sign(vals[:-1])) and abs(off - 0.02) < 0.01
    assert math.isnan(extinction_curve("x", [(times[:1], vals[:1])], I, C).a)
    trial, segs = roll_trial(3)
    assert analyse_decays(trial, segs, VESSEL, "pitch") is None
