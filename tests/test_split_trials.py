"""Split trials: a trial day comes as several run files.

Files that continue one logger's clock without a gap (a logger that rotates its file) are one run
and give the segments and estimates of the unsplit log; files with a real gap between them are
separate runs, each segmented on its own, and a manoeuvre a file boundary cuts is dropped with a
note. Every run's segments are counted in ``Segments.notes``. All logs are real CSV files.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pipeline.align import group_runs
from pipeline.fit import fit_trial
from pipeline.fit.segment_fit import settled_at_run_end
from pipeline.flow import load_trial, read_logs, segments_from_json, segments_to_json, write_json
from pipeline.segment import detect_segments, segment_table, segment_trial
from pipeline.sim import simulate
from pipeline.sim.manoeuvres import chain, rudder_step, zigzag
from pipeline.vessel import load_vessel

ROOT = Path(__file__).resolve().parents[1]
VESSEL = load_vessel(ROOT / "vessel_configs" / "aauship.toml")
RATE = 10.0


@pytest.fixture(scope="module")
def table() -> pd.DataFrame:
    """Rudder steps (8-28 s to +10 deg, 28-48 s back), a 10/10 zig-zag (56-116 s) and two more steps,
    logged at 10 Hz as a user's logger writes them: t, yaw rate, heading, speed, rudder command."""
    z = math.radians(10)
    tau_x = {"tau_x": float(np.diag(VESSEL.damping)[0])}
    sched = chain(rudder_step(z, 20.0, 20.0, tau_x), zigzag(z, z, 60.0, tau_x), rudder_step(-z, 20.0, 20.0, tau_x),
                  rest_s=8.0)
    ch = simulate(VESSEL, sched, seed=3).log.channels
    t = np.round(np.arange(0.0, 172.0 + 1e-9, 1 / RATE), 6)

    def at(name: str) -> np.ndarray:
        return ch[name].values[np.clip(np.searchsorted(ch[name].t, t - 1e-9), 0, len(ch[name].t) - 1)]

    return pd.DataFrame({"t": t, "r": at("r"), "psi": at("psi"), "u": at("sog"), "delta": at("delta")})


def _write(frame: pd.DataFrame, path: Path, iso: bool) -> Path:
    out = frame.copy()
    if iso:
        out["t"] = [(pd.Timestamp("2024-05-05T09:00:00Z") + pd.Timedelta(seconds=float(x))).isoformat() for x in out["t"]]
    out.to_csv(path, index=False, float_format="%.10g")
    return path


def _pieces(frame: pd.DataFrame, cuts: list[float], folder: Path, iso: bool = False,
            gap_s: float = 0.0) -> list[Path]:
    """The log as consecutive files cut at ``cuts`` [s]; each later file's clock ``gap_s`` later than the one before."""
    folder.mkdir()
    edges = [-math.inf] + list(cuts) + [math.inf]
    paths = []
    for k, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
        part = frame[(frame["t"] >= a) & (frame["t"] < b)].assign(t=lambda f, k=k: f["t"] + k * gap_s)
        paths.append(_write(part, folder / f"part{k + 1}.csv", iso))
    return paths


@pytest.mark.parametrize("iso", [False, True], ids=["logged time", "ISO UTC time"])
def test_files_that_continue_one_clock_are_one_run_with_the_segments_of_the_unsplit_log(table, tmp_path, iso):
    one = load_trial([_write(table, tmp_path / "day.csv", iso)])
    # Cut inside the first rudder step and inside the zig-zag.
    parts = _pieces(table, [20.05, 90.0], tmp_path / "parts", iso)
    split = load_trial(parts)
    assert len(split.runs) == 1 and split.runs[0].sources == tuple(str(p) for p in parts)
    assert "rotated its file" in split.runs[0].reason
    assert list(split.data.columns) == list(one.data.columns)
    a, b = detect_segments(one), detect_segments(split)
    if iso:
        # Each file's times count from its own UTC start (a float of 1.7e9 s): equal to ~1e-7 s.
        assert split.fs == pytest.approx(one.fs, rel=1e-12)
        for c in one.data.columns:
            np.testing.assert_allclose(split.data[c].to_numpy(), one.data[c].to_numpy(), rtol=0, atol=1e-6, err_msg=c)
        assert [(s.kind, s.dof) for s in b.items] == [(s.kind, s.dof) for s in a.items]
        for x, y in zip(a.items, b.items):
            assert x.t_start == pytest.approx(y.t_start, abs=1e-6) and x.t_end == pytest.approx(y.t_end, abs=1e-6)
    else:
        assert split.fs == one.fs
        for c in one.data.columns:
            np.testing.assert_array_equal(split.data[c].to_numpy(), one.data[c].to_numpy(), err_msg=c)
        assert b.items == a.items
    assert [s.kind for s in a.items if s.dof == "yaw"] == ["rudder_step", "rudder_step", "zigzag", "rudder_step",
                                                           "rudder_step", "rudder_step"]
    # Every file is counted: the one run lists its three files and its nine segments.
    assert b.notes == ("segments per run: run 0 'part1' (part1.csv, part2.csv, part3.csv): 9 (yaw rudder_step 5, "
                       "surge coast_down 3, yaw zigzag 1)",)
    assert not a.notes
    if not iso:
        fa, fb = fit_trial(one, a, VESSEL, extend=False), fit_trial(split, b, VESSEL, extend=False)
        for name in ("K_nomoto", "T_nomoto"):
            assert fb.estimates[name].value == fa.estimates[name].value
            assert fb.estimates[name].stderr == fa.estimates[name].stderr


