"""ingest stage: log files -> RawLog (one reader per format; raw names mapped to canonical channels).

:func:`read_log` picks the reader from the file's content (:mod:`pipeline.ingest.sniff`; the
extension only when the content matches no known format, and always for ``.csv``); each reader
can also be called directly.
Every reader returns a :class:`pipeline.records.RawLog` whose summary counts the messages read
and skipped per type.

| format | extensions | reader |
|---|---|---|
| canonical CSV (or mapped columns/units) | .csv | :func:`pipeline.ingest.csv_log.read_csv_log` |
| MAVLink telemetry | .tlog | :func:`pipeline.ingest.mavlink_tlog.read_tlog` |
| ArduPilot DataFlash | .bin | :func:`pipeline.ingest.dataflash.read_dataflash` |
| PX4 ULog | .ulg | :func:`pipeline.ingest.ulog.read_ulog` |
| u-blox UBX (with NMEA inside) | .ubx, any | :func:`pipeline.ingest.ubx.read_ubx` |
| NMEA 0183 | .nmea, .txt, .log, any | :func:`pipeline.ingest.nmea.read_nmea` |
| ROS 1 / ROS 2 bags | .bag, .db3, .mcap, bag folder | :func:`pipeline.ingest.rosbag.read_rosbag` |
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

from ..errors import IngestError
from ..records import RawLog
from .csv_log import read_csv_log, read_csv_recordings


def _read_csv(path: Path, vessel=None, columns=None, units=None, **_: Any) -> RawLog:
    return read_csv_log(path, columns=columns, units=units)


def _read_tlog(path: Path, vessel=None, **_: Any) -> RawLog:
    from .mavlink_tlog import read_tlog

    return read_tlog(path, vessel=vessel)


def _read_dataflash(path: Path, vessel=None, **_: Any) -> RawLog:
    from .dataflash import read_dataflash

    return read_dataflash(path, vessel=vessel)


def _read_ubx(path: Path, vessel=None, sensor: str = "", **_: Any) -> RawLog:
    from .ubx import read_ubx

    return read_ubx(path, sensor=sensor)


def _read_nmea(path: Path, vessel=None, sensor: str = "", **_: Any) -> RawLog:
    from .nmea import read_nmea

    return read_nmea(path, sensor=sensor)


def _read_rosbag(path: Path, vessel=None, topics=None, **_: Any) -> RawLog:
    from .rosbag import read_rosbag

    if topics is None and vessel is not None:
        topics = vessel.extra.get("topics")
    return read_rosbag(path, topics=topics)


def _read_ulog(path: Path, vessel=None, **_: Any) -> RawLog:
    from .ulog import read_ulog

    return read_ulog(path, vessel=vessel)


#: File extension -> reader(path, vessel=None, **options).
READERS: dict[str, Callable[..., RawLog]] = {
    ".csv": _read_csv,
    ".tlog": _read_tlog,
    ".bin": _read_dataflash,
    ".ubx": _read_ubx,
    ".nmea": _read_nmea,
    ".ulg": _read_ulog,
    ".bag": _read_rosbag,
    ".db3": _read_rosbag,
    ".mcap": _read_rosbag,
}


#: Format found by content (:func:`pipeline.ingest.sniff.sniff`) -> reader.
CONTENT_READERS: dict[str, Callable[..., RawLog]] = {
    "ulog": _read_ulog,
    "dataflash": _read_dataflash,
    "rosbag": _read_rosbag,
    "tlog": _read_tlog,
    "ubx": _read_ubx,
    "nmea": _read_nmea,
}


def read_log(path: str | Path, vessel=None, **options: Any) -> RawLog:
    """Read one log file with the reader for its format, found from its content.

    The content decides (ULog, DataFlash, ROS bag, MAVLink telemetry, UBX, NMEA signatures;
    see :mod:`pipeline.ingest.sniff`); ``.csv`` always goes to the CSV reader, and a file
    whose content matches no signature goes to the reader of its extension when it has one
    (that reader then says what is wrong). A file with RTCM 3 corrections only, or with no
    known content, is an error that says what its first bytes look like.

    Parameters
    ----------
    path : str or Path
        Log file, or a ROS 2 bag folder.
    vessel : pipeline.vessel.Vessel, optional
        Needed by readers that map actuator channels (MAVLink, DataFlash, ULog) and gives a ROS
        topic map (``[topics]``).
    **options
        Reader options: ``columns``, ``units`` (CSV); ``sensor`` (UBX, NMEA: suffix for the
        channel names, e.g. ``gps2``); ``topics`` (ROS).

    Raises
    ------
    IngestError
        Unknown format, or the reader's own errors.
    """
    from ._common import check_file
    from .sniff import sniff

    p = Path(path)
    if p.is_dir():
        from .rosbag import looks_like_rosbag

        if looks_like_rosbag(p):
            return _read_rosbag(p, vessel=vessel, **options)
        raise IngestError(f"{p}: expected a log file or a ROS 2 bag folder (metadata.yaml), found a folder without one")
    suffix = p.suffix.lower()
    if suffix == ".csv":
        return _read_csv(p, vessel=vessel, **options)
    check_file(p, "log file")
    try:
        fmt, what = sniff(p)
    except OSError as exc:
        raise IngestError(f"{p}: expected a readable log file, found {exc.strerror or exc}") from None
    if fmt == "rtcm3":
        raise IngestError(f"{p}: expected vessel motion (position, velocity, attitude or IMU), found {what}: "
                          f"differential corrections for a receiver, with no vessel state")
    reader = CONTENT_READERS.get(fmt) if fmt else READERS.get(suffix)
    if reader is None:
        known = "ULog, DataFlash, MAVLink .tlog, u-blox UBX, NMEA 0183, ROS bag, CSV"
        raise IngestError(f"{p}: expected a log with extension {sorted(READERS)} or content in a known format "
                          f"({known}), found {p.suffix or 'no extension'!r} holding {what}")
    return reader(p, vessel=vessel, **options)


def read_recordings(path: str | Path, vessel=None, **options: Any) -> list[RawLog]:
    """Every recording in one log file: one for most formats, one per recording for a CSV that stacks several.

    A CSV whose rows name their recording in a run column (``series``, ``run``, ...; see
    :func:`pipeline.ingest.csv_log.read_csv_recordings`) gives one RawLog per recording; every
    other file gives what :func:`read_log` gives.

    Parameters
    ----------
    path, vessel, **options
        As :func:`read_log`.

    Returns
    -------
    list[RawLog]
        The file's recordings in file order.

    Raises
    ------
    IngestError
        As :func:`read_log`.
    """
    p = Path(path)
    if p.suffix.lower() == ".csv" and not p.is_dir():
        return read_csv_recordings(p, columns=options.get("columns"), units=options.get("units"))
    return [read_log(p, vessel=vessel, **options)]


__all__ = ["read_log", "read_recordings", "read_csv_log", "read_csv_recordings", "READERS", "CONTENT_READERS"]
