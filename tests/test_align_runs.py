"""Runs: a trial of several recordings. Logs that overlap in absolute time or share a clock by
cross-correlation are sensors of one run; non-overlapping absolute times are never merged; runs
are separated by a NaN gap so no segment spans two; a folder of separate runs (CSV, .bin, .tlog)
fits like the runs fitted one by one, combined."""

from __future__ import annotations

import math
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pytest

from pipeline.align import align, group_runs, grouping_text
from pipeline.errors import AlignError
from pipeline.fit import fit_trial
from pipeline.flow import load_trial, read_logs, runs_text, segment_trial
from pipeline.ingest import read_log
from pipeline.records import RUN_BOUNDARY, Channel, IngestSummary, RawLog
from pipeline.sim import simulate
from pipeline.sim.manoeuvres import chain, free_decay, rudder_step, step_and_coast, zigzag
from pipeline.sim.writers import write_log
from pipeline.vessel import load_vessel

ROOT = Path(__file__).resolve().parents[1]
VESSEL = load_vessel(ROOT / "vessel_configs" / "aauship.toml")
D = np.diag(VESSEL.damping)
CE6 = Path("/work/shared/realdata/ce6-boat-limfjord-2022/Estimations/Boat test 2/VirtualMass")


def _log(name, chans, start=math.nan, tod=math.nan):
    return RawLog(name, "sim", {n: Channel(n, t, v) for n, (t, v) in chans.items()}, IngestSummary(name, "sim"),
                  start_time=start, time_of_day=tod)


@pytest.fixture(scope="module")
def yaw_sim():
    """Rudder steps and a zig-zag sampled by IMU, attitude and GNSS."""
    z = math.radians(10)
    sched = chain(rudder_step(z, 20.0, 20.0, {"tau_x": float(D[0])}), zigzag(z, z, 60.0, {"tau_x": float(D[0])}),
                  rudder_step(-z, 20.0, 20.0, {"tau_x": float(D[0])}), rest_s=8.0)
    return simulate(VESSEL, sched, seed=3)


# --------------------------------------------------------------------------- grouping rules
def test_overlapping_absolute_times_are_one_run_and_distant_ones_never_merged(yaw_sim):
    ch = yaw_sim.log.channels
    t0 = 1.7e9
    imu = _log("imu", {"r": (ch["r"].t, ch["r"].values), "p": (ch["p"].t, ch["p"].values)}, start=t0)
    gnss = _log("gnss", {n: (ch[n].t - 2.0, ch[n].values) for n in ("lat", "lon", "sog", "cog")}, start=t0 + 2.0)
    # The same recording again an hour later: its rates correlate perfectly with the first, but
    # its absolute time does not overlap, so it is another run.
    later = _log("later", {"r": (ch["r"].t, ch["r"].values), "p": (ch["p"].t, ch["p"].values)}, start=t0 + 3600)
    groups = group_runs([imu, gnss, later])
    assert [g.sources for g in groups] == [("imu", "gnss"), ("later",)]
    assert groups[0].offsets["gnss"].offset_s == pytest.approx(2.0)
    assert "absolute times overlap" in groups[0].reason
    assert "never merged" in groups[1].reason
    trial = align([imu, gnss, later])
    assert len(trial.runs) == 2
    run0, run1 = trial.runs
    assert run0.start_time == pytest.approx(t0) and run1.start_time == pytest.approx(t0 + 3600)
    # Runs lie one after the other on the trial clock, separated by a NaN gap.
    boundary = [g for g in trial.gaps if g.channel == RUN_BOUNDARY]
    assert len(boundary) == 1 and boundary[0].t_start == pytest.approx(run0.t_end)
    between = (trial.t > run0.t_end) & (trial.t < run1.t_start)
    assert between.sum() >= 2 and np.isnan(trial.data.loc[between, "r"]).all()
    np.testing.assert_allclose(trial.run_data(1)["r"].to_numpy()[:100], trial.run_data(0)["r"].to_numpy()[:100])
    assert trial.run_index(run1.t_start + 1.0) == 1 and trial.run_index(run0.t_end - 1.0) == 0
    assert np.allclose(np.diff(trial.t), 1.0 / trial.fs)
    assert "runs: 2" in trial.notes[0] if trial.notes[0].startswith("runs") else any("runs: 2" in n for n in trial.notes)


