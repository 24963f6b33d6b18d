"""ingest stage: log files -> RawLog (one reader per format; raw names mapped to canonical channels).

:func:`read_log` picks the reader from the file's extension (or, for ROS 2 bag folders and
``.txt``/``.log`` NMEA captures, from the content); each reader can also be called directly.
Every reader returns a :class:`pipeline.records.RawLog` whose summary counts the messages read
and skipped per type.

| format | extensions | reader |
|---|---|---|
| canonical CSV (or mapped columns/units) | .csv | :func:`pipeline.ingest.csv_log.read_csv_log` |
| MAVLink telemetry | .tlog | :func:`pipeline.ingest.mavlink_tlog.read_tlog` |
| ArduPilot DataFlash | .bin | :func:`pipeline.ingest.dataflash.read_dataflash` |
| u-blox UBX | .ubx | :func:`pipeline.ingest.ubx.read_ubx` |
| NMEA 0183 | .nmea, .txt, .log | :func:`pipeline.ingest.nmea.read_nmea` |
| ROS 1 / ROS 2 bags | .bag, .db3, .mcap, bag folder | :func:`pipeline.ingest.rosbag.read_rosbag` |
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

from ..errors import IngestError
from ..records import RawLog
from .csv_log import read_csv_log


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


#: File extension -> reader(path, vessel=None, **options).
READERS: dict[str, Callable[..., RawLog]] = {
    ".csv": _read_csv,
    ".tlog": _read_tlog,
    ".bin": _read_dataflash,
    ".ubx": _read_ubx,
    ".nmea": _read_nmea,
    ".bag": _read_rosbag,
    ".db3": _read_rosbag,
    ".mcap": _read_rosbag,
}
#: Extensions loggers use for NMEA captures among other text; read as NMEA when the content is.
_SNIFFED_TEXT = (".txt", ".log")


def read_log(path: str | Path, vessel=None, **options: Any) -> RawLog:
    """Read one log file with the reader for its format.

    Parameters
    ----------
    path : str or Path
        Log file, or a ROS 2 bag folder.
    vessel : pipeline.vessel.Vessel, optional
        Needed by readers that map actuator channels (MAVLink, DataFlash) and gives a ROS topic
        map (``[topics]``).
    **options
        Reader options: ``columns``, ``units`` (CSV); ``sensor`` (UBX, NMEA: suffix for the
        channel names, e.g. ``gps2``); ``topics`` (ROS).

    Raises
    ------
    IngestError
        Unknown format, or the reader's own errors.
    """
    p = Path(path)
    if p.is_dir():
        from .rosbag import looks_like_rosbag

        if looks_like_rosbag(p):
            return _read_rosbag(p, vessel=vessel, **options)
        raise IngestError(f"{p}: expected a log file or a ROS 2 bag folder (metadata.yaml), found a folder without one")
    suffix = p.suffix.lower()
    reader = READERS.get(suffix)
    if reader is None and suffix in _SNIFFED_TEXT:
        from .nmea import looks_like_nmea

        if p.is_file() and looks_like_nmea(p):
            reader = _read_nmea
    if reader is None:
        known = sorted(READERS) + [f"{s} (NMEA content)" for s in _SNIFFED_TEXT]
        raise IngestError(f"{p}: expected a log with extension {known} or a ROS 2 bag folder, "
                          f"found {p.suffix or 'no extension'!r}")
    return reader(p, vessel=vessel, **options)


__all__ = ["read_log", "read_csv_log", "READERS"]
