"""CE6 Limfjord coast-downs through the whole pipeline: ingest -> align -> segment -> fit -> report.

The CE6 boat's logs (``../shared/realdata/ce6-boat-limfjord-2022``, see its SOURCE.md) are 20 Hz
NMEA GPS files without heading or actuator channels; the throttle cut of a coast-down is not
logged. This script reads every NMEA file of the folder, lets the pipeline find the input-free
coast-downs (:mod:`pipeline.segment.speed_events`), fits them, and writes

- ``<out>/<run>/`` the pipeline's report (``report.html`` with the segment table, figures,
  ``coefficients.json``) for every run where a coast-down was found;
- ``<out>/summary.md`` and ``summary.json``: every file with its coast-downs (cut time, speeds,
  fitted time constant with standard error) and the reasons candidates were rejected, the
  time constants per run direction (E against W) and, for comparison, the authors' cut times.

The real data are for internal testing only: nothing is copied into the project, and the script
does nothing (exit 0) when the folder is absent.

Usage::

    .venv/bin/python benchmarks/ce6_coastdowns.py [--data DIR] [--out reports/ce6]
"""

from __future__ import annotations

import argparse
import html
import json
import math
import re
import sys
import time
from collections import Counter, defaultdict
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.align import align  # noqa: E402
from pipeline.errors import FitError, VesselidError  # noqa: E402
from pipeline.fit import fit_trial  # noqa: E402
from pipeline.fit.first_order import fit_step  # noqa: E402
from pipeline.flow import segment_trial  # noqa: E402
from pipeline.ingest import read_log  # noqa: E402
from pipeline.ingest.nmea import looks_like_nmea  # noqa: E402
from pipeline.report import write_report  # noqa: E402
from pipeline.segment.speed_events import find_coast_downs  # noqa: E402
from pipeline.vessel import load_vessel  # noqa: E402

DATA = ROOT.parent / "shared" / "realdata" / "ce6-boat-limfjord-2022"
OUT = ROOT / "reports" / "ce6"
VESSEL = ROOT / "vessel_configs" / "ce6.toml"


def nmea_files(data: Path) -> list[Path]:
    """Every NMEA log under ``data/Estimations`` (by content: the folder also holds result notes).

    Parameters
    ----------
    data : Path
        The CE6 folder.
    """
    return [p for p in sorted((data / "Estimations").rglob("*")) if p.is_file()
            and p.suffix.lower() in (".txt", ".log") and looks_like_nmea(p)]


def authors_cut_times(data: Path) -> dict[str, float]:
    """The authors' start of the deceleration interval per VirtualMass run [s] (virtualmassResults.txt).

    Parameters
    ----------
    data : Path
        The CE6 folder.
    """
    out: dict[str, float] = {}
    for notes in (data / "Estimations").rglob("virtualmassResults.txt"):
        text = notes.read_text(errors="replace")
        for name, t in re.findall(r"(throt\d+[EW]\.txt):\s*\n\s*([\d.]+),", text):
            out[f"{notes.parent.relative_to(data / 'Estimations')}/{name}"] = float(t)
    return out


def _direction(name: str) -> str:
    m = re.search(r"throt\d+([EW])\.txt$", name)
    return m.group(1) if m else ""


