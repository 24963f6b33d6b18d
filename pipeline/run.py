"""``vesselid run``: a trial manifest -> :func:`pipeline.flow.run_flow`, into one report folder."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from .flow import FlowResult, make_provenance, run_flow
from .manifest import load_manifest
from .vessel import load_vessel


def run_manifest(manifest_path: str | Path, out: str | Path | None = None,
                 argv: Sequence[str] | None = None) -> FlowResult:
    """Every stage on the trial a manifest names, into one report folder.

    Parameters
    ----------
    manifest_path : str or Path
        Trial manifest (:mod:`pipeline.manifest`).
    out : str or Path, optional
        Report folder; default ``reports/<trial name>``.
    argv : Sequence[str], optional
        The command line for the report footer; default ``sys.argv``.

    Returns
    -------
    FlowResult
        Every stage's record; ``result.report.out_dir`` is the report folder.
    """
    man = load_manifest(manifest_path)
    vessel = load_vessel(man.vessel)
    out_dir = Path(out) if out else Path("reports") / man.name
    prov = make_provenance([man.path, man.vessel, *man.logs], argv)
    return run_flow(man.logs, vessel, out_dir, name=man.name, fs=man.fs, columns=man.columns, units=man.units,
                    manual_segments=man.segments, segments_mode=man.segments_mode,
                    autopilot_options=man.options.get("autopilot"), provenance=prov,
                    runs=man.run_sources, run_names=man.run_names, input_kinds=man.inputs or None)
