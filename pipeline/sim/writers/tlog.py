"""Write a RawLog as a MAVLink telemetry log (``.tlog``), the file a ground station saves.

Each record is an 8-byte big-endian uint64 receive time [us since the Unix epoch] followed by one
MAVLink frame packed by pymavlink's generated ``ardupilotmega`` dialect (MAVLink 2 from
``pymavlink.dialects.v20``, MAVLink 1 from ``pymavlink.dialects.v10``; both are imported directly
so one process can write either, whatever ``MAVLINK20`` says). Messages carry the autopilot boot
clock (``time_boot_ms``/``time_usec``); the receive time is a wall clock plus a fixed latency, as a
ground station would stamp it, and is deliberately not what :func:`read_tlog` uses.

Messages written (each at the timestamps of the channels it carries; other channels interpolated
onto them)
-----------------------------------------------------------------------------------------------
ATTITUDE             phi, theta, psi (wrapped to (-pi, pi]), p, q, r; a missing one is NaN
GLOBAL_POSITION_INT  lat, lon, NED ground velocity from sog/cog, else u/v/psi, else lat/lon
                     differences; hdg from psi
GPS_RAW_INT          lat@gps, lon@gps (+ sog@gps, cog@gps) when present
SCALED_IMU           ax, ay, az and gyro p@imu, q@imu, r@imu (else p, q, r)
SERVO_OUTPUT_RAW     inputs through the vessel's actuator maps with source ``servo``
RC_CHANNELS          inputs through the vessel's actuator maps with source ``rc``
HEARTBEAT            once a second, as the vehicle sends it
SYSTEM_TIME          once a second: time_unix_usec (UTC from the wall clock at t) and time_boot_ms
"""

from __future__ import annotations

import math
import struct
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ...atomic import atomic_path
from ...errors import SimError
from ...geo import wrap_pi
from ...records import INPUT_UNITS, RawLog
from ...vessel import ActuatorMap, Vessel
from ._sampling import check_channel, hold_channel as _hold, interp_channel as _interp, to_int_field

#: Standard gravity [m/s^2], the one ArduPilot uses to turn m/s^2 into mG.
G0 = 9.80665
#: Mean Earth radius [m], for velocity from lat/lon differences only.
_R_EARTH = 6_371_000.0
_UINT16_MAX = 65535
_DEFAULT_WALL_START = datetime(2024, 5, 5, 10, 0, tzinfo=timezone.utc)
#: Tie-break for messages at one time, so the file (and its sequence numbers) is deterministic.
_RANK = {"HEARTBEAT": 0, "ATTITUDE": 1, "GLOBAL_POSITION_INT": 2, "GPS_RAW_INT": 3, "SCALED_IMU": 4,
         "SERVO_OUTPUT_RAW": 5, "RC_CHANNELS": 6, "SYSTEM_TIME": 7}
_SERVO_CHANNELS = {True: 16, False: 8}  # MAVLink 2 adds servo9..16 as extension fields
_RC_CHANNELS = 18


