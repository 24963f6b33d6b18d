"""NMEA 0183 logs: position, speed, heading, rate of turn and attitude from GNSS receivers and marine instruments.

A log is a text file of sentences ``$<address>,field,...*hh``, one a line, from any talker: two
letters (GP, GN, HE, II, ...), two digits (``$02MWV``, ``$24HDG``, instrument bus addresses) or a
proprietary address (``$PASHR``, ``$PTNL,AVR``). Real logs are messy, and the reader is tolerant
of what loggers do to them:

- a leading column (a PC timestamp, a line number, ``t`` or binary noise from a serial port that
  was opened mid-sentence) before the ``$`` is ignored, as is anything after the checksum;
- lines without a complete sentence (fragments, blank lines, garbage) are counted and skipped;
- every sentence's ``*hh`` checksum (XOR of the bytes between ``$`` and ``*``) is checked; bad
  ones are counted, skipped and reported in a warning;
- a sentence repeating its own epoch, or stepping back in time, is dropped and counted once (not
  once per channel it carries).

Time comes from the sentences, not from the PC. Time-bearing sentences are GGA, RMC, GLL, GNS,
ZDA, PASHR and PTNL,AVR (UTC time of day; RMC and ZDA also the date); the others (VTG, HDT, THS,
HDG, HDM, VHW, ROT) take the time of the latest time-bearing sentence before them (an instrument
bus sends an epoch's sentences together). A time of day that falls back by more than 12 h is a
midnight rollover; an RMC/ZDA date overrides the day count, so a log that spans days or pauses
over midnight stays on one clock. ``t`` is seconds from the first sample and ``time_reference``
is ``gps`` (UTC from the receiver); the UTC of ``t = 0`` is in the summary and, when a date makes
it absolute, in ``RawLog.start_time``.

Mapping (``VARIABLE_MAP``; SI units, radians, NED: course and heading clockwise from true north)
------------------------------------------------------------------------------------------------
GGA  lat, lon [ddmm.mmmm + N/S, E/W] -> lat, lon [deg]  (fix quality 0 is skipped and counted)
GNS  lat, lon -> lat, lon  (mode N for every constellation skipped)
GLL  lat, lon -> lat, lon  (status V or mode N skipped)
RMC  lat, lon -> lat, lon; spd [knots] -> sog [m/s]; cog [deg] -> cog [rad]  (status V skipped)
VTG  sogk [km/h] (or sogn [knots]) -> sog [m/s]; cogt [deg true] -> cog [rad]  (mode N skipped)
HDT  heading [deg true] -> psi [rad]
THS  headt [deg true] -> psi [rad]  (mode V, invalid, skipped and counted)
HDG  heading [deg magnetic] + deviation + variation (E positive) -> psi [rad, true]
HDM  heading [deg magnetic] + the latest variation (HDG or RMC) -> psi [rad, true]
VHW  speed through water [km/h or knots] -> u [m/s] (log speed, relative to the water); true
     heading -> psi
ROT  rate of turn [deg/min, positive to starboard] -> r [rad/s]  (status V skipped)
PASHR  heading [deg true], roll [deg, starboard down positive], pitch [deg, bow up positive]
       -> psi, phi, theta [rad]
PTNL,AVR  yaw [deg true] of the two-antenna baseline -> psi [rad]  (quality 0 skipped)
ZDA  time and date only (sets the clock)

A magnetic heading (HDG without variation, HDM) with no variation anywhere in the log is kept as
``psi`` and flagged in a warning: it differs from the true heading by the local variation, a
constant that does not change yaw rate, but does change the comparison with course over ground.
When two sentences give the same quantity at the same epoch one sample is kept (GGA/GNS before
GLL before RMC for position; VTG before RMC for speed and course; HDT before THS/PASHR/PTNL
before HDG before VHW before HDM for heading). The summary's warnings name every sentence type
seen and what became of it. The field names are those of pynmeagps (``nmeatypes_get``), so the
map can be read next to its documentation.

Parsing is done here by hand, not with ``pynmeagps.NMEAReader.parse``: the sentences have
fixed, simple layouts, and the hand parser is about ten times faster (measured on the CE6
Limfjord logs: ~6 us against ~60 us a sentence; an hour of 20 Hz GGA+VTG is 144 000 sentences,
so 1 s against 9 s), and it can count each kind of defect separately. pynmeagps is used by the
tests as an independent check of the parser and of the writer's checksums.
"""

