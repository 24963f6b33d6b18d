"""Segment detection against the simulator's truth segments, gaps, sinusoids, manifest segments.

The AAUSHIP sea trial is simulated once per (noise level, seed); seed 1 of every level goes
through the canonical CSV writer and reader into ``tmp_path`` as a user's file would.
"""

from __future__ import annotations

import functools
import re
from pathlib import Path

import numpy as np
import pytest

from pipeline.align import align
from pipeline.errors import SegmentError
from pipeline.ingest import read_csv_log
from pipeline.records import SEGMENT_DOFS, SEGMENT_KINDS, Channel, RawLog, Segments
from pipeline.segment import apply_manifest_segments, detect_segments, noise_std, segment_table
from pipeline.segment.inputs import split_levels
from pipeline.sim import (chain, default_sensors, rudder_step, sea_trial, simulate, sinusoid,
                          step_and_coast)
from pipeline.sim.writers.csv_writer import write_csv_log
from pipeline.vessel import load_vessel, parse_vessel

from conftest import simulated_sea_trial  # noqa: E402
from conftest import AAUSHIP  # noqa: E402 - the vessel, loaded once per session
SHIP = parse_vessel({"name": "ship", "nomoto": {"K": 0.156, "T": 72.4}})
SCHEDULE = sea_trial(AAUSHIP)
MATCHED_KINDS = ("step", "coast_down", "free_decay", "rudder_step", "zigzag")
CASES = [(level, seed) for level in ("low", "nominal", "high") for seed in (1, 2)]


@functools.lru_cache(maxsize=None)
def _sea_trial(level: str, seed: int):
    """One simulation per configuration for the whole session (about 3 s each; tests/conftest.py)."""
    return simulated_sea_trial(level, seed)


@pytest.fixture(scope="module", params=CASES, ids=[f"{l}-seed{s}" for l, s in CASES])
def run(request, tmp_path_factory):
    level, seed = request.param
    res = _sea_trial(level, seed)
    log = res.log
    if seed == 1:
        path = write_csv_log(log, tmp_path_factory.mktemp(f"seg-{level}") / "trial.csv")
        log = read_csv_log(path)
    trial = align([log], name=f"{level}-{seed}")
    return res, trial, detect_segments(trial)


def _match(truth, detected):
    tol = 0.2 if truth.kind == "free_decay" else 0.1
    return [d for d in detected.items if d.kind == truth.kind and d.dof == truth.dof
            and abs(d.t_start - truth.t_start) <= tol]


# --------------------------------------------------------------------------- sea trial
def test_every_truth_segment_is_detected(run):
    res, _, detected = run
    missed = [(s.kind, s.dof, round(s.t_start, 2)) for s in res.segments.items
              if s.kind in MATCHED_KINDS and not _match(s, detected)]
    assert not missed, f"missed {missed}; detected:\n{segment_table(detected)}"


def test_detected_levels_and_extent_match_truth(run):
    res, _, detected = run
    for s in res.segments.items:
        if s.kind not in MATCHED_KINDS:
            continue
        (d,) = _match(s, detected)
        assert d.input_channel == s.input_channel
        if s.kind != "free_decay":
            assert d.input_after == pytest.approx(s.input_after, rel=1e-6, abs=1e-9)
            assert d.input_before == pytest.approx(s.input_before, rel=1e-6, abs=1e-9)
        # A detected segment lies within its manoeuvre (plus the rest that follows it).
        assert d.t_end > d.t_start + 0.5
        assert d.t_end <= s.t_end + 40.0


def test_detected_segments_are_well_formed(run):
    res, trial, detected = run
    assert detected.trial == trial.name
    starts = [s.t_start for s in detected.items]
    assert starts == sorted(starts)
    for s in detected.items:
        assert s.kind in SEGMENT_KINDS and s.dof in SEGMENT_DOFS and s.origin == "detected"
        assert 0.0 <= s.t_start < s.t_end <= trial.t[-1] + 1e-9
        assert 0.0 <= s.quality <= 1.0
    # Clean, long manoeuvres score well.
    for s in res.segments.of("step", "surge") + res.segments.of("zigzag"):
        assert _match(s, detected)[0].quality > 0.5
    # Free decays are found where the hull was released, and nowhere else.
    truth_decays = res.segments.of("free_decay")
    for d in detected.of("free_decay"):
        assert any(d.dof == s.dof and abs(d.t_start - s.t_start) <= 0.2 for s in truth_decays), d


