"""The catalogue's tables, versioned: each migration moves the schema up by one version.

A catalogue records the version it is at in ``schema_version``; :func:`migrate` applies the missing
migrations in order, each in its own transaction, so a catalogue written by an older vesselid is
brought up to date when it is opened and a newer one is refused with a clear message.

Tables (version 1)::

    vessels        config_hash PK, name, config_path, config_text
    trials         trial_id PK, name, files_hash, package_version, vessel_hash, vessel_name,
                   manifest_path, report_dir, status ('ok' | 'failed'), error, started_utc,
                   date_source, lat, lon, place_source, mode, command, processed_at, duration_s
    files          trial_id, role ('manifest' | 'vessel' | 'log'), path, sha256, size_bytes
    runs           trial_id, run_index, fs, duration_s, n_samples, channels, sources, n_gaps, notes
    segments       trial_id, seg_index, kind, dof, t_start, t_end, input_channel, quality, origin, label
    coefficients   trial_id, name, value, stderr, ci_low, ci_high, unit, n_segments, structure,
                   method, success, message, consistency_p
    diagnoses      trial_id, status, effect, dof, gap_before, gap_after, shrink, message
    diagnosis_gaps trial_id, dof, gap, noise_floor, replay_gap
"""

from __future__ import annotations

from typing import Sequence

from .errors import CatalogError

#: Catalogue file used when none is given (in the working folder).
DEFAULT_CATALOG = "vesselid.duckdb"

#: Each entry moves the schema from version ``i`` to ``i + 1`` (index ``i``).
MIGRATIONS: tuple[Sequence[str], ...] = (
    (
        """CREATE TABLE vessels (
            config_hash VARCHAR PRIMARY KEY, name VARCHAR NOT NULL, config_path VARCHAR, config_text VARCHAR)""",
        """CREATE TABLE trials (
            trial_id VARCHAR PRIMARY KEY, name VARCHAR NOT NULL, files_hash VARCHAR NOT NULL,
            package_version VARCHAR NOT NULL, vessel_hash VARCHAR, vessel_name VARCHAR,
            manifest_path VARCHAR NOT NULL, report_dir VARCHAR, status VARCHAR NOT NULL, error VARCHAR,
            started_utc TIMESTAMPTZ, date_source VARCHAR, lat DOUBLE, lon DOUBLE, place_source VARCHAR,
            mode VARCHAR, command VARCHAR, processed_at TIMESTAMPTZ NOT NULL, duration_s DOUBLE)""",
        """CREATE TABLE files (
            trial_id VARCHAR NOT NULL, role VARCHAR NOT NULL, path VARCHAR NOT NULL, sha256 VARCHAR NOT NULL,
            size_bytes BIGINT)""",
        """CREATE TABLE runs (
            trial_id VARCHAR NOT NULL, run_index INTEGER NOT NULL, fs DOUBLE, duration_s DOUBLE,
            n_samples BIGINT, channels VARCHAR, sources VARCHAR, n_gaps INTEGER, notes VARCHAR)""",
        """CREATE TABLE segments (
            trial_id VARCHAR NOT NULL, seg_index INTEGER NOT NULL, kind VARCHAR, dof VARCHAR, t_start DOUBLE,
            t_end DOUBLE, input_channel VARCHAR, quality DOUBLE, origin VARCHAR, label VARCHAR)""",
        """CREATE TABLE coefficients (
            trial_id VARCHAR NOT NULL, name VARCHAR NOT NULL, value DOUBLE, stderr DOUBLE, ci_low DOUBLE,
            ci_high DOUBLE, unit VARCHAR, n_segments INTEGER, structure VARCHAR, method VARCHAR,
            success BOOLEAN, message VARCHAR, consistency_p DOUBLE)""",
        """CREATE TABLE diagnoses (
            trial_id VARCHAR NOT NULL, status VARCHAR, effect VARCHAR, dof VARCHAR, gap_before DOUBLE,
            gap_after DOUBLE, shrink DOUBLE, message VARCHAR)""",
        """CREATE TABLE diagnosis_gaps (
            trial_id VARCHAR NOT NULL, dof VARCHAR, gap DOUBLE, noise_floor DOUBLE, replay_gap DOUBLE)""",
    ),
)
#: The schema version this vesselid writes.
SCHEMA_VERSION = len(MIGRATIONS)
#: Tables holding one trial's rows (deleted together when a trial is replaced).
TRIAL_TABLES = ("files", "runs", "segments", "coefficients", "diagnoses", "diagnosis_gaps")


def current_version(con) -> int:
    """The schema version a catalogue is at (0 for an empty file).

    Parameters
    ----------
    con : duckdb.DuckDBPyConnection
        Open connection.
    """
    has = con.execute("SELECT count(*) FROM information_schema.tables WHERE table_name = 'schema_version'").fetchone()[0]
    if not has:
        return 0
    row = con.execute("SELECT max(version) FROM schema_version").fetchone()
    return int(row[0] or 0)


def migrate(con, where: str = "catalogue") -> int:
    """Bring the schema up to :data:`SCHEMA_VERSION`, one transaction per migration.

    Parameters
    ----------
    con : duckdb.DuckDBPyConnection
        Open read-write connection.
    where : str
        Name of the catalogue, for messages.

    Returns
    -------
    int
        The version the catalogue is at afterwards.

    Raises
    ------
    CatalogError
        The catalogue was written by a newer vesselid (a schema version this one does not know).
    """
    version = current_version(con)
    if version > SCHEMA_VERSION:
        raise CatalogError(f"{where}: expected schema version <= {SCHEMA_VERSION}, found {version} "
                           f"(written by a newer vesselid; upgrade vesselid to read it)")
    for target in range(version + 1, SCHEMA_VERSION + 1):
        con.execute("BEGIN TRANSACTION")
        try:
            if target == 1:
                con.execute("CREATE TABLE schema_version (version INTEGER NOT NULL, applied_at TIMESTAMPTZ NOT NULL)")
            for stmt in MIGRATIONS[target - 1]:
                con.execute(stmt)
            con.execute("INSERT INTO schema_version VALUES (?, now())", [target])
            con.execute("COMMIT")
        except BaseException:
            con.execute("ROLLBACK")
            raise
    return SCHEMA_VERSION