def test_files_with_a_real_gap_are_runs_of_their_own_and_a_cut_manoeuvre_is_dropped_with_a_note(table, tmp_path):
    # The same cuts, each later file's clock 100 s on: the logger was off in between.
    parts = _pieces(table, [20.05, 90.0], tmp_path / "parts", gap_s=100.0)
    trial = load_trial(parts)
    assert [r.sources for r in trial.runs] == [(str(p),) for p in parts]
    segs = detect_segments(trial)
    runs = [trial.run_index(s.t_start) for s in segs.items]
    dropped = [n for n in segs.notes if n.startswith("dropped: ")]
    kept = [n for n in segs.notes if n.startswith("kept: ")]
    # The zig-zag's piece at the start of part3: its (held, command) rudder began while nothing was logged.
    assert len(dropped) == 1, segs.notes
    assert "yaw zigzag" in dropped[0] and "the start of run 2 'part3'" in dropped[0]
    # The rudder step under way at the end of part1 is kept, flagged for the fit to judge whether it settled
    # (ident33; before, dropped); the zig-zag's piece at the end of part2 (57-91 s, from its first reversal
    # on) is kept for the whole-record fit, which needs no settled end (before, dropped).
    assert len(kept) == 2 and "yaw rudder_step at t = 8.00-20.00 s" in kept[0] and "still at 0.1741 rad" in kept[0]
    assert "yaw zigzag at t = 57.10-91.00 s" in kept[1] and "the end of run 1 'part2'" in kept[1]
    assert [(s.kind, s.cut_at_run_end) for s in segs.items if round(s.t_start, 1) in (8.0, 57.1)] == \
        [("rudder_step", True), ("zigzag", False)]
    # part2 begins with the rudder still at +10 deg: the rest of the step cut at the end of part1.
    (cut,) = [n for n in segs.notes if n.startswith("cut: ")]
    assert cut.startswith("cut: run 1 'part2' starts with delta up to 0.174 rad"), cut
    # Each run is segmented on its own: the rudder manoeuvres kept are those its file alone gives, minus
    # the cut ones. (Coast-downs found in the speed may move by a sample next to a run boundary.)
    for k, p in enumerate(parts):
        alone = load_trial([p])
        mine = [s for s, r in zip(segs.items, runs) if r == k and s.input_channel]
        theirs = [s for s in detect_segments(alone).items
                  if s.input_channel and not any(math.isclose(s.t_start + trial.runs[k].t_start, d, abs_tol=1e-6)
                                                 for d in _dropped(segs, k))]
        assert [(s.kind, round(s.t_start - trial.runs[k].t_start, 6)) for s in mine] == \
               [(s.kind, round(s.t_start, 6)) for s in theirs]
    counts = segs.notes[-1]
    assert counts == ("segments per run: run 0 'part1' (part1.csv): 1 (yaw rudder_step 1); "
                      "run 1 'part2' (part2.csv): 3 (yaw rudder_step 1, surge coast_down 1, yaw zigzag 1); "
                      "run 2 'part3' (part3.csv): 5 (surge coast_down 2, yaw rudder_step 3), 1 dropped at "
                      "a file boundary"), counts
    assert sum(int(part.split("): ", 1)[1].split(" ")[0].rstrip(",")) for part in counts.split("; ")) == len(segs.items)
    assert "note: dropped: yaw zigzag" in segment_table(segs)


def _dropped(segs, k: int) -> list[float]:
    """Start times [s, trial clock] of the segments of run ``k`` that the trial dropped (from their notes)."""
    return [float(n.split("t = ", 1)[1].split("-", 1)[0]) for n in segs.notes
            if n.startswith("dropped: ") and f"run {k} " in n]


