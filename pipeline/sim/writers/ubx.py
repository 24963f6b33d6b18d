"""Write a RawLog as a u-blox UBX binary log (``.ubx``), as u-center or a logging script records it.

Every message is built and framed by pyubx2 (``UBXMessage(cls, id, GET, **fields).serialize()``:
GET is pyubx2's mode for receiver output). pyubx2 takes scaled fields in their physical unit
(``lat``/``lon`` [deg], ``headMot`` [deg], ...) and converts them with ``int(value / scale)``,
which truncates; values are therefore handed over as the intended integer count plus half a
step (:func:`_scaled`) so the file holds the rounded value.

Messages written (in time order; at equal times NAV-PVT, then NAV-RELPOSNED, then ESF-RAW)
------------------------------------------------------------------------------------------
NAV-PVT        at the receiver's position stamps: iTOW [ms], UTC date and time, fixType 3,
               gnssFixOK, carrSoln, numSV, lat/lon [1e-7 deg], velN/velE/gSpeed [mm/s] from
               sog/cog, headMot [1e-5 deg] from cog, hAcc/vAcc [mm], sAcc [mm/s]
NAV-RELPOSNED  (``include_relposned``) moving-base dual-antenna heading at the same epochs:
               relPosHeading [1e-5 deg] from psi, relPosLength [cm] = ``baseline_m``, relPosN/E,
               flags gnssFixOK, diffSoln, relPosValid, carrSoln, isMoving, relPosHeadingValid
ESF-RAW        (``include_esf``) at the IMU stamps: gyro x/y/z [2^-12 deg/s] from p q r (or
               ``p@imu``...), accelerometer x/y/z [2^-10 m/s^2] from ax ay az, gyro temperature
               [0.01 degC]; u-blox ESF axes (x fwd, y left, z up: a receiver mounted aligned), so
               q, r, ay, az are written with their sign changed (see pipeline.ingest.ubx, ESF axes)

Time: ``t = 0`` is the UTC instant ``week_start``; iTOW is GPS time of week [ms] (GPS = UTC +
:data:`GPS_LEAP_S`). The ESF sensor time tag ``sTag`` is written as milliseconds of a
receiver-local clock that started :data:`ESF_TAG_OFFSET_MS` before ``t = 0`` (wrapping at 2^32),
so it is not iTOW: the reader has to place it on GPS time.
"""

from __future__ import annotations

import math
import struct
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Callable

import numpy as np
from pyubx2 import GET, UBXMessage

from ...atomic import atomic_path
from ...errors import SimError
from ...records import Channel, RawLog
from ._sampling import interp_channel as _interp

#: Leap seconds GPS - UTC [s] (constant since 2017-01-01).
GPS_LEAP_S = 18
GPS_EPOCH = datetime(1980, 1, 6, tzinfo=timezone.utc)
WEEK_S = 604800
#: Receiver-local clock of the ESF sensor time tag at t = 0 [ms].
ESF_TAG_OFFSET_MS = 3_600_000
#: ESF data types (u-blox interface description, "ESF measurement data").
ESF_TYPES = {"r": 5, "temp": 12, "q": 13, "p": 14, "ax": 16, "ay": 17, "az": 18}
ESF_GYRO_LSB = 2.0**-12   # [deg/s]
ESF_ACC_LSB = 2.0**-10    # [m/s^2]
_CARR = {"none": 0, "float": 1, "fixed": 2}
_DEFAULT_START = datetime(2024, 5, 5, 10, 0, tzinfo=timezone.utc)
_RANK = {"NAV-PVT": 0, "NAV-RELPOSNED": 1, "ESF-RAW": 2}


def _scaled(count: int, res: float) -> float:
    """A value pyubx2 turns into ``count`` with ``int(value / res)`` (it truncates towards zero)."""
    return (count + (0.5 if count >= 0 else -0.5)) * res


def _gps_seconds(when: datetime) -> float:
    if when.tzinfo is None:
        raise SimError(f"week_start: expected a timezone-aware UTC datetime, found naive {when}")
    return (when - GPS_EPOCH).total_seconds() + GPS_LEAP_S


def _check(name: str, ch: Channel) -> None:
    t = np.asarray(ch.t, float)
    if t.shape != np.asarray(ch.values).shape or t.ndim != 1:
        raise SimError(f"channel {name}: expected t and values of one length, found shapes {t.shape} and "
                       f"{np.asarray(ch.values).shape}")
    if len(t) and (not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0)):
        raise SimError(f"channel {name}: expected finite, strictly increasing t [s], found "
                       f"{int((~np.isfinite(t)).sum())} non-finite and {int((np.diff(t) <= 0).sum())} non-increasing")


