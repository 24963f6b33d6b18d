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
    steps = ["ingest + align", "segment", "fit", "autopilot", "diagnose", "report"]
    bar = tqdm(steps, desc=f"vesselid run {man.name}", disable=not show_progress(), leave=False)
    bar.set_postfix_str(steps[0])
    vessel = load_vessel(man.vessel)
    trial = load_trial(man.logs, vessel, name=man.name, fs=man.fs, columns=man.columns, units=man.units,
                       runs=man.run_sources, run_names=man.run_names, input_kinds=man.inputs or None)
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
    extra += _diagnosis_section(trial, vessel, fits, out_dir)
    bar.update()
    bar.set_postfix_str(steps[5])
    write_report(fits, out_dir, trial=trial, segments=segments, extra_sections=extra)
    bar.update()
    bar.close()
    return out_dir


def _diagnosis_section(trial, vessel, fits, out_dir: Path) -> list[tuple[str, str]]:
    """Run the gap diagnosis, write ``diagnosis.json`` and its figures, return the report section.

    A trial the diagnosis cannot use (no manoeuvre it can replay) gets a section saying why.

    Parameters
    ----------
    trial : pipeline.records.Trial
        The aligned trial.
    vessel : pipeline.vessel.Vessel
        Vessel config.
    fits : pipeline.records.Fits
        The fit stage's result.
    out_dir : Path
        Report folder.
    """
    import html

    from .diagnose import diagnose
    from .diagnose.figures import write_figures
    from .diagnose.html import diagnose_html_section
    from .errors import DiagnoseError

    title = "Sim-to-real gap"
    try:
        report = diagnose(trial, vessel, fits=fits)
    except DiagnoseError as exc:
        return [(title, f"<p>No diagnosis: {html.escape(str(exc))}</p>")]
    write_json(report.to_dict(), out_dir / "diagnosis.json")
    write_figures(report, out_dir)
    return [diagnose_html_section(report)]
