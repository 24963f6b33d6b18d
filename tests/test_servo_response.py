"""The rate-limited servo (pipeline.model.nomoto.servo_response) against the scalar Euler loop it replaced."""

import math

import numpy as np
import pytest

from pipeline.model.nomoto import servo_response


def reference_servo(delta_c, h, t_servo, rate_max=math.inf, delta0=None, substeps=40):
    """The previous implementation, written as the plain loop (the definition of the recursion)."""
    u = np.asarray(delta_c, float)
    d = float(u[0] if delta0 is None else delta0)
    lim = rate_max if rate_max > 0 else math.inf
    if t_servo > 0:
        a = math.exp(-h / t_servo)
        start = np.empty(u.size)
        start[0] = d
        for k in range(1, u.size):
            start[k] = a * start[k - 1] + (1 - a) * u[k - 1]
        if not np.isfinite(lim) or float(np.max(np.abs(u - start))) <= lim * t_servo:
            return None  # linear path: not the loop under test
    dt = h / substeps
    out = np.empty(u.size)
    lag = t_servo if t_servo > 2 * dt else 0.0
    for k, uk in enumerate(u):
        acc = 0.0
        for _ in range(substeps):
            err = uk - d
            rate = err / lag if lag else (err / dt if abs(err) < lim * dt else math.copysign(lim, err))
            rate = min(max(rate, -lim), lim)
            d_new = d + dt * rate
            acc += 0.5 * (d + d_new)
            d = d_new
        out[k] = acc / substeps
    return out


@pytest.mark.parametrize("seed", range(6))
def test_rate_limited_servo_is_bit_identical_to_the_loop(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(50, 5000))  # spans more than one compiled chunk at the top end
    h = float(rng.choice([0.02, 0.05, 0.1]))
    # Steps, ramps and noise in the command, as a zig-zag with jitter.
    u = np.repeat(rng.uniform(-0.6, 0.6, size=n // 25 + 1), 25)[:n] + 0.01 * rng.normal(size=n)
    t_servo = float(rng.choice([0.0, 1e-4, 0.1, 0.5, 2.0]))
    rate = float(rng.uniform(0.05, 0.5))
    substeps = int(rng.choice([1, 7, 40]))
    delta0 = None if seed % 2 else float(rng.uniform(-0.3, 0.3))
    ref = reference_servo(u, h, t_servo, rate, delta0, substeps)
    if ref is None:
        pytest.skip("command slow enough for the linear path")
    new = servo_response(u, h, t_servo, rate, delta0, substeps)
    assert new.shape == ref.shape
    assert np.array_equal(new, ref), float(np.max(np.abs(new - ref)))


def test_pure_rate_limiter_and_chunk_boundary():
    rng = np.random.default_rng(11)
    u = np.sign(np.sin(np.arange(9000) * 0.01)) * 0.4 + 0.001 * rng.normal(size=9000)
    ref = reference_servo(u, 0.02, 0.0, 0.2)
    new = servo_response(u, 0.02, 0.0, 0.2)
    assert np.array_equal(new, ref)
    # The rate limit acts: the servo lags a step by 0.4 / 0.2 = 2 s; the mean angle never jumps.
    assert np.max(np.abs(np.diff(new))) <= 0.2 * 0.02 + 1e-12


def test_linear_lag_path_unchanged():
    u = np.r_[np.zeros(10), np.full(200, 0.1)]
    out = servo_response(u, 0.1, 0.5, math.inf)
    a = math.exp(-0.1 / 0.5)
    assert out[-1] == pytest.approx(0.1, abs=1e-6)
    assert out[10] == pytest.approx(0.1 + (0.0 - 0.1) * (0.5 / 0.1) * (1 - a))