def test_files_without_time_share_a_run_by_cross_correlation(yaw_sim):
    ch = yaw_sim.log.channels
    imu = _log("imu.csv", {n: (ch[n].t, ch[n].values) for n in ("r", "p", "q", "psi", "phi", "theta")})
    # GNSS in its own file, its logger started 3 s later.
    gnss = _log("gnss.csv", {n: (ch[n + "@gps"].t - 3.0, ch[n + "@gps"].values) for n in ("lat", "lon", "sog", "cog")})
    (group,) = group_runs([imu, gnss])
    assert group.offsets["gnss.csv"].offset_s == pytest.approx(3.0, abs=max(3 * group.offsets["gnss.csv"].stderr_s, 0.05))
    assert "cross-correlation" in group.reason
    trial = align([imu, gnss])
    assert len(trial.runs) == 1 and trial.has("u") and trial.has("v")


def test_same_channels_without_time_are_separate_runs(yaw_sim):
    ch = yaw_sim.log.channels
    a = _log("a.csv", {n: (ch[n].t, ch[n].values) for n in ("r", "psi", "sog", "cog")})
    b = _log("b.csv", {n: (ch[n].t, ch[n].values) for n in ("r", "psi", "sog", "cog")})
    groups = group_runs([a, b])
    assert [g.sources for g in groups] == [("a.csv",), ("b.csv",)]
    assert "same channels as a.csv" in groups[1].reason
    text = grouping_text(groups)
    assert "2 run(s)" in text and "why:" in text


def test_a_command_file_that_repeats_the_gyro_joins_the_sensor_file(yaw_sim):
    """A sensor CSV and a command CSV (rudder and the gyro, its logger started 2 s later), no absolute
    time: the command file brings inputs the sensor file lacks, so it is not "the same sensors again"
    but the same recording, placed by cross-correlating the shared gyro."""
    ch = yaw_sim.log.channels
    sensors = _log("sensors.csv", {n: (ch[n].t, ch[n].values) for n in ("r", "p", "q", "psi", "phi", "theta")})
    commands = _log("commands.csv", {n: (ch[n].t - 2.0, ch[n].values) for n in ("delta", "tau_x", "r")})
    (group,) = group_runs([sensors, commands])
    assert group.offsets["commands.csv"].offset_s == pytest.approx(2.0, abs=0.05)
    assert "cross-correlation" in group.reason
    # Two files of the same loggers (same inputs, nested states) stay separate runs.
    again = _log("again.csv", {n: (ch[n].t, ch[n].values) for n in ("delta", "tau_x", "r")})
    groups = group_runs([sensors, commands, again])
    assert [g.sources for g in groups] == [("sensors.csv", "commands.csv"), ("again.csv",)]


def test_a_log_of_inputs_only_without_a_clock_is_refused(yaw_sim):
    ch = yaw_sim.log.channels
    a = _log("nav.csv", {n: (ch[n].t, ch[n].values) for n in ("r", "psi")})
    cmds = _log("cmds.csv", {"delta": (ch["delta"].t, ch["delta"].values)})
    with pytest.raises(AlignError, match=r"runs: cmds.csv holds only inputs \(\['delta'\]\) and no absolute "
                                         r"time: expected a measured response channel, or another log that shares its clock"):
        align([a, cmds])


