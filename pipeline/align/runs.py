"""Group the logs of a trial into runs: the recordings that share one clock.

A trial day is many recordings: ArduPilot starts a new .bin at every arming, a pool roll-decay
test is its own file, a ship's rudder steps and zig-zags are two files. Logs are sensors of one
run when

1. their absolute times overlap (UTC from the reader, ``RawLog.start_time``; or, for logs that
   know only the UTC time of day such as NMEA without RMC, ``RawLog.time_of_day``), or
2. a log without absolute time shares a clock with a run by a significant cross-correlation of
   their turn rates or accelerations (:func:`pipeline.align.clock.estimate_offsets`).

Logs whose absolute times do not overlap are never merged, whatever a correlation says. A log
without absolute time whose measured quantities (state channels, ``@sensor`` suffixes ignored) are
all in a log of a run, or that holds all of that log's, and that does not bring logged inputs along with fewer measured quantities (a command file), adds no sensor to the run: it is taken as
another recording of the same sensors and is not correlated against it. Two surge coast-downs of
one boat on different days correlate as well as two sensors of one coast-down, so a correlation
alone cannot tell them apart; a redundant second logger of one recording is therefore kept as a
run of its own unless the manifest states the runs. A log that
can be placed nowhere becomes a run of its own.

One exception comes first: a log that continues another one's clock (the channels of one all in
the other, the first samples of the shared ones after the other's last ones by no more than a
dropout, on the absolute clock when both have one, else on the logged time itself) is the same
recording, written by a logger that rotates its file. Such files are one run and their channels are joined end to end (:attr:`RunGroup.continued`),
so they give the segments of one file; files with a real gap between them (more than a dropout,
:func:`pipeline.align.resample.dropout_limit`) stay separate runs. A manifest can state the runs instead
(``explicit``); their clocks are still estimated, and a stated run whose files do not overlap in
absolute time is refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..errors import AlignError
from ..records import INPUT_UNITS, Channel, RawLog
from .clock import ClockOffset, estimate_offsets
from .resample import dropout_limit

#: Two absolute spans count as overlapping only when they share more than this [s]; two files
#: written back to back by one logger may touch at a sample.
MIN_OVERLAP_S = 0.0


@dataclass(frozen=True)
class RunGroup:
    """Logs of one run with their clock offsets and the reason they were grouped.

    Attributes
    ----------
    name : str
        Run name.
    sources : tuple[str, ...]
        ``RawLog.source`` of each log in the run.
    offsets : Mapping[str, ClockOffset]
        Offset of each log onto the run's clock.
    reason : str
        Why these logs form one run and why it is separate from the others.
    continued : tuple[str, ...]
        Sources that continue the clock of the source before them in ``sources`` (files of one
        logger that rotates its file): their channels are appended to that file's channels,
        not kept as a second sensor.
    """

    name: str
    sources: tuple[str, ...]
    offsets: Mapping[str, ClockOffset] = field(default_factory=dict)
    reason: str = ""
    continued: tuple[str, ...] = ()


def _span(log: RawLog) -> tuple[float, float]:
    """First and last sample of a log on its own clock [s]."""
    firsts = [float(c.t[0]) for c in log.channels.values() if len(c.t)]
    lasts = [float(c.t[-1]) for c in log.channels.values() if len(c.t)]
    return (min(firsts), max(lasts)) if firsts else (math.nan, math.nan)


def _clock_text(seconds: float, utc: bool) -> str:
    if not math.isfinite(seconds):
        return "?"
    if utc:
        from ..ingest._gpstime import unix_text

        return unix_text(seconds) + " UTC"
    tod = seconds % 86400.0
    return f"{int(tod // 3600):02d}:{int(tod % 3600 // 60):02d}:{tod % 60:05.2f} UTC (time of day)"


@dataclass(frozen=True)
class _Timed:
    """A log's span on an absolute clock: UTC where known, else the UTC time of day."""

    utc: tuple[float, float] | None
    tod: tuple[float, float] | None

    def overlap(self, other: "_Timed") -> float | None:
        """Overlap [s] (negative: the distance apart); None when the two cannot be compared."""
        if self.utc and other.utc:
            a, b = self.utc, other.utc
        elif self.tod and other.tod:
            a, b = self.tod, other.tod
        else:
            return None
        return min(a[1], b[1]) - max(a[0], b[0])

    def text(self) -> str:
        if self.utc:
            return f"{_clock_text(self.utc[0], True)} to {_clock_text(self.utc[1], True)}"
        if self.tod:
            return f"{_clock_text(self.tod[0], False)} to {_clock_text(self.tod[1], False)}"
        return "no absolute time"


