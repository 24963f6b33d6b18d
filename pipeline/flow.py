"""The flow, stage by stage: each function starts from the record of the stage before it.

``read_logs`` -> ``align`` -> ``segment_trial`` -> ``fit_trial`` -> ``write_report`` (+ autopilot,
diagnosis). The CLI and ``vesselid run`` are thin layers over these functions, so a script can
start at any stage (a re-fit never re-parses logs when it keeps the Trial).
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Mapping, Sequence

from .align import align
from .atomic import atomic_path
from .errors import SegmentError
from .ingest import read_log
from .manifest import expand_logs
from .records import RawLog, Segment, Segments, Trial
from .segment import apply_manifest_segments, detect_segments
from .vessel import Vessel


def show_progress() -> bool:
    """Progress bars on an interactive terminal only; quiet under CI and when piped."""
    return sys.stderr.isatty() and not os.environ.get("CI")


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
        One per file, in the order given (a folder's files in name order).

    Raises
    ------
    ConfigError
        A folder with no log in it.
    IngestError
        As the readers.
    """
    return [read_log(p, vessel=vessel, columns=columns, units=units) for p in expand_logs(paths)]


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
    files = expand_logs(paths)
    logs = read_logs(files, vessel, columns, units)
    stated = None if runs is None else [[str(f) for f in expand_logs(r)] for r in runs]
    return align(logs, name=name or Path(paths[0]).stem, fs=fs, vessel=vessel, runs=stated, run_names=run_names,
                 input_kinds=input_kinds)


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


def segment_trial(trial: Trial, manual: Sequence[Mapping[str, Any]] = (), mode: str = "replace") -> Segments:
    """Detect segments, then apply hand-named ones from a manifest; each is tagged with its run.

    ``Segment.run`` is the index of the run (``Trial.run_list()``) the segment starts in; no
    segment spans a run boundary (the NaN gap between runs cuts every detector).

    Parameters
    ----------
    trial : Trial
        The aligned trial.
    manual : Sequence[Mapping[str, Any]]
        The manifest's ``[[segments]]`` tables; empty keeps the detected segments.
    mode : str
        ``replace`` (only the manifest's segments) or ``add`` (manifest segments plus detected
        ones that do not overlap them); see :func:`pipeline.segment.apply_manifest_segments`.
    """
    segs = apply_manifest_segments(trial, detect_segments(trial), manual, mode)
    return Segments(segs.trial, tuple(replace(s, run=trial.run_index(s.t_start)) for s in segs.items))


def segments_to_json(segments: Segments) -> dict:
    """Segments as a JSON-ready dict (the ``segments.json`` a later ``fit --segments`` reads).

    Parameters
    ----------
    segments : Segments
        Segments of one trial; each item becomes a dict of its fields.
    """
    return {"trial": segments.trial, "segments": [asdict(s) for s in segments.items]}


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
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as exc:
        raise SegmentError(f"{p}: expected a segments JSON {{'trial', 'segments': [...]}}, found: {exc}") from None
    return Segments(str(doc.get("trial", p.stem)), items)


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
