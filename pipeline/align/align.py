"""Align raw logs into one Trial: one clock, uniform rate, body frame, derived channels."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from ..errors import AlignError
from ..geo import latlon_to_ned, wrap_pi
from ..records import CHANNEL_UNITS, INPUT_KINDS, INPUT_UNITS, RUN_BOUNDARY, Channel, Gap, RawLog, Run, Trial
from ..vessel import Vessel
from .antenna import apply_sensors
from .clock import ClockOffset
from .gnss import collapse_held_fixes
from .runs import RunGroup, group_runs
from .plausibility import check_duration, plausibility_notes
from .resample import find_gaps, resample_channel

#: Highest rate the aligner resamples to by default [Hz]; faster sensors are decimated by
#: interpolation, which is fine for the dynamics of a surface vessel.
MAX_DEFAULT_RATE = 100.0
#: Formats whose time stamps are a logger's rows, not the receiver's fix times: only there can a GNSS
#: fix be repeated (held) on later rows (``pipeline.align.gnss.collapse_held_fixes``).
LOGGER_ROW_FORMATS = frozenset({"csv"})


def _native_rate(ch: Channel) -> float:
    dt = np.diff(ch.t)
    return 1.0 / float(np.median(dt)) if len(dt) else 0.0


def align(logs: Sequence[RawLog], name: str = "trial", fs: float | None = None,
          offsets: Mapping[str, float] | str | None = "auto", gap_threshold: float | None = None,
          vessel: Vessel | None = None, runs: Sequence[Sequence[str]] | None = None,
          run_names: Sequence[str] | None = None, input_kinds: Mapping[str, str] | None = None) -> Trial:
    """Put the channels of one or more raw logs on one uniform clock, run by run.

    Parameters
    ----------
    logs : Sequence[RawLog]
        Logs of the same trial: sensors of one recording, or several recordings (runs).
    name : str
        Trial name.
    fs : float, optional
        Output rate [Hz]; default the fastest state channel, at most ``MAX_DEFAULT_RATE``.
    offsets : Mapping[str, float] or "auto" or None
        ``"auto"`` (the default; None means the same): group the logs into runs with
        :func:`pipeline.align.runs.group_runs` (overlapping absolute time, or a clock shared by
        cross-correlation; non-overlapping absolute times are never merged) and estimate each
        log's offset within its run (:func:`pipeline.align.clock.estimate_offsets`); offsets,
        their standard errors and methods, and the grouping with its reasons, go to
        ``Trial.notes`` and ``Trial.runs``. A mapping declares all logs one run and gives the
        clock offset [s] to add to each log (keyed by ``RawLog.source``); logs it does not name
        share the first log's clock, so ``{}`` means "the logs already share one clock".
    gap_threshold : float, optional
        Dropout threshold [s] (default: :func:`pipeline.align.resample.find_gaps`).
    vessel : Vessel, optional
        Its ``[sensors]`` table (:mod:`pipeline.align.antenna`): dual-antenna headings
        ``psi@<baseline>`` and GPS lever-arm corrections to the body origin, applied on the
        uniform grid before body velocities are derived.
    runs : Sequence[Sequence[str]], optional
        Runs stated by the user (a manifest's ``[[runs]]``): the sources of each run; the
        offsets inside each are still estimated. Overrides the automatic grouping.
    run_names : Sequence[str], optional
        Names of the stated ``runs``.
    input_kinds : Mapping[str, str], optional
        Input channel (canonical name, any ``@sensor`` suffix matches the base name) ->
        ``command`` (zero-order hold) or ``measured`` (interpolated); overrides what the
        reader said (``Channel.input_kind``; default ``command``).

    Returns
    -------
    Trial
        Column ``t`` on one uniform grid; run after run, each followed by a NaN gap (a
        :class:`pipeline.records.Gap` on channel ``RUN_BOUNDARY``); canonical channels, derived
        ``x_n``, ``y_e`` (from lat/lon, about each run's first fix) and ``u``, ``v`` (from speed
        and course over ground and heading) where they were not logged. Held GNSS fixes
        (:mod:`pipeline.align.gnss`) count once.

    Raises
    ------
    AlignError
        No logs, no channels, a channel with non-increasing time, an unknown input kind, a stated
        run whose files do not overlap in time, a log with only inputs and no clock shared with
        any other log, or (stated runs) a log whose offset can be found neither by absolute time
        nor by a significant cross-correlation.
    ConfigError
        A malformed ``[sensors]`` table in the vessel config.
    """
    if not logs:
        raise AlignError("align: expected at least one log, found none")
    for k, v in (input_kinds or {}).items():
        if v not in INPUT_KINDS:
            raise AlignError(f"align: input kind of {k!r}: expected one of {list(INPUT_KINDS)}, found {v!r}")
    for log in logs:
        for ch in log.channels.values():
            if len(ch.t) and np.any(np.diff(ch.t) <= 0):
                raise AlignError(f"{log.source}: channel {ch.name!r}: expected strictly increasing time, "
                                 f"found a step back at t = {ch.t[np.flatnonzero(np.diff(ch.t) <= 0)[0] + 1]:.6f} s")
    if not any(len(c.t) for log in logs for c in log.channels.values()):
        raise AlignError(f"align: expected channels with samples, found none in {[l.source for l in logs]}")
    notes: list[str] = []
    collapsed = []
    for log in logs:
        # Only a logger's rows can hold a fix: NMEA, UBX and the autopilot and bag formats stamp each fix
        # with its own time, so identical values there are a boat at rest, not a copy.
        if log.format not in LOGGER_ROW_FORMATS:
            collapsed.append(log)
            continue
        chans, held = collapse_held_fixes(log.channels)
        notes += [f"{log.source}: {h}" for h in held]
        collapsed.append(replace(log, channels=chans) if held else log)
    logs = collapsed
    by_source = {l.source: l for l in logs}
    if offsets is None or isinstance(offsets, str):
        if offsets not in (None, "auto"):
            raise AlignError(f"align: offsets expected 'auto' or a mapping source -> seconds, found {offsets!r}")
        groups = group_runs(logs, explicit=runs, names=run_names)
    else:
        given = {src: ClockOffset(float(off), 0.0, "given") for src, off in dict(offsets).items()}
        groups = [RunGroup(name, tuple(l.source for l in logs),
                           {l.source: given.get(l.source, ClockOffset(0.0, 0.0, "given")) for l in logs},
                           "one run: clock offsets given by the caller")]
    if len(groups) > 1 or runs is not None or any(g.continued for g in groups):
        notes.append(f"runs: {len(groups)} - " + " | ".join(
            f"{g.name} ({', '.join(Path(s).name for s in g.sources)}): {g.reason}" for g in groups))
    for g in groups:
        # Before choosing a rate: a single epoch has none, and its error should say so.
        check_duration([c for l in logs if l.source in g.sources for c in l.channels.values()])
    if fs is None:
        # Per run, with rotated files joined: the rate of a recording, not of its pieces.
        run_chans = [c for g in groups for c in run_channels([by_source[s] for s in g.sources], g, {})[0].values()]
        rates = [_native_rate(c) for c in run_chans if c.name.split("@")[0] not in INPUT_UNITS and len(c.t) > 1]
        rates = rates or [_native_rate(c) for c in run_chans if len(c.t) > 1]
        fs = min(max(rates), MAX_DEFAULT_RATE) if rates else 0.0
    if not fs > 0:
        raise AlignError(f"align: expected a positive sample rate [Hz], found {fs}")
    fs = float(fs)
    frames, gaps, run_records = [], [], []
    run_sample_times: list[tuple[pd.DataFrame, dict[str, np.ndarray]]] = []
    index = 0
    gap_rows = max(int(np.ceil(RUN_GAP_S * fs)), 2)
    for k, g in enumerate(groups):
        multi = len(groups) > 1
        tag = f"run {g.name}: " if multi else ""
        frame, run_gaps, run_notes, kinds, t_first, run_times = _align_run(
            [by_source[s] for s in g.sources], g, fs, gap_threshold, vessel, input_kinds or {})
        shift = index / fs
        frame["t"] = frame["t"].to_numpy() + shift
        run_sample_times.append((frame, {key: times + shift for key, times in run_times.items()}))
        gaps += [Gap(x.channel, x.t_start + shift, x.t_end + shift) for x in run_gaps]
        notes += [tag + n for n in run_notes]
        t_end = shift + (len(frame) - 1) / fs
        abs_start = _run_abs_start([by_source[s] for s in g.sources], g, t_first)
        tod = _run_tod([by_source[s] for s in g.sources], g, t_first)
        run_records.append(Run(g.name, g.sources, {s: o.offset_s for s, o in g.offsets.items()},
                               {s: o.stderr_s for s, o in g.offsets.items()}, abs_start, float(shift), float(t_end),
                               g.reason, kinds, tod))
        frames.append(frame)
        index += len(frame)
        if k < len(groups) - 1:
            t_gap = (index + np.arange(gap_rows)) / fs
            frames.append(pd.DataFrame({"t": t_gap}))
            gaps.append(Gap(RUN_BOUNDARY, float(t_end), float((index + gap_rows) / fs)))
            index += gap_rows
    data = pd.concat(frames, ignore_index=True) if len(frames) > 1 else frames[0]
    data = as_float64_block(data[_ordered(data.columns)])
    return Trial(name=name, data=data, fs=fs, gaps=tuple(gaps), sources=tuple(l.source for l in logs),
                 notes=tuple(notes), summaries=tuple(l.summary for l in logs), runs=tuple(run_records),
                 sample_times=merge_sample_times(run_sample_times, data.columns))


def merge_sample_times(runs: Sequence[tuple[pd.DataFrame, Mapping[str, np.ndarray]]],
                       columns) -> dict[str, np.ndarray]:
    """The trial's real sample times of each slow channel, run after run.

    A channel can be slower than the grid in one run and measured at every grid sample in another
    (u derived from a 5 Hz GNSS in an autopilot log, u logged at the grid rate in a CSV of the same
    day): in such a run every grid row where the channel holds a value is a real sample, else
    ``Trial.measured_rows`` would find no measurement there at all.

    Parameters
    ----------
    runs : sequence of (pandas.DataFrame, Mapping[str, numpy.ndarray])
        Per run, in trial-clock order: its resampled frame (column ``t`` on the trial clock) and
        its slow channels' sample times [s, trial clock].
    columns : iterable of str
        Columns of the trial's data; slow channels not among them are dropped.

    Returns
    -------
    dict[str, numpy.ndarray]
        Channel -> increasing sample times [s, trial clock].
    """
    slow = {key for _, times in runs for key in times if key in columns}
    out: dict[str, list[np.ndarray]] = {key: [] for key in slow}
    for frame, times in runs:
        for key in slow:
            if key in times:
                out[key].append(np.asarray(times[key], float))
            elif key in frame:
                values = frame[key].to_numpy(dtype=float)
                out[key].append(frame["t"].to_numpy(dtype=float)[np.isfinite(values)])
    return {key: np.concatenate(parts) for key, parts in out.items()}


def as_float64_block(frame: pd.DataFrame) -> pd.DataFrame:
    """The frame's columns as one float64 array, each column contiguous in memory.

    float64 throughout: float32 keeps 7 significant digits, which puts a latitude of 57 deg on a
    1 m grid and a Unix time on a 2-minute one. One block of ``columns x rows`` (a 2-hour trial at
    50 Hz with 26 channels is 75 MB) instead of one per channel kind, so a column is a view, no copy.

    Parameters
    ----------
    frame : pandas.DataFrame
        Numeric columns (booleans and integers are converted); a frame holding anything else is
        returned unchanged.

    Returns
    -------
    pandas.DataFrame
        Same columns, index and values.
    """
    if not all(pd.api.types.is_numeric_dtype(dt) or pd.api.types.is_bool_dtype(dt) for dt in frame.dtypes):
        return frame
    values = np.empty((frame.shape[1], frame.shape[0]), dtype=np.float64)
    for k, col in enumerate(frame.columns):
        values[k] = frame[col].to_numpy(dtype=np.float64, na_value=np.nan)
    return pd.DataFrame(values.T, columns=frame.columns, index=frame.index, copy=False)


#: NaN stretch between two runs in ``Trial.data`` [s] (at least two samples).
RUN_GAP_S = 1.0


def _run_abs_start(logs: Sequence[RawLog], group: RunGroup, t_first: float) -> float:
    """UTC of the run's first sample [s, Unix]; NaN without an absolute clock."""
    for log in logs:
        if math.isfinite(log.start_time):
            # t_run = t_log + offset, so the run clock's zero is start_time - offset.
            return float(log.start_time - group.offsets[log.source].offset_s + t_first)
    return math.nan


def _run_tod(logs: Sequence[RawLog], group: RunGroup, t_first: float) -> float:
    for log in logs:
        if math.isfinite(log.time_of_day) and not math.isfinite(log.start_time):
            return float((log.time_of_day - group.offsets[log.source].offset_s + t_first) % 86400.0)
    return math.nan


def run_channels(logs: Sequence[RawLog], group: RunGroup, input_kinds: Mapping[str, str]
                 ) -> tuple[dict[str, Channel], list[str]]:
    """The channels of one run on its clock, before resampling.

    Each log's times are shifted by its offset; a channel that two sensor logs share is kept twice
    (the second as ``name@<file stem>``); a file that continues the one before it
    (``RunGroup.continued``, a logger that rotates its file) has its samples appended to that file's
    channels.

    Parameters
    ----------
    logs : Sequence[RawLog]
        The run's logs, in the order of ``group.sources``.
    group : RunGroup
        Their grouping (offsets, continued files).
    input_kinds : Mapping[str, str]
        Input channel -> ``command`` or ``measured`` (overrides the reader's).

    Returns
    -------
    chans : dict[str, Channel]
        Channel key -> channel on the run clock [s]; channels without samples are left out.
    notes : list[str]
        Offsets applied and channels renamed.
    """
    notes: list[str] = []
    chans: dict[str, Channel] = {}
    keys_of: dict[str, dict[str, str]] = {}
    for i, log in enumerate(logs):
        off = float(group.offsets[log.source].offset_s)
        if log.source in group.continued:
            # The next file of one logger: its samples go on after the file before it, channel by channel.
            prev = keys_of[logs[i - 1].source]
            keys_of[log.source] = prev
            for ch in log.channels.values():
                if not len(ch.t):
                    continue
                if ch.name in prev:
                    old = chans[prev[ch.name]]
                    chans[old.name] = replace(old, t=np.concatenate([old.t, ch.t + off]),
                                              values=np.concatenate([old.values, ch.values]))
                    continue
                # A channel the file before did not have (a GNSS that found its fix): it starts here.
                key = ch.name if ch.name not in chans else f"{ch.name}@{Path(log.source).stem}"
                while key in chans:
                    key += "_"
                kind = input_kinds.get(key, input_kinds.get(ch.name.split("@")[0], ch.input_kind))
                chans[key] = Channel(key, ch.t + off, ch.values, ch.source, kind)
                prev[ch.name] = key
            continue
        keys_of[log.source] = {}
        if off:
            notes.append(f"{log.source}: clock offset {off:+.3f} s applied")
        for ch in log.channels.values():
            key = ch.name
            if key in chans:
                # Same channel from two files: keep both, the second under a file-specific name.
                key = f"{ch.name}@{Path(log.source).stem}"
                while key in chans:
                    key += "_"
                notes.append(f"{log.source}: channel {ch.name} also in another log; kept as {key}")
            kind = input_kinds.get(key, input_kinds.get(ch.name.split("@")[0], ch.input_kind))
            chans[key] = Channel(key, ch.t + off, ch.values, ch.source, kind)
            keys_of[log.source][ch.name] = key
    return {k: c for k, c in chans.items() if len(c.t)}, notes


def _align_run(logs: Sequence[RawLog], group: RunGroup, fs: float, gap_threshold: float | None,
               vessel: Vessel | None, input_kinds: Mapping[str, str]
               ) -> tuple[pd.DataFrame, list[Gap], list[str], dict[str, str], float, dict[str, np.ndarray]]:
    """One run on its own uniform grid from its first sample: frame, gaps, notes, input kinds, t0, and the
    real sample times [s from the run's start] of the channels measured slower than the grid
    (:func:`slow_sample_times`)."""
    notes: list[str] = []
    if len(logs) > 1:
        for src in group.sources:
            est = group.offsets[src]
            notes.append(f"clock: {src} offset {est.offset_s:+.6f} s +- {est.stderr_s:.3g} s ({est.method})")
    chans, chan_notes = run_channels(logs, group, input_kinds)
    notes += chan_notes
    if not chans:
        raise AlignError(f"align: expected channels with samples, found none in {[l.source for l in logs]}")
    t0 = min(float(c.t[0]) for c in chans.values())
    t1 = max(float(c.t[-1]) for c in chans.values())
    check_duration(chans.values(), fs)
    n = int(np.floor((t1 - t0) * fs + 1e-9)) + 1
    grid = t0 + np.arange(n) / fs
    data = {"t": grid - t0}
    gaps: list[Gap] = []
    kinds: dict[str, str] = {}
    for key, ch in chans.items():
        g = find_gaps(ch, gap_threshold)
        gaps += g
        data[key] = resample_channel(ch, grid, g)
        if key.split("@")[0] in INPUT_UNITS:
            kinds[key] = "command" if ch.held else "measured"
    coarse = sorted(k for k, c in chans.items() if c.held and _native_rate(c) > 1.001 * fs)
    if coarse:
        # A command change between two grid points is held until the next one: up to one grid
        # step late, which a fit at this rate reads as a longer time constant or a delay.
        notes.append(f"warning: {fs:g} Hz is coarser than the logged rate of the commands {', '.join(coarse)} "
                     f"(up to {max(_native_rate(chans[k]) for k in coarse):g} Hz): their changes move to the next "
                     f"grid point, up to {1 / fs:g} s late; align at their own rate for unbiased fits")
    if kinds:
        notes.append("inputs: " + ", ".join(f"{k} {'held (command)' if v == 'command' else 'interpolated (measured)'}"
                                            for k, v in sorted(kinds.items())))
    if gaps:
        notes.append(f"{len(gaps)} dropout(s): " + ", ".join(f"{g.channel} {g.t_start - t0:.2f}-{g.t_end - t0:.2f} s"
                                                              for g in gaps[:10]))
    frame = pd.DataFrame(data)
    if vessel is not None:
        frame, sensor_notes = apply_sensors(frame, vessel)
        notes += sensor_notes
    rates = {k: _native_rate(c) for k, c in chans.items()}
    frame, derived = _derive(frame, rates)
    notes += derived
    notes += plausibility_notes(frame, fs)
    shifted = [Gap(g.channel, g.t_start - t0, g.t_end - t0) for g in gaps]
    times = slow_sample_times(chans, fs, t0)
    times.update(_derived_sample_times(frame, chans, times, rates))
    if times:
        notes.append("measured slower than the grid (real samples recorded, values between them interpolated): "
                     + ", ".join(f"{k} {len(v)} samples" for k, v in sorted(times.items())))
    return frame, shifted, notes, kinds, t0, times


#: A channel whose median sample interval exceeds this many grid steps is "slower than the grid":
#: its real sample times are kept on the Trial (``Trial.sample_times``).
SLOW_FACTOR = 1.5


def slow_sample_times(chans: Mapping[str, Channel], fs: float, t0: float) -> dict[str, np.ndarray]:
    """Real sample times of the state channels measured slower than the grid.

    Parameters
    ----------
    chans : Mapping[str, Channel]
        One run's channels (held GNSS fixes already collapsed to one sample per fix).
    fs : float
        Grid rate [Hz].
    t0 : float
        The run's first sample time [s, run clock].

    Returns
    -------
    dict[str, numpy.ndarray]
        Channel -> its sample times [s from ``t0``], for every state channel (not an input) whose
        median sample interval is above ``SLOW_FACTOR`` grid steps.
    """
    out = {}
    for key, ch in chans.items():
        if key.split("@")[0] in INPUT_UNITS or len(ch.t) < 2:
            continue
        if float(np.median(np.diff(ch.t))) * fs > SLOW_FACTOR:
            out[key] = np.asarray(ch.t, float) - t0
    return out


def _derived_sample_times(frame: pd.DataFrame, chans: Mapping[str, Channel], times: Mapping[str, np.ndarray],
                          rates: Mapping[str, float]) -> dict[str, np.ndarray]:
    """Sample times of ``x_n, y_e`` and ``u, v`` derived from slow GNSS: those of the fixes they came from."""
    out = {}
    lat, lon = _first_present(frame, "lat"), _first_present(frame, "lon")
    if "x_n" not in chans and lat in times and lon in times and np.array_equal(times[lat], times[lon]):
        out["x_n"] = out["y_e"] = times[lat]
    sog, cog = _fastest_velocity(frame, rates)
    psi = _first_present(frame, "psi")
    if sog in times and cog in times and np.array_equal(times[sog], times[cog]) and psi not in times:
        for k in ("u", "v"):
            if k not in chans and k in frame:
                out[k] = times[sog]
    return out


def _ordered(columns) -> list[str]:
    cols = [c for c in columns if c != "t"]
    return ["t"] + [c for c in CHANNEL_UNITS if c in cols] + sorted(c for c in cols if c not in CHANNEL_UNITS)


def _first_present(frame: pd.DataFrame, base: str) -> str | None:
    if base in frame and np.isfinite(frame[base]).any():
        return base
    for c in frame.columns:
        if c.split("@")[0] == base and np.isfinite(frame[c]).any():
            return c
    return None


def _fastest_velocity(frame: pd.DataFrame, rates: Mapping[str, float]) -> tuple[str | None, str | None]:
    """The sog/cog pair from one sensor (same suffix) with the highest native rate.

    A fast navigation-filter velocity resolves a sway time constant of 0.4 s where a 10 Hz GPS
    cannot, so the fastest complete pair feeds the body velocities.
    """
    best, best_rate = (None, None), -1.0
    for c in frame.columns:
        if c.split("@")[0] != "sog" or not np.isfinite(frame[c]).any():
            continue
        cog = "cog" + c[3:]
        if cog in frame and np.isfinite(frame[cog]).any() and rates.get(c, 0.0) > best_rate:
            best, best_rate = (c, cog), rates.get(c, 0.0)
    return best


def _derive(frame: pd.DataFrame, rates: Mapping[str, float] | None = None) -> tuple[pd.DataFrame, list[str]]:
    """Add x_n, y_e from lat/lon and body u, v from sog/cog/psi when not logged.

    Parameters
    ----------
    frame : pandas.DataFrame
        Resampled channels.
    rates : Mapping[str, float], optional
        Native sample rate of each channel [Hz], to pick the fastest velocity source.
    """
    notes = []
    out = frame.copy()
    lat, lon = _first_present(out, "lat"), _first_present(out, "lon")
    if "x_n" not in out and lat and lon:
        la, lo = out[lat].to_numpy(), out[lon].to_numpy()
        first = np.flatnonzero(np.isfinite(la) & np.isfinite(lo))[0]
        out["x_n"], out["y_e"] = latlon_to_ned(la, lo, la[first], lo[first])
        notes.append(f"x_n, y_e from {lat}/{lon} (flat earth about the first fix {la[first]:.6f}, {lo[first]:.6f} deg)")
    sog, cog = _fastest_velocity(out, rates or {})
    psi = _first_present(out, "psi")
    if sog and cog and psi and not ("u" in out and "v" in out):
        # Velocity over ground in the body frame: [u, v] = R(psi)^T [v_n, v_e]. With a water
        # current this is not the velocity through the water; the diagnosis tests for that.
        beta = wrap_pi(out[cog].to_numpy() - out[psi].to_numpy())
        speed = out[sog].to_numpy()
        if "u" not in out:
            out["u"] = speed * np.cos(beta)
        if "v" not in out:
            out["v"] = speed * np.sin(beta)
        notes.append(f"u, v over ground from {sog}, {cog} ({(rates or {}).get(sog, float('nan')):.3g} Hz) "
                     f"and heading {psi}")
    ordered = ["t"] + [c for c in CHANNEL_UNITS if c in out] + sorted(c for c in out if c != "t" and c not in CHANNEL_UNITS)
    return out[ordered], notes
