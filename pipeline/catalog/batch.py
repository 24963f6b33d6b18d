"""``vesselid batch``: every trial under a folder, in parallel on Dask, into the catalogue.

The trials are hashed first (cheap); those already catalogued with the same files and vesselid
version are skipped unless forced. The rest go to Dask workers (a local cluster by default, or an
existing ``dask.distributed`` scheduler), each returning its rows; the batch writes each trial to
the catalogue in its own transaction as soon as it finishes, so a batch killed part-way keeps every
trial finished before the kill and a rerun completes the others.
"""

from __future__ import annotations

import logging
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from .errors import CatalogError
from .store import Catalog
from .trial_job import TrialIdentity, TrialRecord, identify_trial, process_trial


@dataclass(frozen=True)
class BatchSummary:
    """What a batch did.

    Attributes
    ----------
    found : int
        Trial manifests found.
    skipped : tuple[str, ...]
        Names of trials already catalogued (same files, same version), not processed again.
    ok, failed : tuple[str, ...]
        Names of trials processed without error / recorded with their error.
    wall_s : float
        Wall-clock time of the processing (hashing, cluster start and writes included) [s].
    workers : int
        Dask workers used.
    errors : dict
        Trial name -> error text of the failed trials.
    """

    found: int
    skipped: tuple[str, ...] = ()
    ok: tuple[str, ...] = ()
    failed: tuple[str, ...] = ()
    wall_s: float = 0.0
    workers: int = 0
    errors: dict = field(default_factory=dict)


def find_trials(root: str | Path) -> list[Path]:
    """Every trial manifest under ``root``: a TOML file with a ``logs`` key.

    A TOML file that does not parse is returned too (it will be recorded as a failed trial with
    the parse error); one that parses without ``logs`` (a vessel config) is not a trial.

    Parameters
    ----------
    root : str or Path
        Folder searched recursively (hidden folders skipped), or one manifest file.

    Raises
    ------
    CatalogError
        ``root`` does not exist.
    """
    root = Path(root)
    if root.is_file():
        return [root.resolve()]
    if not root.is_dir():
        raise CatalogError(f"trials: expected a folder of trial manifests, found nothing at {root}")
    found = []
    for p in sorted(root.rglob("*.toml")):
        if any(part.startswith(".") for part in p.relative_to(root).parts):
            continue
        try:
            doc = tomllib.loads(p.read_text(encoding="utf-8"))
        except (tomllib.TOMLDecodeError, UnicodeDecodeError):
            found.append(p.resolve())
            continue
        if "logs" in doc:
            found.append(p.resolve())
    return found


def _client(workers: int, scheduler: str | None):
    """A Dask client on a new local cluster, or on the scheduler at ``scheduler``."""
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            return Client(scheduler, timeout="10s"), None
        except (OSError, TimeoutError) as exc:
            raise CatalogError(f"--scheduler: expected a dask.distributed scheduler at {scheduler}, "
                               f"found none answering ({exc})") from None
    # One worker runs as a thread of this process: no worker process to start and import the
    # pipeline into, and nothing to gain from a process of its own. The scheduler's HTTP server
    # always starts; ":0" puts it on a free port instead of warning that 8787 is taken.
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=workers > 1, dashboard_address=":0",
                           silence_logs=logging.ERROR)
    return Client(cluster), cluster


def _failed_record(identity: TrialIdentity, error: str, command: str) -> TrialRecord:
    row = {"manifest_path": str(identity.manifest), "report_dir": None, "mode": None, "command": command,
           "processed_at": time.time(), "status": "failed", "error": error}
    return TrialRecord(identity, row)


def run_batch(root: str | Path, catalog: str | Path, reports: str | Path | None = None, workers: int = 1,
              scheduler: str | None = None, force: bool = False, quick: bool = False, command: str = "",
              on_result: Callable[[TrialRecord], None] | None = None, progress: bool = False) -> BatchSummary:
    """Process every trial under ``root`` on Dask and store each in the catalogue.

    Parameters
    ----------
    root : str or Path
        Folder of trial manifests (searched recursively, :func:`find_trials`).
    catalog : str or Path
        Catalogue file (created and migrated if needed).
    reports : str or Path, optional
        Root of the per-trial report folders; default ``reports`` beside the catalogue.
    workers : int
        Worker processes of the local cluster (ignored with ``scheduler``); 1 runs the trials in
        one worker thread of this process.
    scheduler : str, optional
        Address of an existing ``dask.distributed`` scheduler (``tcp://host:8786``); its workers
        must see the same file paths (a shared file system) and have vesselid installed.
    force : bool
        Process trials already catalogued with the same files and version again (replacing them).
    quick : bool
        Single-DOF fits and the report only (no joint fits, autopilot or diagnosis).
    command : str
        The command line, recorded with each trial.
    on_result : callable, optional
        Called with each :class:`TrialRecord` once it is in the catalogue.
    progress : bool
        Show a tqdm bar over the trials.

    Returns
    -------
    BatchSummary
    """
    from tqdm import tqdm

    if workers < 1:
        raise CatalogError(f"--workers: expected a positive number of workers, found {workers}")
    t0 = time.perf_counter()
    catalog = Path(catalog).resolve()
    reports = Path(reports).resolve() if reports else catalog.parent / "reports"
    manifests = find_trials(root)
    identities = [identify_trial(m) for m in manifests]
    with Catalog(catalog, create=True) as cat:
        done = cat.done_ids()
    todo = [i for i in identities if force or i.trial_id not in done]
    skipped = tuple(i.name for i in identities if i not in todo)
    ok: list[str] = []
    failed: list[str] = []
    errors: dict[str, str] = {}
    if not todo:
        return BatchSummary(len(identities), skipped, wall_s=time.perf_counter() - t0, workers=0)
    client, cluster = _client(workers, scheduler)
    try:
        try:
            client.wait_for_workers(1, timeout=120)
        except TimeoutError:
            raise CatalogError(f"--scheduler {scheduler}: expected at least one worker, found none after 120 s "
                               f"(start one with 'dask worker {scheduler}')") from None
        n_workers = len(client.scheduler_info().get("workers", {})) or workers
        from distributed import as_completed

        futures = {client.submit(process_trial, ident, reports, quick, command, pure=False, key=f"trial-{ident.trial_id}"):
                   ident for ident in todo}
        bar = tqdm(total=len(todo), desc="vesselid batch", unit="trial", disable=not progress)
        for fut in as_completed(futures):
            ident = futures[fut]
            try:
                record = fut.result()
            except Exception as exc:  # noqa: BLE001 - a lost worker fails this trial only
                record = _failed_record(ident, f"worker failed: {type(exc).__name__}: {exc}", command)
            with Catalog(catalog, create=True, wait_s=120.0) as cat:
                cat.write(record)
            (ok if record.ok else failed).append(ident.name)
            if not record.ok:
                errors[ident.name] = str(record.trial.get("error"))
            if on_result is not None:
                on_result(record)
            bar.update()
        bar.close()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return BatchSummary(len(identities), skipped, tuple(ok), tuple(failed), time.perf_counter() - t0, n_workers,
                        errors)
