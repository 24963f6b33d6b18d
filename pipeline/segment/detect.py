"""Detect coast-downs, steps, rudder steps, zig-zags, sinusoids and free decays in a Trial.

Input-driven segments start at a command change and end at the next change of any input, a
dropout, or once the response has settled (about five time constants later, estimated from the
data). Free decays in roll and pitch are found in the attitude itself: a sudden large angle,
released with no input, oscillating down. Without a logged surge input, coast-downs are found in
the speed itself (:mod:`pipeline.segment.speed_events`). Each segment carries a quality score in
[0, 1] built from the response's signal-to-noise ratio and its length in time constants.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from ..align.plausibility import check_segmentable, without_implausible
from ..records import DOF_ANGLE, DOF_CHANNELS, DOF_NAMES, INPUT_UNITS, RUN_BOUNDARY, Segment, Segments, Trial
from .decays import equilibrium, release_decays, release_index
from .inputs import Level, split_levels
from .quality import detection_quality, noise_std
from .replay import dof_channels, gaps_of
from .rudder import RudderChange, classify_changes, find_holds, is_command_like, sine_fit_r2, zigzag_runs
from .speed_events import coast_down_segments

#: Input channel -> (DOF, response channel) for input-driven segments.
INPUT_DOF = {
    "tau_x": ("surge", "u"), "tau_y": ("sway", "v"), "tau_n": ("yaw", "r"),
    "tau_k": ("roll", "p"), "tau_m": ("pitch", "q"), "delta": ("yaw", "r"),
}
#: Attitude channel -> DOF for free decays.
DECAY_DOF = {"phi": "roll", "theta": "pitch"}


def _settle_index(y: np.ndarray, fs: float, noise: float) -> tuple[int, float]:
    """Index at which a first-order-like response is within 2% of its final change, and T [s].

    The final value is the median of the last fifth; T is the time to 63% of the change.
    """
    n = len(y)
    if n < 5:
        return n, np.nan
    final = float(np.nanmedian(y[-max(n // 5, 2):]))
    start = float(np.nanmedian(y[: max(int(0.02 * fs), 1)]))
    change = final - start
    if not np.isfinite(change) or abs(change) < 3 * max(noise, 1e-12):
        return n, np.nan
    frac = (y - start) / change
    # Smooth over ~0.1 s so noise does not trigger the thresholds early.
    w = max(int(0.1 * fs), 1)
    frac = np.convolve(np.nan_to_num(frac), np.ones(w) / w, mode="same")
    i63 = int(np.argmax(frac >= 0.632)) if np.any(frac >= 0.632) else n
    return n, (i63 / fs if i63 < n else np.nan)


def _gaps(trial: Trial, channel: str | None):
    """Dropouts of ``channel``, of its DOF's velocity and attitude, or of an input (every dropout when
    None): a GNSS gap does not end a yaw step, a compass gap does."""
    if channel is None:
        return trial.gaps
    dof = DOF_NAMES.get(channel) or {a: d for d, a in DOF_ANGLE.items()}.get(channel)
    return gaps_of(trial, (channel, *(dof_channels(trial, dof) if dof else ()), *INPUT_UNITS))


def _gap_cut(trial: Trial, t_start: float, t_end: float, channel: str) -> float:
    for g in _gaps(trial, channel):
        if g.t_start >= t_start and g.t_start < t_end:
            t_end = g.t_start
    return t_end


def _in_gap(trial: Trial, t: float, channel: str | None = None) -> bool:
    """True when ``t`` [s] falls inside a dropout (of ``channel`` or an input): a segment starting
    there would span it."""
    return any(g.t_start < t < g.t_end for g in _gaps(trial, channel))


def _end_cut(trial: Trial, t_end: float, channel: str, later: list[float]) -> str:
    """What ended a step's window short of the next input change ('' when the next change did).

    A dropout (of the response, its DOF's channels or an input, :func:`_gaps`) that starts at the
    window's last sample, or the end of the run that holds it with no input change there.

    Parameters
    ----------
    trial : Trial
        Aligned trial.
    t_end : float
        The window's end [s] (after :func:`_gap_cut`).
    channel : str
        The response channel (its dropouts and its DOF's count, :func:`_gaps`).
    later : list of float
        Input changes after the step [s].

    Returns
    -------
    str
        ``'a dropout of <channel> at t = a-b s'``, ``'the end of run k ...'`` or ``'the end of the
        log'``; '' when an input change ends the window.
    """
    step = 1.0 / trial.fs
    gap = next((g for g in _gaps(trial, channel) if abs(g.t_start - t_end) <= 0.5 * step), None)
    if gap is not None:
        if gap.channel == RUN_BOUNDARY:
            return _run_end_text(trial, t_end)
        return f"a dropout of {gap.channel} at t = {gap.t_start:.2f}-{gap.t_end:.2f} s"
    run = trial.run_list()[trial.run_index(t_end)]
    if t_end >= min(run.t_end, float(trial.t[-1])) - 1.5 * step and not (later and later[0] <= t_end + 1.5 * step):
        return _run_end_text(trial, t_end)
    return ""


def _run_end_text(trial: Trial, t: float) -> str:
    """The end of the run that holds ``t`` [s], in words."""
    runs = trial.run_list()
    if len(runs) < 2:
        return "the end of the log"
    k = trial.run_index(t)
    if k < len(runs) - 1:
        return f"the end of its run (run {k} {runs[k].name!r}: a file boundary, a gap to the next run)"
    return f"the end of the log (run {k} {runs[k].name!r}, the trial's last)"


def _input_segments(trial: Trial) -> list[Segment]:
    t = trial.t
    fs = trial.fs
    inputs = [c for c in trial.data.columns if c in INPUT_UNITS and trial.has(c)]
    # All change instants of every input: a segment ends at the next change of any input.
    changes: list[float] = []
    per_input: dict[str, tuple[list[Level], list]] = {}
    measured_rudder = None
    for ch in inputs:
        u = trial.data[ch].to_numpy()
        if ch == "delta" and not is_command_like(u):
            # A measured servo angle: holds and ramps, not levels and jumps.
            noise = noise_std(u)
            holds = find_holds(u, fs, noise)
            finite = u[np.isfinite(u)]
            # A manoeuvre's step is well above the sensor noise and a tenth of the rudder's range.
            min_step = max(10 * noise, 0.1 * float(np.ptp(finite))) if finite.size else 0.0
            steps, varying_r = classify_changes(holds, fs, min_step)
            measured_rudder = (steps, varying_r)
            changes += [t[st.before.i_end] for st in steps] + [t[a] for a, _ in varying_r]
            continue
        levels, varying = split_levels(u, fs)
        per_input[ch] = (levels, varying)
        changes += [t[lv.i_start] for lv in levels] + [t[v.i_start] for v in varying]
    changes = sorted(set(changes))
    segs: list[Segment] = []
    for ch in inputs:
        if ch not in INPUT_DOF:
            continue
        dof, resp = INPUT_DOF[ch]
        if not trial.has(resp):
            continue
        if ch == "delta" and measured_rudder is not None:
            segs += _measured_rudder_segments(trial, *measured_rudder, changes)
            continue
        levels, varying = per_input[ch]
        zig_idx = _zigzag_runs(levels) if ch == "delta" else []
        in_zig = {i for run in zig_idx for i in run}
        for run in zig_idx:
            a, b = levels[run[0]], levels[run[-1]]
            t0 = float(t[a.i_start])
            t1 = _gap_cut(trial, t0, float(t[b.i_end - 1]), resp)
            if _in_gap(trial, t0, resp) or t1 - t0 < 5 / fs:
                continue
            segs.append(Segment("zigzag", dof, t0, t1, ch,
                                levels[run[0] - 1].value if run[0] > 0 else 0.0, a.value,
                                quality=1.0, label=f"{len(run)} rudder reversals"))
        for v in varying:
            seg = _sinusoid(trial, ch, dof, v.i_start, v.i_end)
            if seg is None or _in_gap(trial, seg.t_start, resp):
                continue
            t1 = _gap_cut(trial, seg.t_start, seg.t_end, resp)
            if t1 - seg.t_start >= 5 / fs:
                segs.append(replace(seg, t_end=t1))
        for k, lv in enumerate(levels):
            if k == 0 or k in in_zig:
                continue
            prev = levels[k - 1]
            if prev.i_end != lv.i_start:
                continue  # a varying stretch or missing data came between: not a clean step
            t0 = float(t[lv.i_start])
            if _in_gap(trial, t0, resp):
                continue  # the response at the input change was not logged
            later = [c for c in changes if c > t0 + 0.5 / fs]
            t_end = min(later[0] if later else float(t[-1]), float(t[lv.i_end - 1]))
            t_end = _gap_cut(trial, t0, t_end, resp)
            cut_by = _end_cut(trial, t_end, resp, later)
            window = trial.window(t0, t_end)
            y = window[resp].to_numpy()
            noise = noise_std(y)
            _, tau = _settle_index(y, fs, noise)
            if np.isfinite(tau) and ch != "delta" and t0 + 8 * tau < t_end:
                # A rudder step's window ends at the next input change: a noisy settle-time
                # estimate of a slow ship must not cut it (the whole-record fit uses it all).
                t_end, cut_by = t0 + 8 * tau, ""
            if t_end - t0 < 5 / fs:
                continue
            if ch == "delta":
                kind = "rudder_step"
            elif abs(lv.value) <= 0.05 * max(abs(prev.value), 1e-12):
                kind = "coast_down"
            else:
                kind = "step"
            y = trial.window(t0, t_end)[resp].to_numpy()
            snr = abs(np.nanmedian(y[-max(len(y) // 10, 2):]) - np.nanmedian(y[:3])) / max(noise, 1e-12)
            if kind == "coast_down":
                snr = abs(np.nanmedian(y[:3])) / max(noise, 1e-12)
            if ch == "delta":
                snr = max(snr, _heading_snr(trial, t0, t_end))
            q = detection_quality(snr, (t_end - t0) / tau if np.isfinite(tau) else np.nan)
            segs.append(Segment(kind, dof, t0, float(t_end), ch, prev.value, lv.value, quality=q,
                                label=f"T~{tau:.2f} s, SNR {snr:.0f}" if np.isfinite(tau) else f"SNR {snr:.0f}",
                                cut_at_run_end=bool(cut_by), cut_by=cut_by))
    return segs


def _heading_snr(trial: Trial, t0: float, t1: float) -> float:
    """Heading change over a window against the compass noise: a slow ship's rudder step moves the
    heading by many degrees while its yaw rate barely leaves the gyro noise."""
    if not trial.has("psi"):
        return 0.0
    psi = trial.window(t0, t1)["psi"].to_numpy()
    psi = psi[np.isfinite(psi)]
    if psi.size < 4:
        return 0.0
    psi = np.unwrap(psi)
    return float(np.ptp(psi) / max(noise_std(psi), 1e-6))


def _measured_rudder_segments(trial: Trial, steps: list[RudderChange], varying: list[tuple[int, int]],
                              changes: list[float]) -> list[Segment]:
    """Rudder steps, zig-zags and sinusoids of a measured rudder angle (:mod:`pipeline.segment.rudder`)."""
    t = trial.t
    fs = trial.fs
    segs: list[Segment] = []
    runs = zigzag_runs(steps)
    in_zig = {k for run in runs for k in run}
    # A zig-zag that a run boundary or a dropout interrupts is a piece on each side, each a zig-zag
    # of its own when it holds three holds (its first change logged, the state there estimated).
    runs = [piece for run in runs
            for piece in _split_at_gaps(trial, run, [float(t[steps[k].before.i_end]) for k in run], "r")
            if len(piece) >= 3]
    for run in runs:
        first, last = steps[run[0]], steps[run[-1]]
        t0 = float(t[first.before.i_end])
        t1 = _gap_cut(trial, t0, float(t[last.after.i_end - 1]), "r")
        if _in_gap(trial, t0, "r") or t1 - t0 < 5 / fs:
            continue
        segs.append(Segment("zigzag", "yaw", t0, t1, "delta", first.before.value, first.after.value, quality=1.0,
                            label=f"{len(run)} rudder holds, measured rudder"))
    u = trial.data["delta"].to_numpy()
    for i0, i1 in (piece for a, b in varying for piece in _pieces_between_gaps(trial, a, b, "r")):
        seg = u[i0:i1]
        if len(seg) < 8 or not np.all(np.isfinite(seg)):
            continue
        r2, w, amp = sine_fit_r2(seg, fs)
        periods = w * (i1 - i0) / fs / (2 * np.pi) if np.isfinite(w) else 0.0
        t0, t1 = float(t[i0]), float(t[i1 - 1])
        if r2 < 0.9 or periods < 1.0 or _in_gap(trial, t0, "r"):
            continue
        t1 = _gap_cut(trial, t0, t1, "r")
        segs.append(Segment("sinusoid", "yaw", t0, t1, "delta", 0.0, amp, quality=float(np.clip(periods / 3, 0, 1)),
                            label=f"omega {w:.4g} rad/s, {periods:.1f} periods, sine fit R^2 {r2:.3f}"))
    for k, st in enumerate(steps):
        if k in in_zig:
            continue
        t0 = float(t[st.before.i_end])
        if _in_gap(trial, t0, "r"):
            continue
        later = [c for c in changes if c > t0 + 0.5 / fs]
        t1 = min(later[0] if later else float(t[-1]), float(t[st.after.i_end - 1]))
        t1 = _gap_cut(trial, t0, t1, "r")
        cut_by = _end_cut(trial, t1, "r", later)
        if t1 - t0 < 5 / fs:
            continue
        ramp = (st.after.i_start - st.before.i_end) / fs
        snr = _heading_snr(trial, t0, t1)
        if trial.has("r"):
            r = trial.window(t0, t1)["r"].to_numpy()
            snr = max(snr, abs(np.nanmedian(r[-max(len(r) // 10, 2):]) - np.nanmedian(r[:3]))
                      / max(noise_std(r), 1e-12))
        segs.append(Segment("rudder_step", "yaw", t0, t1, "delta", st.before.value, st.after.value,
                            quality=detection_quality(snr, (t1 - t0) / max(ramp, 1.0)),
                            label=f"measured rudder, {ramp:.1f} s ramp, SNR {snr:.0f}",
                            cut_at_run_end=bool(cut_by), cut_by=cut_by))
    return segs


def _split_at_gaps(trial: Trial, items: list[int], times: list[float], channel: str) -> list[list[int]]:
    """``items`` (in time order, at ``times`` [s]) in groups that no dropout of ``channel`` (:func:`_gaps`,
    run boundaries included) separates."""
    gaps = _gaps(trial, channel)
    out: list[list[int]] = []
    for k, (item, tk) in enumerate(zip(items, times)):
        if k and not any(times[k - 1] <= g.t_start < tk for g in gaps):
            out[-1].append(item)
        else:
            out.append([item])
    return out


def _pieces_between_gaps(trial: Trial, i0: int, i1: int, channel: str) -> list[tuple[int, int]]:
    """Sample ranges ``[a, b)`` of ``[i0, i1)`` that no dropout of ``channel`` (or run boundary) interrupts."""
    t = trial.t
    pieces, a = [], i0
    for g in sorted(_gaps(trial, channel), key=lambda g: g.t_start):
        if t[i0] <= g.t_start < t[i1 - 1]:
            b = int(np.searchsorted(t, g.t_start, side="right"))
            if b > a:
                pieces.append((a, b))
            a = max(a, int(np.searchsorted(t, g.t_end, side="left")))
    if i1 > a:
        pieces.append((a, i1))
    return pieces


def _zigzag_runs(levels: list[Level]) -> list[list[int]]:
    """Runs of at least 3 consecutive rudder levels alternating +a, -a (same magnitude)."""
    runs: list[list[int]] = []
    cur: list[int] = []
    for k, lv in enumerate(levels):
        if lv.value == 0:
            if len(cur) >= 3:
                runs.append(cur)
            cur = []
            continue
        if cur:
            p = levels[cur[-1]]
            if p.i_end == lv.i_start and np.sign(p.value) == -np.sign(lv.value) and \
                    abs(abs(p.value) - abs(lv.value)) <= 0.05 * abs(lv.value):
                cur.append(k)
                continue
            if len(cur) >= 3:
                runs.append(cur)
        cur = [k]
    if len(cur) >= 3:
        runs.append(cur)
    return runs


def _sinusoid(trial: Trial, ch: str, dof: str, i0: int, i1: int) -> Segment | None:
    u = trial.data[ch].to_numpy()[i0:i1]
    if len(u) < 8:
        return None
    spec = np.abs(np.fft.rfft(u - u.mean()))
    freqs = np.fft.rfftfreq(len(u), 1 / trial.fs)
    k = int(np.argmax(spec[1:]) + 1)
    periods = freqs[k] * len(u) / trial.fs
    if periods < 1.0:
        return None
    t = trial.t
    return Segment("sinusoid", dof, float(t[i0]), float(t[i1 - 1]), ch, 0.0, float(np.ptp(u) / 2),
                   quality=float(np.clip(periods / 3, 0, 1)),
                   label=f"omega {2 * np.pi * freqs[k]:.4g} rad/s, {periods:.1f} periods")


def _decay_segments(trial: Trial, busy: list[tuple[float, float]]) -> list[Segment]:
    """Roll and pitch free decays: large releases from an angle, oscillating out with no input."""
    segs = []
    t = trial.t
    fs = trial.fs
    for ang, dof in DECAY_DOF.items():
        if not trial.has(ang):
            continue
        y = trial.data[ang].to_numpy()
        noise = noise_std(y)
        base = equilibrium(y, fs, noise)
        dev = np.abs(np.nan_to_num(y - base))
        # 10 sigma never happens by chance, and at the high regression noise (attitude 0.006 rad)
        # still finds a 6 deg pitch release, which 20 sigma (6.9 deg) missed.
        thresh = max(10 * noise, np.radians(1.0))
        i = 0
        n = len(y)
        while i < n:
            hits = np.flatnonzero(dev[i:] > thresh)
            if len(hits) == 0:
                break
            j = i + int(hits[0])
            # The release is the end of the hold (the peak itself for an instantaneous release),
            # not where a hand or a heeling moment began to heel the hull.
            k0 = release_index(y - base, j, noise)
            # Decay ends when the deviation stays below the threshold for a second.
            below = dev[k0:] < max(3 * noise, 0.05 * dev[k0])
            run = np.convolve(below.astype(int), np.ones(int(fs)), mode="valid") if len(below) >= fs else np.array([])
            done = np.flatnonzero(run >= int(fs))
            # Keep the quiet second too: noise after the decay costs the fit nothing, and the
            # last small swings it holds still carry information on zeta and wn.
            k1 = k0 + (int(done[0]) + int(fs) if len(done) else len(below) - 1)
            t0, t1 = float(t[k0]), float(t[min(k1, n - 1)])
            t1 = _gap_cut(trial, t0, t1, ang)
            if _in_gap(trial, t0, ang):
                i = max(k1, k0 + 1) + 1
                continue
            seg_y = y[k0:min(k1, n - 1) + 1] - base
            crossings = int(np.sum(np.diff(np.sign(seg_y)) != 0))
            overlaps_input = any(a < t1 and t0 < b for a, b in busy)
            if crossings >= 2 and t1 - t0 > 10 / fs and not overlaps_input:
                snr = dev[k0] / max(noise, 1e-12)
                segs.append(Segment("free_decay", dof, t0, t1, None, 0.0, 0.0,
                                    quality=detection_quality(snr, crossings / 2),
                                    label=f"from {np.degrees(y[k0]):.1f} deg, {crossings} zero crossings"))
            i = max(k1, k0 + 1) + 1
    return segs


def _has_input_for(trial: Trial, dof: str) -> bool:
    """True when the trial logs an input that drives ``dof`` (any sensor suffix)."""
    return any(c.split("@")[0] in INPUT_DOF and INPUT_DOF[c.split("@")[0]][0] == dof and trial.has(c)
               for c in trial.data.columns)


#: An input within this fraction of its largest magnitude in the trial (or within 3 noise sigma) is at rest.
REST_FRACTION = 0.05
#: Stretch [s] at a run's end or start over which an input must stay at rest for no manoeuvre to be under way.
BOUNDARY_S = 2.0


def _under_way(s: Segment) -> bool:
    """Whether the manoeuvre of an input-driven segment was still going at the segment's end.

    Zig-zags and sinusoids are; a step is unless it brought the input back to rest (a coast-down,
    a rudder step back to zero: the rest after it is no manoeuvre); decays and coast-downs found
    from the speed have no input and are over once they have died out.
    """
    if s.input_channel is None:
        return False
    if s.kind in ("zigzag", "sinusoid"):
        return True
    return abs(s.input_after) > REST_FRACTION * max(abs(s.input_before), abs(s.input_after))


def _measured_input(trial: Trial, s: Segment) -> bool:
    """Whether the segment's input is a measured rudder angle (holds and ramps with sensor noise), not a held command."""
    u = trial.window(s.t_start, s.t_end)[s.input_channel].to_numpy(dtype=float)
    return s.input_channel.split("@")[0] == "delta" and not is_command_like(u[np.isfinite(u)])


def _inputs_under_way(trial: Trial, t0: float, t1: float) -> list[str]:
    """The inputs not at rest (``REST_FRACTION``) somewhere in ``t0 .. t1`` [s], as ``'delta up to 0.17 rad'``."""
    out = []
    window = trial.window(t0, t1)
    for ch in trial.data.columns:
        if ch.split("@")[0] not in INPUT_UNITS or not trial.has(ch):
            continue
        u = trial.data[ch].to_numpy()
        w = np.abs(window[ch].to_numpy())
        w = w[np.isfinite(w)]
        if w.size and float(np.max(w)) > max(REST_FRACTION * float(np.nanmax(np.abs(u))), 3 * noise_std(u)):
            out.append(f"{ch} up to {float(np.max(w)):.3g} {INPUT_UNITS[ch.split('@')[0]]}")
    return out


def _file_boundaries(trial: Trial, segs: list[Segment]) -> tuple[list[Segment], list[str]]:
    """Drop the segments a boundary between two runs cuts at their start, say what else it cuts, count every run's segments.

    Runs are recordings with a real gap between them (files that continue one clock are one run,
    :func:`pipeline.align.runs.group_runs`). An input-driven segment that starts at the first sample
    of a run that follows another began while nothing was logged (its input before is unknown): it
    is dropped, with a note naming it, unless it is a piece of a zig-zag or sinusoid driven by a
    measured rudder angle (:func:`_measured_input`), which the whole-record fit takes from an
    estimated initial state with no servo state to start. A segment whose window reaches the last
    sample of a run that another run follows is kept with a note: a step (back to rest or not,
    :func:`_under_way`) with ``Segment.cut_at_run_end`` set, so the fit judges whether its response
    settled (:func:`pipeline.fit.segment_fit.settled_at_run_end`); a zig-zag or sinusoid piece as it
    is (a whole-record fit needs no settled end). An input under way at a boundary
    (``BOUNDARY_S``) that no segment accounts for (a stretch too short to be a segment) gets a note
    too, so nothing a boundary cuts goes unsaid.

    Returns
    -------
    kept : list[Segment]
        The segments kept (steps a boundary ended flagged).
    notes : list[str]
        One per dropped segment, per segment kept with its window cut by a boundary, per input
        under way at a boundary otherwise unaccounted for, then the count of each run's segments
        (with its files); empty for a trial of one file.
    """
    runs = trial.run_list()
    if len(runs) < 2 and all(len(r.sources) < 2 for r in runs):
        return segs, []
    step = 1.0 / trial.fs
    kept: list[Segment] = []
    notes: list[str] = []
    dropped = [0] * len(runs)
    said: set[tuple[int, str]] = set()
    for s in segs:
        k = trial.run_index(s.t_start)
        run = runs[k]
        reaches_end = k < len(runs) - 1 and s.t_end >= run.t_end - step and s.input_channel is not None
        at_start = k > 0 and s.t_start <= run.t_start + step and s.input_channel is not None
        piece = s.kind in ("zigzag", "sinusoid")
        if at_start and not (piece and _measured_input(trial, s)):
            dropped[k] += 1
            said.add((k, "start"))
            notes.append(f"dropped: {s.dof} {s.kind} at t = {s.t_start:.2f}-{s.t_end:.2f} s cut by the start of run "
                         f"{k} {run.name!r} (a gap after the run before it): the manoeuvre went on while nothing was "
                         f"logged, so its input before the first sample is unknown")
            continue
        if not (reaches_end or at_start):
            kept.append(s)
            continue
        if piece:
            # A whole-record fit simulates the logged input from an estimated initial state: a piece of a
            # zig-zag or sinusoid needs no settled end, and with a measured rudder angle no servo state.
            where = " and ".join(w for w, c in ((f"the start of run {k} {run.name!r}", at_start),
                                                (f"the end of run {k} {run.name!r}", reaches_end)) if c)
            said.update({(k, side) for side, c in (("start", at_start), ("end", reaches_end)) if c})
            notes.append(f"kept: {s.dof} {s.kind} at t = {s.t_start:.2f}-{s.t_end:.2f} s: {where} (a file boundary, "
                         f"a gap) cuts the manoeuvre; the piece logged ({s.t_end - s.t_start:.1f} s) is fitted whole "
                         f"from its estimated initial state"
                         + (" (the rudder is a measured angle: no servo state to start)" if at_start else ""))
            kept.append(s)
            continue
        said.add((k, "end"))
        kept.append(replace(s, cut_at_run_end=True, cut_by=_run_end_text(trial, s.t_end)))
        rest = ("with its input back at rest" if not _under_way(s) else
                f"with its input still at {s.input_after:.4g} {INPUT_UNITS.get(s.input_channel.split('@')[0], '')}")
        notes.append(f"kept: {s.dof} {s.kind} at t = {s.t_start:.2f}-{s.t_end:.2f} s: the end of run {k} {run.name!r} "
                     f"(a file boundary, a gap to the next run) ends its window {rest}; fitted on the "
                     f"{s.t_end - s.t_start:.1f} s logged and judged by whether its response settled")
    for k, run in enumerate(runs):
        sides = ([("end", run.t_end - BOUNDARY_S, run.t_end)] if k < len(runs) - 1 else []) + \
                ([("start", run.t_start, run.t_start + BOUNDARY_S)] if k > 0 else [])
        for side, t0, t1 in sides:
            busy = _inputs_under_way(trial, t0, t1) if (k, side) not in said else []
            if busy:
                notes.append(f"cut: run {k} {run.name!r} {'ends' if side == 'end' else 'starts'} with "
                             f"{', '.join(busy)} (a manoeuvre under way at a file boundary, a gap "
                             f"{'to the next run' if side == 'end' else 'after the run before it'}): its part "
                             f"{'after the last' if side == 'end' else 'before the first'} segment of this run is "
                             f"not fitted")
    counts = []
    for k, run in enumerate(runs):
        mine = [s for s in kept if trial.run_index(s.t_start) == k]
        kinds: dict[str, int] = {}
        for s in mine:
            kinds[f"{s.dof} {s.kind}"] = kinds.get(f"{s.dof} {s.kind}", 0) + 1
        what = ", ".join(f"{n} {v}" for n, v in kinds.items())
        counts.append(f"run {k} {run.name!r} ({', '.join(Path(f).name for f in run.sources)}): {len(mine)}"
                      + (f" ({what})" if what else "")
                      + (f", {dropped[k]} dropped at a file boundary" if dropped[k] else ""))
    notes.append(f"segments per run: {'; '.join(counts)}")
    return kept, notes


def detect_segments(trial: Trial) -> Segments:
    """Detect every segment kind in ``trial``.

    Input-driven segments come from the logged inputs; when no surge input is logged (a GPS-only
    log), coast-downs are found from the speed alone by :mod:`pipeline.segment.speed_events`. A
    segment cut by a boundary between two runs (files with a gap between them) is dropped with a
    note, and a trial of several files counts every run's segments in ``Segments.notes``.

    Parameters
    ----------
    trial : Trial
        Aligned trial.

    Returns
    -------
    Segments
        In time order, ``origin='detected'``; ``notes`` as above.
    """
    check_segmentable(trial)
    trial = without_implausible(trial)
    # A released heeling moment (tau_k/tau_m back to zero) starts a free decay at the release.
    segs = release_decays(trial, _input_segments(trial))
    if not _has_input_for(trial, "surge"):
        segs += coast_down_segments(trial)
    # Roll/pitch excursions during input-driven manoeuvres are forced responses, not free decays;
    # a heeling test's hold is one, and its decay is already found from the release.
    busy = [(s.t_start, s.t_end) for s in segs
            if s.kind in ("step", "zigzag", "sinusoid", "free_decay") and s.dof in ("roll", "pitch")]
    segs += _decay_segments(trial, busy)
    segs.sort(key=lambda s: (s.t_start, s.dof))
    segs, notes = _file_boundaries(trial, segs)
    return Segments(trial.name, tuple(segs), tuple(notes))


def segment_table(segments: Segments) -> str:
    """Plain-text table of segments for the terminal.

    Parameters
    ----------
    segments : Segments
        Segments to list, one row each (``level`` is ``input_after``), then its notes.
    """
    head = f"{'#':>3} {'kind':<12} {'dof':<6} {'start [s]':>10} {'end [s]':>10} {'input':<6} {'level':>10} {'quality':>7} {'origin':<9} label"
    rows = [head, "-" * len(head)]
    for i, s in enumerate(segments.items):
        rows.append(f"{i:>3} {s.kind:<12} {s.dof:<6} {s.t_start:>10.2f} {s.t_end:>10.2f} {s.input_channel or '-':<6} "
                    f"{s.input_after:>10.4g} {s.quality:>7.2f} {s.origin:<9} {s.label}")
    rows += [f"note: {n}" for n in segments.notes]
    return "\n".join(rows)