from __future__ import annotations

import contextlib
import math
import re
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from datetime import date, datetime, timedelta, timezone
from functools import reduce
from operator import xor
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import IngestError
from ..records import ANGLE_CHANNELS, Channel, IngestSummary, RawLog
from ..terminal import want_progress
from ._common import check_file, describe_failure

_DEG = math.pi / 180.0
_KNOT = 1852.0 / 3600.0   # [m/s] per knot
_KMH = 1.0 / 3.6          # [m/s] per km/h

#: (sentence, field) -> (canonical channel, scale to SI). lat/lon are decoded from ddmm.mmmm first.
VARIABLE_MAP: dict[tuple[str, str], tuple[str, float]] = {
    ("GGA", "lat"): ("lat", 1.0),
    ("GGA", "lon"): ("lon", 1.0),
    ("GNS", "lat"): ("lat", 1.0),
    ("GNS", "lon"): ("lon", 1.0),
    ("GLL", "lat"): ("lat", 1.0),
    ("GLL", "lon"): ("lon", 1.0),
    ("RMC", "lat"): ("lat", 1.0),
    ("RMC", "lon"): ("lon", 1.0),
    ("RMC", "spd"): ("sog", _KNOT),
    ("RMC", "cog"): ("cog", _DEG),
    ("VTG", "sogk"): ("sog", _KMH),
    ("VTG", "sogn"): ("sog", _KNOT),
    ("VTG", "cogt"): ("cog", _DEG),
    ("HDT", "heading"): ("psi", _DEG),
    ("THS", "headt"): ("psi", _DEG),
    ("HDG", "heading"): ("psi", _DEG),
    ("HDM", "heading"): ("psi", _DEG),
    ("VHW", "hdgT"): ("psi", _DEG),
    ("VHW", "spdwK"): ("u", _KMH),
    ("VHW", "spdwN"): ("u", _KNOT),
    ("ROT", "rot"): ("r", _DEG / 60.0),
    ("PASHR", "heading"): ("psi", _DEG),
    ("PASHR", "roll"): ("phi", _DEG),
    ("PASHR", "pitch"): ("theta", _DEG),
    ("PTNL,AVR", "yaw"): ("psi", _DEG),
}
#: Sentences the reader uses (ZDA only for the clock).
SENTENCES = ("GGA", "RMC", "GNS", "GLL", "VTG", "HDT", "THS", "HDG", "HDM", "VHW", "ROT", "ZDA", "PASHR",
             "PTNL,AVR")
#: Sentences that carry their own UTC time of day.
TIMED = ("GGA", "RMC", "GNS", "GLL", "ZDA", "PASHR", "PTNL,AVR")
#: Sentences that give a heading.
HEADINGS = ("HDT", "THS", "PASHR", "PTNL,AVR", "HDG", "VHW", "HDM")
#: Which sentence wins when two give a channel at the same epoch (lower first).
_PRIORITY = {"GGA": 0, "GNS": 0, "VTG": 0, "HDT": 0, "ROT": 0, "GLL": 1, "THS": 1, "PASHR": 1, "PTNL,AVR": 1,
             "RMC": 2, "HDG": 2, "VHW": 3, "HDM": 4}
#: GGA fix quality indicator -> name (NMEA 0183 v4.11).
FIX_QUALITY = {0: "invalid", 1: "GPS", 2: "DGPS", 3: "PPS", 4: "RTK fixed", 5: "RTK float",
               6: "estimated", 7: "manual", 8: "simulation"}
#: Why common sentence types carry nothing for the vessel's motion (for the summary).
_NOT_USED = {"GSV": "satellites in view", "GSA": "DOP and active satellites", "GST": "error statistics",
             "TXT": "text", "DBT": "depth", "DPT": "depth", "MWV": "wind", "MWD": "wind", "VWR": "wind",
             "MTW": "water temperature", "XDR": "transducer values", "RMB": "navigation to waypoint",
             "APB": "autopilot", "XTE": "cross-track error", "BWC": "bearing to waypoint",
             "VLW": "distance log", "RSA": "rudder angle (instrument)", "VDM": "AIS", "VDO": "AIS"}