def test_stated_runs_are_kept_and_a_stated_run_must_overlap_in_time(yaw_sim):
    ch = yaw_sim.log.channels
    a = _log("a", {"r": (ch["r"].t, ch["r"].values)}, start=1.7e9)
    b = _log("b", {"psi": (ch["psi"].t, ch["psi"].values)}, start=1.7e9)
    c = _log("c", {"r": (ch["r"].t, ch["r"].values)}, start=1.7e9 + 7200)
    trial = align([a, b, c], runs=[["a", "b"], ["c"]], run_names=["first", "second"])
    assert [r.name for r in trial.runs] == ["first", "second"]
    assert trial.runs[0].reason.startswith("stated in the manifest")
    with pytest.raises(AlignError, match=r"runs: run 'x' states a \(.*\) and c \(.*\) as one recording, but their "
                                         r"absolute times do not overlap \(7\d\d\d.\d s apart\)"):
        align([a, b, c], runs=[["a", "c"], ["b"]], run_names=["x", "y"])
    with pytest.raises(AlignError, match=r"expected every log in exactly one stated run; found not in any run \['c'\]"):
        align([a, b, c], runs=[["a", "b"]])


@pytest.mark.skipif(not CE6.is_dir(), reason="CE6 real data (../shared/realdata) not present")
def test_ce6_nmea_recordings_that_do_not_overlap_are_two_runs():
    """09:47:01-09:47:34 and 09:48:25-09:49:01 UTC: once merged with a -2.06 s 'offset'."""
    files = [CE6 / "throt15003W.txt", CE6 / "throt15012W.txt"]
    trial = load_trial(files)
    assert len(trial.runs) == 2
    assert [r.sources for r in trial.runs] == [(str(files[0]),), (str(files[1]),)]
    assert "09:47:01.10" in trial.runs[0].reason and "never merged" in trial.runs[0].reason
    assert trial.runs[0].time_of_day == pytest.approx(9 * 3600 + 47 * 60 + 1.1)
    # Without the time of day they are still apart: the same channels and no common clock.
    logs = [replace(l, time_of_day=math.nan) for l in read_logs(files)]
    groups = group_runs(logs)
    assert len(groups) == 2 and "same channels" in groups[1].reason
    text = runs_text(trial)
    assert "2 run(s)" in text and "throt15012W" in text


def test_a_folder_of_eight_ce6_coast_downs_is_eight_runs_each_named_beside_its_nearest():
    import re

    trial = load_trial([CE6])
    assert len(trial.runs) == 8 and all(len(r.sources) == 1 for r in trial.runs)
    run = next(r for r in trial.runs if r.name == "throt15003W")
    # Before: the first other run in the list was named (throt11866E.txt, 177.2 s apart).
    assert re.search(r"no overlap with throt15012W.txt \(51\.[45] s apart, the nearest run\): never merged", run.reason), \
        run.reason


# --------------------------------------------------------------------------- inputs and GNSS
def test_commands_are_held_and_measured_inputs_interpolated():
    t = np.array([0.0, 1.0, 2.0])
    log = RawLog("a", "sim", {"delta": Channel("delta", t, np.array([0.0, 0.2, 0.2])),
                              "tau_x": Channel("tau_x", t, np.array([0.0, 4.0, 4.0]), input_kind="measured"),
                              "r": Channel("r", np.arange(0, 2.01, 0.25), np.zeros(9))}, IngestSummary("a", "sim"))
    trial = align([log])
    at = trial.data.set_index("t")
    assert at.loc[0.5, "delta"] == 0.0 and at.loc[0.75, "delta"] == 0.0
    assert at.loc[0.5, "tau_x"] == pytest.approx(2.0)
    assert trial.runs[0].input_kinds == {"delta": "command", "tau_x": "measured"}
    assert any("delta held (command)" in n and "tau_x interpolated (measured)" in n for n in trial.notes)
    # The caller (a manifest's [inputs]) overrides what the reader said.
    flipped = align([log], input_kinds={"delta": "measured", "tau_x": "command"}).data.set_index("t")
    assert flipped.loc[0.5, "delta"] == pytest.approx(0.1) and flipped.loc[0.5, "tau_x"] == 0.0
    with pytest.raises(AlignError, match=r"input kind of 'delta': expected one of \['command', 'measured'\], found 'servo'"):
        align([log], input_kinds={"delta": "servo"})


