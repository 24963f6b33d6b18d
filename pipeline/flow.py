"""The flow, stage by stage: each function starts from the record of the stage before it.

``read_logs`` -> ``load_trial`` (ingest + align) -> ``segment_trial`` -> ``fit_segments`` ->
``design_autopilot`` -> ``diagnose_trial`` -> ``write_outputs`` (report). :func:`run_flow` chains
them; ``vesselid run`` is manifest -> :func:`run_flow`, and every CLI subcommand calls these same
functions, so ``vesselid report`` and ``vesselid run`` write the same report and ``vesselid
autopilot`` and ``run`` design the same autopilot (one default crossover,
:func:`pipeline.autopilot.pd.default_crossover`). A script can start at any stage (a re-fit never
re-parses logs when it keeps the Trial).
"""

from __future__ import annotations

import contextlib
import datetime
import hashlib
import json
import math
import sys
import threading
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator, Mapping, Sequence

from tqdm import tqdm

from . import __version__
from .align import align
from .atomic import atomic_folder, atomic_path, check_output_folder
from .errors import AutopilotError, DiagnoseError, SegmentError
from .ingest import read_log, read_recordings
from .manifest import expand_logs, scan_logs
from .records import AutopilotResult, Fits, Provenance, RawLog, Segment, Segments, Trial
from .segment import segment_trial
from .terminal import show_progress
from .vessel import Vessel

if TYPE_CHECKING:  # the later stages are imported where they run: they import this module themselves
    from .report import ReportPaths


#: A step shorter than this [s] shows no progress line at all.
PROGRESS_DELAY = 2.0


@contextlib.contextmanager
def progress(total: int, desc: str) -> Iterator[tqdm]:
    """A step counter on the terminal that appears after ``PROGRESS_DELAY`` s and ticks every 0.5 s.

    The elapsed time keeps moving while one long step (a grey-box fit) runs, so the user sees the
    command is alive; nothing is printed when not on a terminal (:func:`show_progress`).

    Parameters
    ----------
    total : int
        Number of steps.
    desc : str
        Label in front of the counter.
    """
    bar = tqdm(total=total, desc=desc, disable=not show_progress(), leave=False, delay=PROGRESS_DELAY,
               bar_format="{desc}: {n_fmt}/{total_fmt} [{elapsed}] {postfix}")
    stop = threading.Event()

    def tick() -> None:
        if stop.wait(PROGRESS_DELAY):
            return
        while not stop.wait(0.5):
            bar.refresh()

    ticker = threading.Thread(target=tick, daemon=True)
    if not bar.disable:
        ticker.start()
    try:
        yield bar
    finally:
        stop.set()
        if ticker.is_alive():
            ticker.join()
        bar.close()


def read_logs(paths: Sequence[str | Path], vessel: Vessel | None = None,
              columns: Mapping[str, str] | None = None, units: Mapping[str, str] | None = None) -> list[RawLog]:
    """Read every log file (ingest stage).

    Parameters
    ----------
    paths : Sequence[str or Path]
        Log files, ROS 2 bag folders, or folders of logs (every log in the folder, sorted by
        name: :func:`pipeline.manifest.expand_logs`), each file read by
        :func:`pipeline.ingest.read_log`.
    vessel : Vessel, optional
        Passed to the readers that map actuator channels (MAVLink, DataFlash) or ROS topics.
    columns : Mapping[str, str], optional
        CSV only: raw column name -> canonical channel.
    units : Mapping[str, str], optional
        CSV only: raw column name -> unit of its values (converted to SI).

    Returns
    -------
    list[RawLog]
        One per file, in the order given (a folder's files in name order); a CSV that stacks several
        recordings gives one per recording (:func:`pipeline.ingest.read_recordings`).

    Raises
    ------
    ConfigError
        A folder with no log in it.
    IngestError
        As the readers.
    """
    return [log for p in expand_logs(paths) for log in read_recordings(p, vessel=vessel, columns=columns, units=units)]


