"""``vesselid diagnose --vessel VESSEL.toml LOG.csv [LOG.csv ...] --json OUT.json [--plots DIR]``.

Writes the diagnosis contract (:meth:`pipeline.diagnose.records.GapReport.to_dict`)::

    {"verdict": {"effect": name or null, "dof": name or null}, "gap_before": number,
     "gap_after": number, "shrink": number,
     "candidates": [{"effect", "dof", "gap_before", "gap_after", "shrink", "significant", ...}],
     "effects": [{"step", "effect", "dof", "gap_before", "gap_after", "shrink", "trial_gap_after", ...}],
     "gap_final": number, "unexplained": [{"dof", "channel", "gap", "share", "place", "band",
     "correlations", "looks_like", ...}], "status": "model fine" | "explained" | "partly explained" |
     "unexplained", "ranking_rule": text, "unexplained_test": text, ...}

``verdict`` is the first of ``effects`` (forward selection). Effect names: the candidates'
(``nonlinear_damping``, ``current``, ``actuator_delay``, ``actuator_rate_limit``, ``thrust_asymmetry``,
``waves``, ``coupling``, ``sensor_bias``, and with an actuator allocation ``thrust_imbalance``: one
thruster pushing more or less than the other, relative to their allocation) and ``sensor_delay`` (an
input delay that another channel driven by the same inputs does not show). An effect whose ``why``
starts with ``unsure:`` is one the held-out data cannot tell from another (a rate limit on top of a
delay of the same input). It prints what is unexplained first, then the verdict and the further
effects, the candidates that count and where the gap lives. Every error is a
:class:`pipeline.errors.DiagnoseError` naming what was expected and what was found.
"""

from __future__ import annotations

import argparse
import os
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
                    "actuator_rate_limit, thrust_asymmetry, thrust_imbalance, waves, coupling, sensor_bias) by cross-validation, and report the "
                    "verdict and how far the gap shrinks.")
    p.add_argument("logs", nargs="+", metavar="LOG", help="log files of one trial (.csv, .tlog, ...)")
    p.add_argument("--vessel", required=True, metavar="VESSEL.toml", help="vessel config (a rudder ship may give only name)")
    p.add_argument("--json", required=True, metavar="OUT.json", help="diagnosis JSON to write")
    p.add_argument("--plots", metavar="DIR", help="write the diagnosis figures into this folder")
    p.add_argument("--fs", type=float, help="resample rate [Hz] (default: the fastest state channel, at most 100)")
    p.add_argument("--segments", metavar="SEGMENTS.json", help="use these segments instead of detecting them")
    p.add_argument("--jobs", type=int, default=None, metavar="N",
                   help="processes that analyse the DOFs side by side (default: 2, or 1 on a one-core machine)")
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
    jobs = args.jobs if args.jobs is not None else min(2, os.cpu_count() or 1)
    if jobs < 1:
        raise DiagnoseError(f"--jobs: expected a positive number of processes, found {args.jobs}")
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
        report = diagnose(trial, vessel, segments, progress=factory, jobs=jobs)
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


def _unexplained_lines(report) -> list[str]:
    """What is left unexplained, printed before anything else (never reads as "model fine")."""
    lines = []
    if report.unexplained:
        head = ("UNEXPLAINED: no library effect explains the gap" if not report.effects else
                "UNEXPLAINED: a gap is left after the selected effects")
        lines.append(f"{head} (trial gap {report.gap_before:.3g} -> {report.gap_final:.3g} noise units; "
                     f"1 = sensor noise only)")
        for u in report.unexplained[:5]:
            lines.append(f"  {u.dof} {u.channel}: gap {u.gap:.3g} noise units, {100 * u.share:.0f}% of what is left"
                         + (f", mostly in {u.place}" if u.place else "") + f"; {u.looks_like}")
    return lines


def _summary(report) -> str:
    """Terminal summary: what is unexplained first, then the verdict and further effects, the
    candidates that count, and the top places."""
    lines = _unexplained_lines(report)
    v = report.verdict
    if not report.effects:
        if report.unexplained:
            lines.append("verdict: none of the library's effects is significant -- the model is NOT fine, see above")
        else:
            floors = [f"{d.dof} {ch} {f:.3g}" for d in report.dofs
                      for ch, f in getattr(d, "heldout_floor", {}).items() if f >= 1.5]
            lines.append(f"verdict: no effect, and nothing left above what a correct model leaves (trial gap "
                         f"{report.gap_before:.3g} noise units"
                         + (f"; held-out floor, the gap of a correct model whose fitted parameters carry the "
                            f"noise: {', '.join(floors)}" if floors else "") + ")")
    for e in report.effects:
        params = ", ".join(f"{p.name} = {p.value:.4g} +- {p.stderr:.2g} {p.unit}" for p in e.params)
        head = "verdict" if e.step == 1 else f"effect {e.step}"
        lines.append(f"{head}: {e.effect} in {e.dof}" + (f" [{e.input_channel}]" if e.input_channel else "")
                     + f": {e.dof} gap {e.gap_before:.3g} -> {e.gap_after:.3g} ({e.shrink:.1f}%), trial gap now "
                     f"{e.trial_gap_after:.3g}; {params}" + (f" ({e.why})" if e.why else ""))
    if report.effects:
        lines.append(f"trial gap {report.gap_before:.3g} -> {report.gap_final:.3g} noise units with every selected "
                     f"effect (verdict alone: {report.gap_after:.3g})")
    shown = [c for c in report.candidates if c.significant] or list(report.candidates[:3])
    # Wide enough for the longest label shown (an actuator's name, a composed transform).
    w = max([28] + [len(c.label) for c in shown[:10]])
    lines.append(f"{'dof':<6} {'candidate':<{w}} {'gap before':>10} {'gap after':>10} {'shrink %':>9} {'p':>9}  significant")
    for c in shown[:10]:
        lines.append(f"{c.dof:<6} {c.label:<{w}} {c.gap_before:>10.3g} {c.gap_after:>10.3g} {c.shrink:>9.1f} "
                     f"{c.p_value:>9.2g}  {'yes' if c.significant else 'no'}")
    top = [p for p in report.places if p.share > 0][:5]
    if top:
        lines.append("where: " + "; ".join(f"{p.dof} {p.category} {p.name} {100 * p.share:.0f}%" for p in top))
    lines.append(f"ranking: {report.ranking_rule}")
    del v
    return "\n".join(lines)