def _timed(log: RawLog) -> _Timed:
    a, b = _span(log)
    utc = (log.start_time + a, log.start_time + b) if math.isfinite(log.start_time) else None
    tod0 = log.time_of_day if math.isfinite(log.time_of_day) else (
        log.start_time % 86400.0 if math.isfinite(log.start_time) else math.nan)
    tod = (tod0 + a, tod0 + b) if math.isfinite(tod0) else None
    return _Timed(utc, tod)


def _channel_set(log: RawLog) -> frozenset[str]:
    """Measured quantities of a log: base names of its state channels."""
    return frozenset(n.split("@")[0] for n, c in log.channels.items() if n.split("@")[0] not in INPUT_UNITS and len(c.t))


def _input_set(log: RawLog) -> frozenset[str]:
    """Logged inputs of a log: base names of its input channels."""
    return frozenset(n.split("@")[0] for n, c in log.channels.items() if n.split("@")[0] in INPUT_UNITS and len(c.t))


def _same_sensors(a: RawLog, b: RawLog) -> bool:
    """Whether ``a`` and ``b`` look like two recordings of one logger: nested measured quantities,
    unless the log with fewer of them brings logged inputs the other lacks (a command file that
    repeats the gyro beside a sensor file: a second logger of the same recording, placed by its clock)."""
    sa, sb = _channel_set(a), _channel_set(b)
    if not (sa and sb and (sa <= sb or sb <= sa)):
        return False
    ia, ib = _input_set(a), _input_set(b)
    command_file = (sa < sb and bool(ia - ib)) or (sb < sa and bool(ib - ia))
    return not command_file


def _has_states(log: RawLog) -> bool:
    return any(n.split("@")[0] not in INPUT_UNITS and len(c.t) for n, c in log.channels.items())


def _clock_view(logs: Sequence[RawLog]) -> list[RawLog]:
    """Logs as :func:`estimate_offsets` should see them: time-of-day logs get a day-less start_time.

    When some log of a run knows only the time of day, every log of the run is compared on the
    time of day (UTC modulo one day), so the offsets stay right without a date.
    """
    if all(math.isfinite(l.start_time) or not math.isfinite(l.time_of_day) for l in logs):
        return list(logs)
    out = []
    for log in logs:
        if math.isfinite(log.time_of_day):
            out.append(replace(log, start_time=float(log.time_of_day)))
        elif math.isfinite(log.start_time):
            out.append(replace(log, start_time=float(log.start_time % 86400.0)))
        else:
            out.append(log)
    return out


def run_offsets(logs: Sequence[RawLog]) -> dict[str, ClockOffset]:
    """Clock offsets of the logs of one run (absolute time, time of day, or cross-correlation).

    Parameters
    ----------
    logs : Sequence[RawLog]
        Logs of one run.

    Returns
    -------
    dict[str, ClockOffset]
        ``RawLog.source`` -> offset onto the run's clock; a single log gets offset 0.

    Raises
    ------
    AlignError
        As :func:`pipeline.align.clock.estimate_offsets`.
    """
    if len(logs) == 1:
        return {logs[0].source: ClockOffset(0.0, 0.0, "the run's only log")}
    return estimate_offsets(_clock_view(logs))


def _condensed(tried: list[str]) -> list[str]:
    """Why a log joined no run: the first 'same channels' reason once (with how many more), other reasons as they are."""
    same = [x for x in tried if x.startswith("same channels as ")]
    other = [x for x in tried if not x.startswith("same channels as ")]
    if len(same) > 1:
        same = [same[0] + f" (and {len(same) - 1} more run(s) of the same channels)"]
    return same + other