def load_trial(paths: Sequence[str | Path], vessel: Vessel | None = None, name: str | None = None,
               fs: float | None = None, columns: Mapping[str, str] | None = None,
               units: Mapping[str, str] | None = None, runs: Sequence[Sequence[str | Path]] | None = None,
               run_names: Sequence[str] | None = None, input_kinds: Mapping[str, str] | None = None) -> Trial:
    """Ingest and align log files into one Trial of one or more runs.

    Parameters
    ----------
    paths : Sequence[str or Path]
        Log files (or folders of logs) of the same trial (at least one); separate recordings
        become separate runs (:func:`pipeline.align.runs.group_runs`).
    vessel : Vessel, optional
        Passed to the log readers (see :func:`read_logs`) and to :func:`pipeline.align.align`
        (GPS lever arms and dual-antenna headings from its ``[sensors]``).
    name : str, optional
        Trial name; default the stem of the first path.
    fs : float, optional
        Output sample rate [Hz]; default chosen by :func:`pipeline.align.align`.
    columns : Mapping[str, str], optional
        CSV only: raw column name -> canonical channel.
    units : Mapping[str, str], optional
        CSV only: raw column name -> unit of its values (converted to SI).
    runs : Sequence[Sequence[str or Path]], optional
        Stated runs (a manifest's ``[[runs]]``): the files (or folders) of each; default: align
        groups the logs itself.
    run_names : Sequence[str], optional
        Names of the stated runs.
    input_kinds : Mapping[str, str], optional
        Input channel -> ``command`` (held) or ``measured`` (interpolated); see
        :func:`pipeline.align.align`.

    Returns
    -------
    Trial
        ``Trial.runs`` lists the runs with their files, clock offsets, spans and why they were
        grouped so.
    """
    files, left_out = scan_logs(paths)
    logs = read_logs(files, vessel, columns, units)
    stated = None if runs is None else [[str(f) for f in expand_logs(r)] for r in runs]
    trial = align(logs, name=name or Path(paths[0]).stem, fs=fs, vessel=vessel, runs=stated, run_names=run_names,
                  input_kinds=input_kinds)
    return replace(trial, notes=trial.notes + tuple(left_out)) if left_out else trial


def runs_text(trial: Trial) -> str:
    """The runs of a trial and why they were grouped so, for the terminal and the report.

    Parameters
    ----------
    trial : Trial
        An aligned trial.

    Returns
    -------
    str
        One block per run: name, files with clock offsets, span on the trial clock, absolute
        start where known, and the reason for the grouping.
    """
    from .ingest._gpstime import unix_text

    runs = trial.run_list()
    lines = [f"{len(runs)} run(s):"]
    for k, run in enumerate(runs):
        when = (f", starts {unix_text(run.start_time)} UTC" if run.start_time == run.start_time else "")
        lines.append(f"  run {k} {run.name!r}: t = {run.t_start:.2f} .. {run.t_end:.2f} s ({run.duration:.1f} s){when}")
        for src in run.sources:
            off = run.offsets.get(src, 0.0)
            se = run.offset_stderr.get(src, 0.0)
            lines.append(f"    {src}: clock offset {off:+.3f} s +- {se:.2g} s")
        if run.reason:
            lines.append(f"    why: {run.reason}")
    return "\n".join(lines)


def segments_to_json(segments: Segments) -> dict:
    """Segments as a JSON-ready dict (the ``segments.json`` a later ``fit --segments`` reads).

    Parameters
    ----------
    segments : Segments
        Segments of one trial; each item becomes a dict of its fields, and the detector's notes
        (what it left out at a boundary between runs, and why) are kept under ``notes``.
    """
    return {"trial": segments.trial, "segments": [asdict(s) for s in segments.items],
            "notes": list(segments.notes)}


