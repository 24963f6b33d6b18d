"""u-blox UBX binary logs (``.ubx``), as u-center, a logging script or a ROS driver records them.

A UBX frame is ``B5 62 <class> <id> <length u16> <payload> <CK_A> <CK_B>`` with an 8-bit Fletcher
checksum over class..payload. Frames are found vectorised: every ``B5 62`` in the byte stream is
a candidate, lengths and checksums are checked for all candidates at once (the Fletcher sums of
any byte range come from two running uint8 cumulative sums), and overlapping candidates (a
``B5 62`` inside a payload) resolve to the earlier valid frame. NAV-PVT, the bulk of a log, is
decoded with a numpy structured dtype over its fixed payload; NAV-RELPOSNED (version 1) and
ESF-RAW (4 reserved bytes + 8-byte blocks) likewise by one gather each, other RELPOSNED versions
through pyubx2 (``UBXReader.parse``); every other message is counted by its pyubx2 name.
NMEA sentences interleaved with UBX (receivers often output both) are parsed and read; RTCM 3
frames are recognised and counted.

Mapping (``VARIABLE_MAP``; SI units, radians; ``<s>`` is ``@<sensor>`` or empty)
--------------------------------------------------------------------------------
NAV-PVT        lat, lon [1e-7 deg]   -> lat<s>, lon<s> [deg]
               gSpeed [mm/s]         -> sog<s> [m/s]
               headMot [1e-5 deg]    -> cog<s> [rad, wrapped to (-pi, pi]]
               only samples with gnssFixOK, fixType 2D/3D/GNSS+DR and a valid position
NAV-RELPOSNED  relPosHeading [deg]   -> psi@<sensor or 'dual'> [rad], only with relPosHeadingValid
ESF-RAW        gyro x/y/z [2^-12 deg/s]   -> p@esf, -q@esf, -r@esf [rad/s]
               accel x/y/z [2^-10 m/s^2]  -> ax@esf, -ay@esf, -az@esf [m/s^2] (ESF axes below)
               (``@esf_<sensor>`` when a sensor name is given)
ESF-MEAS       the same data types and scales as ESF-RAW (``@esfmeas`` when the log has ESF-RAW too)
NAV-ATT        roll, pitch, heading [1e-5 deg] -> phi<s>, theta<s>, psi<s> [rad] (``@att`` when NAV-PVAT
               gives them too)
NAV-PVAT       lat, lon, gSpeed, motHeading -> lat, lon, sog, cog (``@pvat`` when NAV-PVT gives them);
               vehRoll, vehPitch, vehHeading -> phi, theta, psi (each only with its valid flag)
HNR-PVT        lat, lon, gSpeed, headMot -> lat@hnr, lon@hnr, sog@hnr, cog@hnr; headVeh -> psi@hnr (with
               headVehValid); plain names when the log has no NAV-PVT/NAV-PVAT
HNR-ATT        roll, pitch, heading -> phi, theta, psi (``@hnr`` when NAV-ATT or NAV-PVAT give them too)
NMEA           sentences between the frames are read by :func:`pipeline.ingest.nmea.parse_nmea` and
               put on the UBX clock through their UTC date and time (``@nmea`` when UBX messages give
               the same channel; plain names when the log has no UBX channels at all)
RTCM 3         correction frames between the frames are recognised (CRC-24Q) and counted per
               message number in ``summary.skipped`` (``RTCM3-1005`` ...)

ESF axes
--------
The ESF-RAW / ESF-MEAS IMU data are taken as x forward, y left, z up (specific force, so a level
receiver at rest reads +9.8 m/s^2 on z), and turned into Fossen's body frame (x forward, y
starboard, z down) by negating y and z, as for ROS FLU data. u-blox's manuals define the vehicle
frame (x forward, y right, z down) and the data types, but no sign for the raw sensor axes; the
convention here is measured on real logs (tests/data): three receivers (gpsd ``ublox-neo-m8l.log``,
``ublox-neo-m8u.log``, pyubx2 ``pygpsdata-ESF.log``) read z = +9.76, +10.03, +9.88 m/s^2 with x, y
near 0; in the NEO-M8L drive (ESF-ALG mount angles 0, HNR-ATT pitch +10.8 deg) the raw gyro z
against the receiver's own vehicle-frame rate (ESF-INS, gravity-free, 19 epochs) has correlation
-0.95 and slope -1.08, raw accel y against ESF-INS y -0.78, raw gyro x against ESF-INS x +0.72,
and the raw gyro z averages -4.4 deg/s while the HNR-ATT heading turns at +4.3 deg/s. A receiver
mounted otherwise shows up in ``align``'s mounting check (gravity on the wrong axis).

Time
----
``time_reference='gps'``: ``t`` [s] is GPS time of week from iTOW, unwrapped across week
rollovers (iTOW restarts at 0 every 604800 s; a backward jump of more than half a week is a new
week), so ``t = 0`` is the start of the GPS week of the first message. That week comes from the
UTC date in NAV-PVT (GPS = UTC + leap seconds; rounding makes the leap-second count immaterial)
and is stated in the summary (``t = 0 is the start of GPS week W (YYYY-MM-DD)``) and in every
``Channel.source``; ``RawLog.start_time`` is that instant in Unix UTC (GPS - UTC leap seconds from
the receiver when it flags UTC fully resolved, else from the table), so logs of several receivers
can be put on one clock.

ESF-RAW carries a sensor time tag (``sTag``) instead of iTOW. It is read as milliseconds of the
receiver's local clock and placed on GPS time by one offset: the median, over ESF-RAW messages,
of (midpoint of the iTOWs of the NAV-PVT before and after it in the stream) - (its sTag). This is
accurate to about one IMU sample when ESF-RAW is output promptly; the offset is in the summary.
"""

from __future__ import annotations

import math
import re
import struct
import sys
from collections import Counter
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any, Mapping, NamedTuple

import numpy as np
from pyubx2 import GET, UBXReader
from pyubx2.exceptions import UBXMessageError, UBXParseError, UBXTypeError
from pyubx2.ubxtypes_core import SCALROUND, UBX_MSGIDS

from ..errors import IngestError
from ..geo import wrap_pi
from ..records import Channel, IngestSummary, RawLog
from ..terminal import want_progress
from ._common import check_file
from ._gpstime import GPS_EPOCH_UNIX, WEEK_S, leap_seconds, unix_text
from .nmea import nmea_rawlog, parse_nmea
from .sniff import rtcm3_frames