def test_held_gnss_fixes_are_one_fix_each(yaw_sim, tmp_path):
    """An IMU-rate CSV that repeats a 1 Hz fix in every row: one sample per fix, not 50."""
    ch = yaw_sim.log.channels
    t = np.arange(0.0, 60.0, 0.02)
    cols = {"t": t, "r": np.interp(t, ch["r"].t, ch["r"].values), "psi": np.interp(t, ch["psi"].t, ch["psi"].values)}
    fix_t = np.floor(t)  # the logger holds the fix received at each whole second
    for n in ("lat", "lon", "sog", "cog"):
        c = ch[n + "@gps"]
        cols[n] = np.interp(fix_t, c.t, c.values)
    path = tmp_path / "held.csv"
    import pandas as pd

    pd.DataFrame(cols).to_csv(path, index=False, float_format="%.9f")
    trial = load_trial([path])
    note = next(n for n in trial.notes if "GNSS" in n)
    assert "3000 rows hold 60 fixes (about 1 Hz)" in note
    # Between fixes the speed is interpolated, not a staircase.
    sog = trial.data["sog"].to_numpy()
    inside = (trial.t > 10.1) & (trial.t < 10.9)
    assert np.ptp(np.diff(sog[inside])) < 1e-9 or np.unique(np.round(sog[inside], 12)).size > 5


def test_a_channel_slow_in_one_run_and_at_the_grid_rate_in_another_is_measured_in_both():
    """u derived from a 5 Hz GNSS in one run (an autopilot log), logged at 50 Hz in the next (a CSV):
    every grid row of the second run holds a real u (before: none did, and each surge and sway
    segment of that run was refused with "found 0 samples")."""
    t50, t5 = np.arange(0.0, 30.0, 0.02), np.arange(0.0, 30.0, 0.2)
    gnss = _log("autopilot", {"sog": (t5, 1.0 + 0 * t5), "cog": (t5, 0 * t5), "psi": (t50, 0 * t50),
                              "r": (t50, 0 * t50)}, start=1.7e9)
    dvl = _log("dvl", {"u": (t50, 1.0 + 0 * t50), "v": (t50, 0 * t50), "psi": (t50, 0 * t50), "r": (t50, 0 * t50)},
               start=1.7e9 + 3600)
    trial = align([gnss, dvl])
    first, second = trial.runs
    t = trial.t
    in_first, in_second = (t >= first.t_start) & (t <= first.t_end), (t >= second.t_start) & (t <= second.t_end)
    for ch in ("u", "v"):
        rows = trial.measured_rows(ch, t)
        assert rows[in_first].sum() == t5.size, ch       # the fixes only
        assert rows[in_second].all(), ch                 # every logged sample
    # A channel slow in every run keeps only its fixes.
    assert trial.measured_rows("sog", t)[in_second].sum() == 0


# --------------------------------------------------------------------------- runs through the flow
def _recording(k: int):
    """Run ``k`` of the day: a surge step and coast-down, a roll free decay, two rudder steps (sizes per run)."""
    return chain(step_and_coast("surge", float(D[0] * (1.2 + 0.15 * k)), 20.0, 20.0),
                 free_decay("roll", math.radians(15 + 3 * k), 15.0),
                 rudder_step(math.radians(8 + 2 * k), 20.0, 20.0, {"tau_x": float(D[0])}), rest_s=8.0)


