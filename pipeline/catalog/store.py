"""The catalogue: an embedded DuckDB file holding every processed trial.

One writer at a time (DuckDB locks the file); a batch opens it for each trial's write, so the
lock is held only for the length of one transaction. Every trial is written in one transaction:
its old rows (same files, same vesselid version) are deleted and the new ones inserted, so a
killed process leaves the catalogue as it was before that trial.
"""

from __future__ import annotations

import math
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterable, Mapping

import pandas as pd

from .errors import CatalogError
from .schema import DEFAULT_CATALOG, SCHEMA_VERSION, TRIAL_TABLES, migrate
from .trial_job import TrialRecord

#: Default catalogue file, in the working folder.

_TRIAL_COLUMNS = ("trial_id", "name", "files_hash", "package_version", "vessel_hash", "vessel_name",
                  "manifest_path", "report_dir", "status", "error", "started_utc", "date_source", "lat", "lon",
                  "place_source", "mode", "command", "processed_at", "duration_s")
_TABLE_COLUMNS = {
    "files": ("role", "path", "sha256", "size_bytes"),
    "runs": ("run_index", "fs", "duration_s", "n_samples", "channels", "sources", "n_gaps", "notes"),
    "segments": ("seg_index", "kind", "dof", "t_start", "t_end", "input_channel", "quality", "origin", "label"),
    "coefficients": ("name", "value", "stderr", "ci_low", "ci_high", "unit", "n_segments", "structure", "method",
                     "success", "message", "consistency_p"),
    "diagnoses": ("status", "effect", "dof", "gap_before", "gap_after", "shrink", "message"),
    "diagnosis_gaps": ("dof", "gap", "noise_floor", "replay_gap"),
}


def _timestamp(x: float | None):
    return None if x is None or not math.isfinite(x) else datetime.fromtimestamp(x, tz=timezone.utc)


