"""Write a RawLog as a canonical CSV log (DESIGN.md): one row per sample time, SI units."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ...atomic import atomic_path
from ...records import CHANNEL_UNITS, RawLog

_ORDER = list(CHANNEL_UNITS)


def _sort_key(name: str) -> tuple[int, str]:
    base, _, sensor = name.partition("@")
    return (_ORDER.index(base) if base in _ORDER else len(_ORDER), sensor)


def write_csv_log(log: RawLog, path: str | Path, time_resolution: float = 1e-6) -> Path:
    """Write ``log`` as canonical CSV; channels at different rates share rows, blanks elsewhere.

    Parameters
    ----------
    log : RawLog
        Channels to write.
    path : str or Path
        Output file (written atomically).
    time_resolution : float
        Sample times are rounded to this [s] so that sensors on a common clock share rows.

    Returns
    -------
    Path
        The file written.
    """
    names = sorted(log.channels, key=_sort_key)
    ticks = {n: np.round(log.channels[n].t / time_resolution).astype(np.int64) for n in names}
    all_ticks = np.unique(np.concatenate(list(ticks.values())))
    frame = pd.DataFrame({"t": all_ticks * time_resolution})
    for n in names:
        col = np.full(len(all_ticks), np.nan)
        col[np.searchsorted(all_ticks, ticks[n])] = log.channels[n].values
        frame[n] = col
    # lat/lon need ~1e-8 deg (1 mm) and time 1 us; 7 significant digits are far below the
    # noise of every other channel.
    fmt = {n: "{:.9f}".format for n in names if n.split("@")[0] in ("lat", "lon")}
    fmt["t"] = "{:.6f}".format
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as fh:
            fh.write(",".join(frame.columns) + "\n")
            cols = []
            for c in frame.columns:
                v = frame[c].to_numpy()
                f = fmt.get(c, "{:.7g}".format)
                # Only the samples are formatted (a 10 Hz GNSS column on 100 Hz rows is 90 % blank);
                # Python floats format as numpy's do, a third faster.
                col = np.full(len(v), "", dtype=object)
                finite = np.isfinite(v)
                col[finite] = [f(x) for x in v[finite].tolist()]
                cols.append(col)
            for row in zip(*cols):
                fh.write(",".join(row) + "\n")
    return Path(path)
