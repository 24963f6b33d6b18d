"""Channels measured slower than the grid: the Trial keeps their real sample times, and the
first-order fits use only those (not the values interpolated between them); GNSS fixes held by a
logger are told apart by the logger's own fix time; commands stamped a hair after a grid point."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from pipeline.align import align
from pipeline.fit.first_order import fit_coast_down
from pipeline.flow import load_trial
from pipeline.ingest.csv_log import read_csv_log
from pipeline.records import Channel, IngestSummary, RawLog, Segment

T_SWAY = 0.4  # s: two 5 Hz fix intervals, where linear interpolation between fixes is worst


def _log(fix_hz: float = 5.0, grid_hz: float = 10.0) -> RawLog:
    """A coast-down in u measured by GNSS at ``fix_hz`` next to an IMU at ``grid_hz`` (noise-free)."""
    t_imu = np.arange(0.0, 6.0 + 1e-9, 1.0 / grid_hz)
    t_fix = np.arange(0.0, 6.0 + 1e-9, 1.0 / fix_hz)
    u = lambda t: np.where(t < 1.0, 1.0, np.exp(-(t - 1.0) / T_SWAY))  # noqa: E731
    chans = {"psi": Channel("psi", t_imu, np.zeros_like(t_imu)), "r": Channel("r", t_imu, np.zeros_like(t_imu)),
             "sog": Channel("sog", t_fix, u(t_fix)), "cog": Channel("cog", t_fix, np.zeros_like(t_fix))}
    return RawLog("gnss_imu", "sim", chans, IngestSummary("gnss_imu", "sim"))


def test_the_trial_keeps_the_real_fix_times_of_slow_channels_and_of_u_v_derived_from_them():
    trial = align([_log()], fs=10.0)
    assert trial.fs == 10.0
    for ch in ("sog", "cog", "u", "v"):
        np.testing.assert_allclose(trial.sample_times[ch], np.arange(0.0, 6.0 + 1e-9, 0.2), atol=1e-12)
    assert "r" not in trial.sample_times and "psi" not in trial.sample_times
    rows = trial.measured_rows("u", trial.t)
    assert rows.sum() == 31 and rows[::2].all() and not rows[1::2].any()
    assert trial.measured_rows("r", trial.t).all()
    assert any("measured slower than the grid" in n and "u 31 samples" in n for n in trial.notes)


def test_a_fix_between_grid_points_marks_the_nearer_one():
    log = _log()
    sog = log.channels["sog"]
    log.channels["sog"] = Channel("sog", sog.t + 0.03, sog.values)
    log.channels["cog"] = Channel("cog", sog.t + 0.03, log.channels["cog"].values)
    trial = align([log], fs=10.0)
    rows = trial.measured_rows("sog", trial.t)
    # Fixes at 0.03, 0.23, ... (grid from 0 at 10 Hz): the nearer grid points are 0.0, 0.2, ...
    assert rows[::2].sum() == rows.sum() >= 30


def test_first_order_fit_uses_only_the_real_fixes():
    """Noise-free: on the real fixes T is exact; with the chords between them it would be longer."""
    trial = align([_log()], fs=10.0)
    seg = Segment("coast_down", "surge", 1.0, 6.0)
    fit = fit_coast_down(trial, seg)
    assert fit.success
    assert fit.params["T"] == pytest.approx(T_SWAY, rel=1e-6)
    assert "interpolated between its real measurements" in fit.message and "25 of 51 samples of u" in fit.message
    # The same data with every grid sample taken as a measurement: the chords lengthen T.
    from dataclasses import replace

    chords = fit_coast_down(replace(trial, sample_times={}), seg)
    assert chords.params["T"] > T_SWAY * 1.005


def test_a_csv_fix_time_column_tells_held_copies_from_new_fixes(tmp_path):
    """10 Hz rows, a 5 Hz fix held two rows: the values alone cannot tell (a boat at rest repeats
    too); the logger's own fix time can."""
    t = np.arange(0.0, 4.0 + 1e-9, 0.1)
    fix_t = np.floor(t * 5 + 1e-9) / 5
    df = pd.DataFrame({"t": t, "r": 0.01 * t, "psi": 0.1 * t, "t_fix_ms": fix_t * 1000,
                       "lat": 57.0 + 1e-6 * fix_t, "lon": 10.0 + 1e-6 * fix_t, "sog": 1.0 + 0.1 * fix_t,
                       "cog": 0.1 * fix_t})
    path = tmp_path / "held.csv"
    df.to_csv(path, index=False, float_format="%.10g")
    log = read_csv_log(path)
    for n in ("lat", "lon", "sog", "cog"):
        np.testing.assert_allclose(log.channels[n].t, np.arange(0.0, 4.0 + 1e-9, 0.2), atol=1e-9)
    assert len(log.channels["r"].t) == 41
    assert any("'t_fix_ms' gives the fix time of each row: 21 fixes in 41 rows" in w for w in log.summary.warnings)
    trial = load_trial([path])
    np.testing.assert_allclose(trial.sample_times["u"], np.arange(0.0, 4.0 + 1e-9, 0.2), atol=1e-9)
    # Without the column nothing is dropped (two rows per fix are not recognised from values).
    log2 = read_csv_log(path, columns={"t_fix_ms": "not_a_channel"})
    assert len(log2.channels["sog"].t) == 41


