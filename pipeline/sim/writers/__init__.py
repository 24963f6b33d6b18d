"""Log writers: the simulator writes every format the ingest stage reads.

:func:`write_log` picks the writer from the output file's extension.
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


#: Output extension -> writer(log, path, vessel=None, **options).
WRITERS = {".csv": _csv, ".tlog": _tlog}


def write_log(log: RawLog, path: str | Path, vessel=None, **options: Any) -> Path:
    """Write ``log`` in the format named by ``path``'s extension.

    Parameters
    ----------
    log : RawLog
        Channels to write (usually :attr:`pipeline.sim.SimResult.log`).
    path : str or Path
        Output file.
    vessel : pipeline.vessel.Vessel, optional
        Needed by formats that log actuators as PWM (MAVLink, DataFlash).
    """
    p = Path(path)
    writer = WRITERS.get(p.suffix.lower())
    if writer is None:
        raise SimError(f"{p}: expected an output extension in {sorted(WRITERS)}, found {p.suffix or 'none'!r}")
    return Path(writer(log, p, vessel=vessel, **options))
