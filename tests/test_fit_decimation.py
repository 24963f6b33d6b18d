"""Decimation of the joint damping fit's records: logged samples kept, inputs keep their impulse."""

from __future__ import annotations

import numpy as np

from pipeline.fit.quadratic import DofRecord, decimate_records, interval_mean, logged_phase


def test_interval_mean_keeps_the_impulse_of_a_cut_between_kept_samples():
    u = np.r_[np.full(1, 76.0), np.zeros(9)]  # thrust cut one sample after the record starts
    out = interval_mean(u, 2)
    assert out.size == 5
    assert out[0] == 38.0 and np.all(out[1:] == 0.0)
    assert interval_mean(u, 2).sum() * 2 == u.sum()
    assert np.array_equal(interval_mean(np.arange(5.0), 2), [0.5, 2.5, 4.0])  # last interval padded with its value


def test_logged_phase_finds_the_logged_samples_of_an_interpolated_channel():
    rng = np.random.default_rng(0)
    logged = 1.0 + 0.01 * rng.standard_normal(400)
    grid = np.empty(799)
    grid[0::2] = logged
    grid[1::2] = 0.5 * (logged[:-1] + logged[1:])  # 2x linear interpolation
    for start in (0, 1):
        j, sigma = logged_phase(grid[start:], 2, 1.0)
        assert (start + j) % 2 == 0, start
        assert 0.007 < sigma < 0.013
    # A channel logged at the trial rate has no such contrast: offset 0.
    j, sigma = logged_phase(1.0 + 0.01 * rng.standard_normal(800), 2, 1.0)
    assert j == 0 and 0.007 < sigma < 0.013


def test_decimated_records_start_on_logged_samples_with_equal_noise_levels():
    rng = np.random.default_rng(1)
    logged = 0.01 * rng.standard_normal(1000)
    grid = np.interp(np.arange(1999) / 2.0, np.arange(1000), logged)
    recs = [DofRecord(f"r{s}", "coast_down", np.exp(-np.arange(700) / 300.0) + grid[s:s + 700],
                      {"tau_x": np.zeros(700)}, 0.001, "rate", "u") for s in (10, 11)]
    out, dt, k = decimate_records(recs, 0.01, "surge")
    assert k == 2 and dt == 0.02
    assert [r.offset for r in out] == [0, 1]
    assert abs(out[0].sigma / out[1].sigma - 1) < 0.2
    assert out[1].y.size == out[1].inputs["tau_x"].size