def write_tlog(log: RawLog, path: str | Path, vessel: Vessel | None = None, mavlink2: bool = True, *,
               boot_offset_ms: int = 5000, wall_start: datetime | float = _DEFAULT_WALL_START,
               latency_s: float = 0.02, heartbeat_hz: float = 1.0, system_time_hz: float = 1.0,
               system_id: int = 1, component_id: int = 1) -> Path:
    """Write ``log`` as a MAVLink ``.tlog``, atomically (temporary file beside it, then ``os.replace``).

    Parameters
    ----------
    log : RawLog
        Canonical channels; ``t`` [s] from trial start, SI units and radians.
    path : str or Path
        Output file; missing folders are created.
    vessel : Vessel, optional
        Its ``actuators`` map inputs to PWM (``ActuatorMap.to_pwm``). Required when ``log`` has
        input channels. Several maps with one target within one message share the value
        equally (twin thrusters), which the reader adds back up.
    mavlink2 : bool
        MAVLink 2 frames (``0xFD``) when True, MAVLink 1 (``0xFE``) when False.
    boot_offset_ms : int
        Boot time at ``t = 0`` [ms], so the log's boot clock does not start at 0.
        ``time_boot_ms = round(t * 1000) + boot_offset_ms``.
    wall_start : datetime or float
        Wall clock at ``t = 0`` (aware datetime, or Unix time [s]) for the receive stamps.
    latency_s : float
        Constant link latency added to the receive stamps [s].
    heartbeat_hz : float
        HEARTBEAT rate [Hz]; 0 writes none.
    system_time_hz : float
        SYSTEM_TIME rate [Hz]; 0 writes none. Each carries ``time_unix_usec`` = ``wall_start``
        + t (the autopilot's GPS-derived UTC) with ``time_boot_ms``, as ArduPilot sends it, so
        the reader can put the boot clock on UTC (``RawLog.start_time``).
    system_id, component_id : int
        MAVLink sender of every message (1, 1: the autopilot).

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    SimError
        Inputs without a vessel or without an actuator map for one of them, a channel whose
        ``t`` is not strictly increasing, or a value outside its MAVLink field.

    Notes
    -----
    Field quantisation: lat/lon 1e-7 deg, velocities 1 cm/s, cog/hdg 0.01 deg, accelerations
    1 mG, IMU rates 1 mrad/s, PWM 1 us, ``time_boot_ms`` 1 ms; ATTITUDE is float32.
    """
    target = Path(path)
    for name, ch in log.channels.items():
        check_channel(name, ch)
    if isinstance(wall_start, datetime):
        if wall_start.tzinfo is None:
            raise SimError(f"write_tlog: expected a timezone-aware wall_start, found naive {wall_start}")
        wall_us = round(wall_start.timestamp() * 1e6)
    else:
        wall_us = round(float(wall_start) * 1e6)

    dialect = _dialect(mavlink2)
    mav = dialect.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
    clock = _Clock(boot_offset_ms)
    messages: list[tuple[float, int, int, Any]] = []

    def add(t: np.ndarray, kind: str, build: Callable[[int], Any]) -> None:
        rank = _RANK[kind]
        for i, ti in enumerate(t):
            messages.append((float(ti), rank, len(messages), build(i)))

    # An empty channel carries nothing to write; treating it as absent keeps the helpers simple.
    ch = {n: c for n, c in log.channels.items() if len(c.t)}
    _attitude(ch, mav, clock, add)
    _global_position(ch, mav, clock, add)
    _gps_raw(ch, mav, clock, add)
    _imu(ch, mav, clock, add)
    _inputs(ch, vessel, mav, clock, add, mavlink2)
    t0 = min((m[0] for m in messages), default=0.0)
    t1 = max((m[0] for m in messages), default=0.0)
    if heartbeat_hz > 0 and messages:
        t_hb = t0 + np.arange(0.0, t1 - t0 + 1e-9, 1.0 / heartbeat_hz)
        add(t_hb, "HEARTBEAT", lambda i: mav.heartbeat_encode(
            dialect.MAV_TYPE_SURFACE_BOAT, dialect.MAV_AUTOPILOT_ARDUPILOTMEGA,
            dialect.MAV_MODE_FLAG_SAFETY_ARMED | dialect.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 0,
            dialect.MAV_STATE_ACTIVE))
    if system_time_hz > 0 and messages:
        t_st = t0 + np.arange(0.0, t1 - t0 + 1e-9, 1.0 / system_time_hz)
        st_ms = clock.ms(t_st)
        # The autopilot's UTC is the wall clock without the link latency of the receive stamps.
        st_unix = wall_us + np.round(t_st * 1e6).astype(np.int64)
        add(t_st, "SYSTEM_TIME", lambda i: mav.system_time_encode(int(st_unix[i]), int(st_ms[i] % 2**32)))

    # A ground station writes in arrival order; packing after sorting keeps MAVLink sequence
    # numbers increasing through the file, as on a real link.
    messages.sort(key=lambda m: (m[0], m[1], m[2]))
    with atomic_path(target) as tmp, open(tmp, "wb") as fh:
        for t, _, _, msg in messages:
            fh.write(struct.pack(">Q", wall_us + round((t + latency_s) * 1e6)))
            fh.write(msg.pack(mav))
    return target


def _dialect(mavlink2: bool) -> Any:
    if mavlink2:
        from pymavlink.dialects.v20 import ardupilotmega
    else:
        from pymavlink.dialects.v10 import ardupilotmega
    return ardupilotmega


class _Clock:
    """Autopilot boot clock for a trial time ``t`` [s]."""

    def __init__(self, boot_offset_ms: int) -> None:
        self.offset_ms = int(boot_offset_ms)

    def ms(self, t: np.ndarray) -> np.ndarray:
        ms = np.round(np.asarray(t, float) * 1000.0).astype(np.int64) + self.offset_ms
        if ms.size and (ms.min() < 0 or ms.max() >= 2**32):
            raise SimError(f"time_boot_ms: expected 0 <= round(t*1000) + boot_offset_ms < 2**32, found "
                           f"{ms.min()}..{ms.max()} (t {np.min(t)}..{np.max(t)} s, offset {self.offset_ms} ms)")
        return ms

    def us(self, t: np.ndarray) -> np.ndarray:
        us = np.round(np.asarray(t, float) * 1e6).astype(np.int64) + self.offset_ms * 1000
        if us.size and us.min() < 0:
            raise SimError(f"time_usec: expected round(t*1e6) + boot_offset_ms*1000 >= 0, found {us.min()}")
        return us


