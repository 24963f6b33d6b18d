"""Canonical CSV logs (DESIGN.md), and CSV logs with other names and units through a column map.

Canonical: header row, one row per sample, column ``t`` [s] strictly increasing, channels named
as in :data:`pipeline.records.CHANNEL_UNITS` in SI units and radians. A second sensor of the same
quantity is ``name@sensor``. Empty cells mean "not sampled at this time" (sensors at different
rates share one file); they are not samples and are not counted as drops.

CSV as people write it is read too, and every guess is named in the summary:

- the column map renames any column, the time column included (``{"t_s": "t"}``);
- without ``t`` and without a map, a column named ``time``, ``timestamp`` or ``t``/``time`` with a
  unit suffix (``t_ms``, ``time_us``) is the time column;
- time in s, ms, us or ns (a ``units`` entry or the suffix of its name); ISO 8601 timestamps
  (``2022-05-18T09:47:01.10Z``; without a zone they are taken as UTC) and Unix epoch seconds set
  ``RawLog.start_time``, so separate recordings are told apart by their absolute times;
- semicolon separators (with a decimal comma when the numbers use one);
- units by suffix of a canonical name: ``psi_deg``, ``r_degs``/``r_dps`` [deg/s], ``sog_kn``/``sog_kts``
  [knots], ``sog_kmh``, ``u_ms``/``u_mps`` [m/s], ``phi_rad``; a ``units`` entry overrides it;
- several recordings stacked in one table (a ``run``/``series``/``recording`` column naming each row's
  recording, time starting again in each): one RawLog per recording (:func:`read_csv_recordings`).

A logger that writes one row per IMU sample and repeats the last GNSS fix in every row can say which
rows hold a new fix: a column ``t_fix`` (any unit suffix, e.g. ``t_fix_ms``; ``t_fix@sensor`` for the
GNSS channels ``lat@sensor`` ...) holding the receiver's own time of the fix in each row (GPS time of
week, fix time, fix counter: any number that changes with every new fix). Rows where it repeats are
held copies: ``lat``, ``lon``, ``sog`` and ``cog`` keep only the row where each fix first appears.
Without it, held fixes are recognised from their values in :mod:`pipeline.align.gnss`.

Inputs (``delta``, ``tau_*``) are commands by default, held until the next sample; a rudder-angle
sensor or other measured actuator state is declared ``measured`` (``input_kinds``, or a
manifest's ``[inputs]`` table) and is then interpolated like a state.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np
import pandas as pd

from ..errors import IngestError
from ..records import ANGLE_CHANNELS, CHANNEL_UNITS, INPUT_KINDS, INPUT_UNITS, Channel, IngestSummary, RawLog
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


#: Name suffix -> unit of a channel column (``psi_deg``); the stem must be a canonical channel.
SUFFIX_UNITS: Mapping[str, str] = {
    "deg": "deg", "degs": "deg/s", "dps": "deg/s", "rad": "rad", "rads": "rad/s", "kn": "knots",
    "kts": "knots", "knots": "knots", "kmh": "km/h", "ms": "m/s", "mps": "m/s", "cms": "cm/s", "m": "m",
}
#: Name suffix -> unit of the time column (``t_ms``).
TIME_SUFFIX_UNITS: Mapping[str, str] = {"s": "s", "ms": "ms", "us": "us", "ns": "ns"}
#: Time column names recognised when there is no ``t`` and no column map entry for it.
TIME_NAMES = ("time", "timestamp", "datetime", "date_time", "utc")
#: Times above this [s] are Unix epoch seconds (a trial is never 3 years long).
EPOCH_MIN_S = 1e8


def _base(name: str) -> str:
    return name.split("@", 1)[0]


#: Name of the column holding each row's GNSS fix time (see the module notes).
FIX_TIME = "t_fix"
#: Channels of a GNSS receiver, held together by a logger between fixes.
GNSS_BASES = ("lat", "lon", "sog", "cog")


def _fix_time_columns(p: Path, df: pd.DataFrame, columns: Mapping[str, str]) -> dict[str, tuple[str, np.ndarray]]:
    """Sensor suffix ("" for none) -> (raw column, True on the rows where a new GNSS fix appears)."""
    out = {}
    for raw in df.columns:
        name = columns.get(raw, raw)
        base, _, sensor = name.partition("@")
        if base != FIX_TIME and not (base.startswith(FIX_TIME + "_") and base[len(FIX_TIME) + 1:].lower()
                                     in TIME_SUFFIX_UNITS):
            continue
        stamp = pd.to_numeric(df[raw], errors="coerce").to_numpy(float)
        if not np.isfinite(stamp).any():
            # ISO times of the fix: compare them as text.
            text = df[raw].astype(str).to_numpy()
            stamp = pd.factorize(text)[0].astype(float)
            stamp[df[raw].isna().to_numpy()] = np.nan
        ok = np.isfinite(stamp)
        prev = pd.Series(stamp).ffill().shift(1).to_numpy()
        new = ok & ~(stamp == prev)
        out[sensor] = (raw, new)
    return out


def _split_suffix(raw: str, table: Mapping[str, str]) -> tuple[str, str] | None:
    """(stem, unit) when ``raw`` is ``stem_suffix`` with a known suffix, else None."""
    stem, sep, suffix = raw.rpartition("_")
    if sep and stem and suffix.lower() in table:
        return stem, table[suffix.lower()]
    return None


def _sniff_format(p: Path) -> tuple[str, str]:
    """(separator, decimal) from the first lines: semicolons, and a decimal comma with them."""
    with open(p, "r", encoding="utf-8", errors="replace") as fh:
        head = [fh.readline() for _ in range(6)]
    header = head[0]
    if header.count(";") > header.count(","):
        body = "".join(head[1:])
        # With ';' as separator a ',' between digits can only be a decimal comma.
        import re

        return ";", ("," if re.search(r"\d,\d", body) else ".")
    return ",", "."


def _time_column(df: pd.DataFrame, columns: Mapping[str, str], time_column: str) -> str | None:
    mapped = [raw for raw, name in columns.items() if name == "t" and raw in df.columns]
    if mapped:
        return mapped[0]
    if time_column in df.columns:
        return time_column
    if time_column != "t":
        return None
    lower = {c.lower(): c for c in df.columns}
    for n in TIME_NAMES:
        if n in lower:
            return lower[n]
    for c in df.columns:
        split = _split_suffix(c, TIME_SUFFIX_UNITS)
        if split and split[0].lower() in ("t", "time", "timestamp") and c not in columns:
            return c
    return None


#: Column names that name the recording each row belongs to (several recordings stacked in one file).
RUN_COLUMN_NAMES = ("run", "series", "recording", "run_id", "run_name", "recording_id")


def _run_column(df: pd.DataFrame, columns: Mapping[str, str]) -> str | None:
    """Raw name of the column naming each row's recording: mapped to ``run``, or a ``RUN_COLUMN_NAMES`` name."""
    mapped = [raw for raw, name in columns.items() if name == "run" and raw in df.columns]
    if mapped:
        return mapped[0]
    for c in df.columns:
        if c.lower() in RUN_COLUMN_NAMES and c not in columns:
            return c
    return None