def _utc_fields(gps_s: float) -> dict[str, int]:
    """NAV-PVT UTC date/time fields for a GPS time [s since the GPS epoch]."""
    utc = GPS_EPOCH + timedelta(seconds=gps_s - GPS_LEAP_S)
    whole = utc.replace(microsecond=0)
    nano = int(round((utc - whole).total_seconds() * 1e9))
    return {"year": whole.year, "month": whole.month, "day": whole.day, "hour": whole.hour, "min": whole.minute,
            "second": whole.second, "nano": nano}


def _pvt(gps_s: float, lat: float, lon: float, vn: float, ve: float, sog: float, cog: float, carr: int,
         h_acc_mm: int, height_mm: int) -> bytes:
    itow = int(round(gps_s * 1000.0)) % (WEEK_S * 1000)
    lat_i, lon_i = int(round(lat * 1e7)), int(round(lon * 1e7))
    head = int(round(math.degrees(cog % (2 * math.pi)) * 1e5)) % 36_000_000
    return UBXMessage(
        "NAV", "NAV-PVT", GET, iTOW=itow, **_utc_fields(gps_s), validDate=1, validTime=1, fullyResolved=1,
        tAcc=20, fixType=3, gnssFixOk=1, diffSoln=int(carr > 0), carrSoln=carr, confirmedAvai=1, confirmedDate=1,
        confirmedTime=1, numSV=14, lon=_scaled(lon_i, 1e-7), lat=_scaled(lat_i, 1e-7), height=height_mm,
        hMSL=height_mm, hAcc=h_acc_mm, vAcc=2 * h_acc_mm, velN=int(round(vn * 1000)), velE=int(round(ve * 1000)),
        velD=0, gSpeed=int(round(sog * 1000)), headMot=_scaled(head, 1e-5), sAcc=100,
        headAcc=_scaled(50_000, 1e-5), pDOP=_scaled(120, 1e-2),
    ).serialize()


def _relposned(gps_s: float, psi: float, baseline_cm: float, carr: int) -> bytes:
    itow = int(round(gps_s * 1000.0)) % (WEEK_S * 1000)
    heading = int(round(math.degrees(psi % (2 * math.pi)) * 1e5)) % 36_000_000
    parts = {}
    for key, value in (("N", baseline_cm * math.cos(psi)), ("E", baseline_cm * math.sin(psi)), ("D", 0.0),
                       ("Length", baseline_cm)):
        # Whole centimetres plus a high-precision part in 0.1 mm, as the receiver splits them.
        tenth_mm = int(round(value * 100))
        whole = int(math.trunc(tenth_mm / 100))
        parts[f"relPos{key}"] = whole
        parts[f"_HPrelPos{key}"] = _scaled(tenth_mm - 100 * whole, 1e-2)
    return UBXMessage(
        "NAV", "NAV-RELPOSNED", GET, version=1, iTOW=itow, **parts, relPosHeading=_scaled(heading, 1e-5),
        accN=_scaled(10, 0.1), accE=_scaled(10, 0.1), accD=_scaled(20, 0.1), accLength=_scaled(10, 0.1),
        accHeading=_scaled(20_000, 1e-5), gnssFixOK=1, diffSoln=1, relPosValid=1, carrSoln=carr, isMoving=1,
        relPosHeadingValid=int(carr > 0),
    ).serialize()


def _esf_word(kind: str, value: float) -> int:
    lsb = ESF_ACC_LSB if kind.startswith("a") else (0.01 if kind == "temp" else ESF_GYRO_LSB)
    count = int(round(value / lsb))
    if not -(2**23) <= count < 2**23:
        raise SimError(f"ESF-RAW {kind}: expected |value| < {2**23 * lsb:g} (24-bit field), found {value}")
    return (ESF_TYPES[kind] << 24) | (count & 0xFFFFFF)


def _esf(tag_ms: int, values: dict[str, float]) -> bytes:
    # ESF-RAW's repeating group is sized from the payload, so it is built from the packed payload.
    payload = b"\x00" * 4 + b"".join(struct.pack("<II", _esf_word(k, v), tag_ms % 2**32) for k, v in values.items())
    return UBXMessage("ESF", "ESF-RAW", GET, payload=payload).serialize()