def test_a_gap_longer_than_a_dropout_keeps_files_apart(table, tmp_path):
    """0.1 s between the files (one sample) continues the clock; 1.5 s (above the 1 s dropout limit at
    10 Hz: five intervals, at least 0.5 s) is a real gap."""
    joined = read_logs(_pieces(table, [60.0], tmp_path / "near"))
    assert [g.sources for g in group_runs(joined)] == [tuple(l.source for l in joined)]
    apart = read_logs(_pieces(table, [60.0], tmp_path / "far", gap_s=1.4))
    groups = group_runs(apart)
    assert [g.sources for g in groups] == [(apart[0].source,), (apart[1].source,)]
    assert not any(g.continued for g in groups)


def test_stated_runs_of_rotated_files_with_utc_times_are_joined(table, tmp_path):
    """A manifest stating the three files of one rotated UTC log as one run: before, refused as files
    of one run that do not overlap in absolute time; now one recording, as the unsplit file."""
    parts = _pieces(table, [20.05, 90.0], tmp_path / "parts", iso=True)
    trial = load_trial(parts, runs=[parts], run_names=["day"])
    assert [r.name for r in trial.runs] == ["day"] and trial.runs[0].sources == tuple(str(p) for p in parts)
    one = load_trial([_write(table, tmp_path / "day.csv", True)])
    assert len(trial.t) == len(one.t)
    np.testing.assert_allclose(trial.data["r"].to_numpy(), one.data["r"].to_numpy(), rtol=0, atol=1e-6)


def test_a_step_back_to_rest_cut_by_a_gap_is_kept_and_said(table, tmp_path):
    """Cut at 40 s, inside the rudder step back to zero (28-48 s): its input is at rest when part1 ends,
    so it is kept as its file alone gives it (12 s of the return to zero), with a note."""
    parts = _pieces(table, [40.05], tmp_path / "parts", gap_s=100.0)
    segs = detect_segments(load_trial(parts))
    kept = [n for n in segs.notes if n.startswith("kept: ")]
    assert len(kept) == 1 and "yaw rudder_step at t = 28.00-40.00 s" in kept[0] and "12.0 s logged" in kept[0], segs.notes
    assert any(s.kind == "rudder_step" and s.t_start == pytest.approx(28.0) for s in segs.items)
    assert not any(n.startswith(("dropped: ", "cut: ")) for n in segs.notes), segs.notes


def test_a_step_back_to_rest_cut_before_it_settled_is_unsure_and_left_out(table, tmp_path):
    """Cut at 40.05 s: the rudder step back to zero (28-48 s) holds 12 s, 2.8 of its fitted T = 4.2 s at the
    95 % upper bound, fewer than the 5 a settled response needs. Before, it was marked success and pooled
    (a Clarke83 step cut to 26.6 s of 80 s gave K +8.6 % success); now it is unsure with the reason and
    left out of K and T."""
    parts = _pieces(table, [40.05], tmp_path / "parts", gap_s=100.0)
    trial = load_trial(parts)
    fits = fit_trial(trial, segment_trial(trial), VESSEL, extend=False)
    cut = [f for f in fits.segment_fits if f.segment.cut_at_run_end]
    # The last step back to zero runs into the end of the log too, but holds 28 s (6.7 T): settled, kept.
    assert [(f.segment.kind, round(f.segment.t_start, 1), round(f.segment.t_end, 1)) for f in cut] == \
        [("rudder_step", 28.0, 40.0), ("rudder_step", 145.1, 173.1)]
    assert cut[1].success and cut[1].segment.cut_by.startswith("the end of the log (run 1 'part2'"), cut[1].message
    assert not cut[0].success and cut[0].message.startswith("unsure: the end of its run"), cut[0].message
    assert "12.0 s after the input change" in cut[0].message and "settled needs 5" in cut[0].message
    # The rule judged a fit that was itself fine (the message goes on with the fit's own, no other failure).
    assert cut[0].message.count("unsure:") == 1 and settled_at_run_end(cut[0]) is cut[0]