@pytest.fixture(scope="module")
def day(tmp_path_factory):
    """Three recordings of one day in three formats, written by the simulator's writers: CSV (no
    absolute time), ArduPilot DataFlash .bin (GPS time, noon) and MAVLink .tlog (wall clock,
    evening). Each holds the same kinds of manoeuvre with its own sizes and noise, so every
    coefficient is combined across all three runs."""
    folder = tmp_path_factory.mktemp("day")
    names = ("a_morning.csv", "b_noon.bin", "c_evening.tlog")
    opts = {"a_morning.csv": {}, "b_noon.bin": {"gps_start": datetime(2024, 5, 5, 12, 0, tzinfo=timezone.utc)},
            "c_evening.tlog": {"wall_start": datetime(2024, 5, 5, 17, 0, tzinfo=timezone.utc)}}
    paths = []
    for k, name in enumerate(names):
        res = simulate(VESSEL, _recording(k), seed=40 + k)
        paths.append(write_log(res.log, folder / name, vessel=VESSEL, **opts[name]))
    return folder, paths


@pytest.mark.slow  # about 60 s of fits and diagnosis; the grouping itself is guarded by the fast tests above
def test_a_folder_of_separate_runs_fits_like_the_runs_one_by_one(day):
    from pipeline.diagnose import diagnose
    from pipeline.diagnose.segments import diagnose_segments

    folder, paths = day
    trial = load_trial([folder], VESSEL)
    # Runs with absolute times first, earliest first; the CSV (no absolute time) after them.
    assert [Path(s).name for r in trial.runs for s in r.sources] == ["b_noon.bin", "c_evening.tlog", "a_morning.csv"]
    assert trial.runs[0].start_time < trial.runs[1].start_time and math.isnan(trial.runs[2].start_time)
    segs = segment_trial(trial)
    fits = fit_trial(trial, segs, VESSEL, extend=False)
    alone = {}
    for p in paths:
        one = load_trial([p], VESSEL)
        alone[p.name] = fit_trial(one, segment_trial(one), VESSEL, extend=False)

    # 1. Every run holds the segments of its file fitted alone (on the run's clock), fitted alike.
    half = 0.5 / trial.fs
    for k, run in enumerate(trial.runs):
        mine = [f for f in fits.segment_fits if f.segment.run == k]
        theirs = alone[Path(run.sources[0]).name].segment_fits
        assert [(f.segment.kind, f.segment.dof) for f in mine] == [(f.segment.kind, f.segment.dof) for f in theirs]
        assert len(mine) == 7, [(f.segment.kind, f.segment.dof) for f in mine]
        for f, g in zip(mine, theirs):
            assert f.segment.t_start - run.t_start == pytest.approx(g.segment.t_start, abs=half)
            assert f.segment.t_end - run.t_start == pytest.approx(g.segment.t_end, abs=half)
            assert f.success == g.success, (f.message, g.message)
            for name, value in g.params.items():
                # Equal to a tenth of the error (the Nomoto fits of the whole trial and of one run
                # stop their iterations at slightly different points: up to 0.034 SE measured).
                se = g.stderr.get(name, math.nan)
                tol = 0.1 * se if math.isfinite(se) and se > 0 else 1e-9 * max(abs(value), 1.0)
                assert abs(f.params[name] - value) <= tol, (run.name, f.segment.kind, name, f.params[name], value, se)

    # 2. Every coefficient is the combination of the runs fitted one by one: the same per-segment
    # values, and the value of an inverse-variance mean of the runs' own estimates.
    for name in ("X_u", "K_p", "K_nomoto", "T_nomoto"):
        parts = [f.estimates[name] for f in alone.values()]
        assert all(p.success for p in parts), [(p.value, p.message) for p in parts]
        est = fits.estimates[name]
        assert est.success, est.message
        joined = sorted(v for p in parts for v in p.per_segment)
        assert est.n_segments == len(joined) >= 3
        np.testing.assert_allclose(sorted(est.per_segment), joined, rtol=0, atol=0.05 * est.stderr)
        w = np.array([1 / p.stderr**2 for p in parts])
        combined = float(np.sum(w * [p.value for p in parts]) / w.sum())
        assert abs(est.value - combined) < 0.2 * est.stderr, (name, est.value, combined, est.stderr)
    # K_p has one decay per run and no added error term: its error is that of the mean of the three.
    k_p = fits.estimates["K_p"]
    se_mean = 1 / math.sqrt(sum(1 / f.estimates["K_p"].stderr**2 for f in alone.values()))
    assert k_p.stderr == pytest.approx(se_mean, rel=0.01)
    # X_u: twelve segments over three runs know it better than any run alone.
    assert fits.estimates["X_u"].stderr < min(f.estimates["X_u"].stderr for f in alone.values())
    # (The Nomoto K and T carry the speed term of fit/nomoto_quality.add_speed_term, the largest speed
    # loss of any record, which is never averaged down; their errors are not compared here.)

    # 3. The diagnosis runs on the multi-run trial without error, replays every run on its own (no
    # window runs on into the next run) and finds nothing on this clean day.
    for s in diagnose_segments(trial).items:
        assert any(r.t_start - 1e-9 <= s.t_start and s.t_end <= r.t_end + 1e-9 for r in trial.runs), s
    report = diagnose(trial, VESSEL, segments=segs, fits=fits)
    assert report.effect is None and not report.unexplained, [(c.label, c.dof, c.p_value) for c in report.candidates[:3]]