# A sentence anywhere in a line: '$' (or '!' for AIS), an address of two to ten characters
# (talker + id, digits allowed: '$02MWV'; or a proprietary 'P...' address), fields, '*hh'.
# Printable ASCII only, so binary noise cannot extend a match across a corrupted stretch.
_SENTENCE_RE = re.compile(rb"[$!]([A-Z0-9]{2,10})(?:,([\x20-\x23\x25-\x29\x2b-\x7e]*))?\*([0-9A-Fa-f]{2})")
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
    return any(nmea_checksum(m.group(0)[1:-3]) == int(m.group(3), 16) for m in _SENTENCE_RE.finditer(head))




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


def _zda_date(f: list[str]) -> int | None:
    """ZDA day, month, year (4 digits) -> proleptic ordinal; None when absent or invalid."""
    try:
        yy = int(f[3])
        if yy < 100:   # some instruments write two digits; receivers are post-1980
            yy += 1900 if yy >= 80 else 2000
        return date(yy, int(f[2]), int(f[1])).toordinal()
    except (ValueError, IndexError):
        return None


def _signed(s: str, limit: float) -> float:
    x = float(s)
    if not (math.isfinite(x) and abs(x) <= limit):
        raise ValueError(s)
    return x


def _east(value: str, letter: str) -> float:
    """A deviation or variation with its E/W letter -> degrees, east positive; 0 when empty."""
    if not value:
        return 0.0
    x = _signed(value, 180.0)
    if letter == "W":
        return -x
    if letter == "E":
        return x
    raise ValueError(letter)


@dataclass
class NmeaParse:
    """What :func:`parse_nmea` found: per-channel samples on the absolute UTC clock and the counts.

    Attributes
    ----------
    merged : dict
        Channel -> (t [s, UTC seconds from day 0 of ``clock``], values [SI], sentence ids).
    clock : _UtcClock
        The clock that turned times of day into seconds (``clock.unix(t)`` gives Unix time).
    read, skipped : Counter
        Sentences used per type; sentences not used per type and reason.
    warnings : list of str
        Notes for the summary (counts of every defect, sentence types seen and their fate).
    n_sentences : int
        Sentences found (checksum good or bad).
    """

    merged: dict
    clock: "_UtcClock"
    read: Counter
    skipped: Counter
    warnings: list
    n_sentences: int
    n_lines: int


class _Skip(Exception):
    """A sentence not used; the message is the reason counted in the summary (``"GGA no fix"``)."""


#: Decoders' answer for a sentence that only sets the clock (ZDA): read, no samples.
_CLOCK_ONLY = (None, None)


@dataclass
class _ParseState:
    """Everything :func:`parse_nmea` accumulates while it walks the sentences."""

    clock: _UtcClock = field(default_factory=_UtcClock)
    # (channel, sentence id) -> lists of absolute UTC seconds and SI values, in file order.
    samples: dict = field(default_factory=lambda: defaultdict(lambda: ([], [])))
    read: Counter = field(default_factory=Counter)
    skipped: Counter = field(default_factory=Counter)
    seen: Counter = field(default_factory=Counter)
    n_sentences: int = 0
    n_lines: int = 0
    quality: Counter = field(default_factory=Counter)
    nsat: list = field(default_factory=list)
    hdop: list = field(default_factory=list)
    epoch: float | None = None    # time of the latest time-bearing sentence: untimed sentences take it
    fresh: bool = False           # the latest epoch moved time forward (not a repeat or a step back)
    in_epoch: Counter = field(default_factory=Counter)  # untimed sentences of each type since the epoch opened
    untimed: dict = field(default_factory=lambda: defaultdict(list))  # (channel, sid) -> (epoch, k, value)
    last_t: dict = field(default_factory=dict)   # per sentence id, the latest epoch used
    epochs: list = field(default_factory=list)   # every epoch that moved time forward, in order
    variation: float | None = None                # latest magnetic variation [deg, E positive] (HDG or RMC)
    magnetic_only: Counter = field(default_factory=Counter)

    def open(self, t: float) -> None:
        """A time-bearing sentence at ``t`` [s]: open a new epoch when time moved forward."""
        if self.epoch is None or t > self.epoch:
            self.in_epoch.clear()
            self.epochs.append(t)
            self.epoch, self.fresh = t, True
        elif t < self.epoch:
            self.fresh = False   # a step back: untimed sentences after it cannot be placed

    def place(self, sid: str, t_own: float | None, puts: list[tuple[str, float]]) -> None:
        """File one decoded sentence: on its own time, or (untimed) as the k-th of its type in the epoch."""
        if t_own is not None:
            self.open(t_own)
        else:
            if not self.fresh:
                self.skipped[f"{sid} repeated or out of order"] += 1
                return
            k = self.in_epoch[sid]
            self.in_epoch[sid] += 1
            for name, value in puts:
                self.untimed[(name, sid)].append((self.epoch, k, value))
            self.read[sid] += 1
            return
        prev = self.last_t.get(sid)
        if prev is not None and t_own <= prev:
            # Once per sentence, whatever number of channels it carries; the untimed
            # sentences that follow it belong to the repeated epoch and are dropped too.
            self.skipped[f"{sid} repeated or out of order"] += 1
            self.fresh = False
            return
        self.last_t[sid] = t_own
        for name, value in puts:
            ts, vs = self.samples[(name, sid)]
            ts.append(t_own)
            vs.append(value)
        self.read[sid] += 1