def _cdeg(angle: np.ndarray) -> np.ndarray:
    """Angle [rad] -> 0..35999 centidegrees (MAVLink heading/course convention)."""
    return np.mod(np.round(np.degrees(np.mod(angle, 2 * math.pi)) * 100.0), 36000)


def _attitude(ch, mav, clock, add) -> None:
    names = ("phi", "theta", "psi", "p", "q", "r")
    present = [n for n in names if n in ch]
    if not present:
        return
    t = np.asarray(ch[present[0]].t, float)
    ms = clock.ms(t)
    # NaN is MAVLink's "unknown" for float fields; the reader drops it instead of inventing zeros.
    cols = {n: (_interp(ch[n], t) if n in present else np.full(len(t), np.nan)) for n in names}
    cols["psi"] = wrap_pi(cols["psi"])
    cols["phi"] = wrap_pi(cols["phi"])
    cols["theta"] = wrap_pi(cols["theta"])
    add(t, "ATTITUDE", lambda i: mav.attitude_encode(int(ms[i] % 2**32), *(float(cols[n][i]) for n in names)))


def _global_position(ch, mav, clock, add) -> None:
    if "lat" not in ch or "lon" not in ch:
        return
    t = np.asarray(ch["lat"].t, float)
    lat = ch["lat"].values
    lon = _interp(ch["lon"], t)
    if "sog" in ch and "cog" in ch:
        sog, cog = _interp(ch["sog"], t), _interp(ch["cog"], t)
        vn, ve = sog * np.cos(cog), sog * np.sin(cog)
    elif "u" in ch and "v" in ch and "psi" in ch:
        u, v, psi = _interp(ch["u"], t), _interp(ch["v"], t), _interp(ch["psi"], t)
        # Body (Fossen) to NED: v_n = u cos psi - v sin psi, v_e = u sin psi + v cos psi.
        vn, ve = u * np.cos(psi) - v * np.sin(psi), u * np.sin(psi) + v * np.cos(psi)
    elif len(t) > 1:
        vn = np.gradient(np.radians(lat), t) * _R_EARTH
        ve = np.gradient(np.radians(lon), t) * _R_EARTH * np.cos(np.radians(lat))
    else:
        vn = ve = np.zeros(1)
    hdg = (to_int_field(_cdeg(_interp(ch["psi"], t)), 0, 35999, "GLOBAL_POSITION_INT.hdg (psi)") if "psi" in ch
           else np.full(len(t), _UINT16_MAX))
    ms = clock.ms(t)
    lat_e7 = to_int_field(np.asarray(lat, float) * 1e7, -900_000_000, 900_000_000, "GLOBAL_POSITION_INT.lat (lat)")
    lon_e7 = to_int_field(lon * 1e7, -1_800_000_000, 1_800_000_000, "GLOBAL_POSITION_INT.lon (lon)")
    vx = to_int_field(vn * 100.0, -32768, 32767, "GLOBAL_POSITION_INT.vx (north velocity)")
    vy = to_int_field(ve * 100.0, -32768, 32767, "GLOBAL_POSITION_INT.vy (east velocity)")
    add(t, "GLOBAL_POSITION_INT", lambda i: mav.global_position_int_encode(
        int(ms[i] % 2**32), int(lat_e7[i]), int(lon_e7[i]), 0, 0, int(vx[i]), int(vy[i]), 0, int(hdg[i])))


def _gps_raw(ch, mav, clock, add) -> None:
    if "lat@gps" not in ch or "lon@gps" not in ch:
        return
    t = np.asarray(ch["lat@gps"].t, float)
    lat = to_int_field(ch["lat@gps"].values * 1e7, -900_000_000, 900_000_000, "GPS_RAW_INT.lat (lat@gps)")
    lon = to_int_field(_interp(ch["lon@gps"], t) * 1e7, -1_800_000_000, 1_800_000_000, "GPS_RAW_INT.lon (lon@gps)")
    vel = (to_int_field(_interp(ch["sog@gps"], t) * 100.0, 0, _UINT16_MAX - 1, "GPS_RAW_INT.vel (sog@gps)")
           if "sog@gps" in ch else np.full(len(t), _UINT16_MAX))
    cog = (to_int_field(_cdeg(_interp(ch["cog@gps"], t)), 0, 35999, "GPS_RAW_INT.cog (cog@gps)") if "cog@gps" in ch
           else np.full(len(t), _UINT16_MAX))
    us = clock.us(t)
    # 3D fix, 12 satellites, eph/epv 0.8/1.2 (cm-scaled HDOP/VDOP-like): a good open-water fix.
    add(t, "GPS_RAW_INT", lambda i: mav.gps_raw_int_encode(
        int(us[i]), 3, int(lat[i]), int(lon[i]), 0, 80, 120, int(vel[i]), int(cog[i]), 12))