_DEG = math.pi / 180.0
SYNC = b"\xb5\x62"
NAV_PVT = (0x01, 0x07)
NAV_RELPOSNED = (0x01, 0x3C)
ESF_RAW = (0x10, 0x03)
ESF_MEAS = (0x10, 0x02)
NAV_ATT = (0x01, 0x05)
NAV_PVAT = (0x01, 0x17)
HNR_PVT = (0x28, 0x00)
HNR_ATT = (0x28, 0x01)
#: Messages decoded one at a time through pyubx2 (lower rates than NAV-PVT/ESF-RAW), with iTOW.
_PARSED = {NAV_ATT: "NAV-ATT", NAV_PVAT: "NAV-PVAT", HNR_PVT: "HNR-PVT", HNR_ATT: "HNR-ATT"}
WEEK_MS = 604_800_000
#: Leap seconds GPS - UTC [s] (since 2017-01-01); only used to find the GPS week from the UTC date.
GPS_LEAP_S = 18
GPS_EPOCH = datetime(1980, 1, 6, tzinfo=timezone.utc)

#: (message, raw field or ESF data type) -> (canonical base name, scale to SI). NAV-PVT fields are
#: raw payload integers; NAV-RELPOSNED's are pyubx2's scaled attributes; ESF-RAW keys are data types.
VARIABLE_MAP: dict[tuple[str, str | int], tuple[str, float]] = {
    ("NAV-PVT", "lat"): ("lat", 1e-7),
    ("NAV-PVT", "lon"): ("lon", 1e-7),
    ("NAV-PVT", "gSpeed"): ("sog", 1e-3),
    ("NAV-PVT", "headMot"): ("cog", 1e-5 * _DEG),
    ("NAV-RELPOSNED", "relPosHeading"): ("psi", _DEG),
    # ESF axes are x forward, y left, z up (see "ESF axes" in the module docstring): y and z
    # change sign into Fossen's body frame (x forward, y starboard, z down).
    ("ESF-RAW", 14): ("p", 2.0**-12 * _DEG),
    ("ESF-RAW", 13): ("q", -(2.0**-12) * _DEG),
    ("ESF-RAW", 5): ("r", -(2.0**-12) * _DEG),
    ("ESF-RAW", 16): ("ax", 2.0**-10),
    ("ESF-RAW", 17): ("ay", -(2.0**-10)),
    ("ESF-RAW", 18): ("az", -(2.0**-10)),
}

#: NAV-PVT payload up to headVeh: the 84 bytes every protocol version (>= 14) has; version 15+
#: adds headVeh, magDec and magAcc (92 bytes), which are not needed.
NAV_PVT_DTYPE = np.dtype([
    ("iTOW", "<u4"), ("year", "<u2"), ("month", "u1"), ("day", "u1"), ("hour", "u1"), ("min", "u1"),
    ("sec", "u1"), ("valid", "u1"), ("tAcc", "<u4"), ("nano", "<i4"), ("fixType", "u1"), ("flags", "u1"),
    ("flags2", "u1"), ("numSV", "u1"), ("lon", "<i4"), ("lat", "<i4"), ("height", "<i4"), ("hMSL", "<i4"),
    ("hAcc", "<u4"), ("vAcc", "<u4"), ("velN", "<i4"), ("velE", "<i4"), ("velD", "<i4"), ("gSpeed", "<i4"),
    ("headMot", "<i4"), ("sAcc", "<u4"), ("headAcc", "<u4"), ("pDOP", "<u2"), ("flags3", "<u2"),
    ("reserved", "u1", (4,)),
])
FIX_TYPES = {0: "no fix", 1: "dead reckoning", 2: "2D", 3: "3D", 4: "GNSS+DR", 5: "time only"}
CARRIER = {0: "none", 1: "float", 2: "fixed", 3: "invalid"}
_NMEA = re.compile(rb"\$[A-Z][A-Z0-9]{2,}[^\r\n$]*\*[0-9A-Fa-f]{2}\r?\n")
_PYUBX2_ERRORS = (UBXParseError, UBXMessageError, UBXTypeError, struct.error, ValueError, KeyError, IndexError,
                  TypeError)
_PROGRESS_DELAY_S = 1.0


# ----------------------------------------------------------------------------- framing
def _frames(buf: np.ndarray) -> dict[str, Any]:
    """Valid UBX frames (start, end, class, id) and what lies between them, vectorised."""
    n = len(buf)
    empty = np.zeros(0, np.int64)
    cand = np.flatnonzero((buf[:-1] == 0xB5) & (buf[1:] == 0x62)) if n >= 2 else empty
    head_ok = cand + 6 <= n
    c = cand[head_ok]
    plen = buf[c + 4].astype(np.int64) | (buf[c + 5].astype(np.int64) << 8)
    end = c + 8 + plen
    complete = end <= n
    # Fletcher-8 over bytes [s, e): CK_A = sum b, CK_B = sum of the running CK_A; both from
    # prefix sums taken modulo 256 (uint8 cumulative sums wrap exactly that way).
    p1 = np.zeros(n + 1, np.uint8)
    np.cumsum(buf, dtype=np.uint8, out=p1[1:])
    q = np.zeros(n + 1, np.uint8)
    np.cumsum(p1[1:], dtype=np.uint8, out=q[1:])
    cc, pc = c[complete], plen[complete]
    s, e = cc + 2, cc + 6 + pc
    ck_a = (p1[e] - p1[s]).astype(np.uint8)
    ck_b = ((q[e].astype(np.int64) - q[s] - (e - s) * p1[s].astype(np.int64)) & 0xFF).astype(np.uint8)
    good = (ck_a == buf[e]) & (ck_b == buf[e + 1])
    starts, ends = cc[good], (cc + 8 + pc)[good]
    if len(starts) > 1 and np.any(starts[1:] < ends[:-1]):
        # A valid-looking frame inside another one: keep frames in stream order, skip overlaps.
        keep = np.zeros(len(starts), bool)
        last = -1
        for i, (a, b) in enumerate(zip(starts.tolist(), ends.tolist())):
            if a >= last:
                keep[i] = True
                last = b
        starts, ends = starts[keep], ends[keep]

    def inside(pos: np.ndarray) -> np.ndarray:
        j = np.searchsorted(starts, pos, side="right") - 1
        return (j >= 0) & (pos < ends[np.maximum(j, 0)]) if len(starts) else np.zeros(len(pos), bool)

    outside = ~inside(cc[~good])
    bad_crc = _bad_checksum_frames(cc[~good][outside], (cc + 8 + pc)[~good][outside], starts, n)
    tail_from = int(ends[-1]) if len(ends) else 0
    truncated = 0
    # A cut frame at the end: the first candidate after the last frame runs past the end of
    # the file (or its header does), or the file ends in the first sync byte.
    after = cand[cand >= tail_from]
    cut = [a for a in after.tolist() if a + 6 > n or a + 8 + (int(buf[a + 4]) | int(buf[a + 5]) << 8) > n][:1]
    if cut:
        truncated = n - cut[0]
    elif n > tail_from and buf[n - 1] == 0xB5:
        truncated = 1
    gaps = []
    prev = 0
    for a, b in zip(starts.tolist(), ends.tolist()):
        if a > prev:
            gaps.append((prev, a))
        prev = b
    if n - truncated > prev:
        gaps.append((prev, n - truncated))
    return {"starts": starts, "ends": ends, "cls": buf[starts + 2].astype(np.int64),
            "id": buf[starts + 3].astype(np.int64), "bad_crc": bad_crc, "truncated": truncated, "gaps": gaps,
            "size": n}