def _lat_lon(lat: str, ns: str, lon: str, ew: str) -> list[tuple[str, float]]:
    return [("lat", _angle(lat, ns, "N", "S", 90.0)), ("lon", _angle(lon, ew, "E", "W", 180.0))]


# ----------------------------------------------------------------------------- sentence families
# Each decoder takes (sentence id, fields, state) and returns (own time [s] or None, [(channel, SI value)]),
# or raises _Skip (not used, with the reason) or ValueError/IndexError (malformed).

def _position(sid: str, f: list[str], st: _ParseState) -> tuple[float | None, list]:
    """GGA, GNS, GLL: a position fix on its own time; a time without a fix still opens the epoch."""
    if sid == "GGA":
        # time, lat, N/S, lon, E/W, quality, numSV, HDOP, alt, M, sep, M, diffAge, diffStation
        tod, q = _time_of_day(f[0]), int(f[5]) if f[5] else 0
        if q == 0 or not f[1] or not f[3]:
            st.open(st.clock.stamp(tod))
            st.quality[0] += 1
            raise _Skip("GGA no fix")
        puts = _lat_lon(*f[1:5])
        t = st.clock.stamp(tod)
        st.quality[q] += 1
        if len(f) > 6 and f[6].isdigit():
            st.nsat.append(int(f[6]))
        if len(f) > 7 and f[7]:
            with contextlib.suppress(ValueError):
                st.hdop.append(float(f[7]))
        return t, puts
    if sid == "GNS":
        # time, lat, N/S, lon, E/W, mode (one letter per constellation), numSV, HDOP, ...
        tod = _time_of_day(f[0])
        mode = f[5] if len(f) > 5 else ""
        if not f[1] or not f[3] or (mode and set(mode) <= {"N"}):
            st.open(st.clock.stamp(tod))
            raise _Skip("GNS no fix")
        puts = _lat_lon(*f[1:5])
        return st.clock.stamp(tod), puts
    # GLL: lat, N/S, lon, E/W, time, status, posMode
    tod = _time_of_day(f[4])
    if f[5] != "A" or (len(f) > 6 and f[6] == "N") or not f[0] or not f[2]:
        st.open(st.clock.stamp(tod))
        raise _Skip("GLL void")
    puts = _lat_lon(*f[0:4])
    return st.clock.stamp(tod), puts


def _date_time(sid: str, f: list[str], st: _ParseState) -> tuple[float | None, list | None]:
    """ZDA: time, day, month, year, local zone hours, minutes: the clock only."""
    st.open(st.clock.stamp(_time_of_day(f[0]), _zda_date(f)))
    return _CLOCK_ONLY


