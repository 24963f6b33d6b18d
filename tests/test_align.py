"""align: raw logs -> one uniform clock; input hold, angle wrap, gaps, derived body velocity and
position, clock offsets, errors; Hypothesis properties of the resampler.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pipeline.align import align
from pipeline.align.align import MAX_DEFAULT_RATE
from pipeline.align.resample import find_gaps, resample_channel
from pipeline.errors import AlignError
from pipeline.records import Channel, Gap, IngestSummary, RawLog
from pipeline.sim import chain, default_sensors, simulate
from pipeline.sim.manoeuvres import Manoeuvre
from pipeline.sim.sensors import SensorSpec
from pipeline.vessel import load_vessel

from conftest import AAUSHIP  # noqa: E402 - the vessel, loaded once per session


def _log(source, **channels):
    """A RawLog from name=(t, values) pairs."""
    chans = {n: Channel(n, np.asarray(t, float), np.asarray(v, float), source) for n, (t, v) in channels.items()}
    return RawLog(source, "sim", chans, IngestSummary(source, "sim"))


def _turn():
    """Surge and sway thrust throughout, a yaw moment from 10 s: a drifting turn (v != 0, psi sweeps)."""
    return Manoeuvre("drifting turn", 40.0, ("tau_x", "tau_y", "tau_n"),
                     lambda t, x: {"tau_x": 4.0, "tau_y": 3.0, "tau_n": 0.05 if t >= 10.0 else 0.0})


@pytest.fixture(scope="module")
def sim():
    return simulate(AAUSHIP, chain(_turn(), rest_s=2.0), seed=4)


def _truth_on(sim, trial, col):
    return np.interp(trial.t, sim.truth["t"].to_numpy(), sim.truth[col].to_numpy())


# --------------------------------------------------------------------------- grid
def test_single_log_uniform_grid_at_fastest_rate(sim):
    trial = align([sim.log], name="turn")
    assert trial.name == "turn" and trial.fs == 100.0
    t = trial.t
    assert t[0] == 0.0
    np.testing.assert_allclose(np.diff(t), 0.01, rtol=0, atol=1e-9)
    t_end = sim.truth["t"].iloc[-1]
    assert len(t) == int(round(t_end * 100)) + 1
    assert trial.sources == (sim.log.source,) and trial.summaries == (sim.log.summary,)
    # Every channel of the log is a column; canonical ones first, in CHANNEL_UNITS order.
    assert set(sim.log.channels) <= set(trial.data.columns)
    assert list(trial.data.columns[:4]) == ["t", "u", "v", "p"]
    np.testing.assert_allclose(trial.data["r"].to_numpy(), sim.log.channels["r"].values, atol=1e-12)


def test_fastest_state_sets_rate_inputs_do_not():
    t20, t5, t50 = np.arange(0, 10.001, 0.05), np.arange(0, 10.001, 0.2), np.arange(0, 10.001, 0.02)
    trial = align([_log("a", r=(t20, np.sin(t20)), sog=(t5, 1 + 0 * t5), delta=(t50, 0 * t50))])
    assert trial.fs == pytest.approx(20.0)
    fast = np.arange(0, 2.0, 1 / 400)
    assert align([_log("b", r=(fast, 0 * fast))]).fs == MAX_DEFAULT_RATE
    assert align([_log("c", r=(t20, 0 * t20))], fs=7.0).fs == 7.0


# --------------------------------------------------------------------------- hold and wrap
def test_inputs_are_held_and_states_interpolated():
    t = np.arange(0.0, 3.0001, 0.1)
    step = np.where(t >= 1.0 - 1e-9, 0.1, 0.0)
    trial = align([_log("a", delta=(t, step), r=(t, step))], fs=100.0)
    tg, delta, r = trial.t, trial.data["delta"].to_numpy(), trial.data["r"].to_numpy()
    # A step stays a step: only the two levels, switching at the command time.
    assert set(np.unique(delta)) == {0.0, 0.1}
    np.testing.assert_array_equal(delta, np.where(tg >= 1.0 - 1e-9, 0.1, 0.0))
    # A state between samples is interpolated (the ramp from 0.9 to 1.0 s).
    mid = np.argmin(np.abs(tg - 0.95))
    assert r[mid] == pytest.approx(0.05)


def test_angles_interpolate_across_the_wrap():
    t = np.arange(0.0, 4.0001, 1.0)
    psi = np.array([3.0, 3.1, -3.1, -3.0, -2.9])
    trial = align([_log("a", psi=(t, psi))], fs=10.0)
    out = trial.data["psi"].to_numpy()
    # Between 3.1 and -3.1 the heading goes the short way, through +-pi, never through 0.
    assert np.all(np.abs(out) > 2.85)
    unwrapped = np.interp(trial.t, t, np.unwrap(psi))
    np.testing.assert_allclose(np.angle(np.exp(1j * (out - unwrapped))), 0.0, atol=1e-12)
    assert np.all((out > -np.pi) & (out <= np.pi))
    assert out[15] == pytest.approx(np.angle(np.exp(1j * (3.1 + 0.5 * (2 * np.pi - 6.2)))), abs=1e-12)


# --------------------------------------------------------------------------- gaps
def test_deleted_chunk_is_a_gap_with_nan_inside(sim):
    r = sim.log.channels["r"]
    keep = (r.t < 20.0) | (r.t > 23.0)
    chans = dict(sim.log.channels)
    chans["r"] = Channel("r", r.t[keep], r.values[keep], r.source)
    trial = align([RawLog("gappy", "sim", chans, sim.log.summary)])
    (gap,) = trial.gaps
    assert gap == Gap("r", pytest.approx(19.99), pytest.approx(23.01))
    t, rr = trial.t, trial.data["r"].to_numpy()
    inside = (t > gap.t_start) & (t < gap.t_end)
    assert inside.sum() == 301 and np.all(np.isnan(rr[inside]))
    assert np.all(np.isfinite(rr[~inside]))
    assert np.all(np.isfinite(trial.data["p"].to_numpy()))  # other channels untouched
    assert any("1 dropout(s): r 19.99-23.01 s" in n for n in trial.notes)


def test_gap_threshold():
    t = np.concatenate([np.arange(0, 5, 0.1), np.arange(5.4, 10, 0.1)])
    ch = Channel("r", t, np.zeros(len(t)))
    assert find_gaps(ch) == ()  # 0.5 s is the floor of the default threshold
    (g,) = find_gaps(ch, threshold=0.3)
    assert (g.t_start, g.t_end) == (pytest.approx(4.9), pytest.approx(5.4))
    trial = align([_log("a", r=(t, np.ones(len(t))))], gap_threshold=0.3)
    assert len(trial.gaps) == 1 and np.isnan(trial.data["r"].to_numpy()[(trial.t > 4.95) & (trial.t < 5.35)]).all()


# --------------------------------------------------------------------------- derived channels
def test_derived_body_velocity_matches_truth(sim):
    assert "u" not in sim.log.channels and "v" not in sim.log.channels
    trial = align([sim.log])
    u, v = trial.data["u"].to_numpy(), trial.data["v"].to_numpy()
    tu, tv = _truth_on(sim, trial, "u"), _truth_on(sim, trial, "v")
    moving = np.hypot(tu, tv) > 0.3
    assert moving.sum() > 3000 and np.max(np.abs(tv[moving])) > 0.08  # there is sway to find
    # Noise: sog 0.005 m/s per NED component, heading 0.002 rad at ~1.4 m/s.
    err_u, err_v = u[moving] - tu[moving], v[moving] - tv[moving]
    assert np.sqrt(np.mean(err_u**2)) < 0.008 and np.sqrt(np.mean(err_v**2)) < 0.008
    assert abs(np.mean(err_u)) < 0.002 and abs(np.mean(err_v)) < 0.002
    assert np.max(np.abs(err_u)) < 0.04 and np.max(np.abs(err_v)) < 0.04
    # The 50 Hz navigation velocity is used, not the 10 Hz raw GPS one.
    assert any(n.startswith("u, v over ground from sog, cog ") and "heading psi" in n for n in trial.notes)


def test_derived_position_from_lat_lon(sim):
    trial = align([sim.log])
    xn, ye = trial.data["x_n"].to_numpy(), trial.data["y_e"].to_numpy()
    tx, ty = _truth_on(sim, trial, "x_n"), _truth_on(sim, trial, "y_e")
    assert np.ptp(tx) > 15 and np.ptp(ty) > 5
    # The navigation filter's position is noise-free: only flat-earth and float error remain.
    np.testing.assert_allclose(xn, tx, atol=2e-3)
    np.testing.assert_allclose(ye, ty, atol=2e-3)


def test_derived_position_from_raw_gps_within_its_noise(sim):
    chans = {n: c for n, c in sim.log.channels.items() if n not in ("lat", "lon")}
    trial = align([RawLog("gps only", "sim", chans, sim.log.summary)])
    on_fix = np.isclose((trial.t * 10) % 1, 0, atol=1e-6) | np.isclose((trial.t * 10) % 1, 1, atol=1e-6)
    for col in ("x_n", "y_e"):
        err = trial.data[col].to_numpy()[on_fix] - _truth_on(sim, trial, col)[on_fix]
        # 0.3 m per axis; the origin is the first (noisy) fix, so the whole track is offset by it.
        assert np.std(err) == pytest.approx(0.3, rel=0.15)
        assert abs(np.mean(err)) < 1.3
    assert any("lat@gps/lon@gps" in n for n in trial.notes)


def test_logged_body_velocity_is_not_overwritten():
    t = np.arange(0, 5, 0.1)
    log = _log("a", u=(t, np.full(len(t), 1.0)), v=(t, np.zeros(len(t))), sog=(t, np.full(len(t), 3.0)),
               cog=(t, np.zeros(len(t))), psi=(t, np.full(len(t), 1.0)))
    trial = align([log])
    np.testing.assert_array_equal(trial.data["u"].to_numpy(), 1.0)
    assert not any("over ground" in n for n in trial.notes)


# --------------------------------------------------------------------------- several logs
def test_two_logs_with_a_clock_offset(sim):
    imu = {n: sim.log.channels[n] for n in ("p", "q", "r", "ax", "ay", "az", "tau_x", "tau_y", "tau_n")}
    nav_names = ("psi", "phi", "theta", "lat", "lon", "sog", "cog", "r")
    # The second logger's clock reads 100 s more than the trial clock.
    nav = {n: Channel(n, sim.log.channels[n].t + 100.0, sim.log.channels[n].values, "nav") for n in nav_names}
    a = RawLog("autopilot.csv", "csv", imu, IngestSummary("autopilot.csv", "csv"))
    b = RawLog("nav.csv", "csv", nav, IngestSummary("nav.csv", "csv"))
    trial = align([a, b], offsets={"nav.csv": -100.0})
    assert trial.t[-1] == pytest.approx(sim.truth["t"].iloc[-1], abs=1e-9)
    assert trial.sources == ("autopilot.csv", "nav.csv")
    assert "nav.csv: clock offset -100.000 s applied" in trial.notes
    # The duplicate yaw rate is kept under its own name, and both agree once on one clock.
    dup = [c for c in trial.data.columns if c.startswith("r@")]
    assert len(dup) == 1 and any(f"kept as {dup[0]}" in n for n in trial.notes)
    np.testing.assert_allclose(trial.data[dup[0]].to_numpy(), trial.data["r"].to_numpy(), atol=1e-12)
    u = trial.data["u"].to_numpy()
    tu = _truth_on(sim, trial, "u")
    assert np.sqrt(np.mean((u - tu) ** 2)) < 0.01
    # With offsets={} (the logs declared to share a clock) they sit 100 s apart: a trial 100 s
    # longer, no overlap. (The default, offsets="auto", would find the offset: test_align_multi.)
    apart = align([a, b], offsets={})
    assert apart.t[-1] == pytest.approx(trial.t[-1] + 100.0, abs=1e-9)
    assert np.isnan(apart.data["psi"].to_numpy()[apart.t < 99.0]).all()


# --------------------------------------------------------------------------- errors
def test_align_errors():
    with pytest.raises(AlignError, match=r"align: expected at least one log, found none"):
        align([])
    bad = _log("bad.csv", r=([0.0, 0.1, 0.1, 0.2], [0, 0, 0, 0]))
    with pytest.raises(AlignError, match=r"bad.csv: channel 'r': expected strictly increasing time, found a step "
                                         r"back at t = 0.100000 s"):
        align([bad])
    back = _log("back.csv", r=([0.0, 0.2, 0.1], [0, 0, 0]))
    with pytest.raises(AlignError, match=r"step back at t = 0.100000 s"):
        align([back])
    empty = _log("empty.csv", r=([], []))
    with pytest.raises(AlignError, match=r"expected channels with samples, found none in \['empty.csv'\]"):
        align([empty])
    ok = _log("ok.csv", r=([0.0, 0.1], [0, 0]))
    with pytest.raises(AlignError, match=r"expected a positive sample rate \[Hz\], found -1"):
        align([ok], fs=-1.0)


# --------------------------------------------------------------------------- properties
@st.composite
def _held_input(draw):
    """Sample ticks [ms], piecewise-constant levels (often repeated), grid ticks [0.1 ms]."""
    ks = np.array(sorted(draw(st.sets(st.integers(0, 100_000), min_size=1, max_size=25))))
    palette = draw(st.lists(st.floats(-1e3, 1e3, allow_nan=False), min_size=1, max_size=4))
    levels = np.array([palette[draw(st.integers(0, len(palette) - 1))] for _ in ks])
    grid = np.array(sorted(draw(st.sets(st.integers(-20_000, 1_020_000), min_size=1, max_size=60))
                           | set((ks * 10).tolist()[:5])))
    return ks, levels, grid


@settings(max_examples=200, deadline=None)
@given(_held_input())
def test_property_zero_order_hold(case):
    ks, levels, grid_ticks = case
    ch = Channel("tau_x", ks * 1e-3, levels)
    out = resample_channel(ch, grid_ticks * 1e-4, ())
    outside = (grid_ticks < ks[0] * 10) | (grid_ticks > ks[-1] * 10)
    assert np.all(np.isnan(out[outside]))
    inside = out[~outside]
    assert np.all(np.isfinite(inside))
    assert set(inside.tolist()) <= set(levels.tolist())  # never a value it was not given
    # Each grid point holds the last command at or before it.
    idx = np.searchsorted(ks * 10, grid_ticks[~outside], side="right") - 1
    np.testing.assert_array_equal(inside, levels[idx])


@settings(max_examples=200, deadline=None)
@given(_held_input())
def test_property_state_interpolation_stays_in_range(case):
    ks, levels, grid_ticks = case
    out = resample_channel(Channel("u", ks * 1e-3, levels), grid_ticks * 1e-4, ())
    outside = (grid_ticks < ks[0] * 10) | (grid_ticks > ks[-1] * 10)
    assert np.all(np.isnan(out[outside]))
    inside = out[~outside]
    assert np.all(np.isfinite(inside))
    assert np.all(inside >= levels.min()) and np.all(inside <= levels.max())


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(-np.pi, np.pi, allow_nan=False), min_size=1, max_size=30),
       st.lists(st.floats(-1.0, 40.0, allow_nan=False), min_size=1, max_size=80))
def test_property_angles_stay_in_half_open_interval(angles, grid):
    t = np.arange(len(angles)) * 1.0
    out = resample_channel(Channel("psi", t, np.array(angles)), np.sort(np.array(grid)), ())
    finite = out[np.isfinite(out)]
    assert np.all((finite > -np.pi) & (finite <= np.pi))
    # Inside the span every grid point has a value.
    g = np.sort(np.array(grid))
    assert np.all(np.isfinite(out[(g >= 0) & (g <= t[-1])]))


def test_angle_just_past_pi_wraps_to_pi_not_minus_pi():
    # Interpolating from 3.0 to -3.0 goes through the wrap; at the grid points where the unwrapped
    # value is within rounding above pi, (pi - x) mod 2 pi rounds to 2 pi and gives -pi.
    t, psi = np.array([0.0, 1.0]), np.array([3.0, -3.0])
    g = [(np.pi - 3.0) / (2 * np.pi - 6.0)]
    for _ in range(40):
        g.append(np.nextafter(g[-1], 2.0))
    g = np.array(g)
    assert np.any(np.interp(g, t, np.unwrap(psi)) > np.pi)  # the case is really hit
    out = resample_channel(Channel("psi", t, psi), g, ())
    assert np.all((out > -np.pi) & (out <= np.pi))
    np.testing.assert_allclose(np.abs(out), np.pi, atol=2e-15)
