"""A right effect's candidate fit reaches what the true model leaves (benchmarks/RESULTS.md, "Shrink
against its ceiling (diag21)").

Randomised seed 45 r020 (AAUSHIP, quadratic sway damping at 7.7 Hz, sway's v derived from GNSS and
compass) is the trial that holds seed 45's median held-out shrink at 61.7 %: its damping shrinks sway
by 34.5 % only. Its DOF has no held-out floor (the noise of v is neither stated nor measurable there),
so the benchmark gives it no ceiling. The ceiling measured instead: the candidate's own model with the
simulator's parameters (``T = M/D = 13/32.5`` s, ``k = 1/D``, ``d2 = D2/D = 192.6/32.5``) leaves as
much of the data unexplained as the fit does, so the low shrink is the data's, not the fit's.
"""

from __future__ import annotations

import numpy as np

from pipeline.diagnose.candidates import Candidate, Fitted, NonlinearDamping, candidates_for
from pipeline.diagnose.gridfit import grid_data, weighted_residuals
from pipeline.diagnose.timing import input_timing


def _rms(d, cand, fitted, idx) -> float:
    r = weighted_residuals(d, cand.simulate(fitted, idx))
    r = r[np.isfinite(r)]
    return float(np.sqrt(np.mean(r * r)))


def test_seed45_r020_sway_damping_fit_leaves_no_more_than_the_true_model():
    from test_diagnose_floor_start import random_problem

    truth, p0 = random_problem(45, 24, (), 20, dof="sway")
    assert truth["effects"][0]["effect"] == "nonlinear_damping" and truth["effects"][0]["dof"] == "sway"
    p, _ = input_timing(p0)
    d = grid_data(p)
    assert p.inputs == ("tau_y",)
    every = np.arange(len(p.windows))
    cands = candidates_for(p, d)
    damping = next(c for c in cands if isinstance(c, NonlinearDamping))
    base = Candidate.fit(cands[0], every)
    fit = damping.fit(every, start=base)
    # AAUSHIP sway: M = 13 kg, D = 32.5 N s/m, the benchmark's D2 = D / 0.3 m/s times the trial's magnitude.
    d2_true = 32.5 / 0.3 * truth["effects"][0]["magnitude"] / 32.5
    x = np.array(fit.state, float).copy()
    x[0], x[1], x[2] = np.log(13.0 / 32.5), d2_true, 1.0 / 32.5
    true = Fitted({**fit.params, "T": 13.0 / 32.5, "k_tau_y": 1.0 / 32.5, "d2": d2_true}, ("d2",), 0.0, x)
    e_fit, e_true, e_base = _rms(d, damping, fit, every), _rms(d, damping, true, every), _rms(d, cands[0], base, every)
    # The fit leaves no more than the true model (measured: 0.0522 against 0.0530 scale units), and both
    # well under the baseline (0.0610): the effect is there and fitted, what stays is the data's.
    assert e_fit <= 1.01 * e_true
    assert e_true < 0.9 * e_base
    assert abs(fit.params["d2"] - d2_true) < 0.25 * d2_true