def _parse_time(p: Path, col: pd.Series, raw: str, unit: str | None) -> tuple[np.ndarray, float, list[str]]:
    """Times [s from the first row], the Unix time of the first row (NaN if unknown), and notes."""
    notes: list[str] = []
    numeric = pd.to_numeric(col, errors="coerce")
    if numeric.notna().all():
        factor_unit = unit or "s"
        t = numeric.to_numpy(float) * UNIT_FACTORS[factor_unit]
        if unit and unit != "s":
            notes.append(f"time: column {raw!r} in {unit}, converted to s")
        if t[0] > EPOCH_MIN_S:
            notes.append(f"time: column {raw!r} holds Unix epoch times; t = 0 is the first row")
            return t - t[0], float(t[0]), notes
        return t, np.nan, notes
    if numeric.notna().any():
        bad = int(np.flatnonzero(numeric.isna().to_numpy())[0])
        raise IngestError(f"{p}: expected a number in {raw!r} on every row, found {col.iloc[bad]!r} on data row "
                          f"{bad + 1}")
    try:
        stamps = pd.to_datetime(col.astype(str).str.strip(), format="ISO8601")
    except (ValueError, TypeError):
        raise IngestError(f"{p}: expected numbers or ISO 8601 timestamps in time column {raw!r}, found "
                          f"{col.iloc[0]!r} on data row 1") from None
    if stamps.isna().any():
        bad = int(np.flatnonzero(stamps.isna().to_numpy())[0])
        raise IngestError(f"{p}: expected an ISO 8601 timestamp in {raw!r} on every row, found {col.iloc[bad]!r} on "
                          f"data row {bad + 1}")
    if stamps.dt.tz is None:
        notes.append(f"time: ISO timestamps in {raw!r} have no time zone; taken as UTC")
        stamps = stamps.dt.tz_localize("UTC")
    stamps = stamps.dt.tz_convert("UTC")
    first = stamps.iloc[0]
    notes.append(f"time: ISO timestamps in {raw!r}; t = 0 is {first.isoformat()}")
    return (stamps - first).dt.total_seconds().to_numpy(float), float(first.timestamp()), notes


