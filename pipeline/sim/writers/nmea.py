"""Write a RawLog as an NMEA 0183 log, the file a GNSS receiver's serial logger saves.

Each epoch gives, in the order a receiver sends them (timed sentences first, so the untimed ones
belong to that epoch for :func:`pipeline.ingest.nmea.read_nmea`):

GGA  UTC time, lat, lon (ddmm.mmmmmmm, 0.2 mm resolution), fix quality, satellites, HDOP
RMC  UTC time, status A, lat, lon, speed [knots], course [deg true], date
VTG  course [deg true], speed [knots] and [km/h], mode A
HDT  true heading [deg] (only when the log has ``psi``)

Values are taken from the channels with the chosen sensor suffix (``lat@gps`` ...), interpolated
onto the epochs where their samples are not on them (angles unwrapped first); a channel that is
missing, or NaN at an epoch, leaves its fields empty there, as a receiver without that solution
does. Each line ends with CR LF and a correct ``*hh`` checksum.
"""

from __future__ import annotations

import math
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np

from ...atomic import atomic_path
from ...errors import SimError
from ...ingest.nmea import nmea_checksum
from ...records import RawLog

_DEFAULT_START = datetime(2024, 5, 5, 10, 0, tzinfo=timezone.utc)
_KNOT = 1852.0 / 3600.0  # [m/s] per knot
#: Minute decimals of lat/lon: 1e-7 min is 0.19 mm, finer than any receiver reports.
_MIN_DECIMALS = 7


def _channel(log: RawLog, base: str, suffix: str):
    return log.channels.get(base + suffix)


def _on(times: np.ndarray, ch, angle: bool = False) -> np.ndarray:
    """Channel values at ``times``: exact where the samples are there, else interpolated; NaN outside."""
    if ch is None or len(ch.t) == 0:
        return np.full(len(times), np.nan)
    t, v = np.asarray(ch.t, float), np.asarray(ch.values, float)
    if len(t) == len(times) and np.array_equal(t, times):
        return v.copy()
    ok = np.isfinite(v)
    t, v = t[ok], v[ok]
    if len(t) == 0:
        return np.full(len(times), np.nan)
    out = np.interp(times, t, np.unwrap(v) if angle else v)
    out[(times < t[0] - 1e-9) | (times > t[-1] + 1e-9)] = np.nan
    return out


def _latlon(value: float, width: int, pos: str, neg: str) -> tuple[str, str]:
    if not math.isfinite(value):
        return "", ""
    # Integer arithmetic in 1e-7 minutes so that 59.99999995 min never prints as 60.0000000.
    scale = 10 ** _MIN_DECIMALS
    total = int(round(abs(value) * 60 * scale))
    deg, rest = divmod(total, 60 * scale)
    minutes, frac = divmod(rest, scale)
    return f"{deg:0{width}d}{minutes:02d}.{frac:0{_MIN_DECIMALS}d}", (pos if value >= 0 else neg)


def _num(value: float, fmt: str) -> str:
    return format(value, fmt) if math.isfinite(value) else ""


def _sentence(talker: str, sid: str, fields: list[str]) -> str:
    body = f"{talker}{sid}," + ",".join(fields)
    return f"${body}*{nmea_checksum(body.encode('ascii')):02X}"