def segments_from_json(path: str | Path) -> Segments:
    """Read ``segments.json`` written by :func:`segments_to_json`.

    Parameters
    ----------
    path : str or Path
        The JSON file; a missing ``trial`` key falls back to the file's stem.

    Raises
    ------
    SegmentError
        Unreadable file, invalid JSON, or no valid ``segments`` list.
    """
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
        items = tuple(Segment(**s) for s in doc["segments"])
        notes = tuple(str(n) for n in doc.get("notes", ()))
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as exc:
        raise SegmentError(f"{p}: expected a segments JSON {{'trial', 'segments': [...]}}, found: {exc}") from None
    return Segments(str(doc.get("trial", p.stem)), items, notes)


def write_json(obj: Any, path: str | Path) -> Path:
    """Write JSON atomically (strict: NaN is not allowed, callers turn it into null).

    Parameters
    ----------
    obj : Any
        JSON-serialisable object, free of NaN and infinity (``json.dumps`` raises ``ValueError``).
    path : str or Path
        Destination file; replaced only once the whole text is written.

    Returns
    -------
    Path
        ``path``.
    """
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(obj, indent=2, allow_nan=False) + "\n")
    return Path(path)


# --------------------------------------------------------------------------- fit, autopilot, diagnose
def fit_segments(trial: Trial, segments: Segments, vessel: Vessel, model: str = "auto") -> Fits:
    """Fit every segment and combine them into coefficients (fit stage).

    Parameters
    ----------
    trial : Trial
        The aligned trial.
    segments : Segments
        Its segments (detected, from a manifest, or from ``segments.json``).
    vessel : Vessel
        Mass, inertia, added mass and restoring.
    model : str
        Damping structure per DOF: ``auto`` (chosen by held-out error), ``linear`` or ``quadratic``
        (see :func:`pipeline.fit.fit_trial`).
    """
    from .fit import fit_trial

    return fit_trial(trial, segments, vessel, model=model)


#: Keys a manifest's ``[autopilot]`` table may hold.
AUTOPILOT_OPTIONS = ("crossover", "phase_margin_deg")


def design_autopilot(fits: Fits, vessel: Vessel | None = None,
                     options: Mapping[str, Any] | None = None) -> AutopilotResult:
    """Design the PD autopilot and Kalman filter from the identified Nomoto K and T (autopilot stage).

    Parameters
    ----------
    fits : Fits
        Needs identified ``K_nomoto`` and ``T_nomoto``.
    vessel : Vessel, optional
        ``[rudder]`` limits; ``[nomoto]`` as the simulated truth of the closed-loop check.
    options : Mapping, optional
        A manifest's ``[autopilot]`` table: ``crossover`` [rad/s] and ``phase_margin_deg`` [deg];
        without ``crossover`` the one default (:func:`pipeline.autopilot.pd.default_crossover`).

    Raises
    ------
    AutopilotError
        An unknown option, or K or T not identified.
    """
    from .autopilot import build_autopilot, nomoto_from_fits

    opts = dict(options or {})
    unknown = sorted(set(opts) - set(AUTOPILOT_OPTIONS))
    if unknown:
        raise AutopilotError(f"manifest [autopilot]: unknown key(s) {unknown}; allowed: {list(AUTOPILOT_OPTIONS)}")
    kwargs: dict[str, float] = {}
    if "crossover" in opts:
        kwargs["crossover"] = float(opts["crossover"])
    if "phase_margin_deg" in opts:
        kwargs["phase_margin"] = math.radians(float(opts["phase_margin_deg"]))
    return build_autopilot(nomoto_from_fits(fits), vessel=vessel, **kwargs)