def _imu(ch, mav, clock, add) -> None:
    acc = [n for n in ("ax", "ay", "az") if n in ch]
    if not acc:
        return
    gyro = []
    for n in ("p", "q", "r"):
        src = f"{n}@imu" if f"{n}@imu" in ch else n
        gyro.append(src if src in ch else None)
    missing = [n for n in ("ax", "ay", "az") if n not in acc] + \
              [f"{n}@imu or {n}" for n, g in zip("pqr", gyro) if g is None]
    if missing:
        raise SimError(f"SCALED_IMU: expected ax, ay, az and gyro rates, found no {', '.join(missing)} "
                       f"(channels present: {sorted(ch)})")
    t = np.asarray(ch["ax"].t, float)
    ms = clock.ms(t)
    a = [to_int_field(_interp(ch[n], t) / G0 * 1000.0, -32768, 32767, f"SCALED_IMU.{x}acc ({n})")
         for n, x in zip(("ax", "ay", "az"), "xyz")]
    g = [to_int_field(_interp(ch[n], t) * 1000.0, -32768, 32767, f"SCALED_IMU.{x}gyro ({n})")
         for n, x in zip(gyro, "xyz")]
    add(t, "SCALED_IMU", lambda i: mav.scaled_imu_encode(
        int(ms[i] % 2**32), int(a[0][i]), int(a[1][i]), int(a[2][i]), int(g[0][i]), int(g[1][i]), int(g[2][i]),
        0, 0, 0))


def _inputs(ch, vessel: Vessel | None, mav, clock, add, mavlink2: bool) -> None:
    inputs = [n for n in INPUT_UNITS if n in ch]
    if not inputs:
        return
    maps: tuple[ActuatorMap, ...] = tuple(vessel.actuators) if vessel is not None else ()
    unmapped = [n for n in inputs if not any(a.target == n for a in maps)]
    if vessel is None:
        raise SimError(f"write_tlog: log has input channels {inputs} but no vessel was given; expected a "
                       "Vessel whose [[actuators]] map them to servo/rc channels")
    if unmapped:
        raise SimError(f"write_tlog: expected an actuator map for input(s) {unmapped} in vessel {vessel.name!r}, "
                       f"found maps only for {sorted({a.target for a in maps}) or 'nothing'}")
    for source, kind, n_max in (("servo", "SERVO_OUTPUT_RAW", _SERVO_CHANNELS[mavlink2]),
                                ("rc", "RC_CHANNELS", _RC_CHANNELS)):
        mine = [a for a in maps if a.source == source and a.target in inputs]
        if not mine:
            continue
        for a in mine:
            if not 1 <= a.channel <= n_max:
                raise SimError(f"{kind}: expected channel 1..{n_max} for {a.target} "
                               f"({'MAVLink 2' if mavlink2 else 'MAVLink 1'}), found channel {a.channel}")
        # Union of the inputs' stamps with a hold: every commanded value appears in the log.
        t = np.unique(np.concatenate([np.asarray(ch[a.target].t, float) for a in mine]))
        n_out = n_max
        pwm = np.zeros((n_out, len(t)), np.int64) if source == "servo" else np.full((n_out, len(t)), _UINT16_MAX)
        for a in mine:
            share = sum(1 for b in mine if b.target == a.target)
            value = _hold(ch[a.target], t) / share
            pwm[a.channel - 1] = to_int_field(a.to_pwm(value), 1, _UINT16_MAX - 1,
                                         f"{kind} channel {a.channel} ({a.target} -> PWM [us])")
        if source == "servo":
            us = clock.us(t) % 2**32  # uint32 field: wraps after 71.6 min of boot time, as on the autopilot
            add(t, kind, lambda i: mav.servo_output_raw_encode(
                int(us[i]), 0, *(int(x) for x in pwm[:, i])))
        else:
            ms = clock.ms(t)
            count = max(a.channel for a in mine)
            add(t, kind, lambda i: mav.rc_channels_encode(
                int(ms[i] % 2**32), count, *(int(x) for x in pwm[:, i]), 255))