def write_nmea(log: RawLog, path: str | Path, talker: str = "GP", rate_hz: float | None = None,
               with_pc_time: bool = False, *, sensor: str | None = None,
               start: datetime = _DEFAULT_START, quality: int = 1, num_sv: int = 10, hdop: float = 0.9,
               pc_latency: float = 0.05) -> Path:
    """Write ``log`` as an NMEA 0183 log (atomically: temporary file, then ``os.replace``).

    Parameters
    ----------
    log : RawLog
        Channels ``lat``, ``lon`` [deg], ``sog`` [m/s], ``cog`` [rad], ``psi`` [rad] (any subset
        with a position or a speed), with ``@sensor`` suffix when ``sensor`` is given.
    path : str or Path
        Output file.
    talker : str
        Two-character talker id (``GP``, ``GN``, ``GL``, ...), used for every sentence.
    rate_hz : float, optional
        Epoch rate [Hz]; default one epoch per sample of the position channel (or of ``sog`` when
        there is no position).
    with_pc_time : bool
        Prefix each line with a PC timestamp column (``2024-05-05 10:00:00.050<TAB>``), as many
        serial loggers do; the reader ignores it.
    sensor : str, optional
        Suffix of the channels to write (``"gps"`` -> ``lat@gps`` ...); default the unsuffixed
        channels when present, else the first suffix that has a position. ``psi`` falls back to
        the unsuffixed heading.
    start : datetime
        UTC date and time of ``t = 0`` [timezone-aware].
    quality, num_sv, hdop : int, int, float
        GGA fix quality (1 GPS, 2 DGPS, 4 RTK fixed), satellites used and HDOP to report.
    pc_latency : float
        Delay of the PC timestamp behind the fix time [s] (``with_pc_time`` only).

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    SimError
        Malformed talker or rate, a naive ``start``, or no position or speed channel to write.
    """
    if not (len(talker) == 2 and talker.isalnum() and talker.isupper() and talker[0] != "P"):
        raise SimError(f"talker: expected two upper-case characters such as 'GP' or 'GN', found {talker!r}")
    if rate_hz is not None and not rate_hz > 0:
        raise SimError(f"rate_hz: expected a positive rate [Hz] or None, found {rate_hz}")
    if start.tzinfo is None:
        raise SimError(f"start: expected a timezone-aware UTC datetime, found naive {start!r}")
    if sensor is None:
        candidates = [""] + sorted({n.partition("@")[2] for n in log.channels if "@" in n})
        sensor = next((s for s in candidates if f"lat{'@' + s if s else ''}" in log.channels),
                      next((s for s in candidates if f"sog{'@' + s if s else ''}" in log.channels), ""))
    suffix = f"@{sensor}" if sensor else ""
    lat_ch, lon_ch = _channel(log, "lat", suffix), _channel(log, "lon", suffix)
    sog_ch, cog_ch = _channel(log, "sog", suffix), _channel(log, "cog", suffix)
    psi_ch = _channel(log, "psi", suffix) or _channel(log, "psi", "")
    clock_ch = lat_ch if lat_ch is not None else sog_ch
    if clock_ch is None or len(clock_ch.t) == 0:
        raise SimError(f"{log.source}: expected lat{suffix}/lon{suffix} or sog{suffix} to write NMEA, found "
                       f"channels {sorted(log.channels)}")
    if rate_hz is None:
        times = np.asarray(clock_ch.t, float)
    else:
        times = np.arange(float(clock_ch.t[0]), float(clock_ch.t[-1]) + 1e-9, 1.0 / rate_hz)

    lat = _on(times, lat_ch)
    lon = _on(times, lon_ch)
    sog = _on(times, sog_ch)
    cog = np.mod(np.degrees(_on(times, cog_ch, angle=True)), 360.0)
    psi = np.mod(np.degrees(_on(times, psi_ch, angle=True)), 360.0) if psi_ch is not None else None

    # Centisecond stamps as receivers print them, milliseconds when the epochs need them.
    start_day = datetime(start.year, start.month, start.day, tzinfo=timezone.utc)
    start_s = (start.astimezone(timezone.utc) - start_day).total_seconds()
    centi = np.abs(times * 100 - np.round(times * 100)) < 1e-6
    decimals = 2 if bool(np.all(centi)) else 3
    ticks = np.round((start_s + times) * 10 ** decimals).astype(np.int64)

    lines: list[str] = []
    for k in range(len(times)):
        day, tick = divmod(int(ticks[k]), 86400 * 10 ** decimals)
        secs, frac = divmod(tick, 10 ** decimals)
        hh, rem = divmod(secs, 3600)
        mm, ss = divmod(rem, 60)
        hms = f"{hh:02d}{mm:02d}{ss:02d}.{frac:0{decimals}d}"
        when = start_day + timedelta(days=day)
        la, ns = _latlon(lat[k], 2, "N", "S")
        lo, ew = _latlon(lon[k], 3, "E", "W")
        fix = bool(la and lo)
        kn = sog[k] / _KNOT
        epoch = [
            _sentence(talker, "GGA", [hms, la, ns, lo, ew, str(quality if fix else 0),
                                      f"{num_sv:02d}" if fix else "00", _num(hdop, ".1f") if fix else "",
                                      "0.0" if fix else "", "M" if fix else "", "", "", "", ""]),
            _sentence(talker, "RMC", [hms, "A" if fix else "V", la, ns, lo, ew, _num(kn, ".3f"),
                                      _num(cog[k], ".2f"), when.strftime("%d%m%y"), "", "",
                                      "A" if fix else "N"]),
            _sentence(talker, "VTG", [_num(cog[k], ".2f"), "T", "", "M", _num(kn, ".3f"), "N",
                                      _num(sog[k] * 3.6, ".3f"), "K", "A" if math.isfinite(sog[k]) else "N"]),
        ]
        if psi is not None and math.isfinite(psi[k]):
            epoch.append(_sentence(talker, "HDT", [f"{psi[k]:.3f}", "T"]))
        if with_pc_time:
            pc = start + timedelta(seconds=float(times[k]) + pc_latency)
            prefix = pc.strftime("%Y-%m-%d %H:%M:%S.%f")[:-3] + "\t"
            epoch = [prefix + s for s in epoch]
        lines += epoch
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="", encoding="ascii") as fh:
            fh.write("\r\n".join(lines) + "\r\n")
    return Path(path)