def test_a_rotated_file_that_gains_a_channel_continues_the_recording(table, tmp_path):
    """The speed appears only from the second file on (a GNSS that found its fix): still one recording,
    the speed NaN before its first sample and equal to the unsplit file's after it."""
    folder = tmp_path / "parts"
    folder.mkdir()
    first = _write(table[table["t"] < 60.0].drop(columns="u"), folder / "part1.csv", False)
    second = _write(table[table["t"] >= 60.0], folder / "part2.csv", False)
    trial = load_trial([first, second])
    one = load_trial([_write(table, tmp_path / "day.csv", False)])
    assert len(trial.runs) == 1 and trial.runs[0].sources == (str(first), str(second))
    u, t = trial.data["u"].to_numpy(), trial.t
    assert np.isnan(u[t < 59.95]).all()
    # (The grid rate comes from the fastest channel's median interval: equal to 1e-11 here.)
    np.testing.assert_allclose(u[t >= 60.0], one.data["u"].to_numpy()[t >= 60.0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(trial.data["r"].to_numpy(), one.data["r"].to_numpy(), rtol=0, atol=1e-9)


def test_segments_json_keeps_the_notes_of_what_was_dropped_at_a_boundary(table, tmp_path):
    # A user who segments once and fits later (`segment --json`, `fit --segments`) keeps the reasons.
    parts = _pieces(table, [20.05, 90.0], tmp_path / "parts", gap_s=100.0)
    segs = detect_segments(load_trial(parts))
    assert any(n.startswith("dropped: ") for n in segs.notes)
    path = write_json(segments_to_json(segs), tmp_path / "segments.json")
    back = segments_from_json(path)
    assert back.notes == segs.notes
    assert back.items == segs.items


def _cut_fit(fits, t_start: float):
    (f,) = [f for f in fits.segment_fits if f.segment.kind == "rudder_step" and f.segment.t_start == pytest.approx(t_start)]
    return f


def test_a_step_cut_by_the_end_of_a_single_file_is_judged_like_one_cut_at_a_file_boundary(table, tmp_path):
    """One file that stops at 40.05 s, inside the rudder step back to zero (28-48 s): the same 12 s as
    the file boundary of the test above, but no second file follows. Before, only a boundary with a gap
    to a next run was judged (this step was pooled as a success); now the end of the log is one too."""
    trial = load_trial([_write(table[table["t"] < 40.05], tmp_path / "short.csv", False)])
    segs = segment_trial(trial)
    fits = fit_trial(trial, segs, VESSEL, extend=False)
    cut = _cut_fit(fits, 28.0)
    assert cut.segment.cut_at_run_end and cut.segment.cut_by == "the end of the log", cut.segment
    assert not cut.success and cut.message.startswith("unsure: the end of the log cut the window at 12.0 s"), cut.message
    # The step before it ends at its input change (28 s): not cut, judged by the ordinary rules only.
    first = _cut_fit(fits, 8.0)
    assert not first.segment.cut_at_run_end and first.segment.cut_by == "" and "cut the window" not in first.message


def test_a_step_cut_by_the_end_of_the_last_run_is_judged(table, tmp_path):
    """Two runs with a gap; the second (from 100 s of the log, 100 s later) stops at 154.05 s, 10 s into the
    last rudder step back to zero (144 s): before, only the end of the first run was judged."""
    parts = _pieces(table[table["t"] < 154.05], [100.0], tmp_path / "parts", gap_s=100.0)
    trial = load_trial(parts)
    segs = segment_trial(trial)
    last = [s for s in segs.items if s.kind == "rudder_step"][-1]
    assert last.cut_at_run_end and last.cut_by == "the end of the log (run 1 'part2', the trial's last)", last
    assert last.t_end - last.t_start == pytest.approx(10.0, abs=0.15)
    f = _cut_fit(fit_trial(trial, segs, VESSEL, extend=False), last.t_start)
    assert not f.success and f.message.startswith("unsure: the end of the log (run 1"), f.message


def test_a_step_cut_by_a_dropout_inside_a_run_is_judged(table, tmp_path):
    """The gyro, compass and rudder stop logging from 40.05 to 45 s (one file, one run): the rudder step back
    to zero from 28 s is cut by that dropout at 12 s, as by the end of a file."""
    lost = table[(table["t"] < 40.05) | (table["t"] >= 45.0)].copy()
    trial = load_trial([_write(lost, tmp_path / "dropout.csv", False)])
    assert len(trial.run_list()) == 1
    segs = segment_trial(trial)
    (seg,) = [s for s in segs.items if s.kind == "rudder_step" and s.t_start == pytest.approx(28.0)]
    assert seg.cut_at_run_end and seg.cut_by.startswith("a dropout of ") and seg.t_end == pytest.approx(40.0), seg
    f = _cut_fit(fit_trial(trial, segs, VESSEL, extend=False), 28.0)
    assert not f.success and f.message.startswith("unsure: a dropout of "), f.message


def test_a_step_cut_before_it_settled_is_kept_out_of_the_joint_fits_of_the_others(table, tmp_path):
    """The step cut at 12 s (28-40 s, unsure) is no record of the ship's settled turn: before, the structure
    choice across segments and the joint fit with one rudder bias still read it (6 records); now they are
    made with the 5 others, and it keeps its own failed fit."""
    from pipeline.fit.nomoto_quality import SHARED_BIAS

    trial = load_trial(_pieces(table, [40.05], tmp_path / "parts", gap_s=100.0))
    fits = fit_trial(trial, segment_trial(trial), VESSEL, extend=False)
    yaw = [f for f in fits.segment_fits if f.segment.dof == "yaw"]
    cut = _cut_fit(fits, 28.0)
    assert not cut.success and cut.message.startswith("unsure: the end of its run")
    others = [f for f in yaw if f is not cut]
    assert len(others) == 5 and all(f.success for f in others)
    for f in others:
        parts = f.message.split("; ")
        assert any(p.startswith(f"{SHARED_BIAS} 5 records") for p in parts), f.message
        assert any(p.startswith("model structure chosen once across the 5 Nomoto segments") for p in parts), f.message
    assert fits.estimates["K_nomoto"].n_segments == 5 and fits.estimates["K_nomoto"].success


def _measured_rudder(frame: pd.DataFrame) -> pd.DataFrame:
    """The rudder as a servo's measured angle: the command through a 0.3 s lag, with 0.02 deg sensor noise."""
    out = frame.copy()
    cmd = frame["delta"].to_numpy()
    meas = np.empty_like(cmd)
    a = math.exp(-1.0 / (RATE * 0.3))
    meas[0] = cmd[0]
    for i in range(1, cmd.size):
        meas[i] = a * meas[i - 1] + (1.0 - a) * cmd[i - 1]
    out["delta"] = meas + np.random.default_rng(5).normal(0.0, math.radians(0.02), cmd.size)
    return out


def test_a_measured_rudder_zigzag_cut_by_a_gap_keeps_the_piece_before_it(table, tmp_path):
    """The 10/10 zig-zag (7 holds, 64-112 s) with its rudder logged as the servo's measured angle, the log cut
    at 90 s with the logger off for 100 s. Before: one zig-zag run across the boundary, dropped, its piece
    before the gap not fitted. Now the piece with four holds (64.3-90 s) is a zig-zag, kept with a note for the
    whole-record fit (which starts from an estimated state and needs no settled end), and fitted."""
    parts = _pieces(_measured_rudder(table), [90.05], tmp_path / "parts", gap_s=100.0)
    trial = load_trial(parts)
    segs = detect_segments(trial)
    (zz,) = [s for s in segs.items if s.kind == "zigzag"]
    assert trial.run_index(zz.t_start) == 0 and zz.t_end == pytest.approx(trial.runs[0].t_end), segment_table(segs)
    assert zz.t_start == pytest.approx(64.3, abs=0.15) and not zz.cut_at_run_end
    assert not any(n.startswith("dropped: ") for n in segs.notes), segs.notes
    assert any(n.startswith("kept: yaw zigzag at t = 64.30-90.00 s: the end of run 0 'part1'") for n in segs.notes)
    fits = fit_trial(trial, segs, VESSEL, extend=False)
    (f,) = [f for f in fits.segment_fits if f.segment.kind == "zigzag"]
    # (Its K is not compared: the log's yaw answers the command, the "measured" angle is the command lagged here.)
    assert f.model.startswith("nomoto") and f.success and np.isfinite(f.stderr["K"]), f.message


def test_a_cut_step_is_judged_by_the_slowest_time_constant_of_the_uncut_records_when_larger(table, tmp_path):
    """Cut at 52 s, 24 s after the step back to zero (28 s): 5.6 of its own T = 4.2 s at the upper bound, settled
    and pooled. Judged by a slower mode the trial's uncut records show (a window cut before that mode shows
    may fit a structure without it: a Clarke83 step cut 39.5 s after its change was settled for the first
    order's 2.4 s, not for the second order's 9.5 s envelope), it is not settled."""
    trial = load_trial(_pieces(table, [52.05], tmp_path / "parts", gap_s=100.0))
    fits = fit_trial(trial, segment_trial(trial), VESSEL, extend=False)
    cut = _cut_fit(fits, 28.0)
    assert cut.segment.cut_at_run_end and cut.success, cut.message
    assert settled_at_run_end(cut) is cut and settled_at_run_end(cut, (4.0, 0.1, "a faster mode")) is cut
    slow = settled_at_run_end(cut, (6.0, 0.1, "the envelope of the uncut records"))
    assert not slow.success and slow.message.startswith("unsure: the end of its run"), slow.message
    assert "3.9 times the envelope of the uncut records at its 95 % upper bound (6 +- 0.1 s" in slow.message
