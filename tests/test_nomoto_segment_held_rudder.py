"""A measured rudder that jumps between samples: its mean over each sample interval (the fit's drive,
pipeline/fit/nomoto_segment.py) places the jump half-way through the interval, the expected moment of
a jump whose phase inside the interval is unknown. T is then unbiased when the jump does happen inside
the interval; a log whose rudder switches exactly at the sample instants (a held command with noise
added, as tests/test_fit_nomoto_structure.py's simulator writes it) gives T about h/2 high instead
(measured: +19 % at 1 Hz, +2.6 to +5.1 % at 5 Hz on this ship). A data-driven choice between the
two timings was tried and rejected: it chose the held timing on 4 of 6 mid-interval logs."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
import scipy.signal

from pipeline.model import discretise
from pipeline.model.nomoto import ORDER2_SUM_PRODUCT, nomoto_matrices, servo_response
from pipeline.records import Trial
from pipeline.segment import detect_segments

#: The second-order ship of tests/test_fit_nomoto_structure.py: K, T1 + T2, T1 T2, T3; T = 2.7 s.
SHIP2 = (0.09, 13.5, 64.0, 10.8)
T_EQ = 13.5 - 10.8

def _log(h, tau, seed, hold=90.0, levels=(0, 10, 0, -10, 0, 5, 0), mid=False):
    """Steps of the second-order ship; the rudder angle logged with 0.1 deg noise, moved by a servo of
    lag ``tau`` [s] or (``tau`` = 0) held from each sample on (``mid``: switched half a sample
    earlier, inside the interval); simulated on a 20x finer grid."""
    sub = 20
    cmd = np.concatenate([np.full(int(round(hold / h)), math.radians(v)) for v in levels])
    fine = np.repeat(cmd, sub)
    if mid:
        fine = np.r_[fine[sub // 2:], np.full(sub // 2, fine[-1])]
    d = servo_response(fine, h / sub, tau, math.inf) if tau > 0 else fine
    return log_of_rudder(d, ORDER2_SUM_PRODUCT, SHIP2, h, sub, seed, (0.1, 0.03, 0.1), "ship2")


def log_of_rudder(d, order, dyn, h, sub, seed, noise_deg, name):
    """The Nomoto ship (``order``, ``dyn``) driven by the rudder ``d`` [rad] held over each fine step of
    ``h / sub`` s (exact), logged every ``h`` s with heading, yaw-rate and rudder noise of ``noise_deg``
    [deg, deg/s, deg]."""
    a, b = nomoto_matrices(order, dyn)
    ad, bd = discretise.zoh(a, b, h / sub)
    k = a.shape[0]
    # States at the fine sample times, the rudder held over each fine step (exact).
    _, xs, _ = scipy.signal.dlsim((ad, bd, np.eye(k), np.zeros((k, 1)), h / sub), d, x0=np.zeros(k))
    rng = np.random.default_rng(seed)
    n = d.size // sub
    psi = xs[::sub, 0] + math.radians(noise_deg[0]) * rng.standard_normal(n)
    r = xs[::sub, 1] + math.radians(noise_deg[1]) * rng.standard_normal(n)
    delta = d[::sub] + math.radians(noise_deg[2]) * rng.standard_normal(n)
    data = pd.DataFrame({"t": np.arange(n) * h, "psi": (psi + np.pi) % (2 * np.pi) - np.pi, "r": r, "delta": delta})
    return Trial(name, data, 1 / h)

@pytest.mark.parametrize("h, seed", [(1.0, 1), (0.2, 2)])
def test_measured_rudder_jumping_inside_the_interval_gives_unbiased_t(h, seed):
    # Measured: T -0.5 % (z -0.19) at 1 Hz, -1.4 % (z -1.26) at 5 Hz. Driving the model with the rudder
    # held from each sample on instead would move every jump half a sample late: T -h/2 (-19 % at 1 Hz).
    from pipeline.fit import fit_trial
    from pipeline.vessel import parse_vessel

    trial = _log(h, 0.0, seed, mid=True)
    fits = fit_trial(trial, detect_segments(trial), parse_vessel({"name": "ship2"}), extend=False)
    k, t = fits.estimates["K_nomoto"], fits.estimates["T_nomoto"]
    assert any("mean over each sample interval" in sf.message for sf in fits.segment_fits)
    # At 1 Hz half a sample, 0.5 s, is 19 % of T: the jumps' unknown moments alone leave T unsure (ident25).
    assert k.success and (t.success or (h >= 1.0 and "jumps within its sample interval" in t.message)), t.message
    assert k.value == pytest.approx(SHIP2[0], rel=0.01)
    assert abs(t.value - T_EQ) < 2.5 * t.stderr, (t.value, t.stderr, t.message)
    assert t.value == pytest.approx(T_EQ, rel=0.03)
