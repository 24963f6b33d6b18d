"""Report warnings: disagreeing segments, and a failed fit that kept no samples."""

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


def _empty_fit(success: bool):
    from pipeline.records import Segment, SegmentFit

    seg = Segment(kind="step", dof="yaw", t_start=37.8, t_end=43.4, input_channel="tau_n", input_before=80.0,
                  input_after=100.0, quality=0.1)
    e = np.empty(0)
    return SegmentFit(segment=seg, model="first_order_step", channel="r", param_names=("T",), params={"T": math.nan},
                      stderr={"T": math.nan}, covariance=np.full((1, 1), np.nan), t=e, y=e, y_fit=e, rmse=math.nan,
                      aic=math.nan, bic=math.nan, success=success,
                      message="" if success else "no excitation: expected a transient of 5 noise std, found 3.5")


def test_failed_fit_without_samples_is_one_warning_not_two(tmp_path):
    """A fit refused for want of excitation keeps no samples: its failure is the warning, not its figure."""
    from pipeline.report import write_report

    nan = np.full((5, 5), np.nan)
    for success, figure_warned in ((False, False), (True, True)):
        paths = write_report(Fits("v", {}, (_empty_fit(success),), nan, nan), tmp_path / str(success))
        page = paths.html.read_text()
        assert ("the fit holds no samples" in page) is figure_warned
        assert ("fit 0 (step/yaw) failed: no excitation" in page) is (not success)


def test_a_trial_without_segments_says_so_and_how_to_name_them():
    nan = np.full((5, 5), np.nan)
    text = " ".join(findings(Fits("v", {}, (), nan, nan), ()).warnings)
    assert "no segment was fitted" in text and "[[segments]]" in text
