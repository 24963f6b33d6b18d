"""Log writers: the simulator writes every format the ingest stage reads.

:func:`write_log` picks the writer from the output file's extension (a path without one is a
ROS 2 bag folder).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ...errors import SimError
from ...records import RawLog


def _csv(log, path, vessel=None, **kw):
    from .csv_writer import write_csv_log

    return write_csv_log(log, path, **kw)


def _tlog(log, path, vessel=None, **kw):
    from .tlog import write_tlog

    return write_tlog(log, path, vessel=vessel, **kw)


def _dataflash(log, path, vessel=None, **kw):
    from .dataflash import write_dataflash

    return write_dataflash(log, path, vessel=vessel, **kw)


def _ubx(log, path, vessel=None, **kw):
    from .ubx import write_ubx

    return write_ubx(log, path, **kw)


def _nmea(log, path, vessel=None, **kw):
    from .nmea import write_nmea

    return write_nmea(log, path, **kw)


def _rosbag(version):
    def write(log, path, vessel=None, **kw):
        from .rosbag import write_rosbag

        return write_rosbag(log, path, version=kw.pop("version", version), **kw)

    return write


#: Output extension -> writer(log, path, vessel=None, **options); "" is a ROS 2 bag folder.
WRITERS = {".csv": _csv, ".tlog": _tlog, ".bin": _dataflash, ".ubx": _ubx, ".nmea": _nmea,
           ".bag": _rosbag("ros1"), ".db3": _rosbag("ros2-sqlite3"), ".mcap": _rosbag("ros2-mcap"),
           "": _rosbag("ros2-sqlite3")}


def write_log(log: RawLog, path: str | Path, vessel=None, **options: Any) -> Path:
    """Write ``log`` in the format named by ``path``'s extension.

    Parameters
    ----------
    log : RawLog
        Channels to write (usually :attr:`pipeline.sim.SimResult.log`).
    path : str or Path
        Output file (``.csv .tlog .bin .ubx .nmea .bag .db3 .mcap``) or a ROS 2 bag folder (no
        extension).
    vessel : pipeline.vessel.Vessel, optional
        Needed by formats that log actuators as PWM (MAVLink, DataFlash).
    **options
        Passed to the format's writer.
    """
    p = Path(path)
    writer = WRITERS.get(p.suffix.lower())
    if writer is None:
        raise SimError(f"{p}: expected an output extension in {sorted(k for k in WRITERS if k)} or none "
                       f"(ROS 2 bag folder), found {p.suffix!r}")
    return Path(writer(log, p, vessel=vessel, **options))