def test_quality_falls_with_noise():
    q = {}
    for level in ("low", "high"):
        sched = chain(step_and_coast("sway", 3.0, 3.0, 3.0), rest_s=2.0)
        res = simulate(AAUSHIP, sched, sensors=default_sensors(level), seed=3)
        (seg,) = detect_segments(align([res.log])).of("step", "sway")
        q[level] = seg.quality
    assert 0.0 <= q["high"] < q["low"] <= 1.0


# --------------------------------------------------------------------------- gaps
@pytest.fixture(scope="module")
def nominal():
    res = _sea_trial("nominal", 1)
    trial = align([res.log], name="nominal")
    return res, trial, detect_segments(trial)


def _gaps_for(truth):
    """Where to delete 3 s of a channel, placed from the truth segments."""
    yaw = truth.of("step", "yaw")[0].t_start
    coast = truth.of("coast_down", "surge")[0].t_start
    roll = truth.of("free_decay", "roll")[0].t_start
    zz = truth.of("zigzag")[0].t_start
    return {"r": (yaw - 1.5, yaw + 1.5),             # over the start of the yaw step
            "sog": (coast + 9.0, coast + 12.0),      # inside the surge coast-down
            "phi": (roll + 0.9, roll + 3.9),         # inside the first roll decay (4.8 s long)
            "psi": (zz + 18.0, zz + 21.0)}           # inside the zig-zag


@pytest.fixture(scope="module")
def gappy(nominal):
    res = nominal[0]
    cut = _gaps_for(res.segments)
    chans = dict(res.log.channels)
    for name, (a, b) in cut.items():
        c = chans[name]
        keep = (c.t < a) | (c.t > b)
        chans[name] = Channel(name, c.t[keep], c.values[keep], c.source)
    trial = align([RawLog("gappy", "sim", chans, res.log.summary)], name="gappy")
    return res, trial, detect_segments(trial)


def test_no_detected_segment_spans_a_gap(gappy):
    _, trial, detected = gappy
    assert sorted(g.channel for g in trial.gaps) == ["phi", "psi", "r", "sog"]
    for s in detected.items:
        for g in trial.gaps:
            assert not (g.t_start < s.t_end and s.t_start < g.t_end), (s, g)


def test_segments_around_gaps_are_cut_not_lost(gappy):
    res, _, detected = gappy
    cut = _gaps_for(res.segments)
    (coast,) = res.segments.of("coast_down", "surge")
    (d,) = _match(coast, detected)
    assert d.t_end <= cut["sog"][0] + 1e-9  # cut where the speed log drops out
    assert d.t_end > cut["sog"][0] - 0.5
    first_roll = res.segments.of("free_decay", "roll")[0]
    (d,) = _match(first_roll, detected)
    assert cut["phi"][0] - 0.5 < d.t_end <= cut["phi"][0] + 1e-9
    # Segments away from the gaps are unaffected.
    for s in res.segments.of("step", "surge") + res.segments.of("rudder_step"):
        assert _match(s, detected)
    # The yaw step began while the yaw rate was not logged: no segment claims that start.
    (yaw_step,) = res.segments.of("step", "yaw")
    assert not _match(yaw_step, detected)


# --------------------------------------------------------------------------- sinusoids
def _sine_label_omega(seg):
    return float(re.search(r"omega ([0-9.e+-]+) rad/s", seg.label).group(1))


def test_sinusoid_manoeuvre_is_detected():
    amp, omega = np.radians(10), 0.5
    res = simulate(AAUSHIP, chain(sinusoid(amp, omega, 4)), seed=2)
    (truth,) = res.segments.items
    detected = detect_segments(align([res.log]))
    sines = detected.of("sinusoid")
    assert len(sines) == 1, segment_table(detected)
    (d,) = sines
    assert d.dof == "yaw" and d.input_channel == "delta"
    assert abs(d.t_start - truth.t_start) < 0.2 and abs(d.t_end - truth.t_end) < 0.2
    assert d.input_after == pytest.approx(amp, rel=0.01)
    assert _sine_label_omega(d) == pytest.approx(omega, rel=0.1)
    assert 0.0 <= d.quality <= 1.0
    # A sine is not a sequence of rudder steps.
    assert not [s for s in detected.of("rudder_step") if truth.t_start < s.t_start < truth.t_end - 0.5]


