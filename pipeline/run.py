"""``vesselid run``: every stage on one trial manifest, into one report folder."""

from __future__ import annotations

from pathlib import Path

from tqdm import tqdm

from .flow import load_trial, segment_trial, segments_to_json, show_progress, write_json
from .manifest import load_manifest
from .vessel import load_vessel


def run_manifest(manifest_path: str | Path, out: str | Path | None = None) -> Path:
    """Ingest, align, segment, fit, build the autopilot and write the report of one trial.

    Parameters
    ----------
    manifest_path : str or Path
        Trial manifest (:mod:`pipeline.manifest`).
    out : str or Path, optional
        Report folder; default ``reports/<trial name>``.

    Returns
    -------
    Path
        The report folder.
    """
    from .fit import fit_trial
    from .report import write_report

    man = load_manifest(manifest_path)
    out_dir = Path(out) if out else Path("reports") / man.name
    steps = ["ingest + align", "segment", "fit", "autopilot", "report"]
    bar = tqdm(steps, desc=f"vesselid run {man.name}", disable=not show_progress(), leave=False)
    bar.set_postfix_str(steps[0])
    vessel = load_vessel(man.vessel)
    trial = load_trial(man.logs, vessel, name=man.name, fs=man.fs, columns=man.columns, units=man.units)
    bar.update()
    bar.set_postfix_str(steps[1])
    segments = segment_trial(trial, man.segments, man.segments_mode)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json(segments_to_json(segments), out_dir / "segments.json")
    bar.update()
    bar.set_postfix_str(steps[2])
    fits = fit_trial(trial, segments, vessel)
    bar.update()
    bar.set_postfix_str(steps[3])
    extra = []
    try:
        from .autopilot.pipeline_step import autopilot_for_report
    except ImportError:
        autopilot_for_report = None
    if autopilot_for_report is not None:
        extra += list(autopilot_for_report(fits, vessel, out_dir, man))
    bar.update()
    bar.set_postfix_str(steps[4])
    write_report(fits, out_dir, trial=trial, segments=segments, extra_sections=extra)
    bar.update()
    bar.close()
    return out_dir
