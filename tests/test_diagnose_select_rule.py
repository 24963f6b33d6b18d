"""The significance rule's shrink once an effect is selected (``on_top``): the shrink of the model error
above the sensor noise counts beside the gap's, the first effect keeps the calibrated rule."""

from __future__ import annotations

import math

import numpy as np

from pipeline.diagnose.significance import channel_significant, excess_shrink, score
from pipeline.diagnose.gridfit import GridData
from pipeline.fit.heldout_test import ChannelScore


def _chan(name, g0, g1, p):
    return ChannelScore(name, 2000, g0, g1, 0.05, 0.1, 1900.0, 40.0, p)


def test_excess_shrink_counts_the_error_above_one_noise_unit():
    # Seed 34 r000, psi on top of the yaw damping: 1.47 -> 1.37 noise units.
    assert math.isclose(excess_shrink(1.472, 1.37), 13.3, abs_tol=0.1)
    assert math.isclose(excess_shrink(2.0, 1.0), 100.0)
    assert math.isnan(excess_shrink(0.95, 0.9))


def test_on_top_a_small_gap_shrink_of_a_large_share_of_the_error_is_significant():
    chans = (_chan("r", 1.263, 1.21, 1e-46), _chan("psi", 1.472, 1.37, 1e-65))
    rob = (1e-40, 1e-60)
    assert not channel_significant(chans, rob, 6.05)
    assert channel_significant(chans, rob, 6.05, on_top=True)
    # The p-value and robustness conditions stay.
    assert not channel_significant(chans, (1e-2, 1e-2), 6.05, on_top=True)
    # A gap already at the noise: a 2 % shrink of r stays under 10 % of its error above the noise too.
    assert not channel_significant((_chan("r", 1.209, 1.2, 1e-4 / 3),), (1e-5,), 0.7, on_top=True)


def test_score_passes_on_top_through():
    rng = np.random.default_rng(3)
    w, n = 12, 200
    truth = np.sin(np.linspace(0, 20, w * n)).reshape(w, n)
    y = truth + rng.standard_normal((w, n))
    d = GridData(dt=0.1, y=y, y0=y[:, 0].copy(), angle=None, mask=np.ones((w, n), bool), sigma_y=1.0)
    base = {"y": truth + 0.45}       # error 0.45 noise units above the noise: gap ~1.1
    cand = {"y": truth + 0.2}
    folds = np.arange(w) % 4
    strict = score(d, base, cand, 1, {"y": "r"}, folds=folds)
    relaxed = score(d, base, cand, 1, {"y": "r"}, folds=folds, on_top=True)
    assert strict.shrink < 10 and not strict.significant
    assert relaxed.significant


def test_on_top_a_channel_at_its_floor_keeps_the_gap_shrink():
    # Seed 34 r006, on top of waves: a rudder rate limit took r from 1.18 to 1.11 noise units, under r's
    # held-out floor of 1.27 (24 % of the error above the noise, 6 % of the gap).
    chans = (_chan("r", 1.177, 1.11, 1.3e-12), _chan("psi", 2.859, 2.83, 0.29))
    rob = (1e-10, 0.5)
    assert channel_significant(chans, rob, 1.5, on_top=True)
    assert not channel_significant(chans, rob, 1.5, on_top=True, floors={"r": 1.271, "psi": 1.107})