def _slug(rel: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", rel.rsplit(".", 1)[0])


def _candidates_html(cands) -> str:
    rows = "".join(f"<tr><td>{c.t_start:.2f}</td><td>{c.t_end:.2f}</td><td>{'yes' if c.accepted else 'no'}</td>"
                   f"<td>{html.escape(c.reason)}</td></tr>" for c in cands)
    return ("<p>Decelerations examined by the input-free coast-down detector (pipeline.segment.speed_events); "
            "the throttle cut is not logged in these files.</p><table><tr><th>start [s]</th><th>end [s]</th>"
            f"<th>coast-down</th><th>detection</th></tr>{rows}</table>")


def _offset_fit(trial, seg) -> tuple[float, float, float]:
    """T [s], its stderr and the final level y_ss [m/s] of a first-order decay to a free level.

    A sensitivity check, not the pipeline's coast-down model (which decays to zero): a current
    under the boat makes the speed over ground settle at the current, not at zero.
    """
    try:
        sf = fit_step(trial, replace(seg, kind="step"))
    except FitError:
        return math.nan, math.nan, math.nan
    return sf.params.get("T", math.nan), sf.stderr.get("T", math.nan), sf.params.get("y_ss", math.nan)


def _wmean(values, errors) -> tuple[float, float, float]:
    """Inverse-variance mean, its standard error, and the Birge ratio sqrt(chi2/(k-1))."""
    v, e = np.asarray(values, float), np.asarray(errors, float)
    ok = np.isfinite(v) & np.isfinite(e) & (e > 0)
    if not ok.any():
        return math.nan, math.nan, math.nan
    w = 1 / e[ok] ** 2
    m = float(np.sum(w * v[ok]) / np.sum(w))
    se = float(1 / math.sqrt(np.sum(w)))
    k = int(ok.sum())
    birge = float(math.sqrt(np.sum(w * (v[ok] - m) ** 2) / (k - 1))) if k > 1 else math.nan
    return m, se, birge


def run(data: Path = DATA, out: Path = OUT, vessel_path: Path = VESSEL, write_reports: bool = True) -> dict:
    """Run the pipeline on every CE6 NMEA file and write the reports and the summary.

    Parameters
    ----------
    data : Path
        The CE6 folder (``Estimations/`` inside).
    out : Path
        Output folder (per-run reports and ``summary.md``/``summary.json``).
    vessel_path : Path
        Vessel config (name only: the boat's mass is not known).
    write_reports : bool
        Write the per-run reports (the summary is always written).

    Returns
    -------
    dict
        ``files`` (per file: segments with fits, rejected candidates), ``directions`` (T per run
        direction) and ``seconds`` (wall time).
    """
    t_start = time.perf_counter()
    vessel = load_vessel(vessel_path)
    authors = authors_cut_times(data)
    files = []
    reasons: Counter = Counter()
    for path in nmea_files(data):
        rel = str(path.relative_to(data / "Estimations"))
        entry = {"file": rel, "folder": str(Path(rel).parent), "segments": [], "rejected": [], "error": ""}
        try:
            trial = align([read_log(path)], name=_slug(rel))
            segments = segment_trial(trial)
            _, cands = find_coast_downs(trial)
            coast = segments.of("coast_down", "surge")
            fits = fit_trial(trial, segments, vessel) if coast else None
        except VesselidError as exc:
            entry["error"] = str(exc)
            files.append(entry)
            continue
        for c in cands:
            if not c.accepted:
                kind = c.reason.split(":")[0].split(" (")[0]
                kind = re.sub(r"[\d.]+", "#", kind)
                reasons[kind] += 1
                entry["rejected"].append({"t_start": c.t_start, "t_end": c.t_end, "reason": c.reason})
        if fits is not None:
            by_seg = {sf.segment: sf for sf in fits.segment_fits}
            for seg in coast:
                sf = by_seg.get(seg)
                t_off, se_off, y_ss = _offset_fit(trial, seg)
                entry["segments"].append({
                    "t_start": seg.t_start, "t_end": seg.t_end, "quality": seg.quality, "label": seg.label,
                    "channel": sf.channel if sf else "", "T": sf.params.get("T", math.nan) if sf else math.nan,
                    "T_stderr": sf.stderr.get("T", math.nan) if sf else math.nan,
                    "y0": sf.params.get("y0", math.nan) if sf else math.nan,
                    "fit_success": bool(sf and sf.success), "fit_message": sf.message if sf else "not fitted",
                    "T_to_level": t_off, "T_to_level_stderr": se_off, "level": y_ss,
                    "authors_cut": authors.get(rel, math.nan)})
            if write_reports:
                write_report(fits, out / _slug(rel), trial=trial, segments=segments,
                             extra_sections=[("Coast-down detection", _candidates_html(cands))])
                entry["report"] = str((out / _slug(rel) / "report.html").relative_to(out))
        files.append(entry)

    directions = {}
    for d in ("E", "W"):
        rows = [s for f in files if "VirtualMass" in f["folder"] and _direction(f["file"]) == d for s in f["segments"]]
        m, se, birge = _wmean([s["T"] for s in rows], [s["T_stderr"] for s in rows])
        m2, se2, birge2 = _wmean([s["T_to_level"] for s in rows], [s["T_to_level_stderr"] for s in rows])
        directions[d] = {"n": len(rows), "T_mean": m, "T_se": se, "T_birge": birge,
                         "T_spread": float(np.std([s["T"] for s in rows], ddof=1)) if len(rows) > 1 else math.nan,
                         "T_to_level_mean": m2, "T_to_level_se": se2, "T_to_level_birge": birge2,
                         "level_mean": float(np.nanmean([s["level"] for s in rows])) if rows else math.nan}
    summary = {"data": str(data), "files": files, "directions": directions, "rejections": dict(reasons),
               "seconds": time.perf_counter() - t_start}
    out.mkdir(parents=True, exist_ok=True)
    (out / "summary.json").write_text(json.dumps(_jsonable(summary), indent=2) + "\n")
    (out / "summary.md").write_text(summary_markdown(summary))
    return summary


def _jsonable(obj):
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    return obj


def _f(x: float, fmt: str = ".2f") -> str:
    return format(x, fmt) if isinstance(x, float) and math.isfinite(x) else "-"


def summary_markdown(summary: dict) -> str:
    """The summary as Markdown: coast-downs per file, T per direction, rejection reasons.

    Parameters
    ----------
    summary : dict
        The return value of :func:`run`.
    """
    lines = ["# CE6 coast-downs (pipeline, input-free detection)", "",
             f"Data: `{summary['data']}`; {len(summary['files'])} NMEA files; "
             f"{summary['seconds']:.1f} s.", "",
             "| file | cut [s] | authors' cut [s] | end [s] | speed [m/s] | T (decay to 0) [s] | "
             "T (decay to a level) [s] | level [m/s] | fit |", "|---|---|---|---|---|---|---|---|---|"]
    per_folder: Counter = Counter()
    found: Counter = Counter()
    for f in summary["files"]:
        per_folder[f["folder"]] += 1
        found[f["folder"]] += len(f["segments"])
        for s in f["segments"]:
            speeds = re.search(r"then ([\d.]+ -> [\d.]+) m/s", s["label"])
            lines.append(f"| {f['file']} | {s['t_start']:.2f} | {_f(s['authors_cut'])} | {s['t_end']:.2f} | "
                         f"{speeds.group(1) if speeds else ''} | {_f(s['T'])} +- {_f(s['T_stderr'], '.2f')} | "
                         f"{_f(s['T_to_level'])} +- {_f(s['T_to_level_stderr'])} | {_f(s['level'])} | "
                         f"{'ok' if s['fit_success'] else 'failed'} |")
    lines += ["", "| folder | files | coast-downs found |", "|---|---|---|"]
    lines += [f"| {k} | {v} | {found[k]} |" for k, v in sorted(per_folder.items())]
    lines += ["", "| direction (VirtualMass runs) | n | T (decay to 0), weighted mean [s] | Birge ratio | "
              "run-to-run std [s] | T (decay to a level) [s] | mean level [m/s] |", "|---|---|---|---|---|---|---|"]
    for d, r in summary["directions"].items():
        lines.append(f"| {d} | {r['n']} | {_f(r['T_mean'])} +- {_f(r['T_se'])} | {_f(r['T_birge'], '.1f')} | "
                     f"{_f(r['T_spread'])} | {_f(r['T_to_level_mean'])} +- {_f(r['T_to_level_se'])} | "
                     f"{_f(r['level_mean'])} |")
    lines += ["", "Rejected candidates by reason:", ""]
    lines += [f"- {k}: {v}" for k, v in sorted(summary["rejections"].items(), key=lambda kv: -kv[1])]
    errors = [f for f in summary["files"] if f["error"]]
    if errors:
        lines += ["", "Files that could not be processed:", ""] + [f"- {f['file']}: {f['error']}" for f in errors]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    """Command line: run on the CE6 folder and print the summary (exit 0 when the folder is absent).

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments (``--data``, ``--out``, ``--no-reports``).
    """
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=DATA, help="CE6 folder (default ../shared/realdata/...)")
    ap.add_argument("--out", type=Path, default=OUT, help="output folder (default reports/ce6)")
    ap.add_argument("--no-reports", action="store_true", help="write only the summary")
    args = ap.parse_args(argv)
    if not (args.data / "Estimations").is_dir():
        print(f"CE6 data not found at {args.data}: nothing to do")
        return 0
    summary = run(args.data, args.out, write_reports=not args.no_reports)
    print(summary_markdown(summary))
    print(f"wrote {args.out / 'summary.md'} and the per-run reports in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
