"""K of sinusoids fitted jointly, whose second order they fix exactly, carries the speed term.

Two sinusoids give four numbers for the second order's four constants: the joint fit is one value
with no residual degree of freedom, so it can neither show nor rule out that K changed with the speed
the turns lost (:func:`pipeline.fit.nomoto_quality.exact_fit_trend`). Records: the project's linear
second-order ship (K 0.09 1/s, T1 + T2 13.5 s, T1 T2 64 s^2, T3 10.8 s) simulated by
:func:`scipy.signal.lsim` at 50 Hz and logged at 5 Hz with compass, gyro and rudder-sensor noise,
the independent benchmark's sinusoid pair (3 periods at 2 / 13.5 and at 0.5 / 13.5 rad/s, 10 deg),
and a surge speed that drops with the square of the yaw rate, as a ship's does in its turns.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
import scipy.signal

from pipeline.records import Trial

#: The ship: K [1/s], T1 + T2 [s], T1 T2 [s^2], T3 [s].
K, T12, T1T2, T3 = 0.09, 13.5, 64.0, 10.8
#: Log interval [s] and the simulation's finer one [s].
H, FINE = 0.2, 0.02
#: Straight-run speed [m/s] and its relative loss at the largest yaw rate [-] (read against the straight run
#: before each sinusoid, 0.05 lost 4.1 %, beyond SPEED_MATERIAL: K unsure, tests/test_nomoto_sinusoid_speed.py).
U0, LOSS = 5.0, 0.02


def _trial(seed: int) -> Trial:
    """The sinusoid pair (holds of 10 x 13.5 s after each, as the benchmark's), logged at 5 Hz."""
    parts = []
    for w in (2.0 / T12, 0.5 / T12):
        tt = np.arange(0.0, 3 * 2 * math.pi / w, FINE)
        parts += [math.radians(10) * np.sin(w * tt), np.zeros(int(10 * T12 / FINE))]
    delta = np.concatenate(parts)
    t = np.arange(delta.size) * FINE
    yaw_rate = scipy.signal.lti([K * T3, K], [T1T2, T12, 1.0])
    _, r, _ = scipy.signal.lsim(yaw_rate, delta, t)
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (r[1:] + r[:-1]) * FINE)])
    sub = int(round(H / FINE))
    rng = np.random.default_rng(seed)
    n = t[::sub].size
    u = U0 * (1.0 - LOSS * (r[::sub] / np.max(np.abs(r))) ** 2)
    psi_log = psi[::sub] + math.radians(0.1) * rng.standard_normal(n)
    return Trial("ship", pd.DataFrame({
        "t": t[::sub], "psi": (psi_log + np.pi) % (2 * np.pi) - np.pi,
        "r": r[::sub] + math.radians(0.03) * rng.standard_normal(n),
        "delta": delta[::sub] + math.radians(0.1) * rng.standard_normal(n),
        "u": u + 0.01 * rng.standard_normal(n)}), 1 / H)


@pytest.mark.slow
def test_joint_sinusoid_k_gets_the_speed_term_it_cannot_rule_out():
    from pipeline.fit import fit_trial
    from pipeline.fit.nomoto_quality import EXACT_FIT, speed_range
    from pipeline.segment import detect_segments
    from pipeline.vessel import parse_vessel

    trial = _trial(seed=0)
    segs = detect_segments(trial)
    assert len(segs.of("sinusoid")) == 2
    fits = fit_trial(trial, segs, parse_vessel({"name": "ship"}), extend=False)
    sines = [sf for sf in fits.segment_fits if sf.segment.kind == "sinusoid"]
    assert all("T3" in sf.params for sf in sines), [sf.message for sf in sines]
    assert any(EXACT_FIT in sf.message for sf in sines)
    loss = speed_range(sines)
    assert 0.002 < loss <= 0.02, loss
    k = fits.estimates["K_nomoto"]
    assert k.value == pytest.approx(K, rel=0.02)
    # Before: "no speed term: ... the segments' values show no trend" (one joint value shows none).
    assert "no speed term" not in k.message, k.message
    assert "with the speed term" in k.message and "can neither show nor rule out" in k.message, k.message
    own = sines[0].stderr["K"]
    # The model-structure term (K's own error) and the speed term, loss / 2 of the value, in quadrature.
    assert k.stderr == pytest.approx(math.sqrt(2 * own**2 + (0.5 * loss * k.value) ** 2), rel=0.05)
    assert k.success, k.message