def diagnose_trial(trial: Trial, vessel: Vessel, fits: Fits, detected: Segments | None = None):
    """Where and why the identified model disagrees with the trial (diagnose stage).

    Parameters
    ----------
    trial : Trial
        The aligned trial.
    vessel : Vessel
        Vessel config.
    fits : Fits
        The fit stage's result.
    detected : Segments, optional
        The segment stage's detection with no manifest segments (``segment_trial(trial)``), which
        the diagnosis then does not run again; default: the diagnosis detects them.

    Returns
    -------
    pipeline.diagnose.records.GapReport

    Raises
    ------
    DiagnoseError
        The trial holds nothing the diagnosis can replay.
    """
    from .diagnose import diagnose
    from .parallel import worker_count

    # The DOFs are cross-validated side by side when the cores allow (the results do not depend on it).
    return diagnose(trial, vessel, fits=fits, jobs=worker_count(), detected=detected)


# --------------------------------------------------------------------------- provenance
def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file (of every file under it, in name order, for a ROS 2 bag folder).

    Parameters
    ----------
    path : str or Path
        Input file or folder.
    """
    h = hashlib.sha256()
    p = Path(path)
    files = sorted(q for q in p.rglob("*") if q.is_file()) if p.is_dir() else [p]
    for f in files:
        with open(f, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def make_provenance(inputs: Sequence[str | Path], argv: Sequence[str] | None = None) -> Provenance:
    """What produced a report: version, UTC time, command line, and input files with their hashes.

    Parameters
    ----------
    inputs : Sequence[str or Path]
        Input files (vessel config, manifest, logs, segments JSON); unreadable ones get an empty hash.
    argv : Sequence[str], optional
        The command line; default ``sys.argv`` with the program shown as ``vesselid``.
    """
    args = list(sys.argv[1:] if argv is None else argv)
    files = []
    for p in inputs:
        try:
            digest = file_sha256(p)
        except OSError:
            digest = ""
        files.append((str(p), digest))
    now = datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0)
    return Provenance(version=f"vesselid {__version__}", created=now.isoformat(),
                      command=" ".join(["vesselid", *args]), inputs=tuple(files))


# --------------------------------------------------------------------------- the whole flow
#: Name of the segments file in a report folder.
SEGMENTS_NAME = "segments.json"
#: Name of the diagnosis file in a report folder.
DIAGNOSIS_NAME = "diagnosis.json"


@dataclass(frozen=True)
class FlowResult:
    """What :func:`run_flow` made.

    Attributes
    ----------
    trial : Trial
    segments : Segments
    fits : Fits
    autopilot : AutopilotResult or None
        None when K or T was not identified (``skipped`` says why).
    diagnosis : GapReport or None
        None when the trial holds nothing to replay (``skipped`` says why).
    report : ReportPaths or None
        The report files; None when no report folder was asked for.
    skipped : Mapping[str, str]
        Stage name -> why it produced nothing.
    """

    trial: Trial
    segments: Segments
    fits: Fits
    autopilot: AutopilotResult | None = None
    diagnosis: Any = None
    report: ReportPaths | None = None
    skipped: Mapping[str, str] = field(default_factory=dict)


STEPS = ("ingest + align", "segment", "fit", "autopilot", "diagnose", "report")


def run_flow(logs: Sequence[str | Path], vessel: Vessel, out: str | Path | None = None, *,
             name: str | None = None, fs: float | None = None, columns: Mapping[str, str] | None = None,
             units: Mapping[str, str] | None = None, manual_segments: Sequence[Mapping[str, Any]] = (),
             segments_mode: str = "replace", segments: Segments | None = None,
             autopilot_options: Mapping[str, Any] | None = None, provenance: Provenance | None = None,
             stop_after: str = "report", trial: Trial | None = None,
             runs: Sequence[Sequence[str | Path]] | None = None, run_names: Sequence[str] | None = None,
             input_kinds: Mapping[str, str] | None = None, model: str = "auto") -> FlowResult:
    """Every stage, in flow order: ingest -> align -> segment -> fit -> autopilot -> diagnose -> report.

    Parameters
    ----------
    logs : Sequence[str or Path]
        Log files of one trial.
    vessel : Vessel
        Vessel config.
    out : str or Path, optional
        Report folder. Checked before any work starts; written as a whole at the end (a staging
        folder swapped in, so a failed or interrupted run leaves the previous report intact).
    name, fs, columns, units
        Trial name, resample rate [Hz], CSV column and unit maps (see :func:`load_trial`).
    manual_segments, segments_mode
        A manifest's ``[[segments]]`` and ``segments_mode`` (see :func:`segment_trial`).
    segments : Segments, optional
        Segments to use instead of detecting them (``--segments SEG.json``).
    autopilot_options : Mapping, optional
        A manifest's ``[autopilot]`` table (see :func:`design_autopilot`).
    provenance : Provenance, optional
        For the report footer; default made from the logs and ``sys.argv``.
    stop_after : str
        Last stage to run: ``fit`` or ``report`` (everything).
    trial : Trial, optional
        An aligned trial to start from instead of reading ``logs``.
    runs, run_names, input_kinds
        Stated runs, their names and input kinds (a manifest's ``[[runs]]`` and ``[inputs]``;
        see :func:`load_trial`).
    model : str
        Damping structure per DOF (see :func:`fit_segments`).

    Returns
    -------
    FlowResult
    """
    if out is not None:
        check_output_folder(out)
    steps = STEPS if stop_after == "report" else STEPS[:STEPS.index(stop_after) + 1]
    with progress(len(steps), "vesselid") as bar:
        load = dict(name=name, fs=fs, columns=columns, units=units, runs=runs, run_names=run_names,
                    input_kinds=input_kinds)
        return _run_steps(bar, steps, logs, vessel, out, load, model, manual_segments,
                          segments_mode, segments, autopilot_options, provenance, stop_after, trial)


def _run_steps(bar, steps, logs, vessel, out, load, model, manual_segments, segments_mode,
               segments, autopilot_options, provenance, stop_after, trial) -> FlowResult:
    """The body of :func:`run_flow`, one progress step per stage (parameters as there)."""
    def step(label: str, fn: Callable[[], Any]) -> Any:
        bar.set_postfix_str(label)
        value = fn()
        bar.update()
        return value

    if trial is None:
        trial = step(steps[0], lambda: load_trial(logs, vessel, **load))
    else:
        bar.update()
    # The segment stage's detection, when it is the diagnosis's own (no manifest segments): handed
    # to the diagnosis, which would otherwise detect the same segments again.
    detected = None
    if segments is None:
        segments = step(steps[1], lambda: segment_trial(trial, manual_segments, segments_mode))
        detected = segments if not manual_segments else None
    else:
        bar.update()
    fits = step(steps[2], lambda: fit_segments(trial, segments, vessel, model))
    if stop_after == "fit":
        return FlowResult(trial, segments, fits)
    skipped: dict[str, str] = {}
    autopilot = diagnosis = None
    try:
        autopilot = step(steps[3], lambda: design_autopilot(fits, vessel, autopilot_options))
    except AutopilotError as exc:
        skipped["autopilot"] = str(exc)
        bar.update()
    try:
        diagnosis = step(steps[4], lambda: diagnose_trial(trial, vessel, fits, detected))
    except DiagnoseError as exc:
        skipped["diagnose"] = str(exc)
        bar.update()
    paths = None
    if out is not None:
        prov = provenance or make_provenance(list(logs))
        paths = step(steps[5], lambda: write_outputs(out, trial, segments, fits, autopilot, diagnosis,
                                                     skipped, prov, vessel))
    return FlowResult(trial, segments, fits, autopilot, diagnosis, paths, skipped)


@dataclass(frozen=True)
class OutputInputs:
    """What :func:`write_outputs`'s units read: the staging folder and the later stages' records."""

    stage: Path
    autopilot: AutopilotResult | None
    diagnosis: Any
    skipped: Mapping[str, str]
    figures: Any


def _output_unit(inputs: OutputInputs, unit) -> Any:
    """One unit of :func:`write_outputs`: a report figure (:func:`pipeline.report.draw_figure`), or
    (``"autopilot"``, ``"diagnosis"``) that stage's files, returning its report section."""
    import html as _html

    if unit == "autopilot":
        from .autopilot import write_autopilot_outputs_and_section

        if inputs.autopilot is None:
            return ("Heading autopilot and Kalman filter",
                    f"<p>No autopilot was designed: {_html.escape(inputs.skipped.get('autopilot', ''))}</p>")
        # The section embeds the figures just written (each drawn once).
        return write_autopilot_outputs_and_section(inputs.autopilot, inputs.stage)[1]
    if unit == "diagnosis":
        from .diagnose.figures import write_figures as write_diagnosis_figures
        from .diagnose.html import diagnose_html_section

        if inputs.diagnosis is None:
            return ("Sim-to-real gap", f"<p>No diagnosis: {_html.escape(inputs.skipped.get('diagnose', ''))}</p>")
        write_json(inputs.diagnosis.to_dict(), inputs.stage / DIAGNOSIS_NAME)
        write_diagnosis_figures(inputs.diagnosis, inputs.stage)
        return diagnose_html_section(inputs.diagnosis)
    from .report import draw_figure

    return draw_figure(inputs.figures, unit)


