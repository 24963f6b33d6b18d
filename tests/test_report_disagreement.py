"""The report's warning for disagreeing segments says what the combination did with the spread."""

import math

import numpy as np

from pipeline.fit.combine import Contribution, combine
from pipeline.records import Fits
from pipeline.report.summary import findings


def _fits(est):
    return Fits(vessel="v", estimates={est.name: est}, segment_fits=(), damping_matrix=np.full((5, 5), math.nan),
                damping_stderr=np.full((5, 5), math.nan))


def test_random_effects_spread_is_not_called_too_small():
    est = combine("T_yaw", "s", "first-order", [Contribution(1.0, 0.01, "a"), Contribution(2.0, 0.01, "b"),
                                                 Contribution(1.5, 0.01, "c")])
    assert est.consistency_p < 0.01 and "random-effects" in est.method  # the premise
    text = " ".join(findings(_fits(est), ()).warnings)
    assert "T_yaw: per-segment values disagree" in text
    assert "too small" not in text and "spread between segments" in text


def test_plain_mean_that_disagrees_still_says_too_small():
    est = combine("T_yaw", "s", "first-order", [Contribution(1.0, 0.01, "a"), Contribution(2.0, 0.01, "b")])
    plain = type(est)(**{**est.__dict__, "method": "first-order; inverse-variance mean of 2 segments"})
    text = " ".join(findings(_fits(plain), ()).warnings)
    assert "the error bar is too small" in text
