"""MAVLink telemetry logs (``.tlog``), as saved by a ground station (Mission Planner, QGC, MAVProxy).

A tlog is a sequence of records: an 8-byte big-endian uint64 receive time [us since the Unix epoch]
followed by one MAVLink 1 (``0xFE``) or MAVLink 2 (``0xFD``) frame. The receive time is the ground
station's clock, delayed and jittered by the radio link, so it is not used for dynamics: every
channel is stamped with the autopilot's boot clock carried inside the message (``time_boot_ms`` or,
for GPS_RAW_INT, RAW_IMU and SERVO_OUTPUT_RAW, ``time_usec``), and the result has
``time_reference='boot'``. When the autopilot sends SYSTEM_TIME (UTC with its boot time), the
median of their difference is ``RawLog.start_time``, the UTC of boot; otherwise it is NaN.

Frames are split and checked here with the tables of the generated
``pymavlink.dialects.v20.ardupilotmega`` module (message ids, CRC extras, x25 CRC, payload struct
layouts; they serve MAVLink 1 frames too) rather than through ``mavutil.mavlink_connection``:
``mavutil`` switches MAVLink 1/2 by setting ``MAVLINK20`` in ``os.environ`` for the whole process,
and its robust parser resynchronises silently, so truncated tails, garbage and bad CRCs could not
be counted.

Mapping (``VARIABLE_MAP``; SI units, radians, Fossen frames: NED world, body x fwd, y stbd, z down)
-------------------------------------------------------------------------------------------------
ATTITUDE             roll, pitch, yaw, rollspeed... -> phi, theta, psi, p, q, r
GLOBAL_POSITION_INT  lat, lon [degE7] -> lat, lon [deg]; vx, vy [cm/s NED] -> sog [m/s], cog [rad]
GPS_RAW_INT          lat, lon, vel [cm/s], cog [cdeg] -> lat@gps, lon@gps, sog@gps, cog@gps
SCALED_IMU, RAW_IMU  x/y/zacc [mG], x/y/zgyro [mrad/s] -> ax, ay, az [m/s^2], p@imu, q@imu, r@imu
SCALED_IMU2, _IMU3   the same with ``@imu2`` / ``@imu3`` on every name
SERVO_OUTPUT_RAW     servoN_raw [us] -> inputs through the vessel's ``[[actuators]]`` (source servo)
RC_CHANNELS          chanN_raw [us]  -> inputs through the vessel's ``[[actuators]]`` (source rc)
SYSTEM_TIME          time_unix_usec, time_boot_ms -> ``RawLog.start_time`` (UTC of boot), not a channel

RAW_IMU is taken in ArduPilot's convention (mG and mrad/s, like SCALED_IMU); the MAVLink spec calls
its values "raw", and other autopilots may fill it with ADC counts.
"""

from __future__ import annotations

import math
import mmap
import struct
import sys
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..errors import IngestError
from ..geo import wrap_pi
from ..records import Channel, IngestSummary, RawLog
from ..terminal import want_progress
from ..vessel import ActuatorMap, Vessel
from ._common import actuators_reading, check_file
from ._gpstime import unix_text

#: Standard gravity [m/s^2], the one ArduPilot uses to turn m/s^2 into mG.
G0 = 9.80665

_CDEG = math.pi / 18000.0
_MG = G0 / 1000.0

