"""Input-free coast-downs (pipeline.segment.speed_events): found from the speed alone when no surge
input is logged, fitted like any coast-down, and rejected when the boat turns, only slows down a
little, or was not steady before.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.align import align
from pipeline.fit import fit_trial
from pipeline.records import Channel, IngestSummary, RawLog
from pipeline.segment import detect_segments
from pipeline.segment.speed_events import find_coast_downs
from pipeline.sim import chain, simulate, step_and_coast
from pipeline.vessel import Vessel, load_vessel

from conftest import AAUSHIP  # noqa: E402 - the vessel, loaded once per session
T_SURGE = 13.0 / 2.86  # m / X_u of the config [s]
INPUTS = ("tau_x", "tau_y", "tau_n", "delta")


@pytest.fixture(scope="module")
def two_coasts():
    return simulate(AAUSHIP, chain(step_and_coast("surge", 2.86 * 1.5, 30.0, 30.0),
                                   step_and_coast("surge", 2.86 * 1.0, 30.0, 30.0)), seed=3)


def _without_inputs(res):
    ch = {k: v for k, v in res.log.channels.items() if k not in INPUTS}
    return RawLog("gps-only", "sim", ch, res.log.summary)


def test_coast_downs_found_without_the_throttle_log_and_fitted(two_coasts):
    trial = align([_without_inputs(two_coasts)])
    segs = detect_segments(trial).of("coast_down", "surge")
    truth = [s for s in two_coasts.segments.items if s.kind == "coast_down"]
    assert len(segs) == len(truth) == 2
    for seg, ref in zip(segs, truth):
        assert seg.input_channel is None and seg.origin == "detected"
        assert abs(seg.t_start - ref.t_start) < 0.1  # the cut, to a few samples of the 100 Hz log
        assert seg.t_end - seg.t_start > 2 * T_SURGE and seg.t_end <= ref.t_end + 1e-9
        assert seg.label.startswith("input-free coast-down from u") and seg.quality > 0.5
    fits = fit_trial(trial, detect_segments(trial), AAUSHIP)
    est = fits.estimates["T_surge"]
    assert est.success and est.n_segments == 2
    assert abs(est.value - T_SURGE) < max(3 * est.stderr, 0.01 * T_SURGE)


def test_with_a_surge_input_the_input_detector_is_used(two_coasts):
    segs = detect_segments(align([two_coasts.log])).of("coast_down")
    assert segs and all(s.input_channel == "tau_x" for s in segs)


def test_speed_over_ground_serves_when_there_is_no_heading(two_coasts):
    ch = {k: v for k, v in two_coasts.log.channels.items() if k in ("lat", "lon", "sog", "cog")}
    trial = align([RawLog("gps", "sim", ch, IngestSummary("gps", "sim"))])
    assert not trial.has("u")
    fits = fit_trial(trial, detect_segments(trial), Vessel(name="no mass"))
    (sf,) = [f for f in fits.segment_fits][:1]
    assert sf.channel == "sog" and "speed over ground" in sf.message
    assert fits.estimates["T_surge"].success
    assert abs(fits.estimates["T_surge"].value - T_SURGE) < 0.05 * T_SURGE


def _speed_log(t, sog, cog):
    return RawLog("g", "sim", {"sog": Channel("sog", t, sog), "cog": Channel("cog", t, cog)}, IngestSummary("g", "sim"))


def test_a_turn_a_slowdown_and_an_unsteady_start_are_not_coast_downs():
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 60.0, 0.05)
    decay = np.where(t < 20, 3.0, 3.0 * np.exp(-(t - 20) / 5.0))
    noise = 0.02 * rng.standard_normal(len(t))
    # Course turning at 15 deg/s from before the cut: a boat slowing in a turn.
    turning = _speed_log(t, decay + noise, np.radians(15.0) * t)
    segs, cands = find_coast_downs(align([turning]))
    assert not segs and any(c.reason.startswith("turning") for c in cands)
    # Straight, the same decay is a coast-down.
    straight = _speed_log(t, decay + noise, np.full(len(t), 1.0))
    (seg,), _ = find_coast_downs(align([straight]))
    assert abs(seg.t_start - 20.0) < 0.15
    # A 10% slowdown is not a coast-down.
    slow = np.where(t < 20, 3.0, 2.7 + 0.3 * np.exp(-(t - 20) / 2.0))
    assert not find_coast_downs(align([_speed_log(t, slow + noise, np.ones(len(t)))]))[0]
    # Accelerating into the cut: not steady before it.
    ramp = np.where(t < 20, 0.2 * t, 4.0 * np.exp(-(t - 20) / 5.0))
    segs, cands = find_coast_downs(align([_speed_log(t, ramp + noise, np.ones(len(t)))]))
    assert not segs and any(c.reason.startswith("not steady") for c in cands)


def test_no_coast_down_spans_a_dropout():
    rng = np.random.default_rng(2)
    t = np.arange(0.0, 60.0, 0.05)
    sog = np.where(t < 20, 3.0, 3.0 * np.exp(-(t - 20) / 5.0)) + 0.02 * rng.standard_normal(len(t))
    keep = (t < 27.0) | (t > 30.0)  # three seconds of GPS lost during the decay
    trial = align([_speed_log(t[keep], sog[keep], np.ones(keep.sum()))])
    (gap,) = trial.gaps[:1]
    (seg,) = find_coast_downs(trial)[0]
    assert seg.t_end <= gap.t_start + 1e-9 and seg.t_start < gap.t_start