def write_outputs(out: str | Path, trial: Trial, segments: Segments, fits: Fits,
                  autopilot: AutopilotResult | None, diagnosis, skipped: Mapping[str, str],
                  provenance: Provenance | None = None, vessel: Vessel | None = None) -> ReportPaths:
    """Write the report folder as a whole: segments, coefficients, autopilot, diagnosis, report.

    Everything goes into a staging folder beside ``out`` that replaces ``out`` only once complete
    (:func:`pipeline.atomic.atomic_folder`).

    Parameters
    ----------
    out : str or Path
        Report folder.
    trial, segments, fits
        The records of the earlier stages.
    autopilot : AutopilotResult or None
        The autopilot design; None writes a section saying why (``skipped["autopilot"]``).
    diagnosis : GapReport or None
        The diagnosis; None writes a section saying why (``skipped["diagnose"]``).
    skipped : Mapping[str, str]
        Stage -> reason it produced nothing.
    provenance : Provenance, optional
        Footer of the report.
    vessel : Vessel, optional
        Its ``[added_mass]`` marks derivatives fitted with the added mass taken as zero.
    """
    from .parallel import ordered_map
    from .report import FigureInputs, figure_plan, write_report
    from .report.quality import segment_quality
    from .report.rows import check_fits, segment_list

    check_fits(fits)
    with atomic_folder(out) as stage:
        write_json(segments_to_json(segments), stage / SEGMENTS_NAME)
        qualities = [segment_quality(sf, trial) for sf in fits.segment_fits]
        inputs = OutputInputs(stage, autopilot, diagnosis, dict(skipped),
                              FigureInputs(fits, qualities, trial, segment_list(fits, segments), stage))
        # The autopilot's and the diagnosis's outputs (their figures) and each report figure are
        # independent units: worker processes draw them side by side when the cores allow, the
        # largest units first (the diagnosis's figures, the trial overview, the autopilot's
        # figures). The report page, which embeds them all, is written after.
        plan = figure_plan(fits, qualities, trial)
        overview = [job for job in plan if job.kind == "overview"]
        units = ["diagnosis", *overview, "autopilot", *(job for job in plan if job.kind != "overview")]
        done = ordered_map(_output_unit, units, context=inputs)
        sections = [done[units.index("autopilot")], done[0]]  # flow order: autopilot, then diagnosis
        added = dict(vessel.added_mass) if vessel is not None and vessel.has_rigid_body else None
        paths = write_report(fits, stage, trial=trial, segments=segments, extra_sections=sections,
                             diagnosis=diagnosis, provenance=provenance, added_mass=added,
                             qualities=qualities, figures_written=True)
    return paths.moved_to(Path(out))