#: (message, field) -> (canonical channel, scale to SI). ``v_n``/``v_e`` (NED ground velocity
#: [m/s]) are intermediate: they become ``sog`` = |v| and ``cog`` = atan2(v_e, v_n).
#: Earlier messages win a name both map to; the later one gets ``name@message``.
VARIABLE_MAP: dict[tuple[str, str], tuple[str, float]] = {
    ("ATTITUDE", "roll"): ("phi", 1.0),
    ("ATTITUDE", "pitch"): ("theta", 1.0),
    ("ATTITUDE", "yaw"): ("psi", 1.0),
    ("ATTITUDE", "rollspeed"): ("p", 1.0),
    ("ATTITUDE", "pitchspeed"): ("q", 1.0),
    ("ATTITUDE", "yawspeed"): ("r", 1.0),
    ("GLOBAL_POSITION_INT", "lat"): ("lat", 1e-7),
    ("GLOBAL_POSITION_INT", "lon"): ("lon", 1e-7),
    ("GLOBAL_POSITION_INT", "vx"): ("v_n", 1e-2),
    ("GLOBAL_POSITION_INT", "vy"): ("v_e", 1e-2),
    ("GPS_RAW_INT", "lat"): ("lat@gps", 1e-7),
    ("GPS_RAW_INT", "lon"): ("lon@gps", 1e-7),
    ("GPS_RAW_INT", "vel"): ("sog@gps", 1e-2),
    ("GPS_RAW_INT", "cog"): ("cog@gps", _CDEG),
    **{(msg, f"{axis}acc"): (f"a{axis}{suffix}", _MG)
       for msg, suffix in (("SCALED_IMU", ""), ("RAW_IMU", ""), ("SCALED_IMU2", "@imu2"), ("SCALED_IMU3", "@imu3"))
       for axis in "xyz"},
    **{(msg, f"{axis}gyro"): (f"{rate}@{sensor}", 1e-3)
       for msg, sensor in (("SCALED_IMU", "imu"), ("RAW_IMU", "imu"), ("SCALED_IMU2", "imu2"), ("SCALED_IMU3", "imu3"))
       for axis, rate in zip("xyz", "pqr")},
}

#: Message -> (boot-clock field, ticks per second). Dividing (not multiplying by 1e-3) gives the
#: correctly rounded seconds, so 5020 ms is exactly the float 5.02.
TIME_FIELDS: dict[str, tuple[str, int]] = {
    "ATTITUDE": ("time_boot_ms", 1000),
    "GLOBAL_POSITION_INT": ("time_boot_ms", 1000),
    "GPS_RAW_INT": ("time_usec", 1_000_000),
    "SCALED_IMU": ("time_boot_ms", 1000),
    "RAW_IMU": ("time_usec", 1_000_000),
    "SCALED_IMU2": ("time_boot_ms", 1000),
    "SCALED_IMU3": ("time_boot_ms", 1000),
    "SERVO_OUTPUT_RAW": ("time_usec", 1_000_000),
    "RC_CHANNELS": ("time_boot_ms", 1000),
}

#: Input messages: message -> (ActuatorMap.source, field name pattern, number of channels).
INPUT_MESSAGES: dict[str, tuple[str, str, int]] = {
    "SERVO_OUTPUT_RAW": ("servo", "servo{}_raw", 16),
    "RC_CHANNELS": ("rc", "chan{}_raw", 18),
}

#: Fields read only to judge validity (not channels).
_EXTRA_FIELDS: dict[str, tuple[str, ...]] = {"GPS_RAW_INT": ("fix_type",), "SERVO_OUTPUT_RAW": ("port",)}

#: Time fields that are uint32 microseconds and wrap every 2**32 us (71.6 min) of boot time.
_WRAPPING_USEC = {"SERVO_OUTPUT_RAW"}

_TS_LEN = 8
_MAGIC_V1 = 0xFE
_MAGIC_V2 = 0xFD
_SIGNED = 0x01
_SIG_LEN = 13
_UINT16_MAX = 65535
#: Files above this size get a progress bar when stderr is a terminal [bytes].
_PROGRESS_MIN_BYTES = 4 * 1024 * 1024
#: Boot-clock usec above this are Unix-epoch stamps (some autopilots put GPS time in time_usec).
_UNIX_USEC = 1e15
#: SYSTEM_TIME pairs the autopilot's UTC with its boot clock: it gives ``RawLog.start_time``.
_SYSTEM_TIME = "SYSTEM_TIME"
_SYSTEM_TIME_FIELDS = ("time_unix_usec", "time_boot_ms")
#: SYSTEM_TIME messages whose UTC - boot offset differs from the median by more than this are a
#: clock step (GPS time arriving, a reboot) and are not used [s].
_SYSTEM_TIME_TOLERANCE_S = 0.5


def _dialect():
    # Imported on first use: the generated module is 2 MB of source and takes ~30 ms to import.
    from pymavlink.dialects.v20 import ardupilotmega

    return ardupilotmega


