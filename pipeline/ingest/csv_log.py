"""Canonical CSV logs (DESIGN.md), and CSV logs with other names and units through a column map.

Canonical: header row, one row per sample, column ``t`` [s] strictly increasing, channels named
as in :data:`pipeline.records.CHANNEL_UNITS` in SI units and radians. A second sensor of the same
quantity is ``name@sensor``. Empty cells mean "not sampled at this time" (sensors at different
rates share one file); they are not samples and are not counted as drops.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np
import pandas as pd

from ..errors import IngestError
from ..records import ANGLE_CHANNELS, CHANNEL_UNITS, Channel, IngestSummary, RawLog
from ._common import check_file

#: Unit conversions to SI accepted in a column map: unit -> factor (value_SI = factor * value).
UNIT_FACTORS: Mapping[str, float] = {
    "": 1.0, "si": 1.0, "m/s": 1.0, "rad": 1.0, "rad/s": 1.0, "m": 1.0, "N": 1.0, "N m": 1.0, "s": 1.0,
    "m/s^2": 1.0,
    "deg": np.pi / 180, "deg/s": np.pi / 180, "km/h": 1 / 3.6, "knots": 1852 / 3600, "kn": 1852 / 3600,
    "ms": 1e-3, "us": 1e-6, "ns": 1e-9, "cm/s": 1e-2, "mG": 9.80665e-3, "g": 9.80665,
}
#: Plausible magnitude limits in SI, to catch a column logged in degrees but declared radians.
_PLAUSIBLE: Mapping[str, float] = {"phi": 3.2, "theta": 3.2, "psi": 6.3 + 0.2, "cog": 6.3 + 0.2,
                                   "p": 20.0, "q": 20.0, "r": 20.0, "delta": 1.6, "sog": 60.0,
                                   "u": 60.0, "v": 60.0, "w": 60.0}


def _base(name: str) -> str:
    return name.split("@", 1)[0]


def read_csv_log(path: str | Path, columns: Mapping[str, str] | None = None,
                 units: Mapping[str, str] | None = None, time_column: str = "t") -> RawLog:
    """Read a canonical CSV log, or any CSV with a column map and units.

    Parameters
    ----------
    path : str or Path
        The CSV file.
    columns : Mapping[str, str], optional
        Raw column name -> canonical channel (``{"heading_deg": "psi"}``); canonical names are
        used as they are.
    units : Mapping[str, str], optional
        Raw column name (or time column) -> unit of the raw values (``UNIT_FACTORS`` keys:
        deg, deg/s, km/h, knots, ms, ...); converted to SI.
    time_column : str
        Raw name of the time column.

    Returns
    -------
    RawLog
        ``format='csv'``, ``time_reference='trial'``.

    Raises
    ------
    IngestError
        Missing or empty file, no time column, non-numeric data, non-monotonic time, values
        implausible for the declared unit (degrees in a radian column).
    """
    p = check_file(path, "CSV log")
    columns = dict(columns or {})
    units = dict(units or {})
    for raw, unit in units.items():
        if unit not in UNIT_FACTORS:
            raise IngestError(f"{p}: unit of column {raw!r}: expected one of {sorted(UNIT_FACTORS)}, found {unit!r}")
    try:
        df = pd.read_csv(p, skipinitialspace=True)
    except pd.errors.EmptyDataError:
        raise IngestError(f"{p}: expected a header row and data rows, found no columns") from None
    except (pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise IngestError(f"{p}: expected comma-separated values, found unparsable content ({exc})") from None
    df.columns = [str(c).strip() for c in df.columns]
    if time_column not in df.columns:
        raise IngestError(f"{p}: expected a time column {time_column!r}, found columns {list(df.columns)}")
    if len(df) == 0:
        raise IngestError(f"{p}: expected data rows after the header, found none")
    t_raw = pd.to_numeric(df[time_column], errors="coerce").to_numpy(float)
    bad = np.flatnonzero(~np.isfinite(t_raw))
    if len(bad):
        raise IngestError(f"{p}: expected a number in {time_column!r} on every row, found "
                          f"{df[time_column].iloc[bad[0]]!r} on data row {bad[0] + 1}")
    t = t_raw * UNIT_FACTORS[units.get(time_column, "s")]
    back = np.flatnonzero(np.diff(t) <= 0)
    if len(back):
        i = int(back[0])
        raise IngestError(f"{p}: expected strictly increasing time in {time_column!r}, found {float(t[i + 1])!r} "
                          f"after {float(t[i])!r} on data row {i + 2} ({len(back)} such rows)")
    chans: dict[str, Channel] = {}
    read: dict[str, int] = {}
    skipped: dict[str, int] = {}
    warnings: list[str] = []
    for raw in df.columns:
        if raw == time_column:
            continue
        name = columns.get(raw, raw)
        if _base(name) not in CHANNEL_UNITS:
            skipped[raw] = int(df[raw].notna().sum())
            warnings.append(f"column {raw!r} is not a canonical channel and has no column map entry; "
                            f"{skipped[raw]} values not used")
            continue
        if pd.api.types.is_float_dtype(df[raw].dtype) or pd.api.types.is_integer_dtype(df[raw].dtype):
            # Already numeric (the usual case): the text checks below would only cost time.
            col = df[raw]
        else:
            col = pd.to_numeric(df[raw], errors="coerce")
            nonnum = int((col.isna() & df[raw].notna()).sum())
            if nonnum:
                first = df[raw][col.isna() & df[raw].notna()].iloc[0]
                raise IngestError(f"{p}: expected numbers in column {raw!r}, found {first!r} ({nonnum} non-numeric "
                                  f"cells)")
        factor = UNIT_FACTORS[units.get(raw, "")]
        values = col.to_numpy(float) * factor if factor != 1.0 else col.to_numpy(float)
        ok = np.isfinite(values)
        n_inf = int(np.isinf(values).sum())
        if n_inf:
            # 'inf' cells are numbers to pandas; they are dropped, but counted, not silently.
            skipped[raw] = n_inf
            warnings.append(f"column {raw!r}: {n_inf} infinite values not used")
        if not ok.any():
            warnings.append(f"column {raw!r} has no values")
            skipped[raw] = n_inf
            continue
        # t was checked strictly increasing above, so every column's sample times already are.
        idx = np.flatnonzero(ok)
        tc, vc = t.take(idx), values.take(idx)
        limit = _PLAUSIBLE.get(_base(name))
        peak = float(max(vc.max(), -vc.min()))
        if limit is not None and peak > limit:
            raise IngestError(f"{p}: column {raw!r} ({_base(name)}) expected in {CHANNEL_UNITS[_base(name)]} "
                              f"(|value| <= {limit}), found {peak:.4g}; degrees or another unit? Declare it "
                              f"with a unit in the manifest's column map")
        if _base(name) in ANGLE_CHANNELS and not ((vc > -np.pi) & (vc <= np.pi)).all():
            vc = np.angle(np.exp(1j * vc))
        chans[name] = Channel(name, tc, vc, source=f"csv:{raw}")
        read[raw] = len(tc)
    if not chans:
        raise IngestError(f"{p}: expected at least one canonical channel ({', '.join(CHANNEL_UNITS)}), "
                          f"found only {list(df.columns)}")
    summary = IngestSummary(path=str(p), format="csv", read=read, skipped=skipped, warnings=tuple(warnings))
    return RawLog(source=str(p), format="csv", channels=chans, summary=summary, time_reference="trial")
