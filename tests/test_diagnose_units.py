"""The diagnosis' building blocks against reference answers: the exact ZOH discretisation against
RK4 of the shared Nomoto right-hand side, input transforms against the simulator's own effects,
the block-noise estimate, the wave-spectrum fit, the report record's JSON."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from pipeline.diagnose.candidates import delay_input, rate_limit
from pipeline.diagnose.gridfit import GridData, LinearSpec, predict_linear, solve_linear
from pipeline.model.first_order_blocks import effective_forcing
from pipeline.diagnose.problem import Window, block_average, block_noise, input_moments
from pipeline.records import CandidateResult, EffectParam, GapReport
from pipeline.diagnose.waves import fit_residual_spectrum, smooth_waves
from pipeline.model import integrate_rk4
from pipeline.model.nomoto import NomotoParams, nomoto_rhs
from pipeline.model.waves import WaveParams, simulate_waves
from pipeline.sim.effects import apply_delay, apply_rate_limit


def _grid(y: np.ndarray, psi: np.ndarray, u: np.ndarray, m: int, h: float) -> GridData:
    """One window covering the whole record, on blocks of ``m`` samples of ``h`` seconds."""
    w = (Window(0, len(y), 0.0, (len(y) - 1) * h, ("step",), ("yaw",)),)
    n = len(y) // m
    yb = block_average(y, w, m, n, trapezoid=True)
    pb = block_average(psi, w, m, n, trapezoid=True)
    return GridData(dt=m * h, y=yb, y0=np.array([y[0]]), angle=pb, mask=np.isfinite(yb),
                    forcing={"delta": input_moments(u, w, m, n)}, m=m)


def test_zoh_model_matches_rk4_of_the_nomoto_rhs():
    # A rudder programme that switches inside analysis blocks (as a zig-zag does).
    h, m = 0.02, 13
    t = np.arange(0, 60, h)
    u = np.where((t > 3.01) & (t < 17.37), 0.17, 0.0) - np.where(t > 31.13, 0.1, 0.0)
    k, tc = 0.5, 5.0
    x = integrate_rk4(nomoto_rhs, np.array([0.3, 0.02]), t, u[:, None], NomotoParams(K=k, T=tc), substeps=4)
    d = _grid(x[:, 1], x[:, 0], u, m, h)
    out = predict_linear(d, LinearSpec(("delta",)), tc, np.array([k]))
    scale = np.max(np.abs(x[:, 1]))
    assert np.nanmax(np.abs(out["y"] - d.y)) < 1e-5 * scale
    assert np.nanmax(np.abs(out["angle"] - d.angle)) < 2e-4 * scale * tc
    theta, sse = solve_linear(d, LinearSpec(("delta",)), tc)
    assert abs(theta[0] - k) < 1e-4 and sse < 1e-6


def test_effective_forcing_of_a_constant_input_is_exact():
    f = np.ones((3, 1, 4))
    m = 10
    lag = m - 1 - np.arange(m)
    f[0], f[1], f[2] = m, lag.sum(), (lag**2).sum()
    fs, fm = effective_forcing(f, 0.7, 0.1, m)
    np.testing.assert_allclose(fs, 1.0, rtol=1e-12)
    np.testing.assert_allclose(fm, 1.0, rtol=1e-12)


def test_delay_and_rate_limit_match_the_simulator_effects():
    rng = np.random.default_rng(1)
    u = np.repeat(rng.uniform(-1, 1, 12), 37)
    fs = 50.0
    steps = 9
    ref = np.array([apply_delay(u[:, None], k, steps)[0] for k in range(len(u))])
    np.testing.assert_allclose(delay_input(u, steps / fs, fs), ref)
    rate = 2.0
    lim = np.empty_like(u)
    prev = np.array([u[0]])
    for k in range(len(u)):
        prev = apply_rate_limit(prev, u[k:k + 1], np.array([rate / fs])) if k else prev
        lim[k] = prev[0]
    np.testing.assert_allclose(rate_limit(u, rate, fs), lim, atol=1e-12)


def test_block_noise_of_white_noise_on_a_ramp():
    rng = np.random.default_rng(3)
    n, m, sigma = 40000, 16, 0.01
    x = np.linspace(0, 5, n) + sigma * rng.standard_normal(n)
    w = (Window(0, n, 0.0, 1.0, ("step",)),)
    assert block_noise(x, w, m) == pytest.approx(sigma / math.sqrt(m), rel=0.1)


def test_wave_spectrum_fit_and_smoother_recover_a_wave():
    rng = np.random.default_rng(4)
    dt = 0.25
    t = np.arange(0, 400, dt)
    wave = simulate_waves(t, WaveParams(omega0=1.5, lam=0.1, kw=2 * 0.1 * 1.5 * 0.05), rng)
    noise = 0.002 * rng.standard_normal(len(t))
    rows = (wave + noise).reshape(8, -1)
    spec = fit_residual_spectrum(rows, dt, (0.3, 6.0))
    assert spec.omega0 == pytest.approx(1.5, rel=0.1)
    est = smooth_waves(rows, dt, spec)
    before = np.sqrt(np.mean(rows**2))
    after = np.sqrt(np.mean((rows - est) ** 2))
    assert after < 0.4 * before
    # White noise alone: no wave is claimed.
    null = fit_residual_spectrum(noise.reshape(8, -1), dt, (0.3, 6.0))
    assert null.sigma == 0.0 or np.nanmax(np.abs(smooth_waves(noise.reshape(8, -1), dt, null))) < 0.5 * 0.002


def test_report_json_is_strict_and_has_the_contract():
    c = CandidateResult("waves", "yaw", "waves", None, 3.0, math.nan, math.nan, math.nan, 1.0, False,
                        (EffectParam("omega0", math.nan, math.inf, "rad/s"),))
    rep = GapReport("t", "v", None, None, 2.0, 2.0, (c,))
    doc = json.loads(json.dumps(rep.to_dict(), allow_nan=False))
    assert doc["verdict"] == {"effect": None, "dof": None}
    assert doc["candidates"][0]["gap_after"] is None
    assert doc["candidates"][0]["params"]["omega0"] == {"value": None, "stderr": None, "unit": "rad/s"}