def _recommended_minimum(sid: str, f: list[str], st: _ParseState) -> tuple[float | None, list]:
    """RMC: time, status, lat, N/S, lon, E/W, spd [kn], cog [deg], date, mv, mvEW, posMode."""
    tod = _time_of_day(f[0])
    t = st.clock.stamp(tod, _rmc_date(f[8]) if len(f) > 8 else None)
    if len(f) > 10 and f[9]:
        with contextlib.suppress(ValueError):
            st.variation = _east(f[9], f[10])
    if f[1] != "A":
        st.open(t)
        raise _Skip("RMC void")
    if not (f[2] and f[4]) and not f[6] and not f[7]:
        st.open(t)
        raise _Skip("RMC empty")
    puts = _lat_lon(*f[2:6]) if f[2] and f[4] else []
    if f[6]:
        puts.append(("sog", _nonneg(f[6], 1e4) * _KNOT))
    if f[7]:
        puts.append(("cog", _nonneg(f[7], 360.0) * _DEG))
    return t, puts


def _attitude(sid: str, f: list[str], st: _ParseState) -> tuple[float | None, list]:
    """Proprietary attitude on its own time: $PASHR (heading, roll, pitch) and $PTNL,AVR (yaw)."""
    if sid == "PASHR":
        # time, heading, T, roll, pitch, heave, acc roll, acc pitch, acc heading, GPS flag, IMU flag
        if len(f) < 5 or f[2] != "T":
            raise _Skip("PASHR other layout")
        t = st.clock.stamp(_time_of_day(f[0]))
        if len(f) > 10 and f[10] == "0":
            st.open(t)
            raise _Skip("PASHR IMU not aligned")
        return t, [("psi", _nonneg(f[1], 360.0) * _DEG), ("phi", _signed(f[3], 180.0) * _DEG),
                   ("theta", _signed(f[4], 90.0) * _DEG)]
    # PTNL,AVR: time, yaw, 'Yaw', tilt, 'Tilt', roll, 'Roll', range, quality, PDOP, numSV
    t = st.clock.stamp(_time_of_day(f[0]))
    if len(f) > 8 and f[8] in ("", "0"):
        st.open(t)
        raise _Skip("PTNL,AVR no solution")
    return t, [("psi", _signed(f[1], 360.0) * _DEG)]


def _velocity(sid: str, f: list[str], st: _ParseState) -> tuple[None, list]:
    """VTG: course and speed over ground (untimed)."""
    if len(f) >= 8 and f[1] == "T":
        # cogt, T, cogm, M, sogn, N, sogk, K[, posMode]
        cogt, sogn, sogk = f[0], f[4], f[6]
        mode = f[8] if len(f) > 8 else ""
    else:
        # NMEA 0183 v1.5 form without unit letters: cogt, cogm, sogn, sogk.
        cogt, sogn, sogk, mode = f[0], f[2], f[3], ""
    if mode == "N":
        raise _Skip("VTG not valid")
    if not (sogk or sogn or cogt):
        # Receivers send an all-empty VTG while they have no velocity solution.
        raise _Skip("VTG empty")
    puts = []
    # km/h first: at the usual three decimals it resolves 0.3 mm/s, knots 0.5 mm/s.
    if sogk:
        puts.append(("sog", _nonneg(sogk, 2e4) * _KMH))
    elif sogn:
        puts.append(("sog", _nonneg(sogn, 1e4) * _KNOT))
    if cogt:
        puts.append(("cog", _nonneg(cogt, 360.0) * _DEG))
    return None, puts


def _heading(sid: str, f: list[str], st: _ParseState) -> tuple[None, list]:
    """HDT, THS (true heading); HDG, HDM (magnetic, corrected by deviation and the latest variation)."""
    if sid == "THS" and (len(f) < 2 or f[1] == "V"):
        raise _Skip("THS invalid")
    if not f[0]:
        raise _Skip(f"{sid} empty")
    if sid in ("HDT", "THS"):
        return None, [("psi", _nonneg(f[0], 360.0) * _DEG)]
    hdg = _nonneg(f[0], 360.0)
    if sid == "HDG":
        # heading [deg magnetic], deviation, E/W, variation, E/W
        hdg += _east(f[1] if len(f) > 1 else "", f[2] if len(f) > 2 else "")
        if len(f) > 4 and f[3]:
            st.variation = _east(f[3], f[4])
    if st.variation is None:
        st.magnetic_only[sid] += 1
    return None, [("psi", (hdg + (st.variation or 0.0)) * _DEG)]