class Catalog:
    """An open catalogue (use as a context manager, or call :meth:`close`).

    Parameters
    ----------
    path : str or Path
        The DuckDB file; created (and its schema migrated) when ``create`` is True.
    create : bool
        Create the file when missing. False: a missing file is an error naming it.
    wait_s : float
        How long to wait [s] for another process that holds the file to release it.
    """

    def __init__(self, path: str | Path = DEFAULT_CATALOG, create: bool = False, wait_s: float = 0.0) -> None:
        import time

        import duckdb

        self.path = Path(path)
        if not self.path.exists() and not create:
            raise CatalogError(f"catalogue: expected a DuckDB file at {self.path}, found nothing "
                               f"(fill one with 'vesselid batch TRIALS_DIR --catalog {self.path}')")
        if self.path.is_dir():
            raise CatalogError(f"catalogue: expected a file at {self.path}, found a folder")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        deadline = time.monotonic() + wait_s
        while True:
            try:
                self.con = duckdb.connect(str(self.path))
                break
            except duckdb.IOException as exc:
                # Another process holds the file (DuckDB allows one writer): wait for it if asked.
                if "lock" not in str(exc).lower() or time.monotonic() >= deadline:
                    error = exc
                    break
                time.sleep(0.5)
            except duckdb.Error as exc:
                raise CatalogError(f"catalogue {self.path}: expected a DuckDB file, found: {exc}") from None
        if not hasattr(self, "con"):
            text = str(error)
            if "lock" in text.lower():
                raise CatalogError(f"catalogue {self.path}: in use by another process; try again when it is done "
                                   f"({text.splitlines()[0]})") from None
            raise CatalogError(f"catalogue {self.path}: expected a DuckDB file, found one DuckDB cannot open: {text}") from None
        try:
            self.con.execute("SET TimeZone = 'UTC'")
            self.version = migrate(self.con, str(self.path))
        except Exception:
            self.con.close()
            raise

    def __enter__(self) -> "Catalog":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        """Close the connection (releases the file lock)."""
        self.con.close()

    # ------------------------------------------------------------------ writing
    def write(self, record: TrialRecord) -> None:
        """Store one trial in one transaction, replacing the rows of the same trial id.

        Parameters
        ----------
        record : TrialRecord
            From :func:`pipeline.catalog.trial_job.process_trial`.
        """
        ident = record.identity
        tid = ident.trial_id
        trial = {**record.trial, "trial_id": tid, "name": ident.name, "files_hash": ident.files_hash,
                 "package_version": ident.package_version}
        trial["started_utc"] = _timestamp(trial.get("started_utc"))
        trial["processed_at"] = _timestamp(trial.get("processed_at"))
        rows: dict[str, Iterable[Mapping[str, Any]]] = {
            "files": ident.files, "runs": record.runs, "segments": record.segments,
            "coefficients": record.coefficients, "diagnoses": [record.diagnosis] if record.diagnosis else [],
            "diagnosis_gaps": record.diagnosis_gaps}
        con = self.con
        con.execute("BEGIN TRANSACTION")
        try:
            if record.vessel:
                v = record.vessel
                con.execute("INSERT OR REPLACE INTO vessels VALUES (?, ?, ?, ?)",
                            [v["config_hash"], v["name"], v["config_path"], v["config_text"]])
            for table in TRIAL_TABLES:
                con.execute(f"DELETE FROM {table} WHERE trial_id = ?", [tid])
            con.execute("DELETE FROM trials WHERE trial_id = ?", [tid])
            con.execute(f"INSERT INTO trials ({', '.join(_TRIAL_COLUMNS)}) VALUES ({', '.join('?' * len(_TRIAL_COLUMNS))})",
                        [trial.get(c) for c in _TRIAL_COLUMNS])
            for table, cols in _TABLE_COLUMNS.items():
                data = [[tid] + [r.get(c) for c in cols] for r in rows[table]]
                if data:
                    con.executemany(f"INSERT INTO {table} (trial_id, {', '.join(cols)}) "
                                    f"VALUES ({', '.join('?' * (len(cols) + 1))})", data)
            con.execute("COMMIT")
        except BaseException:
            con.execute("ROLLBACK")
            raise

    # ------------------------------------------------------------------ reading
    def query(self, sql: str, params: list | None = None) -> pd.DataFrame:
        """Run a read query and return a DataFrame.

        Parameters
        ----------
        sql : str
            SQL text (DuckDB dialect) over the tables in :mod:`pipeline.catalog.schema`.
        params : list, optional
            Values for the ``?`` placeholders.
        """
        return self.con.execute(sql, params or []).df()

    def done_ids(self) -> set[str]:
        """Trial ids already catalogued without error (a batch skips these unless forced)."""
        return {r[0] for r in self.con.execute("SELECT trial_id FROM trials WHERE status = 'ok'").fetchall()}

    def trials(self, vessel: str | None = None) -> pd.DataFrame:
        """Every trial, ordered by vessel, log date, name.

        Parameters
        ----------
        vessel : str, optional
            Only this vessel (its config ``name``).
        """
        where, params = ("WHERE vessel_name = ?", [vessel]) if vessel else ("", [])
        return self.query(f"SELECT * FROM trials {where} ORDER BY vessel_name NULLS LAST, started_utc NULLS LAST, "
                          f"name, processed_at", params)

    def resolve(self, ref: str) -> pd.Series:
        """Find one trial by id (or a unique id prefix of 4+ digits) or by manifest name.

        A name processed by several vesselid versions resolves to the newest processing; a name
        shared by trials with different files is ambiguous and named in the error.

        Parameters
        ----------
        ref : str
            Trial id, id prefix or trial name.

        Raises
        ------
        CatalogError
            No such trial, or an ambiguous reference.
        """
        df = self.query("SELECT * FROM trials WHERE trial_id = ? OR name = ? OR "
                        "(length(?) >= 4 AND starts_with(trial_id, ?)) ORDER BY processed_at DESC", [ref, ref, ref, ref])
        if df.empty:
            names = self.query("SELECT DISTINCT name FROM trials ORDER BY name")["name"].tolist()
            shown = ", ".join(names[:20]) + (" ..." if len(names) > 20 else "")
            raise CatalogError(f"trial {ref!r}: expected a trial name or id in {self.path}, found none; "
                               f"trials: {shown or 'none (empty catalogue)'}")
        exact = df[df["trial_id"] == ref]
        if not exact.empty:
            return exact.iloc[0]
        if df["files_hash"].nunique() > 1:
            listed = "; ".join(f"{r.trial_id} ({r.name}, {r.manifest_path})" for r in df.itertuples())
            raise CatalogError(f"trial {ref!r}: expected one trial, found {df['files_hash'].nunique()} with different "
                               f"files; name one by id: {listed}")
        return df.iloc[0]

    def coefficients(self, trial_id: str) -> pd.DataFrame:
        """The coefficient rows of one trial.

        Parameters
        ----------
        trial_id : str
            Full trial id.
        """
        return self.query("SELECT * FROM coefficients WHERE trial_id = ? ORDER BY rowid", [trial_id])

    def table(self, name: str, trial_id: str) -> pd.DataFrame:
        """Rows of one per-trial table for one trial.

        Parameters
        ----------
        name : str
            One of :data:`pipeline.catalog.schema.TRIAL_TABLES`.
        trial_id : str
            Full trial id.
        """
        if name not in TRIAL_TABLES:
            raise CatalogError(f"table: expected one of {TRIAL_TABLES}, found {name!r}")
        return self.query(f"SELECT * EXCLUDE (trial_id) FROM {name} WHERE trial_id = ? ORDER BY rowid", [trial_id])

    def coefficient_history(self, coefficient: str, vessel: str | None = None) -> pd.DataFrame:
        """One coefficient over every successfully processed trial, with the trial's vessel and date.

        Parameters
        ----------
        coefficient : str
            Coefficient name (``X_u``, ``K_nomoto``, ...).
        vessel : str, optional
            Only this vessel.
        """
        where = "AND t.vessel_name = ?" if vessel else ""
        return self.query(
            "SELECT t.trial_id, t.name, t.files_hash, t.vessel_name, t.started_utc, t.report_dir, t.package_version, t.processed_at, "
            "c.value, c.stderr, c.ci_low, c.ci_high, c.unit, c.success, c.message FROM coefficients c "
            f"JOIN trials t USING (trial_id) WHERE c.name = ? AND t.status = 'ok' {where} "
            "ORDER BY t.vessel_name, t.started_utc NULLS LAST, t.name, t.processed_at",
            [coefficient] + ([vessel] if vessel else []))

    def export(self, out: str | Path) -> Path:
        """Write every coefficient of every trial with its trial's columns, as CSV or Parquet.

        Parameters
        ----------
        out : str or Path
            ``.csv`` or ``.parquet`` file; written to a temporary name and renamed when complete.
        """
        from ..atomic import atomic_path

        out = Path(out)
        fmt = {".csv": "FORMAT CSV, HEADER", ".parquet": "FORMAT PARQUET"}.get(out.suffix.lower())
        if fmt is None:
            raise CatalogError(f"export: expected a .csv or .parquet file name, found {out.name!r}")
        sql = ("SELECT t.trial_id, t.name AS trial, t.vessel_name AS vessel, t.vessel_hash, t.started_utc, "
               "t.date_source, t.lat, t.lon, t.status, t.package_version, t.mode, t.processed_at, t.report_dir, "
               "c.name AS coefficient, c.value, c.stderr, c.ci_low, c.ci_high, c.unit, c.n_segments, c.structure, "
               "c.method, c.success, c.message, c.consistency_p, d.status AS diagnosis, d.effect AS diagnosis_effect "
               "FROM trials t LEFT JOIN coefficients c USING (trial_id) LEFT JOIN diagnoses d USING (trial_id) "
               "ORDER BY t.vessel_name, t.started_utc NULLS LAST, t.name, c.rowid")
        with atomic_path(out) as tmp:
            path_sql = str(tmp).replace("'", "''")
            self.con.execute(f"COPY ({sql}) TO '{path_sql}' ({fmt})")
        return out