def _write(path: str | Path, items: list[tuple[float, int, Callable[[], bytes]]]) -> Path:
    items.sort(key=lambda m: (m[0], m[1]))
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            for _, _, build in items:
                fh.write(build())
    return Path(path)


def write_ubx(log: RawLog, path: str | Path, receiver: str = "", include_relposned: bool = False,
              include_esf: bool = False, week_start: datetime = _DEFAULT_START, *, carr_soln: str | None = None,
              baseline_m: float = 1.0, h_acc_m: float | None = None) -> Path:
    """Write one receiver's channels of ``log`` as a UBX log (atomically: temporary file, then rename).

    Parameters
    ----------
    log : RawLog
        Canonical channels; ``t`` [s] from trial start, SI units and radians.
    path : str or Path
        Output file; its folder is created when missing.
    receiver : str
        Which channels are this receiver's: ``""`` -> ``lat lon sog cog``, ``"gps"`` ->
        ``lat@gps lon@gps sog@gps cog@gps``, any name -> ``...@<name>``. NAV-PVT is written at the
        stamps of ``lat<suffix>``.
    include_relposned : bool
        Also write NAV-RELPOSNED with the heading ``psi`` (interpolated onto the NAV-PVT epochs), as a
        moving-base dual-antenna receiver does.
    include_esf : bool
        Also write ESF-RAW from ``ax ay az`` and ``p q r`` (``p@imu``... preferred) at their stamps.
    week_start : datetime
        UTC time at ``t = 0`` (timezone-aware). It fixes the GPS week and time of week (iTOW) of
        every message; a start late on a Saturday makes iTOW wrap inside the log.
    carr_soln : str, optional
        Carrier-phase solution ``none``, ``float`` or ``fixed`` in NAV-PVT and NAV-RELPOSNED.
        Default ``fixed`` with NAV-RELPOSNED (its heading needs RTK) and ``none`` without.
        NAV-RELPOSNED's relPosHeadingValid is set only for ``float`` and ``fixed``.
    baseline_m : float
        Antenna baseline of the moving-base pair [m].
    h_acc_m : float, optional
        Horizontal accuracy [m]; default 0.02 with RTK, 0.5 without.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    SimError
        The receiver's channels are missing, NAV-RELPOSNED without ``psi``, ESF-RAW without IMU
        channels, a value outside its field, a naive ``week_start`` or an unknown ``carr_soln``.

    Notes
    -----
    Quantisation: iTOW 1 ms, lat/lon 1e-7 deg, speeds 1 mm/s, headMot/relPosHeading 1e-5 deg,
    ESF gyro 2^-12 deg/s and accelerometer 2^-10 m/s^2.
    """
    sfx = f"@{receiver}" if receiver else ""
    for name, ch in log.channels.items():
        _check(name, ch)
    ch = log.channels
    need = [f"lat{sfx}", f"lon{sfx}"]
    if any(n not in ch or not len(ch[n].t) for n in need):
        raise SimError(f"write_ubx: receiver {receiver!r} needs channels {need}, found {sorted(ch)}")
    carr_name = carr_soln or ("fixed" if include_relposned else "none")
    if carr_name not in _CARR:
        raise SimError(f"write_ubx: carr_soln expected one of {sorted(_CARR)}, found {carr_name!r}")
    carr = _CARR[carr_name]
    h_acc_mm = int(round(1000 * (h_acc_m if h_acc_m is not None else (0.02 if carr else 0.5))))
    gps0 = _gps_seconds(week_start)

    t = np.asarray(ch[f"lat{sfx}"].t, float)
    lat = np.asarray(ch[f"lat{sfx}"].values, float)
    lon = _interp(ch[f"lon{sfx}"], t)
    sog = _interp(ch[f"sog{sfx}"], t) if f"sog{sfx}" in ch else np.zeros(len(t))
    cog = _interp(ch[f"cog{sfx}"], t) if f"cog{sfx}" in ch else np.zeros(len(t))
    for what, arr, lim in (("lat", lat, 90.0), ("lon", lon, 180.0), ("sog", sog, 2000.0)):
        if not np.all(np.isfinite(arr)) or np.any(np.abs(arr) > lim):
            raise SimError(f"write_ubx: {what}{sfx} expected finite and |value| <= {lim}, found "
                           f"{np.nanmin(arr)}..{np.nanmax(arr)}")
    vn, ve = sog * np.cos(cog), sog * np.sin(cog)
    items: list[tuple[float, int, Callable[[], bytes]]] = []
    for i in range(len(t)):
        items.append((float(t[i]), _RANK["NAV-PVT"],
                      lambda i=i: _pvt(gps0 + t[i], lat[i], lon[i], vn[i], ve[i], sog[i], cog[i], carr, h_acc_mm, 0)))
    if include_relposned:
        if "psi" not in ch or not len(ch["psi"].t):
            raise SimError(f"write_ubx: NAV-RELPOSNED needs a heading channel 'psi', found {sorted(ch)}")
        psi = _interp(ch["psi"], t)
        for i in range(len(t)):
            items.append((float(t[i]), _RANK["NAV-RELPOSNED"],
                          lambda i=i: _relposned(gps0 + t[i], psi[i], baseline_m * 100.0, carr)))
    if include_esf:
        items += _esf_items(ch)
    return _write(path, items)


