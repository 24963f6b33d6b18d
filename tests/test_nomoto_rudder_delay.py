"""A lone zig-zag's rudder-to-heading delay fitted with K and T (pipeline/fit/nomoto_rudder_delay.py).

A zig-zag never settles, so its first-order K and T are read together from the transients and a small delay
between the logged rudder angle and the ship's response moves both (PythonVehicleSimulator's frigate: its
0.05 s Euler step acts as a 0.024 s delay and gave K and T +0.18 % each noise-free, +0.09 to +0.29 % with
standard errors of 0.075 % under the benchmark's noise). Here a first-order ship (K = 0.1 1/s, T = 10 s)
behind a 1 s servo responds to its rudder 0.1 s after the logged angle: without the delay fitted K and T
came out +0.66 +- 0.08 % and +1.74 +- 0.14 % (seed 0), marked success, the intervals missing the truth.
"""

from __future__ import annotations

import math
import re
import tempfile
from pathlib import Path

import numpy as np

from pipeline.fit import fit_trial
from pipeline.fit.nomoto_rudder_delay import RUDDER_DELAY_TERM, fractional_delay
from pipeline.flow import load_trial
from pipeline.segment import detect_segments
from pipeline.vessel import parse_vessel

K_TRUE, T_TRUE = 0.1, 10.0
DELAY = 0.1          # the ship responds this long after the logged rudder angle [s]
FS = 5.0


def _zigzag_log(seed: int, delay: float = DELAY) -> dict[str, np.ndarray]:
    """A 10/10 zig-zag of the first-order ship behind a 1 s servo, simulated at 100 Hz, logged at 5 Hz."""
    h, every = 0.01, int(round(1.0 / (FS * 0.01)))
    a = math.radians(10.0)
    duration = 30.0 + 7 * (2 * a / (K_TRUE * a) + T_TRUE)
    n = int(duration / h)
    lag = int(round(delay / h))
    delta = np.zeros(n + 1)
    r = psi = 0.0
    cmd = 0.0
    rows = []
    for k in range(n + 1):
        t = k * h
        if t >= 30.0:
            if cmd == 0.0:
                cmd = a
            elif cmd > 0 and psi > a:
                cmd = -a
            elif cmd < 0 and psi < -a:
                cmd = a
        if k % every == 0:
            rows.append((t, psi, r, delta[k]))
        if k < n:
            delta[k + 1] = delta[k] + h * (cmd - delta[k]) / 1.0
        acting = delta[k - lag] if k >= lag else 0.0
        r_new = r + h * (K_TRUE * acting - r) / T_TRUE
        psi += 0.5 * h * (r + r_new)
        r = r_new
    t, psi_s, r_s, d_s = (np.array(c) for c in zip(*rows))
    rng = np.random.default_rng(seed)
    return {"t": t, "psi": psi_s + math.radians(0.2) * rng.standard_normal(t.size),
            "r": r_s + math.radians(0.05) * rng.standard_normal(t.size),
            "delta": d_s + math.radians(0.1) * rng.standard_normal(t.size)}


def _fit(log: dict[str, np.ndarray]):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "zigzag.csv"
        cols = ("t", "psi", "r", "delta")
        np.savetxt(path, np.column_stack([log[c] for c in cols]), delimiter=",", header=",".join(cols), comments="",
                   fmt="%.9g")
        trial = load_trial([path])
        segs = detect_segments(trial)
        fits = fit_trial(trial, segs, parse_vessel({"name": "first_order_ship"}), extend=False)
    assert [s.kind for s in segs.items if s.dof == "yaw"] == ["zigzag"]
    return fits


def test_a_delayed_response_is_fitted_and_k_and_t_cover_the_truth():
    fits = _fit(_zigzag_log(0))
    for key, truth in (("K", K_TRUE), ("T", T_TRUE)):
        est = fits.estimates[f"{key}_nomoto"]
        assert est.success, est.message
        assert "rudder-delay term" in est.message, est.message
        assert est.ci95[0] <= truth <= est.ci95[1], (key, est.value, est.stderr)
        assert abs(est.value / truth - 1) < 0.01, (key, est.value)
    sf = next(f for f in fits.segment_fits if f.segment.kind == "zigzag")
    note = next(p for p in sf.message.split("; ") if p.startswith(f"{RUDDER_DELAY_TERM} K: +-"))
    d, se = (float(x) for x in re.search(r"d = ([-+0-9.e]+) \+- ([0-9.e-]+) s", note).groups())
    assert abs(d - DELAY) < 3 * se and se < 0.1, note


def test_no_delay_keeps_k_and_t_near_the_truth():
    # Seeds 0-5 without a delay: z of K -0.8, -2.1, -0.4, -1.4, +0.9, +1.9 (one seed's 95 % interval may miss).
    fits = _fit(_zigzag_log(1, delay=0.0))
    for key, truth in (("K", K_TRUE), ("T", T_TRUE)):
        est = fits.estimates[f"{key}_nomoto"]
        assert est.success, est.message
        assert abs(est.value - truth) < 3 * est.stderr and abs(est.value / truth - 1) < 0.01, (key, est.value,
                                                                                                est.stderr)


def test_fractional_delay_moves_a_signal_and_keeps_the_noise_variance():
    n = 2000
    t = np.arange(n)
    x = np.sin(2 * np.pi * t / 200.0)
    y = fractional_delay(x, 0.5)
    ref = np.sin(2 * np.pi * (t - 0.5) / 200.0)
    assert np.max(np.abs(y[200:-200] - ref[200:-200])) < 2e-3
    noise = np.random.default_rng(0).standard_normal(n)
    half = fractional_delay(noise, 0.5)
    # A linear interpolation half-way would halve the variance; the all-pass keeps it.
    assert abs(np.var(half[50:-50]) / np.var(noise[50:-50]) - 1) < 0.1
    assert np.allclose(fractional_delay(x, 0.0), x)
    assert np.allclose(fractional_delay(x, 3.0)[3:-3], x[:-6], atol=1e-9)