def _water_speed(sid: str, f: list[str], st: _ParseState) -> tuple[None, list]:
    """VHW: hdgT, T, hdgM, M, spdwN, N, spdwK, K (heading and speed through the water)."""
    puts = []
    if len(f) > 0 and f[0]:
        puts.append(("psi", _nonneg(f[0], 360.0) * _DEG))
    if len(f) > 6 and f[6]:
        puts.append(("u", _signed(f[6], 200.0) * _KMH))
    elif len(f) > 4 and f[4]:
        puts.append(("u", _signed(f[4], 100.0) * _KNOT))
    if not puts:
        raise _Skip("VHW empty")
    return None, puts


def _rate_of_turn(sid: str, f: list[str], st: _ParseState) -> tuple[None, list]:
    """ROT: rate of turn [deg/min], status."""
    if len(f) > 1 and f[1] == "V":
        raise _Skip("ROT invalid")
    if not f[0]:
        raise _Skip("ROT empty")
    return None, [("r", _signed(f[0], 1e4) * _DEG / 60.0)]


#: Sentence id -> its family's decoder (every id in ``SENTENCES``).
_DECODERS = {"GGA": _position, "GNS": _position, "GLL": _position, "ZDA": _date_time, "RMC": _recommended_minimum,
             "PASHR": _attitude, "PTNL,AVR": _attitude, "VTG": _velocity, "HDT": _heading, "THS": _heading,
             "HDG": _heading, "HDM": _heading, "VHW": _water_speed, "ROT": _rate_of_turn}


def _sentences(line: bytes, st: _ParseState) -> Iterator[tuple[str, list[str]]]:
    """The checksum-good sentences of one line as (sentence id, fields); counts the line's defects."""
    matches = list(_SENTENCE_RE.finditer(line))
    if not matches:
        if b"$" in line:
            st.skipped["incomplete sentence"] += 1
        elif line.strip():
            st.skipped["garbage line"] += 1
        return
    for m in matches:
        st.n_sentences += 1
        body = m.group(0)[1:-3]
        if nmea_checksum(body) != int(m.group(3), 16):
            st.skipped["bad checksum"] += 1
            continue
        addr = m.group(1).decode()
        f = (m.group(2) or b"").decode().split(",")
        if m.group(0)[:1] == b"!":
            sid = addr[2:] or addr       # AIS (!AIVDM): other ships, not this one
        elif addr[0] == "P":
            sid = f"{addr},{f[0]}" if addr in ("PTNL", "PSXN", "PGRM") and f else addr
            if sid == "PTNL,AVR":
                f = f[1:]
        else:
            sid = addr[2:]
        yield sid, f


def _spread_untimed(untimed: dict, epochs: np.ndarray, samples: dict) -> dict[str, int]:
    """Give untimed sentences times: the k-th of n in an epoch at e + k/n (e_next - e).

    A heading sensor at 10 Hz between 1 Hz GNSS fixes keeps its rate instead of nine in ten
    sentences being dropped as repeats. Returns the largest count per epoch of each type
    that was spread (types with one per epoch are not listed).
    """
    out: dict[str, int] = {}
    if len(epochs) > 1:
        last_step = float(np.median(np.diff(epochs)))
    else:
        last_step = 0.0
    for (name, sid), rows in untimed.items():
        e = np.array([r[0] for r in rows])
        k = np.array([r[1] for r in rows], float)
        v = np.array([r[2] for r in rows])
        # n per epoch: the count of this type in the epoch of each sample.
        _, inv, counts = np.unique(e, return_inverse=True, return_counts=True)
        n = counts[inv].astype(float)
        j = np.searchsorted(epochs, e, side="right")
        nxt = np.where(j < len(epochs), epochs[np.minimum(j, len(epochs) - 1)], e + last_step)
        t = e + k / n * (nxt - e)
        if counts.max() > 1:
            out[sid] = max(out.get(sid, 0), int(counts.max()))
        ts, vs = samples[(name, sid)]
        ts.extend(t.tolist())
        vs.extend(v.tolist())
    return out


def _merge_channels(samples: dict) -> dict[str, tuple[np.ndarray, np.ndarray, str]]:
    """One series per channel from every sentence giving it; at one epoch the preferred sentence wins."""
    merged: dict[str, tuple[np.ndarray, np.ndarray, str]] = {}
    for name in ("lat", "lon", "sog", "cog", "psi", "phi", "theta", "u", "r"):
        parts = [(np.asarray(ts), np.asarray(vs), sid) for (ch, sid), (ts, vs) in samples.items() if ch == name]
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
    return merged