def _stem(source: str) -> str:
    """A log's short name: the file stem, with the recording for one of several in a file (``roll#Test 2``)."""
    base, sep, recording = source.rpartition("#")
    if sep and Path(base).suffix and "/" not in recording:
        return f"{Path(base).stem}#{recording}"
    return Path(source).stem


def _unique_names(stems: Sequence[str]) -> list[str]:
    seen: dict[str, int] = {}
    out = []
    for s in stems:
        seen[s] = seen.get(s, 0) + 1
        out.append(s if seen[s] == 1 else f"{s}#{seen[s]}")
    return out


def _clock_start(a: RawLog, b: RawLog) -> float | None:
    """Where ``b``'s time zero lies on ``a``'s clock [s]; None when the two clocks cannot be compared.

    Both with UTC: the difference of their start times; both with only the time of day: of those;
    neither: 0 (a logger that keeps its clock across files writes times that continue).
    """
    if math.isfinite(a.start_time) or math.isfinite(b.start_time):
        return b.start_time - a.start_time if math.isfinite(a.start_time) and math.isfinite(b.start_time) else None
    if math.isfinite(a.time_of_day) or math.isfinite(b.time_of_day):
        return (b.time_of_day - a.time_of_day if math.isfinite(a.time_of_day) and math.isfinite(b.time_of_day)
                else None)
    return 0.0


@dataclass(frozen=True)
class _Ends:
    """What tells whether one log continues another: per channel its first and last sample time [s,
    own clock] and, for measured channels, the median sample interval [s]."""

    names: frozenset[str]
    first: Mapping[str, float]
    last: Mapping[str, float]
    interval: Mapping[str, float]


def _ends(log: RawLog) -> _Ends:
    chans = {n: c for n, c in log.channels.items() if len(c.t)}
    return _Ends(frozenset(chans), {n: float(c.t[0]) for n, c in chans.items()},
                 {n: float(c.t[-1]) for n, c in chans.items()},
                 {n: float(np.median(np.diff(c.t))) if len(c.t) > 1 else math.inf
                  for n, c in chans.items() if n.split("@")[0] not in INPUT_UNITS})


def _continuation(a: RawLog, b: RawLog, ea: _Ends, eb: _Ends) -> str | None:
    """Why ``b`` continues ``a``'s recording (None when it does not); ``ea``, ``eb`` their :func:`_ends`.

    The channels of one are all in the other (a file may gain a channel, a GNSS that found its fix,
    or lose one), at least one measured channel in both; every shared measured channel's first
    sample in ``b`` after its last in ``a`` by no more than a dropout
    (:func:`pipeline.align.resample.dropout_limit` of its sample interval); no shared input of ``b``
    before ``a``'s last sample of it.
    """
    shared = ea.names & eb.names
    if not (ea.names <= eb.names or eb.names <= ea.names) or not any(n in ea.interval for n in shared):
        return None
    shift = _clock_start(a, b)
    if shift is None:
        return None
    spacing = []
    for n in sorted(shared):
        gap = eb.first[n] + shift - ea.last[n]
        if not gap > 0:
            return None
        if n not in ea.interval:
            continue
        interval = min(ea.interval[n], eb.interval[n])
        if not (math.isfinite(interval) and gap <= dropout_limit(interval)):
            return None
        spacing.append(gap / interval)
    return f"{max(spacing):.2g} sample interval(s) after"


