"""A fast DOF logged slowly: its windows are too short for the data to measure its noise.

The twin's yaw at 1 Hz (T about 1 s) is cut into windows of a few samples each; the quarter contrast
of :func:`pipeline.diagnose.problem.block_noise` needs blocks of at least 8 samples, found none and
returned NaN, even where the vessel config states the sensor's noise: the DOF then had no noise
units, no held-out floor and no unexplained test (gaps of 0.03-0.07 in scale units). The stated
noise is now used alone there, and the report says the data could not measure it.
"""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.diagnose import problem
from pipeline.diagnose.problem import Window, block_average, block_noise


def _short_windows(n_windows: int, length: int, gap: int = 3) -> tuple[Window, ...]:
    out, i = [], 0
    for _ in range(n_windows):
        out.append(Window(i, i + length, float(i), float(i + length - 1), ("step",), ("yaw",)))
        i += length + gap
    return tuple(out)


@pytest.mark.parametrize("m", [1, 2])
def test_stated_noise_is_used_where_the_windows_are_too_short_to_measure_it(m):
    rng = np.random.default_rng(5)
    w = _short_windows(12, 7)  # 12 windows of 7 samples: no block of 8
    n = w[-1].i1 + 5
    sigma = 0.004
    x = rng.normal(0.0, sigma, n)
    got = block_noise(x, w, m, trapezoid=True, stated=sigma)
    assert got == pytest.approx(sigma * np.sqrt(m - 0.5) / m, rel=1e-9)
    # Without a stated noise nor the whole log the data cannot give it (with the whole log, see
    # tests/test_diagnose_floors_every_dof.py).
    assert not np.isfinite(block_noise(x, w, m, trapezoid=True, whole_log=False))
    assert not problem.noise_measurable(x, w, m)
    # Without the trapezoid weights a block mean of m white samples.
    assert block_noise(x, w, m, stated=sigma) == pytest.approx(sigma / np.sqrt(m), rel=1e-9)


def test_measurable_noise_keeps_the_smaller_of_data_and_stated():
    rng = np.random.default_rng(6)
    w = _short_windows(20, 40)
    n = w[-1].i1 + 5
    sigma = 0.004
    x = rng.normal(0.0, sigma, n)
    assert problem.noise_measurable(x, w, 2)
    data = block_noise(x, w, 2, trapezoid=True)
    measured = float(np.nanstd(block_average(x, w, 2, 20, trapezoid=True)))
    assert data == pytest.approx(measured, rel=0.25)
    # A stated noise ten times the sensor's does not raise the measured floor.
    assert block_noise(x, w, 2, trapezoid=True, stated=10 * sigma) == pytest.approx(data, rel=1e-9)


@pytest.mark.slow
def test_the_twins_yaw_at_1_hz_is_in_noise_units_from_the_stated_noise():
    """Randomised seed 42 r004 (the twin at 1.14 Hz, yaw T about 1 s, [sensor_noise] r and psi stated):
    the yaw's windows are too short for the data to measure its noise; the stated noise gives it."""
    from pipeline.diagnose.gridfit import grid_data
    from pipeline.diagnose.verdict import _stated_noise_notes
    from test_diagnose_floor_start import random_problem

    _, p = random_problem(42, 16, ("pair",), 4)
    assert p.stated_noise.get("r") and p.stated_noise.get("psi")
    d = grid_data(p)
    assert np.isfinite(d.sigma_y) and np.isfinite(d.sigma_angle)
    assert not problem.noise_measurable(p.raw["r"], p.windows, p.m)
    notes = _stated_noise_notes(p)
    assert any("cannot measure" in n and " r " in n for n in notes)