def _bad_checksum_frames(bad: np.ndarray, bad_end: np.ndarray, starts: np.ndarray, n: int) -> int:
    """How many bad-checksum frame candidates outside the valid frames are frames [count].

    A candidate whose declared length ends where a valid frame starts, or at the end of the data,
    is a framed message with a damaged payload (pyubx2, validation off, yields it as a message);
    a candidate inside such a frame is part of its payload, not a frame of its own. Every other
    candidate counts as one bad-checksum frame, as before.

    Parameters
    ----------
    bad, bad_end : numpy.ndarray
        Start and declared end offsets [bytes] of the candidates, in stream order.
    starts : numpy.ndarray
        Start offsets of the valid frames [bytes].
    n : int
        Length of the data [bytes].
    """
    framed = np.isin(bad_end, starts) | (bad_end == n)
    count, covered_to = 0, -1
    for a, e, whole in zip(bad.tolist(), bad_end.tolist(), framed.tolist()):
        if a < covered_to:
            continue
        count += 1
        if whole:
            covered_to = e
    return count


def _nav_pvt(buf: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """NAV-PVT payloads at ``starts`` as a structured array (one gather, one view)."""
    width = NAV_PVT_DTYPE.itemsize
    rows = buf[(starts + 6)[:, None] + np.arange(width)]
    return np.ascontiguousarray(rows).view(NAV_PVT_DTYPE).reshape(len(starts))


def _week_of(pvt: np.ndarray, t_ms: np.ndarray) -> tuple[int | None, int, int | None]:
    """GPS week at ``t = 0``, the NAV-PVT it came from, and the receiver's leap seconds GPS - UTC.

    ``t_ms`` is the unwrapped time [ms] of each NAV-PVT from the start of the first message's
    week, so a week rollover between the first message and the first valid date does not shift
    the week. The leap seconds are the receiver's own (iTOW against its UTC fields) when it
    flags UTC as fully resolved, else None (the caller falls back to the leap-second table).
    """
    ok = ((pvt["valid"] & 0x03) == 0x03) & (pvt["year"] >= 1980) & (pvt["month"] >= 1) & (pvt["month"] <= 12) \
        & (pvt["day"] >= 1) & (pvt["day"] <= 31) & (pvt["hour"] < 24) & (pvt["min"] < 60) & (pvt["sec"] <= 60)
    for i in np.flatnonzero(ok)[:5].tolist():
        r = pvt[i]
        try:
            utc = datetime(int(r["year"]), int(r["month"]), int(r["day"]), int(r["hour"]), int(r["min"]),
                           min(int(r["sec"]), 59), tzinfo=timezone.utc)
        except ValueError:
            continue
        utc_s = (utc - GPS_EPOCH).total_seconds() + int(r["nano"]) * 1e-9
        week = int(round((utc_s + GPS_LEAP_S - int(t_ms[i]) / 1000.0) / 604800.0))
        leap = None
        if r["valid"] & 0x04 and int(r["sec"]) < 60:
            # fullyResolved: the receiver knows the leap seconds, so iTOW - UTC is exactly their count.
            leap = int(round(week * 604800.0 + int(t_ms[i]) / 1000.0 - utc_s))
            if not 0 <= leap < 100:
                leap = None
        return week, i, leap
    return None, -1, None


def _unwrap_itow(itow_ms: np.ndarray) -> np.ndarray:
    """Milliseconds since the start of the first message's GPS week, across week rollovers."""
    ms = itow_ms.astype(np.int64)
    step = np.diff(ms)
    weeks = np.concatenate(([0], np.cumsum(step < -WEEK_MS // 2) - np.cumsum(step > WEEK_MS // 2)))
    return ms + weeks * WEEK_MS


def _increasing(t: np.ndarray) -> np.ndarray:
    ok = np.ones(len(t), bool)
    if len(t) > 1:
        ok[1:] = t[1:] > np.maximum.accumulate(t)[:-1]
    return ok






# ----------------------------------------------------------------------------- reader
def _frames_or_error(p: Path, data: bytes, buf: np.ndarray) -> dict:
    """The UBX frames of a file (:func:`_frames`); IngestError naming the first bytes when there is none."""
    fr = _frames(buf)
    if not len(fr["starts"]):
        cut = " (truncated: the file ends inside its first frame)" if fr["truncated"] else ""
        raise IngestError(f"{p}: expected a u-blox UBX log (frames B5 62 <class> <id> <length> <payload> with a "
                          f"valid checksum), found no valid UBX frame in {len(data)} bytes{cut}; starts with "
                          f"{data[:16]!r}")
    return fr


def _message_kinds(fr: dict, skipped: Counter, warnings: list[str]) -> dict[str, np.ndarray]:
    """Frame masks by kind (``pvt`` long enough, ``rel``, ``esf``, ``meas``, ``parsed``); the rest counted by name."""
    cls, mid = fr["cls"], fr["id"]
    plen = fr["ends"] - fr["starts"] - 8
    is_pvt = (cls == NAV_PVT[0]) & (mid == NAV_PVT[1])
    pvt_ok_len = is_pvt & (plen >= NAV_PVT_DTYPE.itemsize)
    if (is_pvt & ~pvt_ok_len).any():
        warnings.append(f"NAV-PVT: {int((is_pvt & ~pvt_ok_len).sum())} message(s) shorter than "
                        f"{NAV_PVT_DTYPE.itemsize} bytes not used")
        skipped["NAV-PVT"] += int((is_pvt & ~pvt_ok_len).sum())
    is_rel = (cls == NAV_RELPOSNED[0]) & (mid == NAV_RELPOSNED[1])
    is_esf = (cls == ESF_RAW[0]) & (mid == ESF_RAW[1])
    is_meas = (cls == ESF_MEAS[0]) & (mid == ESF_MEAS[1])
    is_parsed = np.zeros(len(cls), bool)
    for c_, i_ in _PARSED:
        is_parsed |= (cls == c_) & (mid == i_)
    known = is_pvt | is_rel | is_esf | is_meas | is_parsed
    for (c_, i_), count in Counter(zip(cls[~known].tolist(), mid[~known].tolist())).items():
        skipped[UBX_MSGIDS.get(bytes((c_, i_)), f"UBX-0x{c_:02X}-0x{i_:02X}")] += count
    return {"pvt": pvt_ok_len, "rel": is_rel, "esf": is_esf, "meas": is_meas, "parsed": is_parsed}


def _relposned_and_esf(p: Path, data: bytes, buf: np.ndarray, fr: dict, rel_idx: np.ndarray, esf_idx: np.ndarray,
                       progress: bool | None) -> tuple[list, np.ndarray, np.ndarray]:
    """NAV-RELPOSNED messages (None where undecodable) and ESF-RAW rows with their validity.

    NAV-RELPOSNED version 1 and ESF-RAW are decoded vectorised (one gather each): through pyubx2 an
    hour of 100 Hz ESF-RAW took ~25 s, as long as the plain pyubx2 loop. Other RELPOSNED versions
    (rare) still go through pyubx2, one message at a time, behind the progress bar.
    """
    starts = fr["starts"]
    bar = None
    if want_progress(progress):
        from tqdm import tqdm

        bar = tqdm(total=len(starts), unit="msg", unit_scale=True, desc=p.name, file=sys.stderr,
                   leave=False, delay=0.0 if progress else _PROGRESS_DELAY_S)
        bar.update(len(starts) - len(rel_idx) - len(esf_idx))
    try:
        rel, rel_slow = _relposned_vectorised(buf, starts, fr["ends"], rel_idx)
        if bar is not None:
            bar.update(len(rel_idx) - len(rel_slow))
        esf_rows, esf_ok = _esf_rows(buf, starts, fr["ends"], esf_idx)
        if bar is not None:
            bar.update(len(esf_idx))
        for j, m in zip(rel_slow.tolist(), _parse_many(data, starts, fr["ends"], rel_idx[rel_slow], bar)):
            rel[j] = m
    finally:
        if bar is not None:
            bar.close()
    return rel, esf_rows, esf_ok


def _esf_meas(buf: np.ndarray, fr: dict, meas_idx: np.ndarray, anchor_idx: np.ndarray, anchor_ms: np.ndarray,
              suffix: str, src_note: str, chans: dict, read: Counter, skipped: Counter, warnings: list[str]) -> None:
    """ESF-MEAS frames -> IMU channels (as ESF-RAW), their time tags through the anchor epochs."""
    if not len(meas_idx):
        return
    meas_rows, meas_ok = _esf_meas_rows(buf, fr["starts"], fr["ends"], meas_idx)
    if (~meas_ok).any():
        skipped["ESF-MEAS undecodable"] += int((~meas_ok).sum())
    _esf_channels(meas_rows, meas_ok, meas_idx, anchor_idx, anchor_ms, suffix, src_note, chans, read, skipped,
                  warnings, msg="ESF-MEAS")


def read_ubx(path: str | Path, sensor: str = "", progress: bool | None = None) -> RawLog:
    """Read a u-blox UBX log into canonical channels on GPS time of week.

    Parameters
    ----------
    path : str or Path
        The log (UBX frames, possibly mixed with NMEA). Opened read-only and never modified.
    sensor : str
        Receiver name for the channel suffix: ``""`` gives ``lat lon sog cog``, ``"gps2"`` gives
        ``lat@gps2`` ...; also names the dual-antenna heading ``psi@<sensor>`` (``psi@dual``
        without a name) and the IMU channels ``p@esf_<sensor>`` (``p@esf`` without).
    progress : bool, optional
        tqdm bar over the messages decoded by pyubx2. ``None``: on a terminal when the read takes
        longer than 1 s, never when the ``CI`` environment variable is set or stderr is not a TTY.

    Returns
    -------
    RawLog
        ``format='ubx'``, ``time_reference='gps'``; ``t`` [s] is GPS time of week (see module
        docstring), channels as in ``VARIABLE_MAP``; ``start_time`` [s, Unix UTC] is the start of
        that GPS week less the leap seconds (NaN when no NAV-PVT has a valid UTC date). Fix types
        and carrier solutions of NAV-PVT and NAV-RELPOSNED are counted in ``summary.warnings``.

    Raises
    ------
    IngestError
        Missing or empty file, no valid UBX frame, or no usable NAV-PVT, NAV-RELPOSNED or
        ESF-RAW sample.

    Notes
    -----
    Counted in ``summary`` rather than raised: frames with a bad checksum, garbage bytes and NMEA
    sentences between frames, a truncated tail (``truncated: N trailing bytes``), samples without
    a fix, headings without relPosHeadingValid, duplicate or out-of-order iTOW (first kept),
    messages pyubx2 cannot decode, and message types not used (counted by name in
    ``summary.skipped``).
    """
    p = check_file(path, "UBX log")
    data = p.read_bytes()
    buf = np.frombuffer(data, np.uint8)
    fr = _frames_or_error(p, data, buf)
    starts = fr["starts"]
    warnings: list[str] = []
    read: Counter = Counter()
    skipped: Counter = Counter()
    suffix = f"@{sensor}" if sensor else ""

    kind = _message_kinds(fr, skipped, warnings)
    pvt_ok_len, is_rel, is_esf, is_meas, is_parsed = (kind[k] for k in ("pvt", "rel", "esf", "meas", "parsed"))
    parsed_idx = np.flatnonzero(is_parsed)
    parsed = _parse_many(data, starts, fr["ends"], parsed_idx, None)
    parsed_name = [_PARSED[(int(fr["cls"][i]), int(fr["id"][i]))] for i in parsed_idx.tolist()]
    for name, m in zip(parsed_name, parsed):
        if m is None:
            skipped[f"{name} undecodable"] += 1

    # Frames whose time is iTOW, in stream order, unwrapped together.
    pvt_idx = np.flatnonzero(pvt_ok_len)
    pvt = _nav_pvt(buf, starts[pvt_idx]) if len(pvt_idx) else np.zeros(0, NAV_PVT_DTYPE)
    rel_idx = np.flatnonzero(is_rel)
    esf_idx = np.flatnonzero(is_esf)
    rel, esf_rows, esf_ok = _relposned_and_esf(p, data, buf, fr, rel_idx, esf_idx, progress)
    undecodable = sum(1 for m in rel if m is None) + int((~esf_ok).sum())
    if undecodable:
        warnings.append(f"{undecodable} NAV-RELPOSNED/ESF-RAW message(s) that could not be decoded skipped")
        skipped["UNDECODABLE"] += undecodable

    rel_itow = np.array([m.iTOW if m is not None else -1 for m in rel], np.int64)
    par_itow = np.array([int(m.iTOW) if m is not None else -1 for m in parsed], np.int64)
    t_pvt_ms, t_rel_ms, t_par_ms = _itow_clock(pvt["iTOW"].astype(np.int64), pvt_idx, rel_itow, rel_idx,
                                               par_itow, parsed_idx)

    week, start_time, week_note = _gps_week(pvt, t_pvt_ms, parsed, t_par_ms)
    warnings.append(week_note)
    src_note = f"GPS week {week}" if week is not None else "GPS week unknown"

    chans: dict[str, Channel] = {}
    if len(pvt):
        _pvt_channels(pvt, t_pvt_ms, suffix, src_note, chans, read, skipped, warnings)
    if len(rel_idx):
        _relposned_channels(rel, t_rel_ms, rel_itow, f"@{sensor or 'dual'}", src_note, chans, read, skipped,
                            warnings)
    if len(parsed):
        _parsed_channels(parsed, parsed_name, t_par_ms, suffix, src_note, chans, read, skipped, warnings)
    # ESF time tags go on GPS time through the NAV-PVT (or, without it, NAV-PVAT/HNR-PVT) epochs around them.
    anchor_idx, anchor_ms = pvt_idx, t_pvt_ms
    if len(anchor_idx) < 2:
        ok_par = par_itow >= 0
        anchor_idx, anchor_ms = parsed_idx[ok_par], t_par_ms[ok_par]
    esf_suffix = f"@esf_{sensor}" if sensor else "@esf"
    if len(esf_idx):
        _esf_channels(esf_rows, esf_ok, esf_idx, anchor_idx, anchor_ms, esf_suffix, src_note, chans, read,
                      skipped, warnings)
    _esf_meas(buf, fr, np.flatnonzero(is_meas), anchor_idx, anchor_ms,
              esf_suffix.replace("@esf", "@esfmeas") if len(esf_idx) else esf_suffix, src_note, chans, read,
              skipped, warnings)

    start_time = _between_frames(data, fr, chans, read, skipped, warnings, start_time, suffix)

    if not chans:
        found = ", ".join(f"{k} {v}" for k, v in sorted((read + skipped).items())) or "none"
        raise IngestError(f"{p}: expected UBX NAV-PVT, NAV-PVAT, NAV-ATT, HNR-PVT, NAV-RELPOSNED, ESF-RAW/MEAS "
                          f"messages or NMEA fixes with usable samples, found "
                          f"none (messages: {found})")
    summary = IngestSummary(path=str(p), format="ubx", read=dict(read), skipped={k: v for k, v in skipped.items() if v},
                            warnings=tuple(warnings))
    return RawLog(source=str(p), format="ubx", channels=chans, summary=summary, time_reference="gps",
                  start_time=start_time)


def _itow_clock(pvt_itow: np.ndarray, pvt_idx: np.ndarray, rel_itow: np.ndarray, rel_idx: np.ndarray,
                par_itow: np.ndarray, parsed_idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """iTOW [ms] of NAV-PVT, NAV-RELPOSNED and the pyubx2-decoded messages, unwrapped together.

    The messages are put in stream order (``*_idx`` are frame numbers) and unwrapped across GPS
    week rollovers as one sequence. ``rel_itow`` / ``par_itow`` are -1 for undecodable messages:
    those get no time (RELPOSNED: left out of the result; parsed: -1).
    """
    n_pvt, n_rel = len(pvt_idx), int((rel_itow >= 0).sum())
    timed_idx = np.concatenate([pvt_idx, rel_idx[rel_itow >= 0], parsed_idx[par_itow >= 0]])
    timed_ms = np.concatenate([pvt_itow, rel_itow[rel_itow >= 0], par_itow[par_itow >= 0]])
    order = np.argsort(timed_idx, kind="stable")
    t_ms = np.empty(len(order), np.int64)
    t_ms[order] = _unwrap_itow(timed_ms[order])
    t_par_ms = np.full(len(par_itow), -1, np.int64)
    t_par_ms[par_itow >= 0] = t_ms[n_pvt + n_rel:]
    return t_ms[:n_pvt], t_ms[n_pvt:n_pvt + n_rel], t_par_ms


def _gps_week(pvt: np.ndarray, t_pvt_ms: np.ndarray, parsed: list, t_par_ms: np.ndarray
              ) -> tuple[int | None, float, str]:
    """GPS week of ``t = 0``, its UTC instant [s, Unix] (NaN when unknown), and the summary note.

    The week comes from NAV-PVT's UTC date, else from a NAV-PVAT / HNR-PVT date; GPS - UTC from the
    receiver when it flags it resolved, else from the leap-second table.
    """
    week, _, leap = _week_of(pvt, t_pvt_ms) if len(pvt) else (None, -1, None)
    if week is None:
        week, leap = _week_of_parsed(parsed, t_par_ms)
    if week is None:
        return None, math.nan, "GPS week unknown (no NAV-PVT with a valid UTC date): t is time of week only"
    day = (GPS_EPOCH + timedelta(weeks=week)).date().isoformat()
    week_start_unix = GPS_EPOCH_UNIX + week * WEEK_S
    leap_from = "receiver"
    if leap is None:
        leap, leap_from = leap_seconds(week_start_unix), "leap-second table"
    # t is GPS time from the week start; UTC lags GPS by the leap seconds.
    start_time = week_start_unix - leap
    return week, start_time, (f"t = 0 is the start of GPS week {week} ({day} 00:00:00 GPS time) = "
                              f"{unix_text(start_time)} UTC (GPS - UTC = {leap} s, {leap_from})")


def _between_frames(data: bytes, fr: Mapping[str, Any], chans: dict, read: Counter, skipped: Counter,
                    warnings: list, start_time: float, suffix: str) -> float:
    """Account for everything outside the valid UBX frames; read the NMEA found there.

    Bad-checksum frames, NMEA sentences (read onto the UBX clock by :func:`_nmea_inside`), RTCM 3
    frames (counted per message number), garbage bytes and a truncated tail are counted in
    ``skipped`` / ``warnings``. Returns ``start_time`` [s, Unix], set from the NMEA dates when the
    UBX messages gave none.
    """
    if fr["bad_crc"]:
        skipped["BAD_CHECKSUM"] += fr["bad_crc"]
        warnings.append(f"bad checksum: {fr['bad_crc']} frame(s) skipped")
    garbage = 0
    nmea_lines: list[bytes] = []
    rtcm: Counter = Counter()
    rtcm_bad = 0
    for a, b in fr["gaps"]:
        chunk = data[a:b]
        hits = _NMEA.findall(chunk)
        nmea_lines += hits
        rest = _NMEA.sub(b"", chunk) if hits else chunk
        frames = rtcm3_frames(rest) if b"\xd3" in rest else {}
        rtcm.update(frames)
        damaged, damaged_bytes = _rtcm_bad_crc(rest) if b"\xd3" in rest else (0, 0)
        rtcm_bad += damaged
        garbage += len(rest) - _rtcm_bytes(rest, frames) - damaged_bytes
    for msg_no, count in rtcm.items():
        skipped[f"RTCM3-{msg_no}"] += count
    if rtcm:
        warnings.append("RTCM 3 correction frames between UBX frames counted, not used: "
                        + ", ".join(f"{k} x{v}" for k, v in sorted(rtcm.items())))
    if rtcm_bad:
        skipped["RTCM3_BAD_CRC"] += rtcm_bad
        warnings.append(f"bad CRC: {rtcm_bad} RTCM 3 frame(s) skipped")
    if nmea_lines:
        start_time = _nmea_inside(nmea_lines, chans, read, skipped, warnings, start_time, suffix)
    if garbage:
        skipped["GARBAGE_BYTES"] += garbage
        warnings.append(f"garbage: {garbage} byte(s) between frames skipped")
    if fr["truncated"]:
        warnings.append(f"truncated: {fr['truncated']} trailing bytes (an incomplete last frame) ignored")
    return start_time


def _parse_many(data: bytes, starts: np.ndarray, ends: np.ndarray, which: np.ndarray, bar: Any) -> list:
    out = []
    for i in which.tolist():
        try:
            out.append(UBXReader.parse(data[int(starts[i]):int(ends[i])], msgmode=GET))
        except _PYUBX2_ERRORS:
            out.append(None)
        if bar is not None:
            bar.update(1)
    return out


def _counts(values: np.ndarray, names: Mapping[int, str]) -> str:
    u, c = np.unique(values, return_counts=True)
    return ", ".join(f"{names.get(int(k), f'type {int(k)}')} {int(v)}" for k, v in zip(u, c))


def _pvt_channels(pvt: np.ndarray, t_ms: np.ndarray, suffix: str, src_note: str, chans: dict, read: Counter,
                  skipped: Counter, warnings: list[str]) -> None:
    fix = pvt["fixType"]
    gnss_ok = (pvt["flags"] & 0x01).astype(bool)
    carr = (pvt["flags"] >> 6) & 0x03
    warnings.append(f"NAV-PVT fix types: {_counts(fix, FIX_TYPES)}; carrier solution: {_counts(carr, CARRIER)}")
    if not np.isin(fix, (3, 4)).any():
        warnings.append(f"no 3D fix in any of the {len(pvt)} NAV-PVT message(s)")
    usable = gnss_ok & np.isin(fix, (2, 3, 4)) & ((pvt["flags3"] & 0x01) == 0)
    if (~usable).any():
        warnings.append(f"NAV-PVT: {int((~usable).sum())} message(s) without a usable fix (gnssFixOK, fixType "
                        "2D/3D/GNSS+DR, valid position) not used")
    t = t_ms * 1e-3
    inc = _increasing(np.where(usable, t, -np.inf)) & usable
    dup = int((usable & ~inc).sum())
    if dup:
        warnings.append(f"NAV-PVT: {dup} message(s) with a duplicate or out-of-order iTOW skipped (first kept)")
    values = {base: pvt[f].astype(np.float64) * scale
              for (m, f), (base, scale) in VARIABLE_MAP.items() if m == "NAV-PVT"}
    values["cog"] = wrap_pi(values["cog"])
    for base, v in values.items():
        if not inc.any():
            break
        chans[base + suffix] = Channel(base + suffix, t[inc], v[inc], source=f"NAV-PVT ({src_note})")
    read["NAV-PVT"] += int(inc.sum())
    skipped["NAV-PVT"] += int(len(pvt) - inc.sum())


def _relposned_channels(rel: list, t_ms: np.ndarray, itow: np.ndarray, suffix: str, src_note: str, chans: dict,
                        read: Counter, skipped: Counter, warnings: list[str]) -> None:
    decoded = [m for m in rel if m is not None and hasattr(m, "relPosHeading")]
    no_heading = sum(1 for m in rel if m is not None and not hasattr(m, "relPosHeading"))
    if no_heading:
        # Version 0 (u-blox M8P) has no heading field: the baseline only.
        skipped["NAV-RELPOSNED without a heading field (version 0)"] += no_heading
    if not decoded:
        return
    head = np.array([float(m.relPosHeading) for m in decoded])
    valid = np.array([bool(m.relPosHeadingValid) for m in decoded])
    carr = np.array([int(m.carrSoln) for m in decoded])
    warnings.append(f"NAV-RELPOSNED carrier solution: {_counts(carr, CARRIER)}")
    rejected = int((~valid).sum())
    if rejected:
        warnings.append(f"NAV-RELPOSNED: {rejected} heading(s) without relPosHeadingValid not used")
    t = t_ms * 1e-3
    inc = _increasing(np.where(valid, t, -np.inf)) & valid
    dup = int((valid & ~inc).sum())
    if dup:
        warnings.append(f"NAV-RELPOSNED: {dup} message(s) with a duplicate or out-of-order iTOW skipped (first kept)")
    base, scale = VARIABLE_MAP[("NAV-RELPOSNED", "relPosHeading")]
    if inc.any():
        chans[base + suffix] = Channel(base + suffix, t[inc], wrap_pi(head[inc] * scale),
                                       source=f"NAV-RELPOSNED ({src_note})")
    read["NAV-RELPOSNED"] += int(inc.sum())
    skipped["NAV-RELPOSNED"] += int(len(decoded) - inc.sum())


class _RelPos(NamedTuple):
    """The NAV-RELPOSNED fields used, with pyubx2's attribute names and scaling."""

    iTOW: int
    relPosHeading: float
    relPosHeadingValid: int
    carrSoln: int


def _relposned_vectorised(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, which: np.ndarray
                          ) -> tuple[list, np.ndarray]:
    """NAV-RELPOSNED version 1 (64-byte payload) decoded in one gather; the others left for pyubx2.

    Returns one entry per message of ``which`` (None where not decoded here) and the positions in
    ``which`` still to decode. Offsets and scaling as in the u-blox interface description (and
    pyubx2): iTOW u4 at 4, relPosHeading i4 at 24 [1e-5 deg], flags x4 at 60 (carrSoln bits 3-4,
    relPosHeadingValid bit 8).
    """
    out: list = [None] * len(which)
    if not len(which):
        return out, np.zeros(0, np.int64)
    s = starts[which]
    plen = ends[which] - s - 8
    fast = (plen == 64) & (buf[s + 6] == 1)
    if fast.any():
        pay = buf[(s[fast] + 6)[:, None] + np.arange(64)]
        itow = np.ascontiguousarray(pay[:, 4:8]).view("<u4").ravel()
        head = np.ascontiguousarray(pay[:, 24:28]).view("<i4").ravel()
        flags = np.ascontiguousarray(pay[:, 60:64]).view("<u4").ravel()
        carr = (flags >> 3) & 0x03
        valid = (flags >> 8) & 0x01
        for j, a, h, v, c in zip(np.flatnonzero(fast).tolist(), itow.tolist(), head.tolist(), valid.tolist(),
                                 carr.tolist()):
            out[j] = _RelPos(a, round(h * 1e-5, SCALROUND), v, c)  # as pyubx2 scales it
    return out, np.flatnonzero(~fast)


def _esf_rows(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, which: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """Blocks of ESF-RAW messages, vectorised: rows (message number, data type, value, sTag) and a
    per-message mask of the payloads that have the ESF-RAW layout (4 reserved bytes + 8-byte blocks).

    Each block is a u4 data word (bits 0-23 a signed 24-bit value, bits 24-31 the data type) and
    a u4 sensor time tag, as pyubx2 splits it into ``data_NN`` / ``sTag_NN``.
    """
    if not len(which):
        return np.zeros((0, 4), np.int64), np.zeros(0, bool)
    s = starts[which]
    plen = ends[which] - s - 8
    ok = (plen >= 4) & ((plen - 4) % 8 == 0)
    nb = np.where(ok, (plen - 4) // 8, 0)
    msg_no = np.repeat(np.arange(len(which)), nb)
    first = np.repeat(s + 6 + 4 - 8 * np.concatenate(([0], np.cumsum(nb)[:-1])), nb)
    off = first + 8 * np.arange(len(msg_no))

    def u32(at: np.ndarray) -> np.ndarray:
        # Four 1-D byte gathers are cheaper than one (n, 8) fancy index on a million blocks.
        return (buf[at].astype(np.int64) | buf[at + 1].astype(np.int64) << 8 | buf[at + 2].astype(np.int64) << 16
                | buf[at + 3].astype(np.int64) << 24)

    word, tag = u32(off), u32(off + 4)
    value = word & 0xFFFFFF
    value = np.where(value & 0x800000, value - (1 << 24), value)
    rows = np.column_stack([msg_no, (word >> 24) & 0xFF, value, tag])
    return rows, ok


def _esf_channels(rows: np.ndarray, decoded: np.ndarray, esf_idx: np.ndarray, pvt_idx: np.ndarray,
                  t_pvt_ms: np.ndarray, suffix: str, src_note: str, chans: dict, read: Counter, skipped: Counter,
                  warnings: list[str], msg: str = "ESF-RAW") -> None:
    n_msgs = int(decoded.sum())
    if not len(rows):
        skipped[msg] += n_msgs
        return
    msg_no, dtype_, value, tag = rows.T
    # sTag [ms] wraps at 2**32; unwrap in stream order.
    step = np.diff(tag)
    tag_ms = tag + np.concatenate(([0], np.cumsum(step < -(2**31)))) * 2**32
    if len(pvt_idx) < 2:
        warnings.append(f"{msg}: {n_msgs} message(s) not used: no NAV-PVT to put the sensor time tags on GPS time")
        skipped[msg] += n_msgs
        return
    # Each ESF message lies in the stream between two NAV-PVT epochs; the midpoint of those is its
    # output time to within half an epoch, and the median over all messages is much better.
    msgs, first = np.unique(msg_no, return_index=True)
    k = np.searchsorted(pvt_idx, esf_idx[msgs])
    inner = (k > 0) & (k < len(pvt_idx))
    if not inner.any():
        warnings.append(f"{msg}: {n_msgs} message(s) not used: none lies between two NAV-PVT messages, so the "
                        "sensor time tags cannot be put on GPS time")
        skipped[msg] += n_msgs
        return
    mid = 0.5 * (t_pvt_ms[k[inner] - 1] + t_pvt_ms[k[inner]])
    offset_ms = float(np.median(mid - tag_ms[first][inner]))
    warnings.append(f"{msg}: sensor time tags put on GPS time with an offset of {offset_ms / 1000:.3f} s, "
                    "estimated from message order")
    used_msgs = np.zeros(len(decoded), bool)
    for (m, dt), (base, scale) in VARIABLE_MAP.items():
        if m != "ESF-RAW":
            continue
        sel = np.flatnonzero(dtype_ == dt)
        if not len(sel):
            continue
        t = (tag_ms[sel] + offset_ms) * 1e-3
        ok = _increasing(t)
        bad = int((~ok).sum())
        if bad:
            warnings.append(f"{msg} {base}: {bad} sample(s) with a duplicate or out-of-order sensor time tag "
                            "skipped (first kept)")
        axes = "; y and z negated from the ESF axes x fwd, y left, z up" if base in ("q", "r", "ay", "az") else ""
        chans[base + suffix] = Channel(base + suffix, t[ok], value[sel][ok] * scale,
                                       source=f"{msg} ({src_note}{axes})")
        used_msgs[msg_no[sel][ok]] = True
    read[msg] += int(used_msgs.sum())
    skipped[msg] += int(n_msgs - used_msgs.sum())


def _rtcm_spans(rest: bytes) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """Start and end offsets of RTCM 3 frame candidates in ``rest``: valid CRC, and bad CRC."""
    from .sniff import crc24q

    good, bad = [], []
    i = rest.find(b"\xd3")
    while 0 <= i < len(rest) - 5:
        length = ((rest[i + 1] & 0x03) << 8) | rest[i + 2]
        end = i + 6 + length
        if rest[i + 1] & 0xFC == 0 and length >= 2 and end <= len(rest):
            if crc24q(rest[i:end - 3]) == int.from_bytes(rest[end - 3:end], "big"):
                good.append((i, end))
                i = rest.find(b"\xd3", end)
                continue
            bad.append((i, end))
        i = rest.find(b"\xd3", i + 1)
    return good, bad


def _rtcm_bad_crc(rest: bytes) -> tuple[int, int]:
    """RTCM 3 frames with a damaged CRC in ``rest``: their count and bytes.

    A candidate (sync byte, zero reserved bits, length) whose CRC fails is a frame only when its
    declared end is where a valid RTCM 3 frame starts or where ``rest`` ends (the next UBX frame or
    the end of the file), and it lies inside no valid frame; anything else stays garbage (a sync
    byte followed by six zero bits occurs by chance in one byte of 64).

    Parameters
    ----------
    rest : bytes
        Bytes between UBX frames, NMEA sentences removed.

    Returns
    -------
    tuple[int, int]
        Damaged frames [count] and the bytes they span.
    """
    good, bad = _rtcm_spans(rest)
    good_starts = {a for a, _ in good}
    count = size = 0
    covered_to = -1
    for a, e in bad:
        inside_good = any(ga <= a < ge for ga, ge in good)
        if a < covered_to or inside_good or not (e == len(rest) or e in good_starts):
            continue
        count += 1
        size += e - a
        covered_to = e
    return count, size


def _rtcm_bytes(rest: bytes, frames: Mapping[int, int]) -> int:
    """Bytes of ``rest`` inside valid RTCM 3 frames (so they are not counted as garbage)."""
    if not frames:
        return 0
    total = 0
    i = rest.find(b"\xd3")
    while 0 <= i < len(rest) - 5:
        length = ((rest[i + 1] & 0x03) << 8) | rest[i + 2]
        end = i + 6 + length
        if rest[i + 1] & 0xFC == 0 and end <= len(rest):
            from .sniff import crc24q

            if crc24q(rest[i:end - 3]) == int.from_bytes(rest[end - 3:end], "big"):
                total += end - i
                i = rest.find(b"\xd3", end)
                continue
        i = rest.find(b"\xd3", i + 1)
    return total


def _week_of_parsed(parsed: list, t_ms: np.ndarray) -> tuple[int | None, int | None]:
    """GPS week at t = 0 from the UTC date of a NAV-PVAT or HNR-PVT (when the log has no NAV-PVT)."""
    for m, tm in zip(parsed, t_ms.tolist()):
        if m is None or tm < 0 or not hasattr(m, "year"):
            continue
        try:
            sec = int(getattr(m, "sec", getattr(m, "second", 0)))
            if not (getattr(m, "validDate", 0) and getattr(m, "validTime", 0)) or m.year < 1980:
                continue
            utc = datetime(int(m.year), int(m.month), int(m.day), int(m.hour), int(m.min), min(sec, 59),
                           tzinfo=timezone.utc)
        except (ValueError, AttributeError):
            continue
        utc_s = (utc - GPS_EPOCH).total_seconds() + int(getattr(m, "nano", 0)) * 1e-9
        return int(round((utc_s + GPS_LEAP_S - tm / 1000.0) / 604800.0)), None
    return None, None


def _parsed_channels(parsed: list, names: list, t_ms: np.ndarray, suffix: str, src_note: str, chans: dict,
                     read: Counter, skipped: Counter, warnings: list[str]) -> None:
    """Channels of NAV-ATT, NAV-PVAT and HNR-PVT (decoded by pyubx2, which scales the fields)."""
    have_pvt = "lat" + suffix in chans
    kinds = set(names)
    rows: dict[str, dict[str, list]] = {}
    t = t_ms * 1e-3
    for name, m, tk in zip(names, parsed, t.tolist()):
        if m is None:
            continue
        if tk < 0:
            skipped[f"{name} undecodable"] += 1
            continue
        got: dict[str, float] = {}
        if name in ("NAV-ATT", "HNR-ATT"):
            got = {"phi": m.roll * _DEG, "theta": m.pitch * _DEG, "psi": m.heading * _DEG}
        elif name == "NAV-PVAT":
            if m.gnssFixOK and m.fixType in (2, 3, 4):
                got.update(lat=m.lat, lon=m.lon, sog=m.gSpeed * 1e-3, cog=m.motHeading * _DEG)
            if m.vehRollValid:
                got["phi"] = m.vehRoll * _DEG
            if m.vehPitchValid:
                got["theta"] = m.vehPitch * _DEG
            if m.vehHeadingValid:
                got["psi"] = m.vehHeading * _DEG
        elif name == "HNR-PVT":
            if m.GPSfixOK and m.gpsFix in (2, 3, 4):
                got.update(lat=m.lat, lon=m.lon, sog=m.gSpeed * 1e-3, cog=m.headMot * _DEG)
            if m.headVehValid:
                got["psi"] = m.headVeh * _DEG
        if not got:
            skipped[f"{name} no valid solution"] += 1
            continue
        r = rows.setdefault(name, {})
        for k, v in got.items():
            r.setdefault(k, []).append((tk, float(v)))
        read[name] += 1
    for name, r in rows.items():
        for base, tv in r.items():
            if name == "NAV-ATT" and "NAV-PVAT" in kinds:
                tag = "@att"
            elif name == "NAV-PVAT" and base in ("lat", "lon", "sog", "cog") and have_pvt:
                tag = "@pvat"
            elif name == "HNR-ATT" and ("NAV-ATT" in kinds or "NAV-PVAT" in kinds):
                tag = "@hnr"
            elif name == "HNR-PVT" and (have_pvt or "NAV-PVAT" in kinds or base == "psi" and "NAV-ATT" in kinds):
                tag = "@hnr"
            else:
                tag = suffix
            arr = np.array(tv)
            ok = _increasing(arr[:, 0])
            if (~ok).any():
                warnings.append(f"{name} {base}: {int((~ok).sum())} sample(s) with a duplicate or out-of-order "
                                "iTOW skipped (first kept)")
            v = arr[ok, 1]
            if base in ("phi", "theta", "psi", "cog"):
                v = wrap_pi(v)
            chans[base + tag] = Channel(base + tag, arr[ok, 0], v, source=f"{name} ({src_note})")


def _esf_meas_rows(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, which: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """ESF-MEAS blocks as rows (message number, data type, value, timeTag) like :func:`_esf_rows`.

    Payload: timeTag u4, flags x2 (numMeas in bits 11-15), id u2, numMeas u4 data words (bits 0-23
    a signed value, bits 24-29 the data type), then an optional calibTtag u4.
    """
    out = []
    ok = np.zeros(len(which), bool)
    for j, i in enumerate(which.tolist()):
        s = int(starts[i]) + 6
        plen = int(ends[i]) - int(starts[i]) - 8
        if plen < 8:
            continue
        tag = int(buf[s]) | int(buf[s + 1]) << 8 | int(buf[s + 2]) << 16 | int(buf[s + 3]) << 24
        flags = int(buf[s + 4]) | int(buf[s + 5]) << 8
        n = flags >> 11
        if plen not in (8 + 4 * n, 12 + 4 * n):
            continue
        ok[j] = True
        for k in range(n):
            a = s + 8 + 4 * k
            word = int(buf[a]) | int(buf[a + 1]) << 8 | int(buf[a + 2]) << 16 | int(buf[a + 3]) << 24
            value = word & 0xFFFFFF
            if value & 0x800000:
                value -= 1 << 24
            out.append((j, (word >> 24) & 0x3F, value, tag))
    return (np.array(out, np.int64).reshape(-1, 4), ok)


def _nmea_inside(lines: list[bytes], chans: dict, read: Counter, skipped: Counter, warnings: list[str],
                 start_time: float, suffix: str) -> float:
    """Read NMEA sentences found between UBX frames onto the UBX clock; return the start time.

    With no UBX channel at all the NMEA clock becomes the log's (t = 0 at the first sentence's
    fix, ``start_time`` from its date). Otherwise each NMEA sample is placed by its UTC date
    and time: t = UTC - start_time; without a date (or a UBX GPS week) they cannot be placed and
    are counted as skipped.
    """
    res = parse_nmea(lines)
    n = sum(res.read.values())
    for k, v in res.skipped.items():
        if v:
            skipped[f"NMEA {k}"] += v
    if not res.merged:
        return start_time
    if not chans:
        log = nmea_rawlog(res, "", suffix)
        chans.update(log.channels)
        for k, v in res.read.items():
            read[f"NMEA {k}"] += v
        warnings.append(f"no UBX message gives a channel: NMEA sentences inside the stream give the clock "
                        f"({log.summary.warnings[0]})")
        warnings.extend(f"NMEA: {w}" for w in log.summary.warnings[1:])
        return log.start_time
    t0 = min(float(v[0][0]) for v in res.merged.values())
    if math.isnan(res.clock.unix(t0)) or math.isnan(start_time):
        for k, v in res.read.items():
            skipped[f"NMEA {k} (no date to place it on the UBX clock)"] += v
        warnings.append(f"NMEA: {n} sentence(s) inside the UBX stream not used: "
                        + ("no RMC/ZDA date" if math.isnan(res.clock.unix(t0)) else "no UBX GPS week")
                        + " to put them on the UBX clock")
        return start_time
    for k, v in res.read.items():
        read[f"NMEA {k}"] += v
    for name, (t_abs, values, sids) in res.merged.items():
        key = name + suffix if name + suffix not in chans else f"{name}@nmea"
        if name in ("phi", "theta", "psi", "cog"):
            values = wrap_pi(values)
        chans[key] = Channel(key, np.array([res.clock.unix(x) for x in t_abs]) - start_time, values,
                             source=f"NMEA inside UBX ({sids})")
    warnings.extend(f"NMEA: {w}" for w in res.warnings if w.startswith(("sentence types", "fix stats")))
    return start_time


__all__ = ["read_ubx", "VARIABLE_MAP", "NAV_PVT_DTYPE"]