def test_a_command_stamped_a_microsecond_after_a_grid_point_acts_at_that_grid_point():
    """ISO times keep microseconds: a command at 1.0000004 s is the 1.0 s command, not the 1.1 s one."""
    t = np.arange(0.0, 3.0 + 1e-9, 0.1)
    delta_t = t + 4e-7
    log = RawLog("a", "sim", {"r": Channel("r", t, np.zeros_like(t)),
                              "delta": Channel("delta", delta_t, np.where(delta_t > 1.0, 0.2, 0.0))},
                 IngestSummary("a", "sim"))
    trial = align([log], offsets={})
    d = trial.data.set_index("t")["delta"]
    assert d.iloc[10] == 0.2 and d.iloc[9] == 0.0
    assert math.isclose(trial.t[10], 1.0)


def test_a_time_constant_shorter_than_the_sample_interval_is_not_identified():
    """A 0.4 s response sampled at 2 Hz settles between two samples: refused, not a confident T."""
    t = np.arange(0.0, 20.0 + 1e-9, 0.5)
    rng = np.random.default_rng(3)
    u = np.where(t < 1.0, 1.0, np.exp(-(t - 1.0) / T_SWAY)) + rng.normal(0, 0.005, t.size)
    log = RawLog("slow", "sim", {"u": Channel("u", t, u), "r": Channel("r", t, np.zeros_like(t))},
                 IngestSummary("slow", "sim"))
    fit = fit_coast_down(align([log], fs=2.0), Segment("coast_down", "surge", 1.0, 20.0))
    assert not fit.success and "time constant not resolved" in fit.message
    # At 10 Hz the same response is resolved.
    t10 = np.arange(0.0, 20.0 + 1e-9, 0.1)
    u10 = np.where(t10 < 1.0, 1.0, np.exp(-(t10 - 1.0) / T_SWAY)) + rng.normal(0, 0.005, t10.size)
    log10 = RawLog("fast", "sim", {"u": Channel("u", t10, u10), "r": Channel("r", t10, np.zeros_like(t10))},
                   IngestSummary("fast", "sim"))
    assert fit_coast_down(align([log10], fs=10.0), Segment("coast_down", "surge", 1.0, 20.0)).success


def test_held_fixes_without_a_fix_time_column_are_one_fix_each_at_their_first_row(tmp_path):
    """10 Hz rows, a 5 Hz fix held two rows and no t_fix column: every fix appears in two rows while
    the boat moves, so the repeats are held copies; each fix is kept once, at the row it appeared."""
    t = np.arange(0.0, 4.0 + 1e-9, 0.1)
    fix_t = np.floor(t * 5 + 1e-9) / 5
    df = pd.DataFrame({"t": t, "r": 0.01 * t, "psi": 0.1 * t, "lat": 57.0 + 1e-6 * fix_t,
                       "lon": 10.0 + 1e-6 * fix_t, "sog": 1.0 + 0.1 * fix_t, "cog": 0.1 * fix_t})
    path = tmp_path / "held.csv"
    df.to_csv(path, index=False, float_format="%.10g")
    trial = load_trial([path])
    np.testing.assert_allclose(trial.sample_times["u"], np.arange(0.0, 4.0 + 1e-9, 0.2), atol=1e-9)
    assert any("41 rows hold 21 fixes" in n and "receiver's clock (period 0.2 s" in n for n in trial.notes)


def test_fix_times_follow_the_receiver_clock_when_it_is_not_a_whole_number_of_rows():
    """A 4 Hz receiver (fixes at 0.03 + 0.25 j s) in 10 Hz rows: a fix first appears up to one row
    late (0.07 or 0.02 s); the receiver's clock bounds the phase to a fraction of a row."""
    from pipeline.align.gnss import fix_times, is_held

    rows = np.arange(0.0, 30.0, 0.1)
    fixes = np.arange(0.03, 29.8, 0.25)
    first = np.zeros(rows.size, bool)
    first[np.searchsorted(rows, fixes - 1e-9)] = True
    assert is_held(first)
    est, how = fix_times(rows, first)
    first_rows = rows[first]
    assert np.max(np.abs(first_rows - fixes)) > 0.06
    # The latest phase the rows allow is 0.02 s late here (fixes at .03/.08 s past a row may all move
    # 0.02 s and still appear in the same rows): within that, against up to 0.07 s for the first rows.
    assert np.max(np.abs(est - fixes)) < 0.021 and np.all(est <= first_rows + 1e-9)
    assert "receiver's clock (period 0.2500" in how or "receiver's clock (period 0.2499" in how


def test_repeats_only_at_rest_are_not_held_fixes():
    """Quantised position and zero speed repeat while a boat rests; while it moves every sample is new."""
    from pipeline.align.gnss import is_held

    new = np.ones(300, bool)
    new[100:180] = False  # 80 s at rest: one long run
    new[100] = True
    assert not is_held(new)
    # Two rows per fix throughout: held.
    assert is_held(np.tile([True, False], 150))
