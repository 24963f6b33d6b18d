"""``vesselid diagnose --vessel VESSEL.toml LOG.csv [LOG.csv ...] --json OUT.json [--plots DIR]``.

Writes the diagnosis contract (:meth:`pipeline.diagnose.records.GapReport.to_dict`)::

    {"verdict": {"effect": name or null, "dof": name or null}, "gap_before": number,
     "gap_after": number, "shrink": number,
     "candidates": [{"effect", "dof", "gap_before", "gap_after", "shrink", "significant", ...}], ...}

and prints the verdict, the candidates that count and where the gap lives. Every error is a
:class:`pipeline.errors.DiagnoseError` naming what was expected and what was found.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import DiagnoseError, VesselidError


def add_diagnose_parser(subparsers) -> argparse.ArgumentParser:
    """Register the ``diagnose`` subcommand.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``vesselid`` subcommand registry.

    Returns
    -------
    argparse.ArgumentParser
        The subcommand's parser.
    """
    p = subparsers.add_parser(
        "diagnose", help="where and why the identified model disagrees with the boat, and what would fix it",
        description="Replay the logged inputs through the identified first-order models, find where the held-out "
                    "gap lives, test candidate unmodelled effects (nonlinear_damping, current, actuator_delay, "
                    "actuator_rate_limit, thrust_asymmetry, waves, coupling) by cross-validation, and report the "
                    "verdict and how far the gap shrinks.")
    p.add_argument("logs", nargs="+", metavar="LOG", help="log files of one trial (.csv, .tlog, ...)")
    p.add_argument("--vessel", required=True, metavar="VESSEL.toml", help="vessel config (a rudder ship may give only name)")
    p.add_argument("--json", required=True, metavar="OUT.json", help="diagnosis JSON to write")
    p.add_argument("--plots", metavar="DIR", help="write the diagnosis figures into this folder")
    p.add_argument("--fs", type=float, help="resample rate [Hz] (default: the fastest state channel, at most 100)")
    p.add_argument("--segments", metavar="SEGMENTS.json", help="use these segments instead of detecting them")
    p.set_defaults(func=cmd_diagnose)
    return p


def _check_output(path: str, what: str) -> Path:
    out = Path(path)
    if out.exists() and out.is_dir():
        raise DiagnoseError(f"{what}: expected a file path, found a directory at {out}")
    if not out.parent.exists():
        raise DiagnoseError(f"{what}: expected an existing folder for {out.name}, found no folder {out.parent}")
    return out


def _progress():
    """A progress-bar factory on a terminal (tqdm on stderr), None under CI or when piped."""
    from ..flow import show_progress

    if not show_progress():
        return None, None
    from tqdm import tqdm

    holder = {}

    def factory(total: int):
        bar = tqdm(total=total, desc="diagnose", unit="fold", leave=False)
        holder["bar"] = bar
        return lambda: bar.update(1)

    return factory, holder


def cmd_diagnose(args: argparse.Namespace) -> int:
    """Run the diagnosis for the CLI; returns 0 (errors raise :class:`DiagnoseError`)."""
    from ..flow import load_trial, segments_from_json, write_json
    from ..vessel import load_vessel
    from . import diagnose
    from .figures import write_figures
    from .segments import diagnose_segments

    out = _check_output(args.json, "--json")
    if args.fs is not None and not args.fs > 0:
        raise DiagnoseError(f"--fs: expected a positive sample rate [Hz], found {args.fs}")
    try:
        vessel = load_vessel(args.vessel)
        trial = load_trial(args.logs, vessel, fs=args.fs)
        segments = segments_from_json(args.segments) if args.segments else diagnose_segments(trial)
    except DiagnoseError:
        raise
    except VesselidError as exc:
        raise DiagnoseError(str(exc)) from exc
    factory, holder = _progress()
    try:
        report = diagnose(trial, vessel, segments, progress=factory)
    finally:
        if holder and "bar" in holder:
            holder["bar"].close()
    write_json(report.to_dict(), out)
    print(_summary(report))
    print(f"wrote {out}")
    if args.plots:
        paths = write_figures(report, args.plots)
        print(f"wrote {len(paths)} figures to {args.plots}")
    return 0


def _summary(report) -> str:
    """Terminal summary: verdict, the candidates that count, the top places."""
    lines = []
    v = report.verdict
    if v is None:
        lines.append(f"verdict: no effect beyond noise (trial gap {report.gap_before:.3g} noise units)")
    else:
        params = ", ".join(f"{p.name} = {p.value:.4g} +- {p.stderr:.2g} {p.unit}" for p in v.params)
        lines.append(f"verdict: {v.effect} in {v.dof}" + (f" [{v.input_channel}]" if v.input_channel else "")
                     + f": {v.dof} gap {v.gap_before:.3g} -> {v.gap_after:.3g} ({v.shrink:.1f}%), trial gap "
                     f"{report.gap_before:.3g} -> {report.gap_after:.3g} ({report.shrink:.1f}%); {params}")
    shown = [c for c in report.candidates if c.significant] or list(report.candidates[:3])
    lines.append(f"{'dof':<6} {'candidate':<28} {'gap before':>10} {'gap after':>10} {'shrink %':>9} {'p':>9}  significant")
    for c in shown[:10]:
        lines.append(f"{c.dof:<6} {c.label:<28} {c.gap_before:>10.3g} {c.gap_after:>10.3g} {c.shrink:>9.1f} "
                     f"{c.p_value:>9.2g}  {'yes' if c.significant else 'no'}")
    top = [p for p in report.places if p.share > 0][:5]
    if top:
        lines.append("where: " + "; ".join(f"{p.dof} {p.category} {p.name} {100 * p.share:.0f}%" for p in top))
    return "\n".join(lines)