def test_cli_ingest_and_align_print_the_grouping_and_why(day, capsys):
    from pipeline.cli import main

    folder, _ = day
    assert main(["ingest", str(folder)]) == 0
    out = capsys.readouterr().out
    assert "3 run(s)" in out and "why:" in out and "never merged" in out
    assert main(["align", str(folder)]) == 0
    out = capsys.readouterr().out
    assert "3 run(s):" in out and "run 2 'a_morning'" in out and "clock offset" in out


def test_writers_hold_commands_and_interpolate_measured_inputs():
    from pipeline.sim.writers._sampling import hold_channel

    t = np.array([0.0, 1.0])
    cmd = Channel("delta", t, np.array([0.0, 1.0]))
    measured = Channel("delta", t, np.array([0.0, 1.0]), input_kind="measured")
    np.testing.assert_allclose(hold_channel(cmd, np.array([0.5, 1.0])), [0.0, 1.0])
    np.testing.assert_allclose(hold_channel(measured, np.array([0.5, 1.0])), [0.5, 1.0])


def test_a_grid_coarser_than_the_command_log_is_warned():
    t = np.arange(0.0, 10.0, 0.02)
    log = RawLog("a", "sim", {"delta": Channel("delta", t, (t > 5.01).astype(float)),
                              "r": Channel("r", t, np.zeros(t.size))}, IngestSummary("a", "sim"))
    assert not any(n.startswith("warning") for n in align([log]).notes)
    notes = align([log], fs=10.0).notes
    assert any("10 Hz is coarser than the logged rate of the commands delta (up to 50 Hz)" in n for n in notes)


def test_trial_columns_are_contiguous_float64_views(yaw_sim):
    ch = yaw_sim.log.channels
    imu = _log("imu", {n: (ch[n].t, ch[n].values) for n in ("r", "p", "phi", "delta")}, start=1.7e9)
    later = _log("later", {n: (ch[n].t, ch[n].values) for n in ("r", "p", "phi", "delta")}, start=1.7e9 + 3600)
    trial = align([imu, later], name="two runs")
    assert set(trial.data.dtypes) == {np.dtype("float64")}
    for c in trial.data.columns:
        col = trial.data[c].to_numpy()
        assert col.flags["C_CONTIGUOUS"] and col.dtype == np.float64
    # One array for all columns: reading a column copies nothing.
    assert len({id(b) for b in trial.data._mgr.blocks}) == 1
    # Values as resampled: the run gap is NaN, the samples are the simulator's.
    assert np.isnan(trial.data["r"].to_numpy()).any()
    first = trial.run_data(0)
    np.testing.assert_allclose(np.interp(ch["r"].t[5:50], first["t"], first["r"]), ch["r"].values[5:50], atol=1e-9)
