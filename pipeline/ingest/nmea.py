"""NMEA 0183 logs: GGA, RMC, VTG, HDT and THS sentences from a GNSS receiver or heading sensor.

A log is a text file of sentences ``$ttSSS,field,...*hh``, one a line, from any talker (GP, GN,
GL, GA, HE, ...). Real logs are messy, and the reader is tolerant of what loggers do to them:

- a leading column (a PC timestamp, a line number, ``t`` or binary noise from a serial port that
  was opened mid-sentence) before the ``$`` is ignored, as is anything after the checksum;
- lines without a complete sentence (fragments, blank lines, garbage) are counted and skipped;
- every sentence's ``*hh`` checksum (XOR of the bytes between ``$`` and ``*``) is checked; bad
  ones are counted, skipped and reported in a warning;
- repeated sentences (same epoch twice) and steps back in time are dropped and counted.

Time comes from the sentences, not from the PC: GGA and RMC carry the UTC time of day (RMC also
the date); VTG, HDT and THS carry none and take the time of the latest GGA/RMC before them (a
receiver sends an epoch's sentences together, GGA or RMC first). A time of day that falls back by
more than 12 h is a midnight rollover; an RMC date overrides the day count, so a log that spans
days or pauses over midnight stays on one clock. ``t`` is seconds from the first fix and
``time_reference`` is ``gps`` (UTC from the receiver); the UTC of ``t = 0`` is in the summary and,
when an RMC date makes it absolute, in ``RawLog.start_time``.

Mapping (``VARIABLE_MAP``; SI units, radians, NED: course and heading clockwise from true north)
------------------------------------------------------------------------------------------------
GGA  lat, lon [ddmm.mmmm + N/S, E/W] -> lat, lon [deg]  (fix quality 0 is skipped and counted)
RMC  lat, lon -> lat, lon; spd [knots] -> sog [m/s]; cog [deg] -> cog [rad]  (status V skipped)
VTG  sogk [km/h] (or sogn [knots]) -> sog [m/s]; cogt [deg true] -> cog [rad]  (mode N skipped)
HDT  heading [deg true] -> psi [rad]
THS  headt [deg true] -> psi [rad]  (mode V, invalid, skipped and counted)

When GGA and RMC (or VTG and RMC) give the same quantity at the same epoch, one sample is kept
(GGA before RMC for position, VTG before RMC for speed and course). The field names are those of
pynmeagps (``nmeatypes_get``), so the map can be read next to its documentation.

Parsing is done here by hand, not with ``pynmeagps.NMEAReader.parse``: the five sentences have
fixed, simple layouts, and the hand parser is about ten times faster (measured on the CE6
Limfjord logs: ~6 us against ~60 us a sentence; an hour of 20 Hz GGA+VTG is 144 000 sentences,
so 1 s against 9 s), and it can count each kind of defect separately. pynmeagps is used by the
tests as an independent check of the parser and of the writer's checksums.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import sys
from collections import Counter, defaultdict
from datetime import date, datetime, timedelta, timezone
from functools import reduce
from operator import xor
from pathlib import Path

import numpy as np

from ..errors import IngestError
from ..records import ANGLE_CHANNELS, Channel, IngestSummary, RawLog
from ._common import check_file, increasing

_DEG = math.pi / 180.0
_KNOT = 1852.0 / 3600.0   # [m/s] per knot
_KMH = 1.0 / 3.6          # [m/s] per km/h

#: (sentence, field) -> (canonical channel, scale to SI). lat/lon are decoded from ddmm.mmmm first.
VARIABLE_MAP: dict[tuple[str, str], tuple[str, float]] = {
    ("GGA", "lat"): ("lat", 1.0),
    ("GGA", "lon"): ("lon", 1.0),
    ("RMC", "lat"): ("lat", 1.0),
    ("RMC", "lon"): ("lon", 1.0),
    ("RMC", "spd"): ("sog", _KNOT),
    ("RMC", "cog"): ("cog", _DEG),
    ("VTG", "sogk"): ("sog", _KMH),
    ("VTG", "sogn"): ("sog", _KNOT),
    ("VTG", "cogt"): ("cog", _DEG),
    ("HDT", "heading"): ("psi", _DEG),
    ("THS", "headt"): ("psi", _DEG),
}
#: Sentences the reader uses.
SENTENCES = ("GGA", "RMC", "VTG", "HDT", "THS")
#: Which sentence wins when two give a channel at the same epoch (lower first).
_PRIORITY = {"GGA": 0, "VTG": 0, "HDT": 0, "THS": 1, "RMC": 2}
#: GGA fix quality indicator -> name (NMEA 0183 v4.11).
FIX_QUALITY = {0: "invalid", 1: "GPS", 2: "DGPS", 3: "PPS", 4: "RTK fixed", 5: "RTK float",
               6: "estimated", 7: "manual", 8: "simulation"}

# A sentence anywhere in a line: '$', two-character talker, three-letter id, fields, '*hh'.
# Printable ASCII only, so binary noise cannot extend a match across a corrupted stretch.
_SENTENCE_RE = re.compile(rb"\$([A-Z][A-Z0-9])([A-Z]{3}),([\x20-\x23\x25-\x29\x2b-\x7e]*)\*([0-9A-Fa-f]{2})")
_SENSOR_RE = re.compile(r"[A-Za-z0-9_]+")
#: Files above this size get a progress bar when stderr is a terminal [bytes].
_PROGRESS_MIN_BYTES = 4 * 1024 * 1024
_HALF_DAY = 43200.0


def nmea_checksum(body: bytes) -> int:
    """NMEA 0183 sentence checksum.

    Parameters
    ----------
    body : bytes
        The bytes between ``$`` and ``*`` (talker, sentence id, fields).

    Returns
    -------
    int
        XOR of the bytes, 0 to 255; written as two upper-case hex digits after ``*``.
    """
    return reduce(xor, body, 0)


def looks_like_nmea(path: str | Path, nbytes: int = 4096) -> bool:
    """True when the first ``nbytes`` of a file hold a checksummed NMEA 0183 sentence.

    Loggers save NMEA as ``.nmea``, ``.txt``, ``.log`` or without extension, so a reader
    registry can route ambiguous extensions by content.

    Parameters
    ----------
    path : str or Path
        Candidate file.
    nbytes : int
        Bytes to look at [bytes].

    Returns
    -------
    bool
    """
    try:
        with open(path, "rb") as fh:
            head = fh.read(nbytes)
    except OSError:
        return False
    return any(nmea_checksum(m.group(0)[1:-3]) == int(m.group(4), 16) for m in _SENTENCE_RE.finditer(head))


def _want_progress(progress: bool | None, size: int) -> bool:
    if progress is not None:
        return bool(progress)
    if os.environ.get("CI"):
        return False
    return size > _PROGRESS_MIN_BYTES and sys.stderr.isatty()


def _time_of_day(s: str) -> float:
    """``hhmmss.sss`` -> seconds of the UTC day; ValueError when malformed."""
    if len(s) < 6 or not s[:6].isdigit():
        raise ValueError(s)
    hh, mm, ss = int(s[0:2]), int(s[2:4]), float(s[4:])
    if hh > 23 or mm > 59 or not 0.0 <= ss < 61.0:  # 60.x is a leap second
        raise ValueError(s)
    return hh * 3600.0 + mm * 60.0 + ss


def _angle(value: str, hemi: str, positive: str, negative: str, max_deg: float) -> float:
    """``dddmm.mmmm`` + hemisphere letter -> signed degrees; ValueError when malformed."""
    x = float(value)
    if not math.isfinite(x) or x < 0:
        raise ValueError(value)
    deg = math.floor(x / 100.0)
    minutes = x - 100.0 * deg
    if minutes >= 60.0 or deg > max_deg:
        raise ValueError(value)
    out = deg + minutes / 60.0
    if out > max_deg:
        raise ValueError(value)
    if hemi == positive:
        return out
    if hemi == negative:
        return -out
    raise ValueError(hemi)


def _nonneg(s: str, limit: float) -> float:
    x = float(s)
    if not (math.isfinite(x) and 0.0 <= x <= limit):
        raise ValueError(s)
    return x


def _rmc_date(s: str) -> int | None:
    """``ddmmyy`` -> proleptic ordinal, None when empty or invalid (the date is optional)."""
    if len(s) != 6 or not s.isdigit():
        return None
    dd, mo, yy = int(s[0:2]), int(s[2:4]), int(s[4:6])
    try:
        # Two-digit years: NMEA receivers are post-1980, so 80..99 are 19xx.
        return date(1900 + yy if yy >= 80 else 2000 + yy, mo, dd).toordinal()
    except ValueError:
        return None


class _UtcClock:
    """Turns time-of-day stamps into seconds on one continuous UTC clock (rollover, dates)."""

    def __init__(self) -> None:
        self.day = 0
        self.last: float | None = None
        self.ref_ordinal: int | None = None  # proleptic ordinal of day 0, once an RMC date is seen
        self.rollovers = 0

    def stamp(self, tod: float, ordinal: int | None = None) -> float:
        if ordinal is not None:
            if self.ref_ordinal is None:
                self.ref_ordinal = ordinal - self.day
            day = ordinal - self.ref_ordinal
            if day != self.day and self.last is not None and day > self.day:
                self.rollovers += 1
            self.day = day
        elif self.last is not None:
            if tod < self.last - _HALF_DAY:
                self.day += 1
                self.rollovers += 1
            elif tod > self.last + _HALF_DAY:
                # A late sentence from before midnight: it belongs to the previous day and is
                # then dropped as out of order; the clock does not move back.
                return (self.day - 1) * 86400.0 + tod
        self.last = tod
        return self.day * 86400.0 + tod

    def unix(self, seconds: float) -> float:
        """Unix time [s] of a clock reading; NaN until an RMC date has fixed the day."""
        if self.ref_ordinal is None:
            return math.nan
        midnight = datetime.combine(date.fromordinal(self.ref_ordinal), datetime.min.time(), timezone.utc)
        return midnight.timestamp() + seconds

    def utc(self, seconds: float) -> str:
        if self.ref_ordinal is None:
            tod = seconds % 86400.0
            return (f"{int(tod // 3600):02d}:{int(tod % 3600 // 60):02d}:{tod % 60:06.3f} UTC "
                    f"(time of day; no RMC date in the log)")
        when = datetime.combine(date.fromordinal(self.ref_ordinal), datetime.min.time(), timezone.utc)
        return (when + timedelta(seconds=seconds)).isoformat(timespec="milliseconds")


def read_nmea(path: str | Path, sensor: str = "", progress: bool | None = None) -> RawLog:
    """Read an NMEA 0183 log (GGA, RMC, VTG, HDT, THS) into canonical channels.

    Parameters
    ----------
    path : str or Path
        The log (text; any line ending; leading PC-time or other columns before ``$`` ignored).
    sensor : str
        Appended to every channel name as ``@sensor`` (``lat@gps2``) when the log is a second
        source of a quantity; empty for none.
    progress : bool, optional
        Show a progress bar; default only for files above 4 MB when stderr is a terminal.

    Returns
    -------
    RawLog
        Channels ``lat``, ``lon`` [deg], ``sog`` [m/s], ``cog`` [rad, wrapped to (-pi, pi]],
        ``psi`` [rad, wrapped] (each only when the log has it), on ``t`` [s] from the first fix;
        ``format='nmea'``, ``time_reference='gps'``; ``start_time`` is the UTC of the first fix
        [s, Unix] when an RMC gives the date, NaN for a log of time of day only (GGA/VTG). The summary counts sentences used and
        skipped (per id, bad checksums, fragments, no-fix, invalid heading, repeats) and gives
        fix-quality, satellite and HDOP statistics.

    Raises
    ------
    IngestError
        Missing or empty file; no NMEA sentence in it; no usable GGA/RMC/VTG/HDT/THS; only
        untimed sentences (VTG/HDT/THS without GGA or RMC); a malformed ``sensor``.
    """
    p = check_file(path, "NMEA 0183 log")
    if sensor and not _SENSOR_RE.fullmatch(sensor):
        raise IngestError(f"sensor: expected letters, digits or '_' (a channel suffix), found {sensor!r}")
    suffix = f"@{sensor}" if sensor else ""
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise IngestError(f"{p}: expected a readable NMEA 0183 log, found {type(exc).__name__}: {exc}") from None

    lines = data.splitlines()
    it = lines
    if _want_progress(progress, len(data)):
        from tqdm import tqdm

        it = tqdm(lines, desc=p.name, unit="line", leave=False)

    clock = _UtcClock()
    # (channel, sentence id) -> lists of absolute UTC seconds and SI values, in file order.
    samples: dict[tuple[str, str], tuple[list[float], list[float]]] = defaultdict(lambda: ([], []))
    read: Counter = Counter()
    skipped: Counter = Counter()
    n_sentences = 0
    n_blank = 0
    quality: Counter = Counter()
    nsat: list[int] = []
    hdop: list[float] = []
    epoch: float | None = None   # time of the latest GGA/RMC: untimed sentences take it

    def put(name: str, sid: str, t_abs: float, value: float) -> None:
        ts, vs = samples[(name, sid)]
        ts.append(t_abs)
        vs.append(value)

    for line in it:
        matches = list(_SENTENCE_RE.finditer(line))
        if not matches:
            if not line.strip():
                n_blank += 1
            elif b"$" in line:
                skipped["incomplete sentence"] += 1
            else:
                skipped["garbage line"] += 1
            continue
        for m in matches:
            n_sentences += 1
            body = m.group(0)[1:-3]
            if nmea_checksum(body) != int(m.group(4), 16):
                skipped["bad checksum"] += 1
                continue
            talker = m.group(1).decode()
            sid = m.group(2).decode()
            if talker[0] == "P":
                skipped["proprietary"] += 1
                continue
            if sid not in SENTENCES:
                skipped[sid] += 1
                continue
            f = m.group(3).decode().split(",")
            try:
                if sid == "GGA":
                    # time, lat, N/S, lon, E/W, quality, numSV, HDOP, alt, M, sep, M, diffAge, diffStation
                    tod = _time_of_day(f[0])
                    q = int(f[5]) if f[5] else 0
                    if q == 0 or not f[1] or not f[3]:
                        t_abs = clock.stamp(tod)
                        epoch = t_abs
                        skipped["GGA no fix"] += 1
                        quality[0] += 1
                        continue
                    lat = _angle(f[1], f[2], "N", "S", 90.0)
                    lon = _angle(f[3], f[4], "E", "W", 180.0)
                    epoch = t_abs = clock.stamp(tod)
                    put("lat", sid, t_abs, lat)
                    put("lon", sid, t_abs, lon)
                    quality[q] += 1
                    if len(f) > 6 and f[6].isdigit():
                        nsat.append(int(f[6]))
                    if len(f) > 7 and f[7]:
                        with contextlib.suppress(ValueError):
                            hdop.append(float(f[7]))
                elif sid == "RMC":
                    # time, status, lat, N/S, lon, E/W, spd [kn], cog [deg], date, mv, mvEW, posMode
                    tod = _time_of_day(f[0])
                    ordinal = _rmc_date(f[8]) if len(f) > 8 else None
                    epoch = t_abs = clock.stamp(tod, ordinal)
                    if f[1] != "A":
                        skipped["RMC void"] += 1
                        continue
                    if not (f[2] and f[4]) and not f[6] and not f[7]:
                        skipped["RMC empty"] += 1
                        continue
                    if f[2] and f[4]:
                        put("lat", sid, t_abs, _angle(f[2], f[3], "N", "S", 90.0))
                        put("lon", sid, t_abs, _angle(f[4], f[5], "E", "W", 180.0))
                    if f[6]:
                        put("sog", sid, t_abs, _nonneg(f[6], 1e4) * VARIABLE_MAP[("RMC", "spd")][1])
                    if f[7]:
                        put("cog", sid, t_abs, _nonneg(f[7], 360.0) * _DEG)
                elif sid == "VTG":
                    if epoch is None:
                        skipped["VTG before the first GGA/RMC time"] += 1
                        continue
                    if len(f) >= 8 and f[1] == "T":
                        # cogt, T, cogm, M, sogn, N, sogk, K[, posMode]
                        cogt, sogn, sogk = f[0], f[4], f[6]
                        mode = f[8] if len(f) > 8 else ""
                    else:
                        # NMEA 0183 v1.5 form without unit letters: cogt, cogm, sogn, sogk.
                        cogt, sogn, sogk, mode = f[0], f[2], f[3], ""
                    if mode == "N":
                        skipped["VTG not valid"] += 1
                        continue
                    if not (sogk or sogn or cogt):
                        # Receivers send an all-empty VTG while they have no velocity solution.
                        skipped["VTG empty"] += 1
                        continue
                    # km/h first: at the usual three decimals it resolves 0.3 mm/s, knots 0.5 mm/s.
                    if sogk:
                        put("sog", sid, epoch, _nonneg(sogk, 2e4) * VARIABLE_MAP[("VTG", "sogk")][1])
                    elif sogn:
                        put("sog", sid, epoch, _nonneg(sogn, 1e4) * VARIABLE_MAP[("VTG", "sogn")][1])
                    if cogt:
                        put("cog", sid, epoch, _nonneg(cogt, 360.0) * _DEG)
                else:  # HDT, THS
                    if epoch is None:
                        skipped[f"{sid} before the first GGA/RMC time"] += 1
                        continue
                    if sid == "THS" and (len(f) < 2 or f[1] == "V"):
                        skipped["THS invalid"] += 1
                        continue
                    if not f[0]:
                        skipped[f"{sid} empty"] += 1
                        continue
                    put("psi", sid, epoch, _nonneg(f[0], 360.0) * _DEG)
            except (ValueError, IndexError):
                skipped[f"{sid} malformed"] += 1
                continue
            read[sid] += 1

    if n_sentences == 0:
        raise IngestError(f"{p}: expected NMEA 0183 sentences ($GPGGA, $GPRMC, ...), found none in "
                          f"{len(lines)} line(s)")
    if not samples:
        found = ", ".join(f"{k} {v}" for k, v in sorted(skipped.items())) or "nothing"
        raise IngestError(f"{p}: expected usable {'/'.join(SENTENCES)} sentences with a time (GGA or RMC), "
                          f"found none usable among {n_sentences} sentence(s) ({found})")

    warnings: list[str] = []
    chans: dict[str, Channel] = {}
    merged: dict[str, tuple[np.ndarray, np.ndarray, str]] = {}
    for name in ("lat", "lon", "sog", "cog", "psi"):
        parts = []
        for (ch, sid), (ts, vs) in samples.items():
            if ch != name:
                continue
            tc, vc, dropped = increasing(np.asarray(ts), np.asarray(vs))
            if dropped and name in ("lat", "sog", "psi"):
                # One count per sentence (lat stands for lat/lon, sog for sog/cog).
                skipped[f"{sid} repeated or out of order"] += dropped
                warnings.append(f"{sid}: {dropped} sentence(s) repeating an earlier epoch or stepping back in "
                                f"time dropped")
            parts.append((tc, vc, sid))
        if not parts:
            continue
        t_all = np.concatenate([x[0] for x in parts])
        v_all = np.concatenate([x[1] for x in parts])
        prio = np.concatenate([np.full(len(x[0]), _PRIORITY[x[2]]) for x in parts])
        order = np.lexsort((prio, t_all))
        t_all, v_all = t_all[order], v_all[order]
        # Same quantity from two sentences at one epoch (GGA and RMC): keep the preferred one.
        keep = np.ones(len(t_all), bool)
        keep[1:] = np.diff(t_all) > 0
        merged[name] = (t_all[keep], v_all[keep], "+".join(sorted({x[2] for x in parts})))
    if not merged:
        raise IngestError(f"{p}: expected GGA or RMC fixes to give the time, found none usable")
    t0 = min(float(v[0][0]) for v in merged.values())
    for name, (t_abs, values, sids) in merged.items():
        if name in ANGLE_CHANNELS:
            values = np.pi - np.mod(np.pi - values, 2 * np.pi)
        chans[name + suffix] = Channel(name + suffix, t_abs - t0, values, source=f"nmea:{sids}")

    warnings.insert(0, f"time origin: t = 0 is the first fix, {clock.utc(t0)}")
    if quality:
        total = sum(quality.values())
        q_text = ", ".join(f"{FIX_QUALITY.get(q, str(q))} {100.0 * c / total:.1f}%" for q, c in sorted(quality.items()))
        s_text = (f"; satellites {min(nsat)}-{max(nsat)} (median {float(np.median(nsat)):g})" if nsat else "")
        h_text = (f"; HDOP {min(hdop):g}-{max(hdop):g} (median {float(np.median(hdop)):g})" if hdop else "")
        warnings.insert(1, f"fix stats (GGA): quality {q_text}{s_text}{h_text}")
    if skipped["bad checksum"]:
        warnings.append(f"bad checksum: {skipped['bad checksum']} of {n_sentences} sentence(s) skipped")
    if skipped["garbage line"] or skipped["incomplete sentence"]:
        warnings.append(f"unreadable lines skipped: {skipped['garbage line']} without a sentence, "
                        f"{skipped['incomplete sentence']} with an incomplete sentence or no checksum")
    if skipped["THS invalid"]:
        warnings.append(f"THS: {skipped['THS invalid']} heading(s) flagged invalid (mode V) skipped")
    if skipped["GGA no fix"]:
        warnings.append(f"GGA: {skipped['GGA no fix']} sentence(s) without a fix (quality 0) skipped")
    empty = {k.split()[0]: v for k, v in skipped.items() if k.endswith(" empty") and v}
    if empty:
        warnings.append("sentences with empty fields (no solution) skipped: "
                        + ", ".join(f"{k} {v}" for k, v in sorted(empty.items())))
    if skipped["RMC void"]:
        warnings.append(f"RMC: {skipped['RMC void']} sentence(s) with status V (void) skipped")
    bad = {k: v for k, v in skipped.items() if k.endswith("malformed")}
    if bad:
        warnings.append("malformed fields: " + ", ".join(f"{k} {v}" for k, v in sorted(bad.items())))
    if clock.rollovers:
        warnings.append(f"UTC day rollover(s) handled: {clock.rollovers}")
    if "psi" not in merged:
        warnings.append("no heading (HDT/THS): yaw only from course over ground, which includes sideslip")
    summary = IngestSummary(path=str(p), format="nmea", read=dict(read),
                            skipped={k: v for k, v in skipped.items() if v}, warnings=tuple(warnings))
    return RawLog(source=str(p), format="nmea", channels=chans, summary=summary, time_reference="gps",
                  start_time=clock.unix(t0), time_of_day=float(t0 % 86400.0))

