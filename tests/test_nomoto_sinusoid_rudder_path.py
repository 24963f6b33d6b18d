"""A measured rudder on a sinusoid logged at 1 Hz: its servo's path between samples is not logged.

A servo driven by a command held over each sample interval (an autopilot updated at the log rate)
relaxes towards it exponentially, ahead of the straight line between its samples that the fit's drive
(each interval's mean of its two samples) assumes: a 1 s servo at 1 Hz leads it by about 0.08 s, so T
comes out about 0.08 s low. A sinusoid's smooth rudder does not show the servo's speed (a step's jump
would), so pipeline/fit/nomoto_structure.py ``with_rudder_timing_note`` gives its T the rudder-timing
term h / sqrt(12) (0.29 s at 1 Hz), added by pipeline/fit/nomoto_quality.py ``judge_nomoto``.
Measured before the term (this first-order ship, T = 20 s, seeds 0-3): T -0.40 to -0.18 % with errors
of 0.13-0.19 %, marked success, the interval missing the truth on seeds 2 and 3 (z -2.7, -2.5).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.model.nomoto import servo_response
from pipeline.records import Trial
from pipeline.segment import detect_segments
from test_nomoto_segment_held_rudder import log_of_rudder

K_TRUE, T_TRUE = 0.15, 20.0


def _sinusoid_log(h: float, tau: float, seed: int) -> Trial:
    """Two sinusoids (3 periods at 2/T, a 10 T hold, 3 periods at 0.5/T, a 4 T hold) of a first-order
    ship; the 10 deg command held over each sample interval drives a servo of lag ``tau`` [s]; the servo's
    angle logged with 0.1 deg noise; simulated on a 20x finer grid."""
    sub = 20
    w_fast, w_slow = 2.0 / T_TRUE, 0.5 / T_TRUE
    t_fast = 3 * 2 * math.pi / w_fast
    t1 = t_fast + 10 * T_TRUE
    t_end = t1 + 3 * 2 * math.pi / w_slow + 4 * T_TRUE
    t = np.arange(int(t_end / h)) * h
    a = math.radians(10.0)
    cmd = np.where(t < t_fast, a * np.sin(w_fast * t), 0.0)
    cmd = np.where((t >= t1) & (t < t1 + 3 * 2 * math.pi / w_slow), a * np.sin(w_slow * (t - t1)), cmd)
    d = servo_response(np.repeat(cmd, sub), h / sub, tau, math.inf)
    return log_of_rudder(d, 1, (K_TRUE, T_TRUE), h, sub, seed, (0.2, 0.05, 0.1), "ship1")


@pytest.mark.parametrize("seed", [2, 3])
def test_sinusoids_behind_a_servo_at_1_hz_cover_t(seed):
    from pipeline.fit import fit_trial
    from pipeline.vessel import parse_vessel

    trial = _sinusoid_log(1.0, 1.0, seed)
    segs = detect_segments(trial)
    assert len(segs.of("sinusoid")) == 2
    fits = fit_trial(trial, segs, parse_vessel({"name": "ship1"}), extend=False)
    k, t = fits.estimates["K_nomoto"], fits.estimates["T_nomoto"]
    assert k.success and k.value == pytest.approx(K_TRUE, rel=0.01), k.message
    # T stays within 1 % (a sample is 5 % of T), and its interval now holds the truth.
    assert t.value == pytest.approx(T_TRUE, rel=0.01)
    sines = [sf for sf in fits.segment_fits if sf.segment.kind == "sinusoid"]
    assert all("path between its samples is not logged" in sf.message for sf in sines)
    assert "rudder-timing term" in t.message and t.success, t.message
    assert t.ci95[0] < T_TRUE < t.ci95[1], (t.value, t.stderr, t.message)
    assert t.stderr >= 1.0 / math.sqrt(12.0)


def test_k_carries_the_timing_term_through_its_slope_on_t():
    # K read together with T (a sinusoid's gain K / |1 + j w T|) moves with T's timing: the term of K is
    # T's term times the slope of K on T in the segment's covariance; a segment without the note adds none.
    from dataclasses import replace

    from pipeline.fit.nomoto_quality import RUDDER_TIMING, k_on_t_slope, rudder_timing_term
    from pipeline.fit.segment_fit import failed_segment_fit
    from pipeline.records import Segment

    seg = Segment("sinusoid", "yaw", 0.0, 100.0, "delta", 0.0, 0.1)
    cov = np.array([[4e-8, 6e-6, 0.0], [6e-6, 1e-2, 0.0], [0.0, 0.0, 1e-6]])
    base = replace(failed_segment_fit(seg, "nomoto_oe", "psi", ""), success=True,
                   params={"K": 0.15, "T": 20.0, "b": 0.0}, param_names=["K", "T", "b"], covariance=cov)
    noted = replace(base, message=f"{RUDDER_TIMING} +-0.2887 s added in quadrature to its standard error: ...")
    assert k_on_t_slope(base) == pytest.approx(6e-4)
    assert rudder_timing_term([base, noted], "T") == pytest.approx(0.2887)
    assert rudder_timing_term([base, noted], "K") == pytest.approx(6e-4 * 0.2887)
    assert rudder_timing_term([base], "K") == 0.0
    # The second order's T = T12 - T3.
    cov2 = np.diag([4e-8, 1.0, 4.0, 1.0])
    cov2[0, 1] = cov2[1, 0] = 1e-4
    cov2[0, 3] = cov2[3, 0] = -1e-4
    cov2[1, 3] = cov2[3, 1] = 0.5
    second = replace(base, params={"K": 0.15, "T12": 13.5, "T1T2": 64.0, "T3": 10.8},
                     param_names=["K", "T12", "T1T2", "T3"], covariance=cov2)
    assert k_on_t_slope(second) == pytest.approx(2e-4 / 1.0)