def _fields_of(msg_type: str) -> tuple[str, ...]:
    fields = [TIME_FIELDS[msg_type][0]]
    fields += [f for (m, f) in VARIABLE_MAP if m == msg_type]
    if msg_type in INPUT_MESSAGES:
        _, pattern, count = INPUT_MESSAGES[msg_type]
        fields += [pattern.format(i) for i in range(1, count + 1)]
    fields += list(_EXTRA_FIELDS.get(msg_type, ()))
    return tuple(fields)






class _Framer:
    """Split a tlog buffer into records and check each frame's header, length and CRC."""

    def __init__(self, buf: Any, dialect: Any) -> None:
        self.buf = buf
        self.n = len(buf)
        self.map = dialect.mavlink_map
        self.crc = dialect.x25crc

    def frame_at(self, pos: int) -> tuple[str, int, int]:
        """Classify the record starting at ``pos``.

        Returns ``(status, end, msgid)``; status is ``ok``, ``short`` (runs past the end of the
        file), ``magic`` (no frame start), ``crc`` (checksum does not match) or
        ``unknown`` (message id not in the dialect, so its CRC cannot be checked).
        """
        buf, n = self.buf, self.n
        m = pos + _TS_LEN
        if m >= n:
            return "short", n, -1
        magic = buf[m]
        if magic == _MAGIC_V1:
            hlen = 6
            if m + hlen > n:
                return "short", n, -1
            plen, msgid, sig = buf[m + 1], buf[m + 5], 0
        elif magic == _MAGIC_V2:
            hlen = 10
            if m + hlen > n:
                return "short", n, -1
            plen, incompat = buf[m + 1], buf[m + 2]
            if incompat & ~_SIGNED:
                # Unknown incompatibility flags: MAVLink 2 says such frames must be dropped.
                return "magic", m, -1
            msgid = buf[m + 7] | (buf[m + 8] << 8) | (buf[m + 9] << 16)
            sig = _SIG_LEN if incompat & _SIGNED else 0
        else:
            return "magic", m, -1
        end = m + hlen + plen + 2 + sig
        if end > n:
            return "short", end, msgid
        cls = self.map.get(msgid)
        if cls is None:
            return "unknown", end, msgid
        crc_at = m + hlen + plen
        crc = self.crc(bytes(buf[m + 1:crc_at]) + bytes((cls.crc_extra,))).crc
        if crc != (buf[crc_at] | (buf[crc_at + 1] << 8)):
            return "crc", end, msgid
        return "ok", end, msgid

    def next_candidate(self, pos: int) -> int:
        """First record start after ``pos`` whose frame byte is a MAVLink magic, or ``n``."""
        hits = [h for h in (self.buf.find(b"\xfe", pos + 1 + _TS_LEN), self.buf.find(b"\xfd", pos + 1 + _TS_LEN))
                if h >= 0]
        return min(hits) - _TS_LEN if hits else self.n


class _Unpacker:
    """Payload fields of the used message types, straight from the frame bytes.

    ``MAVLink.decode`` builds a message object and checks the CRC a second time; the used types
    have no array fields, so one ``struct`` unpack of the zero-padded payload (MAVLink 2 trims
    trailing zeros) gives the fields in wire order at a fraction of the cost.
    """

    def __init__(self, buf: Any, dialect: Any, wanted: Mapping[str, tuple[str, ...]]) -> None:
        self.buf = buf
        self.by_name = {}
        for cls in dialect.mavlink_map.values():
            if cls.msgname in wanted:
                if any(length > 1 for length in cls.lengths):
                    raise RuntimeError(f"{cls.msgname} has array fields; _Unpacker cannot read it")
                idx = tuple(cls.ordered_fieldnames.index(f) for f in wanted[cls.msgname])
                self.by_name[cls.msgname] = (cls.unpacker, cls.unpacker.size, idx)

    def __call__(self, name: str, m: int, end: int) -> tuple | None:
        """Fields of the frame at ``m`` (its magic byte) ending at ``end``, with sender first."""
        buf = self.buf
        unpacker, size, idx = self.by_name[name]
        if buf[m] == _MAGIC_V1:
            hlen, sys_id, comp_id = 6, buf[m + 3], buf[m + 4]
        else:
            hlen, sys_id, comp_id = 10, buf[m + 5], buf[m + 6]
        plen = buf[m + 1]
        payload = buf[m + hlen:m + hlen + min(plen, size)]
        try:
            values = unpacker.unpack(payload + bytes(size - len(payload)))
        except struct.error:
            return None
        return (sys_id, comp_id) + tuple(values[i] for i in idx)