def _esf_items(ch) -> list[tuple[float, int, Callable[[], bytes]]]:
    names = {}
    for n in ("p", "q", "r"):
        src = f"{n}@imu" if f"{n}@imu" in ch else n
        names[n] = src
    names.update({n: n for n in ("ax", "ay", "az")})
    missing = [src for src in names.values() if src not in ch or not len(ch[src].t)]
    if missing:
        raise SimError(f"write_ubx: ESF-RAW needs IMU channels, found no {missing} (channels: {sorted(ch)})")
    t = np.asarray(ch["ax"].t, float)
    vals = {n: _interp(ch[src], t) for n, src in names.items()}
    # p, q, r [rad/s] are written in deg/s, the ESF gyro unit.
    gyro = {n: np.degrees(vals[n]) for n in ("p", "q", "r")}
    tags = np.round(t * 1000.0).astype(np.int64) + ESF_TAG_OFFSET_MS
    items: list[tuple[float, int, Callable[[], bytes]]] = []
    for i in range(len(t)):
        def build(i: int = i) -> bytes:
            # Fossen body axes (y starboard, z down) -> u-blox ESF axes (y left, z up).
            return _esf(int(tags[i]), {"temp": 31.5, "p": gyro["p"][i], "q": -gyro["q"][i], "r": -gyro["r"][i],
                                       "ax": vals["ax"][i], "ay": -vals["ay"][i], "az": -vals["az"][i]})
        items.append((float(t[i]), _RANK["ESF-RAW"], build))
    return items


def write_ubx_base(path: str | Path, duration: float, lat: float, lon: float, *, height_m: float = 0.0,
                   week_start: datetime = _DEFAULT_START, rate: float = 1.0) -> Path:
    """Write the UBX log of a static RTK base station: NAV-PVT at ``rate`` (no RTCM, UBX only).

    Parameters
    ----------
    path : str or Path
        Output file.
    duration : float
        Length of the log [s]; epochs at ``0, 1/rate, ...`` up to ``duration``.
    lat, lon : float
        Base position [deg].
    height_m : float
        Height above the ellipsoid [m].
    week_start : datetime
        UTC time at ``t = 0`` (timezone-aware), as in :func:`write_ubx`.
    rate : float
        Navigation rate [Hz].

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    SimError
        Non-positive duration or rate, a position out of range or a naive ``week_start``.
    """
    if not (duration > 0 and rate > 0):
        raise SimError(f"write_ubx_base: expected positive duration [s] and rate [Hz], found {duration}, {rate}")
    if not (abs(lat) <= 90 and abs(lon) <= 180):
        raise SimError(f"write_ubx_base: expected lat in [-90, 90] and lon in [-180, 180] deg, found {lat}, {lon}")
    gps0 = _gps_seconds(week_start)
    t = np.arange(0.0, duration + 1e-9, 1.0 / rate)
    h_mm = int(round(height_m * 1000))
    items: list[tuple[float, int, Callable[[], bytes]]] = [
        (float(ti), 0, lambda ti=ti: _pvt(gps0 + ti, lat, lon, 0.0, 0.0, 0.0, 0.0, 0, 14, h_mm)) for ti in t]
    return _write(path, items)


__all__ = ["write_ubx", "write_ubx_base", "GPS_LEAP_S", "ESF_TAG_OFFSET_MS", "ESF_TYPES"]
