"""One trial of a batch: identify it by its files' content hashes, process it, collect its rows.

:func:`identify_trial` is cheap (hashes only) and decides whether a batch can skip a trial;
:func:`process_trial` runs on a Dask worker, calls the pipeline (:func:`pipeline.run.run_manifest`,
or the fit-only flow with ``quick=True``) into a fresh report folder, and returns a picklable
:class:`TrialRecord` that the batch writes to the catalogue in one transaction. A trial that fails
returns a record with ``status = 'failed'`` and the error, so it never stops the others.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .. import __version__
from ..errors import VesselidError
from ..text_format import finite_or_none

#: Characters kept in a report folder name; everything else becomes ``_``.
_SAFE = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789-_.")


@dataclass(frozen=True)
class TrialIdentity:
    """What makes a processed trial unique: its files' contents and the vesselid version.

    Attributes
    ----------
    trial_id : str
        16 hex digits of SHA-256 over ``files_hash`` and ``package_version``.
    name : str
        The manifest's ``name`` (its file stem when it has none or cannot be read).
    manifest : Path
        The manifest file.
    files : tuple[Mapping[str, Any], ...]
        ``role``, ``path``, ``sha256``, ``size_bytes`` of the manifest, vessel config and logs.
    files_hash : str
        SHA-256 over the roles and content hashes of ``files``, in manifest order.
    package_version : str
        vesselid version that processes (processed) the trial.
    problem : str
        Why the manifest could not be read ("" when it could); the trial will be recorded as failed.
    """

    trial_id: str
    name: str
    manifest: Path
    files: tuple[Mapping[str, Any], ...]
    files_hash: str
    package_version: str
    problem: str = ""


@dataclass(frozen=True)
class TrialRecord:
    """Everything the catalogue stores about one processed (or failed) trial, as table rows.

    Attributes
    ----------
    identity : TrialIdentity
        Files, hashes, version.
    trial : Mapping[str, Any]
        The ``trials`` row (without ``files_hash``, ``package_version`` and ``name``, which come
        from ``identity``).
    vessel : Mapping[str, Any] or None
        The ``vessels`` row; None when the config could not be read.
    runs, segments, coefficients, diagnosis_gaps : tuple[Mapping[str, Any], ...]
        Rows of those tables.
    diagnosis : Mapping[str, Any] or None
        The ``diagnoses`` row.
    """

    identity: TrialIdentity
    trial: Mapping[str, Any]
    vessel: Mapping[str, Any] | None = None
    runs: tuple[Mapping[str, Any], ...] = ()
    segments: tuple[Mapping[str, Any], ...] = ()
    coefficients: tuple[Mapping[str, Any], ...] = ()
    diagnosis: Mapping[str, Any] | None = None
    diagnosis_gaps: tuple[Mapping[str, Any], ...] = field(default_factory=tuple)

    @property
    def ok(self) -> bool:
        """True when the trial was processed without error."""
        return self.trial.get("status") == "ok"


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file's bytes, hex (a ROS 2 bag folder: of its files, in name order).

    Parameters
    ----------
    path : str or Path
        File or folder.
    """
    p = Path(path)
    h = hashlib.sha256()
    files = sorted(x for x in p.rglob("*") if x.is_file()) if p.is_dir() else [p]
    for f in files:
        if p.is_dir():
            h.update(str(f.relative_to(p)).encode())
        with open(f, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def _size(p: Path) -> int:
    return sum(x.stat().st_size for x in p.rglob("*") if x.is_file()) if p.is_dir() else p.stat().st_size


def _fallback_name(path: Path) -> str:
    """The ``name`` of a manifest that does not load, else its folder's name for ``trial.toml``."""
    import tomllib

    try:
        name = tomllib.loads(path.read_text(encoding="utf-8")).get("name")
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        name = None
    return str(name) if isinstance(name, str) and name else (path.parent.name if path.stem == "trial" else path.stem)


def identify_trial(manifest: str | Path, version: str = __version__) -> TrialIdentity:
    """Hash a trial's manifest, vessel config and logs.

    Parameters
    ----------
    manifest : str or Path
        Trial manifest (:mod:`pipeline.manifest`).
    version : str
        vesselid version the identity is for (default: this one).

    Returns
    -------
    TrialIdentity
        With ``problem`` set (and only the manifest hashed) when the manifest cannot be read.
    """
    from ..manifest import load_manifest

    path = Path(manifest).resolve()
    entries: list[tuple[str, Path]] = [("manifest", path)]
    name, problem = path.stem, ""
    try:
        man = load_manifest(path)
        name = man.name
        entries.append(("vessel", man.vessel))
        entries += [("log", p) for p in man.logs]
    except VesselidError as exc:
        problem = str(exc)
        name = _fallback_name(path)
    files = []
    for role, p in entries:
        try:
            files.append({"role": role, "path": str(p), "sha256": file_sha256(p), "size_bytes": _size(p)})
        except OSError as exc:
            problem = problem or f"{p}: expected a readable {role} file, found {exc.strerror or exc}"
    h = hashlib.sha256()
    for f in files:
        h.update(f"{f['role']}:{f['sha256']}\n".encode())
    files_hash = h.hexdigest()
    trial_id = hashlib.sha256(f"{files_hash}\n{version}".encode()).hexdigest()[:16]
    return TrialIdentity(trial_id, name, path, tuple(files), files_hash, version, problem)


def report_folder(reports: str | Path, identity: TrialIdentity) -> Path:
    """The report folder of a trial: ``<reports>/<name>-<first 8 digits of the trial id>``.

    Parameters
    ----------
    reports : str or Path
        Root folder of the batch's reports.
    identity : TrialIdentity
        The trial.
    """
    safe = "".join(c if c in _SAFE else "_" for c in identity.name) or "trial"
    return Path(reports).resolve() / f"{safe}-{identity.trial_id[:8]}"


def model_structure(method: str) -> str:
    """The model named at the start of a coefficient's ``method`` text.

    The fit stage writes ``method`` as "<model> on <data>; <how combined>"; the model is the text
    before the first " on ", " to ", ";", "(" or ",".

    Parameters
    ----------
    method : str
        The coefficient's method text (``coefficients.json``).
    """
    cut = len(method)
    for sep in (" on ", " to ", ";", "(", ","):
        i = method.find(sep)
        if i > 0:
            cut = min(cut, i)
    return method[:cut].strip()


def _coefficient_rows(doc: Mapping[str, Any]) -> tuple[dict, ...]:
    rows = []
    for name, c in doc.get("coefficients", {}).items():
        ci = c.get("ci95") or [None, None]
        method = str(c.get("method") or "")
        rows.append({"name": name, "value": finite_or_none(c.get("value")), "stderr": finite_or_none(c.get("stderr")),
                     "ci_low": finite_or_none(ci[0]), "ci_high": finite_or_none(ci[1]), "unit": c.get("unit") or "",
                     "n_segments": int(c.get("n_segments") or 0), "structure": model_structure(method),
                     "method": method, "success": bool(c.get("success")), "message": str(c.get("message") or ""),
                     "consistency_p": finite_or_none(c.get("consistency_p"))})
    return tuple(rows)


def _segment_rows(doc: Mapping[str, Any]) -> tuple[dict, ...]:
    keys = ("kind", "dof", "t_start", "t_end", "input_channel", "quality", "origin", "label")
    return tuple({"seg_index": i, **{k: s.get(k) for k in keys}} for i, s in enumerate(doc.get("segments", [])))


def _diagnosis_rows(doc: Mapping[str, Any] | None, quick: bool) -> tuple[dict, tuple[dict, ...]]:
    if doc is None:
        why = ("not run (quick batch: single-DOF fits and report only)" if quick
               else "no diagnosis: the trial has no manoeuvre the diagnosis can replay (see report.html)")
        return {"status": "not run" if quick else "none", "effect": None, "dof": None, "gap_before": None,
                "gap_after": None, "shrink": None, "message": why}, ()
    verdict = doc.get("verdict") or {}
    effect = verdict.get("effect")
    num = finite_or_none
    row = {"status": "effect found" if effect else "no effect found", "effect": effect, "dof": verdict.get("dof"),
           "gap_before": num(doc.get("gap_before")), "gap_after": num(doc.get("gap_after")),
           "shrink": num(doc.get("shrink")), "message": "; ".join(str(n) for n in doc.get("notes", []))[:2000]}
    gaps = tuple({"dof": d.get("dof"), "gap": num(d.get("gap")), "noise_floor": num(d.get("noise_floor")),
                  "replay_gap": num(d.get("replay_gap"))} for d in doc.get("dofs", []))
    return row, gaps


def _when_and_where(logs, trial) -> dict:
    """Start time from the logs' absolute clocks; place from the median position."""
    starts = [(lg.start_time, lg.format) for lg in logs if math.isfinite(lg.start_time)]
    out: dict[str, Any] = {"started_utc": None, "date_source": "none: no log has an absolute clock",
                           "lat": None, "lon": None, "place_source": "none: no position channel"}
    if starts:
        t0, fmt = min(starts)
        out["started_utc"] = float(t0)
        out["date_source"] = f"log clock ({fmt})"
    if trial.has("lat") and trial.has("lon"):
        out["lat"] = finite_or_none(np.nanmedian(trial.data["lat"].to_numpy()))
        out["lon"] = finite_or_none(np.nanmedian(trial.data["lon"].to_numpy()))
        out["place_source"] = "median position of the aligned trial (lat, lon)"
    return out


def _run_row(trial) -> dict:
    t = trial.t
    return {"run_index": 0, "fs": float(trial.fs), "duration_s": float(t[-1] - t[0]) if len(t) else 0.0,
            "n_samples": int(len(t)), "channels": ",".join(c for c in trial.data.columns if c != "t"),
            "sources": ",".join(trial.sources), "n_gaps": len(trial.gaps), "notes": "; ".join(trial.notes)[:2000]}


def _read_json(path: Path) -> Any:
    return json.loads(path.read_text()) if path.is_file() else None


def _swap_in(tmp: Path, final: Path) -> None:
    """Replace ``final`` by ``tmp`` (a reader sees the old or the new folder, each complete)."""
    old = final.with_name(f".{final.name}.old-{os.getpid()}")
    if final.exists():
        os.replace(final, old)
    os.replace(tmp, final)
    shutil.rmtree(old, ignore_errors=True)


def process_trial(identity: TrialIdentity, reports: str | Path, quick: bool = False, command: str = "") -> TrialRecord:
    """Process one trial into its report folder and return its catalogue rows.

    The report is written to a hidden sibling folder first and swapped in only when complete, so
    a killed run never leaves a half-written report under the trial's name. Any error is caught and
    returned as a failed record (with the error text), so one bad trial does not stop a batch.

    Parameters
    ----------
    identity : TrialIdentity
        From :func:`identify_trial`.
    reports : str or Path
        Root folder of the reports; the trial's folder is :func:`report_folder`.
    quick : bool
        False: every stage (:func:`pipeline.run.run_manifest`: fits with the joint grey-box
        extension, autopilot, gap diagnosis, report). True: single-DOF fits and the report only.
    command : str
        The command line that started the batch, recorded with the trial.

    Returns
    -------
    TrialRecord
    """
    started = time.time()
    final = report_folder(reports, identity)
    tmp = final.with_name(f".{final.name}.partial-{os.getpid()}")
    base = {"manifest_path": str(identity.manifest), "report_dir": str(final), "mode": "quick" if quick else "full",
            "command": command, "processed_at": started}
    vessel_row = None
    try:
        if identity.problem:
            raise VesselidError(identity.problem)
        from ..align import align
        from ..flow import read_logs, segment_trial, segments_to_json, write_json
        from ..manifest import load_manifest
        from ..vessel import load_vessel

        man = load_manifest(identity.manifest)
        vessel = load_vessel(man.vessel)
        vfile = next(f for f in identity.files if f["role"] == "vessel")
        vessel_row = {"config_hash": vfile["sha256"], "name": vessel.name, "config_path": vfile["path"],
                      "config_text": Path(vfile["path"]).read_text(encoding="utf-8", errors="replace")}
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        logs = read_logs(man.logs, vessel, man.columns, man.units)
        trial = align(logs, name=man.name, fs=man.fs, vessel=vessel)
        meta = _when_and_where(logs, trial)
        if quick:
            from ..fit import fit_trial
            from ..report import write_report

            segments = segment_trial(trial, man.segments, man.segments_mode)
            write_json(segments_to_json(segments), tmp / "segments.json")
            fits = fit_trial(trial, segments, vessel, extend=False)
            write_report(fits, tmp, trial=trial, segments=segments)
        else:
            from ..run import run_manifest

            run_manifest(identity.manifest, tmp)
        coefs = _read_json(tmp / "coefficients.json") or {}
        diag, gaps = _diagnosis_rows(_read_json(tmp / "diagnosis.json"), quick)
        segs = _read_json(tmp / "segments.json") or {}
        _swap_in(tmp, final)
        row = {**base, **meta, "status": "ok", "error": None, "vessel_hash": vessel_row["config_hash"],
               "vessel_name": vessel.name, "duration_s": time.time() - started}
        return TrialRecord(identity, row, vessel_row, (_run_row(trial),), _segment_rows(segs),
                           _coefficient_rows(coefs), diag, gaps)
    except Exception as exc:  # noqa: BLE001 - one failing trial is recorded, never stops the batch
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, VesselidError):
            error = str(exc)
        else:
            where = traceback.extract_tb(exc.__traceback__)[-1]
            error = f"unexpected {type(exc).__name__} in {Path(where.filename).name}:{where.lineno}: {exc}"
        row = {**base, "status": "failed", "error": error, "report_dir": None,
               "vessel_hash": vessel_row["config_hash"] if vessel_row else None,
               "vessel_name": vessel_row["name"] if vessel_row else None, "started_utc": None,
               "date_source": None, "lat": None, "lon": None, "place_source": None,
               "duration_s": time.time() - started}
        return TrialRecord(identity, row, vessel_row)
