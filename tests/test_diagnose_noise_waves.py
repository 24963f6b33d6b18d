"""The white noise floor where a wave of a dozen samples' period is in the data and no noise is stated
(:func:`pipeline.diagnose.problem.block_noise`): the quarter contrast spanning 8 samples took a heading
wave for noise (randomised seed 26 r014, a 1.4 Hz heading: 4 times the compass); the single samples'
third differences, which a wave that slow barely passes, cap it. Not cured: a wave of 6-8 samples'
period and an amplitude above twice the noise, which :func:`pipeline.diagnose.problem.noise_scale`
takes for noise correlated over 4 samples (a floor 5-7 times the compass' before and after)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.diagnose.problem import Window, block_average, block_noise


def _heading(n: int, period: float, amp: float, sigma: float, rng: np.random.Generator) -> np.ndarray:
    phase = np.cumsum(rng.normal(2 * np.pi / period, 0.05, n))
    return amp * np.sin(phase) + rng.normal(0.0, sigma, n) + 0.3 * np.sin(np.arange(n) / 500.0)


@pytest.mark.parametrize("period", [12.0, 16.0])
@pytest.mark.parametrize("m", [1, 2])
def test_a_wave_of_a_dozen_samples_is_not_the_noise_floor(period, m):
    rng = np.random.default_rng(int(period) + 10 * m)
    n = 20000
    x = _heading(n, period, 0.02, 0.006, rng)
    w = (Window(0, n, 0.0, n - 1.0, ("step",)),)
    white = 0.006 * np.sqrt((m - 0.5) / m) / np.sqrt(m)
    got = block_noise(x, w, m, trapezoid=True)
    # Before: 2.3-3.9 times the compass' white block mean.
    assert white <= got <= 1.5 * white


def test_white_noise_and_a_rising_spectrum_keep_their_floor():
    """The cap does not bind on white noise (the two estimates agree), nor where the third differences
    of 2-sample means rise above the single samples' (the noise is not white at the trial rate)."""
    rng = np.random.default_rng(4)
    n = 20000
    w = (Window(0, n, 0.0, n - 1.0, ("step",)),)
    x = rng.normal(0.0, 0.01, n) + 0.3 * np.sin(np.arange(n) / 500.0)
    for m in (1, 3, 11):
        measured = float(np.nanstd(block_average(x - 0.3 * np.sin(np.arange(n) / 500.0), w, m, n // m,
                                                 trapezoid=True)[0]))
        assert block_noise(x, w, m, trapezoid=True) == pytest.approx(measured, rel=0.1)
    walk = 1e-2 * np.cumsum(np.cumsum(rng.normal(0.0, 1.0, n))) + rng.normal(0.0, 0.002, n)
    from pipeline.diagnose import problem

    s1, s2 = (problem._third_difference_level(walk, w, q) for q in (1, 2))
    assert s2 > problem.WHITE_RATIO * s1
    mb = 8
    c = problem._contrasts(walk, w, 2, mb)
    contrast = problem._robust_sd(c) / 4.0 * np.sqrt(8) * np.sqrt(0.5)
    assert block_noise(walk, w, 1, trapezoid=True) >= 0.99 * contrast