def _join_rotated(logs: Sequence[RawLog], explicit: Sequence[Sequence[str]] | None
                  ) -> tuple[list[RawLog], dict[str, tuple[str, ...]], dict[str, str]]:
    """Chain the files of one logger that rotates its file: each joined log is one recording.

    A log is chained to the one it continues (:func:`_continuation`) when that is its only
    candidate and it is the only candidate of that one; with stated runs only within one run.

    Returns
    -------
    joined : list[RawLog]
        One log per chain (the first file's source, channels joined on its clock), in the order
        of the chains' first files.
    members : dict[str, tuple[str, ...]]
        First file's source -> the sources of the chain, in time order.
    why : dict[str, str]
        First file's source -> why the chain is one recording (chains of one file: absent).
    """
    run_of = {s: k for k, run in enumerate(explicit or ()) for s in run}
    after: dict[str, list[tuple[str, str]]] = {l.source: [] for l in logs}
    before: dict[str, list[str]] = {l.source: [] for l in logs}
    ends = {l.source: _ends(l) for l in logs}
    for a in logs:
        for b in logs:
            if a is b or run_of.get(a.source, -1) != run_of.get(b.source, -1):
                continue
            why = _continuation(a, b, ends[a.source], ends[b.source])
            if why is not None:
                after[a.source].append((b.source, why))
                before[b.source].append(a.source)
    nxt = {a: c[0] for a, c in after.items() if len(c) == 1 and len(before[c[0][0]]) == 1}
    heads = [l.source for l in logs if not any(b == l.source for b, _ in nxt.values())]
    by_source = {l.source: l for l in logs}
    joined, members, why = [], {}, {}
    for h in heads:
        chain, notes = [h], []
        while chain[-1] in nxt and nxt[chain[-1]][0] not in chain:
            b, text = nxt[chain[-1]]
            notes.append(f"{Path(b).name} starts {text} {Path(chain[-1]).name} ends")
            chain.append(b)
        members[h] = tuple(chain)
        head = by_source[h]
        if len(chain) == 1:
            joined.append(head)
            continue
        parts = {n: [c] for n, c in head.channels.items()}
        for s in chain[1:]:
            shift = _clock_start(head, by_source[s])
            for n, c in by_source[s].channels.items():
                parts.setdefault(n, []).append(replace(c, t=np.asarray(c.t, float) + shift))
        chans = {n: Channel(n, np.concatenate([c.t for c in cs]), np.concatenate([c.values for c in cs]),
                            cs[0].source, cs[0].input_kind) for n, cs in parts.items()}
        joined.append(replace(head, channels=chans))
        why[h] = (f"{', '.join(Path(s).name for s in chain)} continue one clock without a gap ({'; '.join(notes)}): "
                  f"one recording whose logger rotated its file, joined end to end")
    return joined, members, why


def _expand(group: RunGroup, members: Mapping[str, tuple[str, ...]], why: Mapping[str, str],
            by_source: Mapping[str, RawLog]) -> RunGroup:
    """A run of joined logs as a run of their files: each later file of a chain continues the one before."""
    if all(len(members[s]) == 1 for s in group.sources):
        return group
    sources, offsets, continued, reasons = [], {}, [], []
    for s in group.sources:
        head = by_source[s]
        for k, m in enumerate(members[s]):
            sources.append(m)
            base = group.offsets[s]
            if k == 0:
                offsets[m] = (ClockOffset(base.offset_s, base.stderr_s, "the first file of the recording")
                              if base.method == "the run's only log" else base)
                continue
            shift = _clock_start(head, by_source[m])
            offsets[m] = ClockOffset(base.offset_s + shift, base.stderr_s,
                                     f"continues the clock of {Path(members[s][k - 1]).name} (the same logger)")
            continued.append(m)
        if s in why:
            reasons.append(why[s])
    return replace(group, sources=tuple(sources), offsets=offsets, continued=tuple(continued),
                   reason="; ".join(reasons + [group.reason]))


def group_runs(logs: Sequence[RawLog], explicit: Sequence[Sequence[str]] | None = None,
               names: Sequence[str] | None = None) -> list[RunGroup]:
    """Group logs into runs and find each log's clock offset within its run.

    Parameters
    ----------
    logs : Sequence[RawLog]
        Every log of the trial (distinct sources).
    explicit : Sequence[Sequence[str]], optional
        Runs stated by the user (a manifest's ``[[runs]]``): the sources of each run. Every log
        must be in exactly one of them.
    names : Sequence[str], optional
        Names of the explicit runs; default the stem of each run's first file.

    Returns
    -------
    list[RunGroup]
        In time order where the runs have absolute times (earliest first), otherwise in the
        order of their first log; each with the reason for its grouping. Files that continue one
        logger's clock are one run (``RunGroup.continued``).

    Raises
    ------
    AlignError
        No logs, repeated sources, an explicit grouping that misses or repeats a log, an explicit
        run whose files do not overlap in absolute time, a log with only inputs that shares no
        clock with any run, or (explicit runs) offsets that cannot be estimated.
    """
    if not logs:
        raise AlignError("runs: expected at least one log, found none")
    sources = [l.source for l in logs]
    dup = sorted({s for s in sources if sources.count(s) > 1})
    if dup:
        raise AlignError(f"runs: expected one log per source, found {dup} more than once")
    if explicit is not None:
        _check_explicit(logs, explicit)
    files = {l.source: l for l in logs}
    joined, members, why = _join_rotated(logs, explicit)
    if explicit is not None:
        explicit = [[s for s in run if s in members] for run in explicit]
    groups = _group_joined(joined, explicit, names)
    return [_expand(g, members, why, files) for g in groups]