def _defect_warnings(st: _ParseState) -> list[str]:
    """Summary lines for the fix statistics and every kind of sentence that was dropped, with counts."""
    skipped, warnings = st.skipped, []
    if st.quality:
        total = sum(st.quality.values())
        q_text = ", ".join(f"{FIX_QUALITY.get(q, str(q))} {100.0 * c / total:.1f}%"
                           for q, c in sorted(st.quality.items()))
        nsat, hdop = st.nsat, st.hdop
        s_text = f"; satellites {min(nsat)}-{max(nsat)} (median {float(np.median(nsat)):g})" if nsat else ""
        h_text = f"; HDOP {min(hdop):g}-{max(hdop):g} (median {float(np.median(hdop)):g})" if hdop else ""
        warnings.append(f"fix stats (GGA): quality {q_text}{s_text}{h_text}")
    if skipped["bad checksum"]:
        warnings.append(f"bad checksum: {skipped['bad checksum']} of {st.n_sentences} sentence(s) skipped")
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
    repeats = {k.split()[0]: v for k, v in skipped.items() if k.endswith("repeated or out of order") and v}
    if repeats:
        warnings.append("sentences repeating an earlier epoch of their type or stepping back in time dropped "
                        "(each counted once): " + ", ".join(f"{k} {v}" for k, v in sorted(repeats.items())))
    bad = {k: v for k, v in skipped.items() if k.endswith("malformed")}
    if bad:
        warnings.append("malformed fields: " + ", ".join(f"{k} {v}" for k, v in sorted(bad.items())))
    if st.magnetic_only:
        warnings.append("magnetic heading without a variation anywhere before it (no HDG variation, no RMC mv): "
                        + ", ".join(f"{k} {v}" for k, v in sorted(st.magnetic_only.items()))
                        + " heading(s) kept as psi = magnetic heading (+ deviation); true heading differs by "
                        "the local variation, a constant offset")
    if st.clock.rollovers:
        warnings.append(f"UTC day rollover(s) handled: {st.clock.rollovers}")
    return warnings


def _fates(st: _ParseState) -> str:
    """``sentence types: GGA 120 (read 118, no fix 2); GSV 40 (not used: satellites in view 40); ...``."""
    parts = []
    for sid, n in sorted(st.seen.items()):
        fate = [f"read {st.read[sid]}"] if st.read[sid] else []
        for k, v in sorted(st.skipped.items()):
            if v and (k == sid or k.startswith(sid + " ")):
                why = k[len(sid):].strip() or "not used" + (f": {_NOT_USED[sid]}" if sid in _NOT_USED else "")
                fate.append(f"{why} {v}")
        parts.append(f"{sid} {n} ({', '.join(fate)})")
    return "sentence types: " + "; ".join(parts)


def parse_nmea(lines, path_text: str = "NMEA") -> NmeaParse:
    """Parse NMEA 0183 lines (bytes) into channels on one UTC clock, counting every sentence.

    Parameters
    ----------
    lines : iterable of bytes
        Text lines, each holding zero or more sentences.
    path_text : str
        Name of the source for messages.

    Returns
    -------
    NmeaParse
        Samples per channel (absolute UTC seconds; ``merged`` may be empty) and the counts.
    """
    st = _ParseState()
    seen, skipped, decoders, timed = st.seen, st.skipped, _DECODERS, frozenset(TIMED)
    for line in lines:
        st.n_lines += 1
        for sid, f in _sentences(line, st):
            seen[sid] += 1
            decode = decoders.get(sid)
            if decode is None:
                skipped[sid] += 1
                continue
            if st.epoch is None and sid not in timed:
                skipped[f"{sid} before the first time-bearing sentence"] += 1
                continue
            try:
                t_own, puts = decode(sid, f, st)
            except _Skip as why:
                skipped[str(why)] += 1
                continue
            except (ValueError, IndexError):
                skipped[f"{sid} malformed"] += 1
                continue
            if puts is None:   # the clock only (ZDA)
                st.read[sid] += 1
            else:
                st.place(sid, t_own, puts)
    warnings: list[str] = []
    spread = _spread_untimed(st.untimed, np.asarray(st.epochs, float), st.samples)
    if spread:
        warnings.append("sentences without their own time, several per epoch, spread evenly between the "
                        "time-bearing sentences around them: " + ", ".join(f"{k} up to {v} an epoch"
                                                                         for k, v in sorted(spread.items())))
    merged = _merge_channels(st.samples)
    warnings += _defect_warnings(st)
    if st.seen:
        warnings.append(_fates(st))
    return NmeaParse(merged=merged, clock=st.clock, read=st.read, skipped=st.skipped, warnings=warnings,
                     n_sentences=st.n_sentences, n_lines=st.n_lines)