def test_slow_rudder_sinusoid_of_the_ship_autopilot_seed():
    # The seed's omega = 0.05 rad/s: the rudder moves 0.03% of its range per logged command.
    res = simulate(SHIP, chain(sinusoid(np.radians(10), 0.05, 2), rest_s=20.0), seed=2, dt=0.1, actuator_rate=10.0)
    (truth,) = res.segments.items
    (d,) = detect_segments(align([res.log])).of("sinusoid")
    assert d.dof == "yaw"
    assert abs(d.t_start - truth.t_start) < 1.0 and abs(d.t_end - truth.t_end) < 1.0
    assert _sine_label_omega(d) == pytest.approx(0.05, rel=0.1)


def test_rudder_step_after_a_sinusoid_is_still_a_step():
    sched = chain(sinusoid(np.radians(10), 0.5, 3), rudder_step(np.radians(10), 20.0, 20.0))
    res = simulate(AAUSHIP, sched, seed=3)
    detected = detect_segments(align([res.log]))
    assert len(detected.of("sinusoid")) == 1
    for s in res.segments.of("rudder_step"):
        assert _match(s, detected), f"{s}\n{segment_table(detected)}"


def test_split_levels_on_steps_and_ramps():
    fs = 100.0
    u = np.concatenate([np.zeros(200), np.full(300, 0.2), np.zeros(100)])
    levels, varying = split_levels(u, fs)
    assert [(l.i_start, l.i_end, l.value) for l in levels] == [(0, 200, 0.0), (200, 500, 0.2), (500, 600, 0.0)]
    assert varying == []
    # A slow ramp (0.1% of the range per sample) between two holds is varying, not a level.
    ramp = np.concatenate([np.zeros(200), np.linspace(0, 1, 1000), np.ones(300)])
    levels, varying = split_levels(ramp, fs)
    (v,) = varying
    assert abs(v.i_start - 200) <= 15 and abs(v.i_end - 1200) <= 15
    assert levels[0].value == 0.0 and levels[-1].value == 1.0 and levels[-1].i_end == 1500


def test_noise_std_is_robust():
    rng = np.random.default_rng(0)
    y = np.concatenate([np.zeros(5000), np.full(5000, 10.0)]) + 0.01 * rng.standard_normal(10_000)
    assert noise_std(y) == pytest.approx(0.01, rel=0.05)  # the jump does not inflate it
    assert np.isnan(noise_std(np.array([1.0, 2.0])))


# --------------------------------------------------------------------------- manifest segments
def _manual(truth):
    """Hand-named segments as a manifest gives them: a coast-down and a roll decay, trimmed."""
    coast = truth.of("coast_down", "surge")[0]
    roll = truth.of("free_decay", "roll")[0]
    return [{"kind": "coast_down", "dof": "surge", "t_start": round(coast.t_start + 0.1, 2),
             "t_end": round(coast.t_start + 19.0, 2), "input_channel": "tau_x", "input_before": 4.29,
             "label": "hand-picked coast-down"},
            {"kind": "free_decay", "dof": "roll", "t_start": round(roll.t_start + 0.05, 2),
             "t_end": round(roll.t_start + 3.0, 2)}]


def test_manifest_segments_replace(nominal):
    res, trial, detected = nominal
    manual = _manual(res.segments)
    out = apply_manifest_segments(trial, detected, manual, mode="replace")
    assert out.trial == detected.trial
    assert [(s.kind, s.dof, s.t_start, s.t_end, s.origin) for s in out.items] == [
        (m["kind"], m["dof"], m["t_start"], m["t_end"], "manifest") for m in manual]
    assert out.items[0].input_channel == "tau_x" and out.items[0].input_before == 4.29
    assert out.items[0].label == "hand-picked coast-down" and out.items[1].quality == 1.0
    assert out.items[1].input_channel is None
    assert apply_manifest_segments(trial, detected, []) is detected