def _group_joined(logs: Sequence[RawLog], explicit: Sequence[Sequence[str]] | None,
                  names: Sequence[str] | None) -> list[RunGroup]:
    """:func:`group_runs` on logs of distinct recordings (rotated files already joined)."""
    sources = [l.source for l in logs]
    by_source = {l.source: l for l in logs}
    timed = {l.source: _timed(l) for l in logs}
    if explicit is not None:
        return _explicit(logs, explicit, names, by_source, timed)

    # 1. Logs with absolute time: connected components of "overlaps in absolute time".
    parent = {s: s for s in sources}

    def find(s: str) -> str:
        while parent[s] != s:
            parent[s] = parent[parent[s]]
            s = parent[s]
        return s

    why_joined: dict[str, list[str]] = {s: [] for s in sources}
    with_time = [s for s in sources if timed[s].utc or timed[s].tod]
    for i, a in enumerate(with_time):
        for b in with_time[i + 1:]:
            ov = timed[a].overlap(timed[b])
            if ov is not None and ov > MIN_OVERLAP_S:
                ra, rb = find(a), find(b)
                if ra != rb:
                    parent[rb] = ra
                why_joined[a].append(f"{Path(b).name} overlaps it by {ov:.1f} s in absolute time")
    comps: dict[str, list[str]] = {}
    for s in with_time:
        comps.setdefault(find(s), []).append(s)
    groups: list[list[str]] = list(comps.values())
    reasons: list[list[str]] = []
    for g in groups:
        if len(g) == 1:
            reasons.append([f"{Path(g[0]).name}: {timed[g[0]].text()}"])
        else:
            reasons.append([f"{Path(s).name}: {timed[s].text()}" for s in g]
                           + [f"absolute times overlap ({'; '.join(j for s in g for j in why_joined[s])})"])
    # Separation from the other timed runs: say how far apart the nearest one is.
    for k, g in enumerate(groups):
        nearest = None
        for m, h in enumerate(groups):
            if m == k:
                continue
            gaps = [x for x in (timed[a].overlap(timed[b]) for a in g for b in h) if x is not None]
            if gaps and (nearest is None or max(gaps) > nearest[0]):
                nearest = (max(gaps), h[0])
        if nearest is not None:
            reasons[k].append(f"no overlap with {Path(nearest[1]).name} ({-nearest[0]:.1f} s apart, the nearest "
                              f"run): never merged")

    # 2. Logs without absolute time: join the run they correlate with, else a run of their own.
    for s in sources:
        if s in with_time:
            continue
        log = by_source[s]
        tried: list[str] = []
        placed = False
        for k, g in enumerate(groups):
            same = [m for m in g if _same_sensors(by_source[m], log)]
            if same:
                tried.append(f"same channels as {Path(same[0]).name} (taken as another recording of the same "
                             f"sensors; state [[runs]] in a manifest if they are one recording)")
                continue
            try:
                offs = run_offsets([by_source[m] for m in g] + [log])
            except AlignError as exc:
                tried.append(f"no common clock with {Path(g[0]).name} ({_short(str(exc))})")
                continue
            groups[k] = g + [s]
            reasons[k].append(f"{Path(s).name}: no absolute time; shares the clock of {Path(g[0]).name} by "
                              f"{offs[s].method}")
            placed = True
            break
        if not placed:
            if not _has_states(log):
                raise AlignError(f"runs: {s} holds only inputs ({sorted(log.channels)}) and no absolute time: expected "
                                 f"a measured response channel, or another log that shares its clock by "
                                 f"cross-correlation; found: " + ("; ".join(tried) or "no other log"))
            groups.append([s])
            reasons.append([f"{Path(s).name}: no absolute time"]
                           + ([f"a run of its own: {'; '.join(_condensed(tried))}"] if tried else []))

    order = sorted(range(len(groups)), key=lambda k: (_start_key(groups[k], timed), sources.index(groups[k][0])))
    groups = [groups[k] for k in order]
    reasons = [reasons[k] for k in order]
    names_ = _unique_names([_stem(g[0]) for g in groups])
    out = []
    for name, g, why in zip(names_, groups, reasons):
        offs = run_offsets([by_source[m] for m in g])
        out.append(RunGroup(name, tuple(g), offs, "; ".join(why)))
    return out


