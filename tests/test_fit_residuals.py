"""Residual whiteness and input cross-correlation tests (MATLAB ``resid``; Ljung 1999, sec. 16.6):
white residuals pass, coloured ones and ones that still hold input response are flagged, on raw
sequences and on SegmentFits. Seeded."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pipeline.errors import FitError
from pipeline.fit import fit_coast_down
from pipeline.fit.residual_tests import (autocorrelation, cross_correlation, prewhiten, residual_test,
                                         segment_fit_residual_test)
from pipeline.records import Segment, Trial


def test_white_residuals_pass_at_about_the_nominal_rate():
    rng = np.random.default_rng(7)
    rejected = 0
    for k in range(200):
        e = rng.standard_normal(1500)
        zigzag = np.sign(np.sin(np.arange(1500) / 40.0 + k))  # a strongly coloured input
        rejected += not residual_test(e, {"delta": zigzag}).passed
    # Three tests at 1% each: well under 5% false alarms.
    assert rejected / 200 < 0.05


def test_coloured_residuals_are_flagged_with_a_reason():
    rng = np.random.default_rng(8)
    e = np.convolve(rng.standard_normal(2000), np.ones(6) / 6, mode="same")
    res = residual_test(e, name="coast-down u")
    assert not res.white and not res.passed
    assert res.ljung_box_p < 1e-6 and res.outside > 5
    assert "coast-down u: residuals are not white" in res.message and "Ljung-Box" in res.message


def test_residual_that_still_holds_input_response_fails_independence():
    rng = np.random.default_rng(9)
    n = 2000
    u = np.sign(np.sin(np.arange(n) / 50.0))
    kernel = 0.1 * np.exp(-np.arange(60) / 15.0)
    e = 0.2 * rng.standard_normal(n) + np.convolve(u, kernel)[:n]
    res = residual_test(e, {"delta": u})
    assert not res.independent
    assert res.cross_p["delta"] < 1e-3
    assert "correlate with input delta" in res.message
    # The same noise without the input term passes.
    assert residual_test(0.2 * rng.standard_normal(n), {"delta": u}).independent


def test_correlation_conventions():
    rng = np.random.default_rng(10)
    u = rng.standard_normal(3000)
    e = np.roll(u, 3)  # e_t = u_(t-3): the input three samples earlier
    c = cross_correlation(e, u, 10)
    assert int(np.argmax(c)) - 10 == 3 and c.max() == pytest.approx(1.0, abs=0.01)
    rho = autocorrelation(rng.standard_normal(500), 5)
    assert rho[0] == 1.0 and rho.shape == (6,)
    # An AR(1) input is whitened by its own AR model.
    x = np.zeros(3000)
    for k in range(1, 3000):
        x[k] = 0.9 * x[k - 1] + u[k]
    assert abs(autocorrelation(prewhiten(x), 3)[1]) < 0.05


def test_constant_inputs_are_skipped_and_short_records_not_tested():
    rng = np.random.default_rng(11)
    res = residual_test(rng.standard_normal(500), {"tau_x": np.full(500, 4.0)})
    assert res.cross_correlation == {} and res.passed
    short = residual_test(np.ones(10), name="tiny")
    assert short.passed and "not run" in short.message and short.n == 10


def test_input_of_the_wrong_length_is_an_error():
    with pytest.raises(FitError, match="expected input 'delta' with 100 samples"):
        residual_test(np.zeros(100), {"delta": np.zeros(99)})


def _coast_trial(extra: np.ndarray | None, seed: int) -> tuple[Trial, Segment]:
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 30.0, 0.05)
    u = np.where(t >= 5, 1.5 * np.exp(-(t - 5) / 4.5), 1.5) + 0.01 * rng.standard_normal(t.size)
    if extra is not None:
        u = u + extra
    tau = np.where(t >= 5, 0.0, 4.3)
    return (Trial("coast", pd.DataFrame({"t": t, "u": u, "tau_x": tau}), 20.0),
            Segment("coast_down", "surge", 5.0, 30.0, "tau_x", 4.3, 0.0))


def test_segment_fit_residuals_white_and_coloured():
    trial, seg = _coast_trial(None, 12)
    sf = fit_coast_down(trial, seg)
    res = segment_fit_residual_test(sf, trial)
    assert res.passed, res.message
    assert res.n == sf.y.size and "coast_down surge" in res.name
    # A slow unmodelled wave on top of the coast-down colours the residuals.
    t = trial.t
    trial2, seg2 = _coast_trial(0.03 * np.sin(2 * np.pi * t / 6.0), 12)
    res2 = segment_fit_residual_test(fit_coast_down(trial2, seg2), trial2)
    assert not res2.white and "not white" in res2.message