def _check_options(p: Path, units: Mapping[str, str], input_kinds: Mapping[str, str]) -> None:
    """IngestError on a unit or input kind this reader does not know."""
    for raw, unit in units.items():
        if unit not in UNIT_FACTORS:
            raise IngestError(f"{p}: unit of column {raw!r}: expected one of {sorted(UNIT_FACTORS)}, found {unit!r}")
    for raw, kind in input_kinds.items():
        if kind not in INPUT_KINDS:
            raise IngestError(f"{p}: input kind of {raw!r}: expected one of {list(INPUT_KINDS)}, found {kind!r}")


def _read_frame(p: Path) -> tuple[pd.DataFrame, str, str]:
    """The table (column names stripped), its separator and decimal mark; IngestError when unparsable."""
    try:
        sep, decimal = _sniff_format(p)
        df = pd.read_csv(p, skipinitialspace=True, sep=sep, decimal=decimal)
    except pd.errors.EmptyDataError:
        raise IngestError(f"{p}: expected a header row and data rows, found no columns") from None
    except (pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise IngestError(f"{p}: expected comma-separated values, found unparsable content ({exc})") from None
    df.columns = [str(c).strip() for c in df.columns]
    return df, sep, decimal


def _time_axis(p: Path, df: pd.DataFrame, columns: Mapping[str, str], units: Mapping[str, str], time_column: str,
               notes: list[str]) -> tuple[np.ndarray, float, str]:
    """Sample times [s], the Unix start time (NaN when relative) and the raw name of the time column.

    Raises IngestError without a time column, without data rows, for an unknown time unit or a
    time that does not increase strictly.
    """
    time_raw = _time_column(df, columns, time_column)
    if time_raw is None:
        raise IngestError(f"{p}: expected a time column {time_column!r} (or a column map entry naming one, "
                          f"e.g. [columns] t_s = \"t\"), found columns {list(df.columns)}")
    if len(df) == 0:
        raise IngestError(f"{p}: expected data rows after the header, found none")
    if time_raw != "t":
        notes.append(f"time: column {time_raw!r} is the time column")
    time_unit = units.get(time_raw)
    if time_unit is None:
        split = _split_suffix(time_raw, TIME_SUFFIX_UNITS)
        time_unit = split[1] if split else None
        if split and split[1] != "s":
            notes.append(f"unit from suffix: {time_raw!r} in {split[1]}")
    if time_unit is not None and time_unit not in ("s", "ms", "us", "ns"):
        raise IngestError(f"{p}: unit of time column {time_raw!r}: expected one of ['s', 'ms', 'us', 'ns'], found "
                          f"{time_unit!r}")
    t, start_time, time_notes = _parse_time(p, df[time_raw], time_raw, time_unit)
    notes += time_notes
    back = np.flatnonzero(np.diff(t) <= 0)
    if len(back):
        i = int(back[0])
        hint = ("" if _run_column(df, columns) is not None else
                "; several recordings in one file? A column naming each row's recording (run, series, "
                "recording, or one mapped to 'run' in the column map) makes each recording a run")
        raise IngestError(f"{p}: expected strictly increasing time in {time_raw!r}, found "
                          f"{str(df[time_raw].iloc[i + 1])} after {str(df[time_raw].iloc[i])} on data row {i + 2} "
                          f"({len(back)} such rows){hint}")
    return t, start_time, time_raw


def _name_and_unit(raw: str, columns: Mapping[str, str], units: Mapping[str, str],
                   notes: list[str]) -> tuple[str, str | None]:
    """Canonical name and unit of a raw column: the column map and units first, then a unit suffix."""
    name = columns.get(raw, raw)
    unit = units.get(raw)
    split = _split_suffix(raw, SUFFIX_UNITS)
    if split and raw not in columns and _base(name) not in CHANNEL_UNITS and _base(split[0]) in CHANNEL_UNITS:
        name = split[0]
        if unit is None:
            unit = split[1]
        notes.append(f"unit from suffix: {raw!r} read as {name} in {unit}")
    elif split and raw in columns and unit is None:
        unit = split[1]
        notes.append(f"unit from suffix: {raw!r} read as {name} in {unit}")
    return name, unit


def _numbers(p: Path, cells: pd.Series, raw: str) -> np.ndarray:
    """A column as floats (empty cells NaN); IngestError naming the first cell that is not a number."""
    if pd.api.types.is_float_dtype(cells.dtype) or pd.api.types.is_integer_dtype(cells.dtype):
        # Already numeric (the usual case): the text checks below would only cost time.
        return cells.to_numpy(float)
    col = pd.to_numeric(cells, errors="coerce")
    nonnum = int((col.isna() & cells.notna()).sum())
    if nonnum:
        first = cells[col.isna() & cells.notna()].iloc[0]
        raise IngestError(f"{p}: expected numbers in column {raw!r}, found {first!r} ({nonnum} non-numeric cells)")
    return col.to_numpy(float)


def _channel(p: Path, raw: str, name: str, t: np.ndarray, v: np.ndarray, input_kinds: Mapping[str, str]) -> Channel:
    """The channel of one column's finite SI values: plausible for its unit, angles wrapped, input kind checked."""
    limit = _PLAUSIBLE.get(_base(name))
    peak = float(max(v.max(), -v.min()))
    if limit is not None and peak > limit:
        raise IngestError(f"{p}: column {raw!r} ({_base(name)}) expected in {CHANNEL_UNITS[_base(name)]} "
                          f"(|value| <= {limit}), found {peak:.4g}; degrees or another unit? Declare it "
                          f"with a unit in the manifest's column map")
    if _base(name) in ANGLE_CHANNELS and not ((v > -np.pi) & (v <= np.pi)).all():
        v = np.angle(np.exp(1j * v))
    kind = input_kinds.get(raw, input_kinds.get(name, input_kinds.get(_base(name), "")))
    if kind and _base(name) not in INPUT_UNITS:
        raise IngestError(f"{p}: input kind given for {raw!r} ({name}), but it is a state; expected one of "
                          f"{sorted(INPUT_UNITS)}")
    return Channel(name, t, v, source=f"csv:{raw}", input_kind=kind)


def read_csv_log(path: str | Path, columns: Mapping[str, str] | None = None,
                 units: Mapping[str, str] | None = None, time_column: str = "t",
                 input_kinds: Mapping[str, str] | None = None) -> RawLog:
    """Read a canonical CSV log, or any CSV with a column map and units.

    Parameters
    ----------
    path : str or Path
        The CSV file.
    columns : Mapping[str, str], optional
        Raw column name -> canonical channel (``{"heading_deg": "psi"}``, ``{"t_s": "t"}`` for
        the time column); canonical names are used as they are.
    units : Mapping[str, str], optional
        Raw column name (or time column) -> unit of the raw values (``UNIT_FACTORS`` keys:
        deg, deg/s, km/h, knots, ms, ...); converted to SI. Without an entry, a unit suffix of
        the raw name (``SUFFIX_UNITS``, ``TIME_SUFFIX_UNITS``) gives the unit.
    time_column : str
        Raw name of the time column (default ``t``; see the module notes for what else is
        recognised).
    input_kinds : Mapping[str, str], optional
        Canonical input channel or raw column -> ``command`` (held, the default) or
        ``measured`` (interpolated); stored in ``Channel.input_kind``.

    Returns
    -------
    RawLog
        ``format='csv'``; ``time_reference='unix'`` with ``start_time`` when the time column
        holds ISO timestamps or Unix epoch seconds, else ``'trial'``.

    Raises
    ------
    IngestError
        Missing or empty file, no time column, non-numeric data, non-monotonic time, values
        implausible for the declared unit (degrees in a radian column), an unknown unit or
        input kind.
    """
    p = check_file(path, "CSV log")
    columns, units, input_kinds = dict(columns or {}), dict(units or {}), dict(input_kinds or {})
    _check_options(p, units, input_kinds)
    df, sep, decimal = _read_frame(p)
    notes: list[str] = [] if sep == "," else [f"format: separator {sep!r}, decimal {decimal!r}"]
    return _frame_log(p, str(p), df, columns, units, time_column, input_kinds, notes)


def _frame_log(p: Path, source: str, df: pd.DataFrame, columns: Mapping[str, str], units: Mapping[str, str],
               time_column: str, input_kinds: Mapping[str, str], notes: list[str]) -> RawLog:
    """The RawLog of a parsed table (one recording); ``source`` names it."""
    t, start_time, time_column = _time_axis(p, df, columns, units, time_column, notes)
    chans: dict[str, Channel] = {}
    read: dict[str, int] = {}
    skipped: dict[str, int] = {}
    warnings: list[str] = []
    fix_rows = _fix_time_columns(p, df, columns)
    run_raw = _run_column(df, columns)
    for sensor, (raw, new) in fix_rows.items():
        notes.append(f"GNSS fixes: column {raw!r} gives the fix time of each row: {int(new.sum())} fixes in "
                     f"{len(new)} rows; GNSS channels{' @' + sensor if sensor else ''} keep the row where each "
                     f"fix first appears (the others are held copies)")
    for raw in df.columns:
        if raw == time_column or raw == run_raw or any(raw == r for r, _ in fix_rows.values()):
            continue
        name, unit = _name_and_unit(raw, columns, units, notes)
        if _base(name) not in CHANNEL_UNITS:
            skipped[raw] = int(df[raw].notna().sum())
            warnings.append(f"column {raw!r} is not a canonical channel and has no column map entry; "
                            f"{skipped[raw]} values not used")
            continue
        values = _numbers(p, df[raw], raw) * UNIT_FACTORS[unit or ""]
        ok = np.isfinite(values)
        base, _, sensor = name.partition("@")
        if base in GNSS_BASES and sensor in fix_rows:
            ok &= fix_rows[sensor][1]
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
        channel = _channel(p, raw, name, t.take(idx), values.take(idx), input_kinds)
        if name in chans:
            raise IngestError(f"{p}: two columns give channel {name!r} (one of them {raw!r}); expected one column "
                              f"per channel, or a second sensor as {name}@sensor")
        chans[name] = channel
        read[raw] = len(idx)
    if not chans:
        raise IngestError(f"{p}: expected at least one canonical channel ({', '.join(CHANNEL_UNITS)}), "
                          f"found only {list(df.columns)}")
    summary = IngestSummary(path=source, format="csv", read=read, skipped=skipped, warnings=tuple(notes + warnings))
    absolute = bool(np.isfinite(start_time))
    return RawLog(source=source, format="csv", channels=chans, summary=summary,
                  time_reference="unix" if absolute else "trial", start_time=start_time)


def read_csv_recordings(path: str | Path, columns: Mapping[str, str] | None = None,
                        units: Mapping[str, str] | None = None, time_column: str = "t",
                        input_kinds: Mapping[str, str] | None = None) -> list[RawLog]:
    """Read a CSV that may hold several recordings stacked in one file, one RawLog per recording.

    People append recordings to one table with a column naming each row's recording (a test
    number, a series label) and a time that starts again in each. Such a file is split when
    a column named ``run``, ``series``, ``recording``, ``run_id``, ``run_name`` or ``recording_id``
    (or one the column map maps to ``run``) holds more than one value and either the time does not
    increase strictly over the whole file or the column map names the run column: each value's rows,
    in their order in the file, are one recording (``RawLog.source`` ``path#value``), read like a
    file of its own (:func:`read_csv_log`), and align makes each its own run unless their absolute
    times overlap. Without such a column the file is one recording.

    Parameters
    ----------
    path, columns, units, time_column, input_kinds
        As :func:`read_csv_log`.

    Returns
    -------
    list[RawLog]
        One per recording, in the order of their first row in the file.

    Raises
    ------
    IngestError
        As :func:`read_csv_log`, for each recording; a run column with empty cells.
    """
    p = check_file(path, "CSV log")
    columns, units, input_kinds = dict(columns or {}), dict(units or {}), dict(input_kinds or {})
    _check_options(p, units, input_kinds)
    df, sep, decimal = _read_frame(p)
    notes: list[str] = [] if sep == "," else [f"format: separator {sep!r}, decimal {decimal!r}"]
    run_raw = _run_column(df, columns)
    names = pd.unique(df[run_raw].dropna()) if run_raw is not None else []
    split = len(names) > 1 and (run_raw in columns or not _time_increases(df, columns, time_column))
    if not split:
        return [_frame_log(p, str(p), df, columns, units, time_column, input_kinds, notes)]
    if df[run_raw].isna().any():
        bad = int(np.flatnonzero(df[run_raw].isna().to_numpy())[0])
        raise IngestError(f"{p}: expected a recording name in column {run_raw!r} on every row, found an empty cell "
                          f"on data row {bad + 1}")
    labels = _recording_labels(df, run_raw, names)
    out = []
    for name in names:
        rows = df[df[run_raw] == name].reset_index(drop=True)
        note = [f"recording: rows with {run_raw} = {str(name)!r} ({len(rows)} of {len(df)} rows; the file holds "
                f"{len(names)} recordings)"] + labels.get(name, [])
        out.append(_frame_log(p, f"{p}#{name}", rows, columns, units, time_column, input_kinds, notes + note))
    return out


def _recording_labels(df: pd.DataFrame, run_raw: str, names) -> dict:
    """Warnings for recordings that a text column labels unlike most (``kind`` = ``fit`` among ``measured``).

    A table of recordings may hold rows that are not measurements (a regression curve, an average
    of the runs); the reader cannot know, but it names them, so that the user can leave them out.
    """
    out: dict = {}
    for col in df.columns:
        if col == run_raw or pd.api.types.is_numeric_dtype(df[col]):
            continue
        per = df.groupby(run_raw, sort=False)[col].agg(lambda x: tuple(pd.unique(x.dropna())))
        if not all(len(v) == 1 for v in per) or len({v[0] for v in per}) < 2:
            continue
        common = pd.Series([v[0] for v in per]).mode().iloc[0]
        for name in names:
            if per[name][0] != common:
                out.setdefault(name, []).append(
                    f"recording {str(name)!r}: column {col!r} is {per[name][0]!r} here and {common!r} in most "
                    f"recordings of the file; if these rows are not measurements (a fit, an average of the "
                    f"others), leave them out of the file: they are read as a recording of their own")
    return out


def _time_increases(df: pd.DataFrame, columns: Mapping[str, str], time_column: str) -> bool:
    """True when the time column of ``df`` increases strictly (or cannot be read: then the reader says why)."""
    raw = _time_column(df, columns, time_column)
    if raw is None:
        return True
    t = pd.to_numeric(df[raw], errors="coerce")
    if t.isna().any():
        stamps = pd.to_datetime(df[raw].astype(str).str.strip(), format="ISO8601", errors="coerce")
        if stamps.isna().any():
            return True
        t = (stamps - stamps.iloc[0]).dt.total_seconds()
    return bool((np.diff(t.to_numpy(float)) > 0).all())