def test_manifest_segments_add(nominal):
    res, trial, detected = nominal
    out = apply_manifest_segments(trial, detected, _manual(res.segments), mode="add")
    manual = [s for s in out.items if s.origin == "manifest"]
    kept = [s for s in out.items if s.origin == "detected"]
    assert len(manual) == 2
    # Detected segments of the same DOF overlapping a manual one are dropped; the rest are kept.
    dropped = [d for d in detected.items if d not in kept]
    assert {(d.kind, d.dof) for d in dropped} == {("coast_down", "surge"), ("free_decay", "roll")}
    assert len(kept) == len(detected.items) - len(dropped)
    assert [s.t_start for s in out.items] == sorted(s.t_start for s in out.items)
    assert any(s.kind == "step" and s.dof == "surge" for s in kept)  # ends where the coast starts


@pytest.mark.parametrize("entry, match", [
    ({"kind": "spin", "dof": "yaw", "t_start": 1, "t_end": 2}, r"segments\[0\].kind: expected one of .*'coast_down'.*found 'spin'"),
    ({"kind": "step", "dof": "yaw", "t_start": 5, "t_end": 5}, r"segments\[0\]: expected t_end > t_start, found 5.0 .. 5.0"),
    ({"kind": "step", "dof": "yaw", "t_start": 9, "t_end": 3}, r"expected t_end > t_start, found 9.0 .. 3.0"),
    ({"kind": "step", "dof": "yaw", "t_start": -1, "t_end": 3}, r"segments\[0\]: expected bounds within the trial 0 .. {end} s, found -1.0 .. 3.0"),
    ({"kind": "step", "dof": "yaw", "t_start": 400, "t_end": 5000}, r"expected bounds within the trial 0 .. {end} s, found 400.0 .. 5000.0"),
    ({"kind": "step", "dof": "spin", "t_start": 1, "t_end": 2}, r"segments\[0\].dof: expected one of .*'surge'.*found 'spin'"),
    ({"kind": "step", "dof": "yaw", "t_start": 1, "t_end": 2, "input_channel": "rudder"}, r"input_channel: expected one of .*'delta'.*found 'rudder'"),
    ({"kind": "step", "dof": "yaw", "t_start": "a", "t_end": 2}, r"expected numbers for t_start/t_end \[s\], found 'a', 2"),
    ({"kind": "step", "dof": "yaw", "t_start": 1}, r"segments\[0\]: expected key 't_end', found keys \['dof', 'kind', 't_start'\]"),
    ({"kind": "step", "dof": "yaw", "t_start": 1, "t_end": 2, "start": 1}, r"segments\[0\]: unknown key\(s\) \['start'\]; allowed: .*'t_start'"),
])
def test_manifest_segment_errors(nominal, entry, match):
    _, trial, detected = nominal
    match = match.replace("{end}", re.escape(f"{trial.t[-1]:.2f}"))
    with pytest.raises(SegmentError, match=match):
        apply_manifest_segments(trial, detected, [entry])


def test_manifest_segment_error_names_the_entry_and_mode(nominal):
    _, trial, detected = nominal
    with pytest.raises(SegmentError, match=r"segments\[1\].kind"):
        apply_manifest_segments(trial, detected, [{"kind": "step", "dof": "yaw", "t_start": 1, "t_end": 2},
                                                  {"kind": "x", "dof": "yaw", "t_start": 1, "t_end": 2}])
    with pytest.raises(SegmentError, match=r"segments mode: expected 'replace' or 'add', found 'merge'"):
        apply_manifest_segments(trial, detected, [], mode="merge")


# --------------------------------------------------------------------------- table
def test_segment_table_renders(nominal):
    _, _, detected = nominal
    table = segment_table(detected)
    lines = table.splitlines()
    assert lines[0].split()[:5] == ["#", "kind", "dof", "start", "[s]"]
    assert set(lines[1]) == {"-"} and len(lines) == 2 + len(detected.items)
    for i, (line, s) in enumerate(zip(lines[2:], detected.items)):
        cols = line.split()
        assert cols[0] == str(i) and cols[1] == s.kind and cols[2] == s.dof
        assert float(cols[3]) == pytest.approx(s.t_start, abs=0.005)
        assert float(cols[4]) == pytest.approx(s.t_end, abs=0.005)
        assert f"{s.quality:.2f}" in line and s.origin in line
    free = [l for l in lines[2:] if " free_decay " in l]
    assert free and all(" - " in l for l in free)  # no input channel
    assert segment_table(Segments("empty", ())).count("\n") == 1
