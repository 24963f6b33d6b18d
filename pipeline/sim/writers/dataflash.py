"""Write a RawLog as an ArduPilot DataFlash binary log (``.bin``), as the autopilot's SD card holds it.

pymavlink reads DataFlash logs but does not write them, so the records are packed here. The format
is self-describing: every record is ``A3 95 <type id>`` followed by the fields packed little-endian
as its FMT record says; FMT itself is type 128 with format ``BBnNZ`` (Type, Length, Name, Format,
Columns). Field codes and scales are pymavlink's (``DFReader.FORMAT_TO_STRUCT``): ``c``/``C``
int16/uint16 x100, ``e``/``E`` int32/uint32 x100, ``L`` int32 degE7, ``Q`` uint64, ``f`` float32, ...
UNIT, MULT and FMTU records carry ArduPilot's units and multipliers (FMTU marks the instance
field with ``#``), so MAVExplorer and pymavlink show the units as for a real log.

Messages written (formats and columns of ArduPilot 4.x ``LogStructure.h``; each message at the
timestamps of the channels it carries, other channels interpolated onto them)
----------------------------------------------------------------------------------------------
ATT    ``QccccCCCCB``  Roll, Pitch [cdeg], Yaw [cdeg 0..360) from phi, theta, psi (a missing
       angle is written 0: ArduPilot always logs all three)
IMU    ``QBffffffIIfBBHH``  I=0: GyrX/Y/Z [rad/s] from ``p@imu``/``p`` ..., AccX/Y/Z [m/s^2] from
       ax ay az; I=1: the same samples plus :data:`IMU2_GYRO_BIAS` / :data:`IMU2_ACCEL_BIAS`
       (a second IMU on the same board). Missing fields are NaN.
GPS    ``QBBIHBcLLeffffB``  the modern form with an instance field ``I`` (ArduPilot >= 4.1; older
       logs have separate GPS and GPS2 messages, which :func:`pipeline.ingest.dataflash.read_dataflash`
       also reads). I=0 from ``lat@gps lon@gps sog@gps cog@gps`` (raw receiver), or from
       ``lat lon sog cog`` when the log has no ``@gps`` channels; I=1 from ``...@gps2``.
       Status 3 (3D fix), GMS/GWk on the GPS clock of ``gps_start``.
POS    ``QLLfff``  Lat, Lng [degE7] from ``lat lon`` (the navigation filter's position)
XKF1   ``QBccCfffffffccce``  core C=0: VN, VE [m/s] from ``sog``/``cog`` (navigation velocity),
       Roll/Pitch/Yaw from phi/theta/psi, PN/PE [m] from lat/lon relative to the first sample
RCOU   ``QHHHHHHHHHHHHHH``  C1..C14 [us] through the vessel's actuator maps with source ``servo``
RCIN   ``QHHHHHHHHHHHHHH``  C1..C14 [us] through the actuator maps with source ``rc``
MSG    one firmware banner, as ArduPilot writes at boot

Channels not listed (``u``, ``v``, ``x_n``, ...) are not written: ArduPilot does not log them.
Records are written in time order (TimeUS, then the order above), as the autopilot's logger does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Mapping

import numpy as np
from pymavlink.DFReader import FORMAT_TO_STRUCT

from ...atomic import atomic_path
from ...errors import SimError
from ...geo import latlon_to_ned
from ...records import INPUT_UNITS, Channel, RawLog
from ...vessel import ActuatorMap, Vessel
from ._sampling import check_channel, hold_channel as _hold, interp_channel as _interp, to_int_field

HEAD1, HEAD2 = 0xA3, 0x95
FMT_TYPE = 128
#: Bias of IMU instance 1 relative to instance 0: gyro [rad/s] and accelerometer [m/s^2], body x y z.
IMU2_GYRO_BIAS = (0.001, -0.0015, 0.0005)
IMU2_ACCEL_BIAS = (0.02, -0.03, 0.04)
#: Leap seconds GPS - UTC [s] (constant since 2017-01-01).
GPS_LEAP_S = 18
GPS_EPOCH = datetime(1980, 1, 6, tzinfo=timezone.utc)
_WEEK_S = 604800
_DEFAULT_GPS_START = datetime(2024, 5, 5, 10, 0, tzinfo=timezone.utc)
_UINT16_MAX = 65535
_N_PWM = 14


@dataclass(frozen=True)
class _Def:
    """One message definition: id, FMT format and columns, FMTU unit and multiplier ids."""

    type: int
    name: str
    format: str
    columns: str
    units: str
    mults: str


#: Message definitions, in the order records of equal TimeUS are written.
DEFINITIONS: Mapping[str, _Def] = {d.name: d for d in (
    _Def(FMT_TYPE, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns", "-----", "-----"),
    _Def(177, "UNIT", "QbZ", "TimeUS,Id,Label", "s--", "F--"),
    _Def(178, "MULT", "Qbd", "TimeUS,Id,Mult", "s--", "F--"),
    _Def(179, "FMTU", "QBNN", "TimeUS,FmtType,UnitIds,MultIds", "s---", "F---"),
    _Def(91, "MSG", "QZ", "TimeUS,Message", "s-", "F-"),
    _Def(35, "ATT", "QccccCCCCB", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw,AEKF",
         "sddddhhdh-", "FBBBBBBBB-"),
    _Def(36, "IMU", "QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz",
         "s#EEEooo--O--zz", "F-000000-----00"),
    _Def(37, "GPS", "QBBIHBcLLeffffB", "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw,U",
         "s#-s-S-DUmnhnh-", "F--C-0BGGB000--"),
    _Def(38, "POS", "QLLfff", "TimeUS,Lat,Lng,Alt,RelHomeAlt,RelOriginAlt", "sDUmmm", "FGG000"),
    _Def(39, "XKF1", "QBccCfffffffccce", "TimeUS,C,Roll,Pitch,Yaw,VN,VE,VD,dPD,PN,PE,PD,GX,GY,GZ,OH",
         "s#ddhnnnnmmmkkkm", "F-BBB0000000BBBB"),
    _Def(40, "RCOU", "Q" + "H" * _N_PWM, "TimeUS," + ",".join(f"C{i}" for i in range(1, _N_PWM + 1)),
         "s" + "Y" * _N_PWM, "F" + "-" * _N_PWM),
    _Def(41, "RCIN", "Q" + "H" * _N_PWM, "TimeUS," + ",".join(f"C{i}" for i in range(1, _N_PWM + 1)),
         "s" + "Y" * _N_PWM, "F" + "-" * _N_PWM),
)}
#: ArduPilot's unit ids (AP_Logger/LogStructure.h) used by the definitions above.
UNITS: Mapping[str, str] = {
    "-": "", "#": "instance", "s": "s", "d": "deg", "h": "degheading", "E": "rad/s", "o": "m/s/s",
    "O": "degC", "z": "Hz", "S": "satellites", "D": "deglatitude", "U": "deglongitude", "m": "m",
    "n": "m/s", "k": "deg/s", "Y": "PWM",
}
#: ArduPilot's multiplier ids used above ('-' no multiplier, '?' unknown).
MULTS: Mapping[str, float] = {"-": 0.0, "?": 1.0, "0": 1.0, "B": 1e-2, "C": 1e-3, "F": 1e-6, "G": 1e-7}

#: struct code (pymavlink's FORMAT_TO_STRUCT) -> little-endian numpy type.
_NUMPY_OF_STRUCT = {"b": "i1", "B": "u1", "h": "<i2", "H": "<u2", "i": "<i4", "I": "<u4", "q": "<i8",
                    "Q": "<u8", "f": "<f4", "d": "<f8", "e": "<f2", "4s": "S4", "16s": "S16", "64s": "S64"}


def record_dtype(fmt: str, columns: str) -> np.dtype:
    """Packed numpy dtype of one record (3-byte header + fields) for a DataFlash format string.

    Parameters
    ----------
    fmt : str
        DataFlash format characters, one per field (pymavlink's ``FORMAT_TO_STRUCT`` keys).
    columns : str
        Comma-separated field names, one per character of ``fmt``.
    """
    names = ["_h1", "_h2", "_id"] + columns.split(",")
    types = ["u1", "u1", "u1"] + [_NUMPY_OF_STRUCT[FORMAT_TO_STRUCT[c][0]] for c in fmt]
    return np.dtype({"names": names, "formats": types})


def write_dataflash(log: RawLog, path: str | Path, vessel: Vessel | None = None, boot_offset_s: float = 5.0,
                    *, gps_start: datetime = _DEFAULT_GPS_START, firmware: str = "ArduRover V4.5.7") -> Path:
    """Write ``log`` as an ArduPilot DataFlash ``.bin`` (atomically: temporary file, then rename).

    Parameters
    ----------
    log : RawLog
        Canonical channels; ``t`` [s] from trial start, SI units and radians.
    path : str or Path
        Output file; its folder is created when missing.
    vessel : Vessel, optional
        Its ``actuators`` map inputs to PWM (``ActuatorMap.to_pwm``). Required when ``log`` has
        input channels. Several maps with one target in one message share the value equally
        (twin thrusters); the reader adds them back up.
    boot_offset_s : float
        Autopilot boot time at ``t = 0`` [s]: ``TimeUS = round((t + boot_offset_s) * 1e6)``.
    gps_start : datetime
        UTC time at ``t = 0`` (timezone-aware), for the GPS week and time of week (GWk, GMS).
    firmware : str
        Banner of the MSG record (``ArduRover`` makes pymavlink treat the log as a rover).

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    SimError
        Inputs without a vessel or without an actuator map, a channel whose ``t`` is not
        strictly increasing, a value outside its field, nothing to write, or a naive ``gps_start``.

    Notes
    -----
    Quantisation: TimeUS 1 us; ATT and XKF1 angles 0.01 deg; GPS/POS lat/lon 1e-7 deg; PWM 1 us;
    IMU, speeds and course are float32.
    """
    if gps_start.tzinfo is None:
        raise SimError(f"write_dataflash: expected a timezone-aware gps_start, found naive {gps_start}")
    if not math.isfinite(boot_offset_s) or boot_offset_s < 0:
        raise SimError(f"write_dataflash: expected boot_offset_s >= 0 [s], found {boot_offset_s}")
    ch = dict(log.channels)
    for name, c in ch.items():
        check_channel(name, c)
    ch = {k: c for k, c in ch.items() if len(c.t)}
    clock = _Clock(boot_offset_s, gps_start)
    tables: list[tuple[str, np.ndarray, np.ndarray]] = []  # (message, TimeUS, packed records)

    def add(name: str, t: np.ndarray, cols: Mapping[str, np.ndarray]) -> None:
        d = DEFINITIONS[name]
        tus = clock.us(t)
        rec = np.zeros(len(t), record_dtype(d.format, d.columns))
        rec["_h1"], rec["_h2"], rec["_id"] = HEAD1, HEAD2, d.type
        rec["TimeUS"] = tus
        for col, values in cols.items():
            rec[col] = values
        tables.append((name, tus, rec))

    _attitude(ch, add)
    _imu(ch, add)
    _gps(ch, clock, add)
    _pos_and_ekf(ch, add)
    _inputs(ch, vessel, add)
    if not tables:
        raise SimError(f"write_dataflash: nothing to write; expected attitude, IMU, position or input channels, "
                       f"found {sorted(log.channels)}")

    t_first = min(float(tus[0]) for _, tus, _ in tables)
    body = _merge(tables)
    head = _header(int(t_first), firmware)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(head)
            fh.write(body)
    return Path(path)


# ----------------------------------------------------------------------------- helpers
class _Clock:
    """Autopilot boot clock and GPS clock for a trial time ``t`` [s]."""

    def __init__(self, boot_offset_s: float, gps_start: datetime) -> None:
        self.boot_offset_s = float(boot_offset_s)
        # GPS seconds since the GPS epoch at t = 0 (GPS runs ahead of UTC by the leap seconds).
        self.gps0 = (gps_start - GPS_EPOCH).total_seconds() + GPS_LEAP_S

    def us(self, t: np.ndarray) -> np.ndarray:
        us = np.round((np.asarray(t, float) + self.boot_offset_s) * 1e6)
        if us.size and us.min() < 0:
            raise SimError(f"TimeUS: expected t + boot_offset_s >= 0, found {us.min() * 1e-6} s")
        return us.astype(np.uint64)

    def gps(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """GPS week and milliseconds of week at ``t``."""
        ms = np.round((self.gps0 + np.asarray(t, float)) * 1000.0).astype(np.int64)
        return ms // (_WEEK_S * 1000), ms % (_WEEK_S * 1000)


def _cdeg_signed(angle: np.ndarray, what: str) -> np.ndarray:
    """Angle [rad] wrapped to (-180, 180] deg, in centidegrees (int16 ``c`` fields)."""
    a = math.pi - np.mod(math.pi - np.asarray(angle, float), 2 * math.pi)
    return to_int_field(np.degrees(a) * 100.0, -18000, 18000, what)


def _cdeg_heading(angle: np.ndarray, what: str) -> np.ndarray:
    """Angle [rad] as 0..35999 centidegrees (uint16 ``C`` heading fields)."""
    return np.mod(to_int_field(np.degrees(np.mod(angle, 2 * math.pi)) * 100.0, 0, 36000, what), 36000)


def _first(ch: Mapping[str, Channel], *names: str) -> Channel | None:
    for n in names:
        if n in ch:
            return ch[n]
    return None


def _attitude(ch, add) -> None:
    present = [n for n in ("phi", "theta", "psi") if n in ch]
    if not present:
        return
    t = np.asarray(ch[present[0]].t, float)
    ang = {n: (_interp(ch[n], t) if n in ch else np.zeros(len(t))) for n in ("phi", "theta", "psi")}
    roll = _cdeg_signed(ang["phi"], "ATT.Roll (phi)")
    pitch = _cdeg_signed(ang["theta"], "ATT.Pitch (theta)")
    yaw = _cdeg_heading(ang["psi"], "ATT.Yaw (psi)")
    add("ATT", t, {"DesRoll": roll, "Roll": roll, "DesPitch": pitch, "Pitch": pitch, "DesYaw": yaw, "Yaw": yaw,
                   "AEKF": 3})


def _imu(ch, add) -> None:
    acc = [ch.get(n) for n in ("ax", "ay", "az")]
    gyro = [_first(ch, f"{n}@imu", n) for n in ("p", "q", "r")]
    base = next((c for c in acc + gyro if c is not None), None)
    if base is None:
        return
    t = np.asarray(base.t, float)
    # NaN marks a field the simulated IMU did not measure; the reader drops it.
    a = [(_interp(c, t) if c is not None else np.full(len(t), np.nan)) for c in acc]
    g = [(_interp(c, t) if c is not None else np.full(len(t), np.nan)) for c in gyro]
    rate = float(round(1.0 / np.median(np.diff(t)))) if len(t) > 1 else 0.0
    for inst, (gb, ab) in enumerate((((0.0,) * 3, (0.0,) * 3), (IMU2_GYRO_BIAS, IMU2_ACCEL_BIAS))):
        add("IMU", t, {"I": inst, "GyrX": g[0] + gb[0], "GyrY": g[1] + gb[1], "GyrZ": g[2] + gb[2],
                       "AccX": a[0] + ab[0], "AccY": a[1] + ab[1], "AccZ": a[2] + ab[2],
                       "T": 25.0 + 3.0 * inst, "GH": 1, "AH": 1, "GHz": rate, "AHz": rate})


def _gps(ch, clock: _Clock, add) -> None:
    primary = "@gps" if "lat@gps" in ch and "lon@gps" in ch else ""
    for inst, sfx in ((0, primary), (1, "@gps2")):
        if f"lat{sfx}" not in ch or f"lon{sfx}" not in ch:
            continue
        t = np.asarray(ch[f"lat{sfx}"].t, float)
        lat = to_int_field(np.asarray(ch[f"lat{sfx}"].values, float) * 1e7, -900_000_000, 900_000_000,
                      f"GPS[{inst}].Lat (lat{sfx})")
        lon = to_int_field(_interp(ch[f"lon{sfx}"], t) * 1e7, -1_800_000_000, 1_800_000_000, f"GPS[{inst}].Lng (lon{sfx})")
        spd = _interp(ch[f"sog{sfx}"], t) if f"sog{sfx}" in ch else np.full(len(t), np.nan)
        crs = (np.degrees(np.mod(_interp(ch[f"cog{sfx}"], t), 2 * math.pi)) if f"cog{sfx}" in ch
               else np.full(len(t), np.nan))
        week, ms = clock.gps(t)
        add("GPS", t, {"I": inst, "Status": 3, "GMS": ms, "GWk": week, "NSats": 12, "HDop": 80, "Lat": lat,
                       "Lng": lon, "Alt": 0, "Spd": spd, "GCrs": crs, "VZ": 0.0, "Yaw": 0.0, "U": 1})


def _pos_and_ekf(ch, add) -> None:
    if "lat" in ch and "lon" in ch:
        t = np.asarray(ch["lat"].t, float)
        lat = to_int_field(np.asarray(ch["lat"].values, float) * 1e7, -900_000_000, 900_000_000, "POS.Lat (lat)")
        lon = to_int_field(_interp(ch["lon"], t) * 1e7, -1_800_000_000, 1_800_000_000, "POS.Lng (lon)")
        add("POS", t, {"Lat": lat, "Lng": lon, "Alt": 0.0, "RelHomeAlt": 0.0, "RelOriginAlt": 0.0})
    if "sog" not in ch or "cog" not in ch:
        return
    t = np.asarray(ch["sog"].t, float)
    sog, cog = _interp(ch["sog"], t), _interp(ch["cog"], t)
    cols: dict[str, np.ndarray | float | int] = {"C": 0, "VN": sog * np.cos(cog), "VE": sog * np.sin(cog), "VD": 0.0}
    for field, name in (("Roll", "phi"), ("Pitch", "theta")):
        cols[field] = _cdeg_signed(_interp(ch[name], t), f"XKF1.{field} ({name})") if name in ch else 0
    cols["Yaw"] = _cdeg_heading(_interp(ch["psi"], t), "XKF1.Yaw (psi)") if "psi" in ch else 0
    if "lat" in ch and "lon" in ch:
        lat, lon = _interp(ch["lat"], t), _interp(ch["lon"], t)
        cols["PN"], cols["PE"] = latlon_to_ned(lat, lon, float(lat[0]), float(lon[0]))
    add("XKF1", t, cols)


def _inputs(ch, vessel: Vessel | None, add) -> None:
    inputs = [n for n in INPUT_UNITS if n in ch]
    if not inputs:
        return
    if vessel is None:
        raise SimError(f"write_dataflash: log has input channels {inputs} but no vessel was given; expected a "
                       "Vessel whose [[actuators]] map them to servo/rc channels")
    maps: tuple[ActuatorMap, ...] = tuple(vessel.actuators)
    unmapped = [n for n in inputs if not any(a.target == n for a in maps)]
    if unmapped:
        raise SimError(f"write_dataflash: expected an actuator map for input(s) {unmapped} in vessel "
                       f"{vessel.name!r}, found maps only for {sorted({a.target for a in maps}) or 'nothing'}")
    for source, name in (("servo", "RCOU"), ("rc", "RCIN")):
        mine = [a for a in maps if a.source == source and a.target in inputs]
        if not mine:
            continue
        for a in mine:
            if not 1 <= a.channel <= _N_PWM:
                raise SimError(f"{name}: expected channel 1..{_N_PWM} for {a.target}, found channel {a.channel}")
        # Union of the inputs' stamps with a hold: every commanded value appears in the log.
        t = np.unique(np.concatenate([np.asarray(ch[a.target].t, float) for a in mine]))
        cols: dict[str, np.ndarray] = {}
        for a in mine:
            share = sum(1 for b in mine if b.target == a.target)
            cols[f"C{a.channel}"] = to_int_field(a.to_pwm(_hold(ch[a.target], t) / share), 1, _UINT16_MAX - 1,
                                            f"{name}.C{a.channel} ({a.target} -> PWM [us])")
        add(name, t, cols)


def _merge(tables: list[tuple[str, np.ndarray, np.ndarray]]) -> bytes:
    """Interleave the per-message record tables in (TimeUS, definition order) order, vectorised."""
    rank = {name: i for i, name in enumerate(DEFINITIONS)}
    tus = np.concatenate([t for _, t, _ in tables])
    ranks = np.concatenate([np.full(len(t), rank[n] * 2 + (int(r["I"][0]) if "I" in r.dtype.names and len(r) else 0))
                            for n, t, r in tables])
    which = np.concatenate([np.full(len(t), k) for k, (_, t, _) in enumerate(tables)])
    within = np.concatenate([np.arange(len(t)) for _, t, _ in tables])
    order = np.lexsort((within, ranks, tus))
    sizes = np.array([r.dtype.itemsize for _, _, r in tables])
    rec_len = sizes[which[order]]
    start = np.concatenate([[0], np.cumsum(rec_len)[:-1]])
    out = np.empty(int(rec_len.sum()), np.uint8)
    pos_of = np.empty(len(order), np.int64)
    pos_of[order] = start
    first = 0
    for k, (_, t, r) in enumerate(tables):
        rows = r.view(np.uint8).reshape(len(r), r.dtype.itemsize)
        pos = pos_of[first:first + len(t)]
        out[pos[:, None] + np.arange(r.dtype.itemsize)] = rows
        first += len(t)
    return out.tobytes()


def _pack(name: str, values: Mapping[str, object]) -> bytes:
    d = DEFINITIONS[name]
    rec = np.zeros(1, record_dtype(d.format, d.columns))
    rec["_h1"], rec["_h2"], rec["_id"] = HEAD1, HEAD2, d.type
    for k, v in values.items():
        rec[k] = v
    return rec.tobytes()


def _header(t_us: int, firmware: str) -> bytes:
    """FMT for every type, then UNIT, MULT, FMTU and the firmware banner, as ArduPilot starts a log."""
    parts = []
    for d in DEFINITIONS.values():
        length = record_dtype(d.format, d.columns).itemsize
        parts.append(_pack("FMT", {"Type": d.type, "Length": length, "Name": d.name.encode(),
                                   "Format": d.format.encode(), "Columns": d.columns.encode()}))
    for uid, label in UNITS.items():
        parts.append(_pack("UNIT", {"TimeUS": t_us, "Id": ord(uid), "Label": label.encode()}))
    for mid, mult in MULTS.items():
        parts.append(_pack("MULT", {"TimeUS": t_us, "Id": ord(mid), "Mult": mult}))
    for d in DEFINITIONS.values():
        if d.name != "FMT":
            parts.append(_pack("FMTU", {"TimeUS": t_us, "FmtType": d.type, "UnitIds": d.units.encode(),
                                        "MultIds": d.mults.encode()}))
    parts.append(_pack("MSG", {"TimeUS": t_us, "Message": f"{firmware} (vesselid simulator)".encode()}))
    return b"".join(parts)


__all__ = ["write_dataflash", "DEFINITIONS", "IMU2_GYRO_BIAS", "IMU2_ACCEL_BIAS", "record_dtype"]
