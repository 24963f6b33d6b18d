"""Plausibility checks at align (pipeline.align.plausibility) and their effect on segment detection.

Each test starts from a simulated trial with roll decays and a rudder step (which passes every
check), then breaks one thing the way real installations break it: an IMU mounted 90 deg rolled,
an IMU that logs zeros while the attitude reads +-170 deg, an attitude offset from what the
accelerometer implies, a vessel lying at rest.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.align import align
from pipeline.align.plausibility import failed_channels, plausibility_notes, without_implausible
from pipeline.records import Channel, RawLog
from pipeline.segment import detect_segments
from pipeline.sim import chain, default_sensors, free_decay, rest, rudder_step, simulate
from pipeline.vessel import load_vessel

VESSEL = Path(__file__).resolve().parents[1] / "vessel_configs" / "aauship.toml"
pytestmark = pytest.mark.slow   # simulates and aligns minute-long trials (about a minute in all)


@pytest.fixture(scope="module")
def sim():
    v = load_vessel(VESSEL)
    sched = chain(free_decay("roll", 0.3, 8.0), rudder_step(0.17, 4.0, 6.0, {"tau_x": 3.0}), rest_s=2.0)
    return simulate(v, sched, sensors=default_sensors(), seed=5).log


def _with(log: RawLog, **new: np.ndarray) -> RawLog:
    chans = dict(log.channels)
    for name, values in new.items():
        chans[name] = Channel(name, chans[name].t, np.asarray(values, float), "edited")
    return RawLog("edited", "sim", chans, log.summary, log.time_reference, log.start_time)


def test_simulated_trial_passes_and_keeps_its_segments(sim):
    trial = align([sim])
    assert not failed_channels(trial.notes)
    assert any(n.startswith("plausibility: ok") and "all channels pass" in n for n in trial.notes)
    assert without_implausible(trial) is trial
    assert len(detect_segments(trial).of("free_decay", "roll")) >= 1


def test_imu_mounted_rolled_90_deg_fails_its_channels(sim):
    c = sim.channels
    rolled = _with(sim, ay=c["az"].values, az=-c["ay"].values, q=c["r"].values, r=-c["q"].values)
    trial = align([rolled])
    bad = failed_channels(trial.notes)
    assert {"p", "q", "r", "ax", "ay", "az"} <= bad
    assert any("gravity on the -y axis" in n for n in trial.notes)
    clean = without_implausible(trial)
    assert not clean.has("r") and clean.has("phi") and trial.has("r")   # the input trial is not modified


def test_zero_imu_and_upside_down_roll_fail_and_give_no_decays(sim):
    c = sim.channels
    zeros = {k: np.zeros(len(c[k].t)) for k in ("p", "q", "r", "ax", "ay", "az")}
    flipped = np.angle(np.exp(1j * (c["phi"].values + np.pi)))   # +-170 deg: a board upside down
    trial = align([_with(sim, phi=flipped, **zeros)])
    bad = failed_channels(trial.notes)
    assert {"p", "q", "r", "ax", "ay", "az", "phi"} <= bad
    assert any("all zero" in n for n in trial.notes)
    assert not detect_segments(trial).of("free_decay", "roll")


def test_attitude_contradicting_the_accelerometer_fails(sim):
    c = sim.channels
    trial = align([_with(sim, phi=c["phi"].values + np.radians(35.0))])
    assert failed_channels(trial.notes) == {"phi"}
    assert any("attitude contradicts the IMU" in n and "35 deg" in n for n in trial.notes)


def test_vessel_at_rest_yields_no_segments():
    v = load_vessel(VESSEL)
    log = simulate(v, chain(rest(60.0)), sensors=default_sensors(), seed=2).log
    trial = align([log])
    assert any("vessel at rest" in n for n in trial.notes)
    assert len(detect_segments(trial).items) == 0


def test_notes_are_plain_data():
    import pandas as pd

    frame = pd.DataFrame({"t": np.arange(100) / 10.0, "r": np.zeros(100)})
    notes = plausibility_notes(frame, 10.0)
    assert notes[0].startswith("plausibility: FAIL [r]: all zero")
    assert failed_channels(notes) == {"r"}