def read_tlog(path: str | Path, vessel: Vessel | None = None, progress: bool | None = None) -> RawLog:
    """Read a MAVLink telemetry log (``.tlog``) into canonical channels on the autopilot boot clock.

    Parameters
    ----------
    path : str or Path
        The tlog (8-byte big-endian receive time [us] before each MAVLink 1 or 2 frame). Opened
        read-only and never modified.
    vessel : Vessel, optional
        Supplies ``actuators``, the map from SERVO_OUTPUT_RAW / RC_CHANNELS PWM [us] to canonical
        inputs (``ActuatorMap.to_input``). Several maps on one target add up (twin thrusters).
        Without it inputs are not read and the summary says so.
    progress : bool, optional
        Show a tqdm bar over the file bytes. ``None``: only for files above 4 MB when stderr is a
        terminal and the ``CI`` environment variable is unset.

    Returns
    -------
    RawLog
        ``format='tlog'``, ``time_reference='boot'``: ``t`` [s] is the autopilot's boot time from
        each message; ``start_time`` [s, Unix UTC] of boot from SYSTEM_TIME (NaN without). Channels (SI, radians, Fossen frames): ``phi theta psi p q r`` (ATTITUDE,
        ``psi`` in (-pi, pi]); ``lat lon`` [deg], ``sog`` [m/s], ``cog`` [rad]
        (GLOBAL_POSITION_INT); ``lat@gps lon@gps sog@gps cog@gps`` (GPS_RAW_INT); ``ax ay az``
        [m/s^2], ``p@imu q@imu r@imu`` [rad/s] (SCALED_IMU / RAW_IMU); inputs (``delta``
        [rad], ``tau_x`` [N], ...) from the actuator map, RC inputs that duplicate a servo
        target as ``name@rc``. ``Channel.source`` is the message type.

    Raises
    ------
    IngestError
        Missing file, empty file, no MAVLink message in the file, a file cut before its
        first complete message, or no message that gives a channel.

    Notes
    -----
    Counted and reported in ``summary`` rather than raised: a truncated tail (``truncated: N
    trailing bytes ignored``), frames with a bad CRC and unframed bytes between messages,
    messages whose boot stamp repeats or goes backwards within a type (the first is kept),
    a type sent by more than one system/component (the most frequent sender is kept),
    sentinel values (no GPS fix, PWM 0 or 65535, position 0/0), and inputs present without an
    actuator map. Unused message types (HEARTBEAT, ...) are counted in ``summary.skipped``.
    """
    p = check_file(path, "MAVLink tlog (8-byte timestamp + MAVLink frame per record)")
    size = p.stat().st_size
    mav = _dialect()
    with open(p, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as buf:
        rows, counts = _scan(p, buf, mav, want_progress(progress, size, _PROGRESS_MIN_BYTES))
    return _build(p, rows, counts, vessel)


def _scan(p: Path, buf: Any, mav: Any, show_progress: bool) -> tuple[dict[str, list], dict[str, Any]]:
    """Pass over the file: decode the used message types, count everything else."""
    framer = _Framer(buf, mav)
    wanted = {t: _fields_of(t) for t in TIME_FIELDS}
    wanted[_SYSTEM_TIME] = _SYSTEM_TIME_FIELDS
    unpack = _Unpacker(buf, mav, wanted)
    rows: dict[str, list] = defaultdict(list)
    skipped: Counter = Counter()
    n_ok = n_bad_crc = n_bad_data = bad_bytes = 0
    unknown: Counter = Counter()
    bad_start: int | None = None
    bad_kind = ""
    truncated = 0
    n = framer.n

    bar = None
    if show_progress:
        from tqdm import tqdm

        bar = tqdm(total=n, unit="B", unit_scale=True, desc=p.name, file=sys.stderr, leave=False)
    last_tick = 0

    def close_bad(upto: int) -> None:
        nonlocal n_bad_crc, n_bad_data, bad_bytes, bad_start
        bad_bytes += upto - bad_start
        if bad_kind == "crc":
            n_bad_crc += 1
        else:
            n_bad_data += 1
        bad_start = None

    pos = 0
    try:
        while pos < n:
            status, end, msgid = framer.frame_at(pos)
            if status == "unknown" and bad_start is None and (
                    end == n or (end + _TS_LEN < n and buf[end + _TS_LEN] in (_MAGIC_V1, _MAGIC_V2))):
                # A well-framed message from another dialect, followed by a frame start: skip it whole.
                unknown[msgid] += 1
                n_ok += 1
                pos = end
                continue
            name = framer.map[msgid].msgname if status == "ok" else ""
            record = None
            if name in wanted:
                record = unpack(name, pos + _TS_LEN, end)
                if record is None:
                    status = "crc"
            if status != "ok":
                if bad_start is None:
                    bad_start, bad_kind = pos, status
                pos = framer.next_candidate(pos)
                continue
            if bad_start is not None:
                close_bad(pos)
            n_ok += 1
            if record is not None:
                rows[name].append(record)
            else:
                skipped[name] += 1
            pos = end
            if bar is not None and pos - last_tick > 1 << 16:
                bar.update(pos - last_tick)
                last_tick = pos
    finally:
        if bar is not None:
            bar.update(n - last_tick)
            bar.close()

    if bad_start is not None:
        if bad_kind == "short":
            truncated = n - bad_start
        else:
            close_bad(n)
    for msgid, c in unknown.items():
        skipped[f"UNKNOWN_{msgid}"] += c
    counts = {"ok": n_ok, "bad_crc": n_bad_crc, "bad_data": n_bad_data, "bad_bytes": bad_bytes,
              "truncated": truncated, "skipped": skipped, "unknown": unknown, "size": n,
              "head": bytes(buf[:24])}
    return rows, counts


def _build(p: Path, rows: Mapping[str, list], counts: Mapping[str, Any], vessel: Vessel | None) -> RawLog:
    """Turn decoded rows into channels, with every drop counted."""
    n_ok = counts["ok"]
    if n_ok == 0:
        if counts["truncated"]:
            raise IngestError(f"{p}: expected at least one complete MAVLink message, found none in "
                              f"{counts['size']} bytes (truncated: the file ends inside its first record "
                              f"or is not a tlog; starts with {counts['head']!r})")
        raise IngestError(f"{p}: expected a MAVLink tlog (8-byte timestamp + MAVLink 1/2 frame per record), "
                          f"found no MAVLink messages in {counts['size']} bytes (starts with {counts['head']!r})")

    warnings: list[str] = []
    read: Counter = Counter()
    skipped: Counter = Counter(counts["skipped"])
    if counts["truncated"]:
        warnings.append(f"truncated: {counts['truncated']} trailing bytes ignored")
    if counts["bad_crc"] or counts["bad_data"]:
        skipped["BAD_CRC"] += counts["bad_crc"]
        skipped["BAD_DATA"] += counts["bad_data"]
        warnings.append(f"bad data: {counts['bad_crc']} frame(s) with a bad CRC and {counts['bad_data']} "
                        f"stretch(es) of garbage bytes skipped ({counts['bad_bytes']} bytes in total)")
    if counts["unknown"]:
        ids = ", ".join(f"{k} ({v})" for k, v in sorted(counts["unknown"].items()))
        warnings.append(f"message ids not in the ardupilotmega dialect skipped: {ids}")

    maps = tuple(vessel.actuators) if vessel is not None else ()
    produced: dict[str, Channel] = {}

    for msg_type in TIME_FIELDS:  # TIME_FIELDS order is the naming priority
        if msg_type not in rows:
            continue
        fields = ("_sys", "_comp") + _fields_of(msg_type)
        arr = np.array(rows[msg_type], dtype=float)
        col = {f: arr[:, i] for i, f in enumerate(fields)}
        keep = _dominant_sender(msg_type, col, warnings)
        t = _boot_seconds(msg_type, col, keep, warnings)
        keep &= np.isfinite(t)
        keep = _increasing(msg_type, t, keep, warnings)
        chans, used = _channels(msg_type, t, col, keep, maps, warnings)
        read[msg_type] += int(used.sum())
        skipped[msg_type] += int(len(t) - used.sum())
        for name, ch in chans.items():
            if name in produced:
                alt = f"{name.split('@')[0]}@{msg_type.lower()}"
                warnings.append(f"{name} is already read from {produced[name].source}; "
                                f"{msg_type} gives it as {alt}")
                name = alt
                ch = Channel(alt, ch.t, ch.values, ch.source)
            produced[name] = ch

    for msg_type, (src, _, _) in INPUT_MESSAGES.items():
        if msg_type in rows or not any(a.source == src for a in maps):
            continue
        wanted = ", ".join(f"{a.target} (channel {a.channel})" for a in maps if a.source == src)
        warnings.append(f"actuator map expects {msg_type} for {wanted}, found no {msg_type} messages")
    start_time = _start_time(rows.get(_SYSTEM_TIME, []), rows, read, skipped, warnings)
    if not produced:
        # Like the other readers: a tlog that gives no channel is an error, not an empty log that
        # would only fail later in align (a truncated file holding one HEARTBEAT, a GCS-only log).
        found = ", ".join(f"{k} {v}" for k, v in sorted((read + skipped).items())) or "none"
        cut = f"; {warnings[0]}" if counts["truncated"] else ""
        raise IngestError(f"{p}: expected MAVLink messages that give channels ({', '.join(TIME_FIELDS)}), found "
                          f"none usable (messages: {found}){cut}")

    summary = IngestSummary(path=str(p), format="tlog", read={k: v for k, v in read.items() if v},
                            skipped={k: v for k, v in skipped.items() if v}, warnings=tuple(warnings))
    return RawLog(source=str(p), format="tlog", channels=produced, summary=summary, time_reference="boot",
                  start_time=start_time)


def _start_time(st_rows: list, rows: Mapping[str, list], read: Counter, skipped: Counter,
                warnings: list[str]) -> float:
    """UTC of boot (``time_boot_ms`` = 0) [s, Unix] from SYSTEM_TIME, NaN without it.

    Ground stations send SYSTEM_TIME too, with their own boot clock, so only the autopilot's are
    used: the sender of the vehicle messages (the most frequent sender of the channel messages).
    ``time_unix_usec`` is 0 until the autopilot has GPS time. The receive stamps of the tlog are
    not used: they carry the radio link's latency and jitter.
    """
    if not st_rows:
        return math.nan
    arr = np.array(st_rows, dtype=float)
    vehicle = Counter((int(r[0]), int(r[1])) for m in TIME_FIELDS for r in rows.get(m, ()))
    sender = vehicle.most_common(1)[0][0] if vehicle else Counter(
        (int(r[0]), int(r[1])) for r in st_rows).most_common(1)[0][0]
    mine = (arr[:, 0] == sender[0]) & (arr[:, 1] == sender[1])
    unix_us, boot_ms = arr[:, 2], arr[:, 3]
    valid = mine & (unix_us > _UNIX_USEC)
    offsets = unix_us * 1e-6 - boot_ms * 1e-3
    used = np.zeros(len(arr), bool)
    start = math.nan
    if valid.any():
        start = float(np.median(offsets[valid]))
        used = valid & (np.abs(offsets - start) <= _SYSTEM_TIME_TOLERANCE_S)
        start = float(np.median(offsets[used]))
    read[_SYSTEM_TIME] += int(used.sum())
    skipped[_SYSTEM_TIME] += int(len(arr) - used.sum())
    notes = []
    if (~mine).any():
        notes.append(f"{int((~mine).sum())} from other senders")
    if (mine & ~valid).any():
        notes.append(f"{int((mine & ~valid).sum())} without UTC (time_unix_usec 0)")
    if (valid & ~used).any():
        notes.append(f"{int((valid & ~used).sum())} off the median by more than {_SYSTEM_TIME_TOLERANCE_S:g} s")
    if notes:
        warnings.append(f"SYSTEM_TIME: {int(len(arr) - used.sum())} message(s) not used for the clock ("
                        + ", ".join(notes) + ")")
    if used.any():
        span = float(np.ptp(offsets[used]))
        warnings.append(f"t = 0 (boot) is {unix_text(start)} UTC, from {int(used.sum())} SYSTEM_TIME message(s) "
                        f"(spread {1e3 * span:.1f} ms)")
    return start


def _dominant_sender(msg_type: str, col: Mapping[str, np.ndarray], warnings: list[str]) -> np.ndarray:
    # Two senders of one type (autopilot + companion, two vehicles) would interleave two clocks.
    sender = col["_sys"] * 256 + col["_comp"]
    ids, n = np.unique(sender, return_counts=True)
    keep = np.ones(len(sender), bool)
    if len(ids) > 1:
        main = ids[np.argmax(n)]
        keep = sender == main
        others = ", ".join(f"system {int(i) // 256} component {int(i) % 256} ({c})"
                           for i, c in zip(ids, n) if i != main)
        warnings.append(f"{msg_type}: {int((~keep).sum())} message(s) from other senders skipped ({others}); "
                        f"kept system {int(main) // 256} component {int(main) % 256}")
    return keep


def _boot_seconds(msg_type: str, col: Mapping[str, np.ndarray], keep: np.ndarray,
                  warnings: list[str]) -> np.ndarray:
    field, ticks = TIME_FIELDS[msg_type]
    raw = col[field].copy()
    if msg_type in _WRAPPING_USEC and keep.any():
        # uint32 us wraps after 71.6 min of boot time; a backward jump of more than half the
        # range is a wrap, not a reordering.
        idx = np.flatnonzero(keep)
        steps = np.diff(raw[idx])
        wraps = np.concatenate(([0], np.cumsum(steps < -(2.0**31))))
        raw[idx] = raw[idx] + wraps * 2.0**32
    if field == "time_usec" and keep.any() and np.median(raw[keep]) > _UNIX_USEC:
        warnings.append(f"{msg_type}: time_usec holds Unix time, not boot time; {int(keep.sum())} message(s) "
                        "not used (their clock cannot be put on the boot clock)")
        return np.full(len(raw), np.nan)
    return raw / ticks


def _increasing(msg_type: str, t: np.ndarray, keep: np.ndarray, warnings: list[str]) -> np.ndarray:
    idx = np.flatnonzero(keep)
    tk = t[idx]
    ok = np.ones(len(tk), bool)
    ok[1:] = tk[1:] > np.maximum.accumulate(tk)[:-1]
    bad = int((~ok).sum())
    if bad:
        field = TIME_FIELDS[msg_type][0]
        warnings.append(f"{msg_type}: {bad} message(s) with a duplicate or non-increasing {field} skipped "
                        "(first kept)")
    out = np.zeros(len(t), bool)
    out[idx[ok]] = True
    return out


def _channels(msg_type: str, t: np.ndarray, col: Mapping[str, np.ndarray], keep: np.ndarray,
              maps: tuple[ActuatorMap, ...], warnings: list[str]) -> tuple[dict[str, Channel], np.ndarray]:
    """Channels of one message type; returns them and which messages contributed a sample."""
    raw: dict[str, np.ndarray] = {}
    for (m, f), (name, scale) in VARIABLE_MAP.items():
        if m == msg_type:
            raw[name] = col[f] * scale
    valid: dict[str, np.ndarray] = {name: keep & np.isfinite(v) for name, v in raw.items()}
    out: dict[str, np.ndarray] = {}
    dropped: list[str] = []

    if msg_type == "ATTITUDE":
        for name in ("phi", "theta", "psi"):
            raw[name] = wrap_pi(raw[name])
        out = raw
    elif msg_type == "GLOBAL_POSITION_INT":
        no_pos = (col["lat"] == 0) & (col["lon"] == 0)
        _drop(valid, ("lat", "lon"), no_pos & keep, "position 0/0 (no position estimate)", dropped)
        vn, ve = raw["v_n"], raw["v_e"]
        out = {"lat": raw["lat"], "lon": raw["lon"], "sog": np.hypot(vn, ve), "cog": np.arctan2(ve, vn)}
        valid["sog"] = valid["cog"] = valid.pop("v_n") & valid.pop("v_e")
    elif msg_type == "GPS_RAW_INT":
        _drop(valid, ("lat@gps", "lon@gps", "sog@gps", "cog@gps"), (col["fix_type"] < 2) & keep,
              "no fix (fix_type < 2)", dropped)
        _drop(valid, ("sog@gps",), (col["vel"] == _UINT16_MAX) & keep, "vel unknown (65535)", dropped)
        _drop(valid, ("cog@gps",), (col["cog"] == _UINT16_MAX) & keep, "cog unknown (65535)", dropped)
        raw["cog@gps"] = wrap_pi(raw["cog@gps"])
        out = raw
    elif msg_type in INPUT_MESSAGES:
        out, valid = _inputs(msg_type, col, keep, maps, warnings, dropped)
    else:
        out = raw

    if msg_type == "ATTITUDE":
        # A field that is NaN throughout is "not estimated" (MAVLink float convention): no channel,
        # no warning. NaN in part of a field is worth a note.
        partial = [name for name in out if (keep & ~np.isfinite(out[name])).any() and valid[name].any()]
        if partial:
            dropped.append(f"{msg_type}: non-finite samples not used for {', '.join(partial)}")
    warnings.extend(dropped)

    chans: dict[str, Channel] = {}
    used = np.zeros(len(t), bool)
    for name, values in out.items():
        ok = valid[name] & np.isfinite(values)
        if not ok.any():
            continue
        used |= ok
        chans[name] = Channel(name=name, t=t[ok], values=np.asarray(values[ok], float), source=msg_type)
    return chans, used


def _drop(valid: dict[str, np.ndarray], names: tuple[str, ...], bad: np.ndarray, why: str,
          notes: list[str]) -> None:
    n = int(bad.sum())
    if not n:
        return
    for name in names:
        valid[name] = valid[name] & ~bad
    notes.append(f"{n} sample(s) of {', '.join(names)} not used: {why}")


def _inputs(msg_type: str, col: Mapping[str, np.ndarray], keep: np.ndarray, maps: tuple[ActuatorMap, ...],
            warnings: list[str], dropped: list[str]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    src, pattern, count = INPUT_MESSAGES[msg_type]
    mine = actuators_reading(maps, src, int(keep.sum()), f"{msg_type} message(s)", warnings)
    if not mine:
        return {}, {}
    keep = keep.copy()
    if msg_type == "SERVO_OUTPUT_RAW":
        # Port k carries channels 8k+1..8k+8 in MAVLink 1; port 0 holds all 16 in MAVLink 2.
        other_port = keep & (col["port"] != 0)
        if other_port.any():
            warnings.append(f"{msg_type}: {int(other_port.sum())} message(s) with port != 0 skipped")
            keep &= ~other_port
    out: dict[str, np.ndarray] = {}
    valid: dict[str, np.ndarray] = {}
    for a in mine:
        if not 1 <= a.channel <= count:
            warnings.append(f"actuator map {src} channel {a.channel} ({a.target}): {msg_type} has channels "
                            f"1..{count}; not read")
            continue
        field = pattern.format(a.channel)
        pwm = col[field]
        unused = keep & ((pwm == 0) | (pwm == _UINT16_MAX))
        if unused.any():
            dropped.append(f"{int(unused.sum())} sample(s) of {a.target} ({msg_type}.{field}) not used: "
                           "PWM 0 or 65535 (channel not driven)")
        ok = keep & ~unused
        value = np.where(ok, a.to_input(pwm), np.nan)
        if a.target in out:
            # Several channels on one target (twin thrusters) add up to the generalised force.
            out[a.target] = out[a.target] + value
            valid[a.target] &= ok
        else:
            out[a.target], valid[a.target] = value, ok
    if src == "rc":
        servo_targets = {a.target for a in maps if a.source == "servo"}
        renamed = {(f"{k}@rc" if k in servo_targets else k): k for k in out}
        out = {new: out[old] for new, old in renamed.items()}
        valid = {new: valid[old] for new, old in renamed.items()}
    return out, valid