def read_nmea(path: str | Path, sensor: str = "", progress: bool | None = None) -> RawLog:
    """Read an NMEA 0183 log (GNSS and marine instrument sentences) into canonical channels.

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
        ``psi``, ``phi``, ``theta`` [rad, wrapped], ``u`` [m/s, through the water], ``r``
        [rad/s] (each only when the log has it), on ``t`` [s] from the first sample;
        ``format='nmea'``, ``time_reference='gps'``; ``start_time`` is the UTC of the first
        sample [s, Unix] when an RMC or ZDA gives the date, NaN for a log of time of day only.
        The summary counts sentences used and skipped (per type and reason) and names every
        sentence type seen and what became of it.

    Raises
    ------
    IngestError
        Missing or empty file; no NMEA sentence in it; no usable sentence; only untimed
        sentences (no time-bearing sentence before them); a malformed ``sensor``.
    """
    p = check_file(path, "NMEA 0183 log")
    if sensor and not _SENSOR_RE.fullmatch(sensor):
        raise IngestError(f"sensor: expected letters, digits or '_' (a channel suffix), found {sensor!r}")
    suffix = f"@{sensor}" if sensor else ""
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise IngestError(f"{p}: expected a readable NMEA 0183 log, found a file that cannot be read ({exc.strerror or describe_failure(exc)})") from None

    lines = data.splitlines()
    it = lines
    if want_progress(progress, len(data), _PROGRESS_MIN_BYTES):
        from tqdm import tqdm

        it = tqdm(lines, desc=p.name, unit="line", leave=False)
    res = parse_nmea(it, str(p))
    if res.n_sentences == 0:
        raise IngestError(f"{p}: expected NMEA 0183 sentences ($GPGGA, $GPRMC, ...), found none in "
                          f"{len(lines)} line(s)")
    if not res.merged:
        found = ", ".join(f"{k} {v}" for k, v in sorted(res.skipped.items()) if v) or "nothing"
        raise IngestError(f"{p}: expected usable {'/'.join(SENTENCES)} sentences with a time "
                          f"({'/'.join(TIMED)}), found none usable among {res.n_sentences} sentence(s) ({found})")
    return nmea_rawlog(res, str(p), suffix)


def nmea_rawlog(res: NmeaParse, source: str, suffix: str = "") -> RawLog:
    """Build the RawLog of a :func:`parse_nmea` result (t = 0 at the first sample).

    Parameters
    ----------
    res : NmeaParse
        Parsed sentences with at least one channel.
    source : str
        File name for the summary.
    suffix : str
        Channel suffix (``@gps2``) or empty.
    """
    warnings = list(res.warnings)
    t0 = min(float(v[0][0]) for v in res.merged.values())
    chans: dict[str, Channel] = {}
    for name, (t_abs, values, sids) in res.merged.items():
        if name in ANGLE_CHANNELS:
            values = np.pi - np.mod(np.pi - values, 2 * np.pi)
        chans[name + suffix] = Channel(name + suffix, t_abs - t0, values, source=f"nmea:{sids}")
    warnings.insert(0, f"time origin: t = 0 is the first sample, {res.clock.utc(t0)}")
    if "psi" not in res.merged:
        warnings.append(f"no heading ({'/'.join(HEADINGS)}): yaw only from course over ground, which "
                        f"includes sideslip")
    if "u" in res.merged:
        warnings.append("u is the VHW log speed through the water (not over ground)")
    summary = IngestSummary(path=source, format="nmea", read=dict(res.read),
                            skipped={k: v for k, v in res.skipped.items() if v}, warnings=tuple(warnings))
    return RawLog(source=source, format="nmea", channels=chans, summary=summary, time_reference="gps",
                  start_time=res.clock.unix(t0), time_of_day=float(t0 % 86400.0))