def _short(text: str, n: int = 160) -> str:
    return text if len(text) <= n else text[:n - 3] + "..."


def _start_key(group: Sequence[str], timed: Mapping[str, _Timed]) -> float:
    starts = [timed[s].utc[0] for s in group if timed[s].utc]
    if starts:
        return min(starts)
    starts = [timed[s].tod[0] for s in group if timed[s].tod]
    return min(starts) if starts else math.inf


def _check_explicit(logs, explicit) -> None:
    """AlignError unless every log is in exactly one stated run and every stated file was read."""
    listed = [s for run in explicit for s in run]
    read = {l.source for l in logs}
    missing = [l.source for l in logs if l.source not in listed]
    extra = sorted({s for s in listed if s not in read})
    twice = sorted({s for s in listed if listed.count(s) > 1})
    if missing or extra or twice:
        raise AlignError(f"runs: expected every log in exactly one stated run; found not in any run {missing}, "
                         f"in a run but not read {extra}, in more than one run {twice}")


def _explicit(logs, explicit, names, by_source, timed) -> list[RunGroup]:
    _check_explicit(logs, explicit)
    if names is not None and len(names) != len(explicit):
        raise AlignError(f"runs: expected one name per run ({len(explicit)}), found {len(names)}")
    names_ = list(names) if names is not None else _unique_names([_stem(r[0]) for r in explicit])
    out = []
    for name, run in zip(names_, explicit):
        if not run:
            raise AlignError(f"runs: run {name!r} expected at least one log, found none")
        for i, a in enumerate(run):
            for b in run[i + 1:]:
                ov = timed[a].overlap(timed[b])
                if ov is not None and ov <= MIN_OVERLAP_S:
                    raise AlignError(f"runs: run {name!r} states {Path(a).name} ({timed[a].text()}) and {Path(b).name} "
                                     f"({timed[b].text()}) as one recording, but their absolute times do not overlap "
                                     f"({-ov:.1f} s apart); expected files of one run to overlap in time")
        offs = run_offsets([by_source[s] for s in run])
        out.append(RunGroup(name, tuple(run), offs, "stated in the manifest: "
                            + ", ".join(f"{Path(s).name} ({timed[s].text()})" for s in run)))
    return out


def grouping_text(groups: Sequence[RunGroup]) -> str:
    """The grouping chosen and why, for the terminal (``vesselid ingest/align``).

    Parameters
    ----------
    groups : Sequence[RunGroup]
        Output of :func:`group_runs`.
    """
    lines = [f"{len(groups)} run(s) (numbered as Segment.run):"]
    for k, g in enumerate(groups):
        lines.append(f"  run {k} {g.name!r}: " + ", ".join(Path(s).name for s in g.sources))
        for s in g.sources:
            off = g.offsets.get(s)
            if off is not None and len(g.sources) > 1:
                lines.append(f"    {Path(s).name}: clock offset {off.offset_s:+.3f} s +- {off.stderr_s:.2g} s ({off.method})")
        lines.append(f"    why: {g.reason}")
    return "\n".join(lines)


__all__ = ["RunGroup", "group_runs", "run_offsets", "grouping_text"]
