"""The ``vesselid`` command line: one subcommand per stage, in flow order, plus ``run``.

Every command has ``--help``, returns 0 on success, and on bad input prints ``error: ...`` (what
was expected and what was found) to stderr and returns a non-zero code, never a traceback.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Sequence

from . import __version__
from .errors import VesselidError

EXIT_BAD_INPUT = 2


def _vessel(path: str | None):
    from .vessel import load_vessel

    return load_vessel(path) if path else None


def cmd_ingest(args: argparse.Namespace) -> int:
    """``vesselid ingest``: read each log and print its summary and channels.

    Parameters
    ----------
    args : argparse.Namespace
        ``logs`` (log paths) and ``vessel`` (vessel TOML or None).

    Returns
    -------
    int
        0 (errors are raised and turned into an exit code by :func:`main`).
    """
    from .flow import read_logs

    for log in read_logs(args.logs, _vessel(args.vessel)):
        print(log.summary.text())
        for name, ch in sorted(log.channels.items()):
            print(f"  {name:<12} {len(ch.t):>8} samples  {ch.t[0]:10.3f} .. {ch.t[-1]:10.3f} s  [{ch.unit}]  from {ch.source}")
    return 0


def cmd_align(args: argparse.Namespace) -> int:
    """``vesselid align``: align the logs into one trial, print the notes, optionally write it.

    Parameters
    ----------
    args : argparse.Namespace
        ``logs`` (log paths), ``vessel`` (vessel TOML or None), ``fs`` (resample rate [Hz] or
        None) and ``out`` (canonical CSV to write, or None).

    Returns
    -------
    int
        0 (errors are raised and turned into an exit code by :func:`main`).
    """
    from .flow import load_trial
    from .records import Channel, IngestSummary, RawLog
    from .sim.writers.csv_writer import write_csv_log

    trial = load_trial(args.logs, _vessel(args.vessel), fs=args.fs)
    for note in trial.notes:
        print(f"note: {note}")
    if args.out:
        t = trial.t
        chans = {c: Channel(c, t, trial.data[c].to_numpy()) for c in trial.data.columns if c != "t"}
        write_csv_log(RawLog(trial.name, "trial", chans, IngestSummary(trial.name, "trial")), args.out)
        print(f"wrote {args.out}: {len(t)} rows at {trial.fs:g} Hz, {len(chans)} channels")
    return 0


def _trial_and_segments(args: argparse.Namespace):
    from .flow import load_trial, segment_trial, segments_from_json

    vessel = _vessel(getattr(args, "vessel", None))
    trial = load_trial(args.logs, vessel, fs=getattr(args, "fs", None))
    seg_file = getattr(args, "segments", None)
    segments = segments_from_json(seg_file) if seg_file else segment_trial(trial)
    return vessel, trial, segments


def cmd_segment(args: argparse.Namespace) -> int:
    """``vesselid segment``: detect segments and print the table; optionally write JSON and a plot.

    Parameters
    ----------
    args : argparse.Namespace
        ``logs`` (log paths), ``vessel`` (vessel TOML or None), ``fs`` (resample rate [Hz] or
        None), ``json`` (segments JSON to write, or None) and ``plot`` (PNG to write, or None).

    Returns
    -------
    int
        0 (errors are raised and turned into an exit code by :func:`main`).
    """
    from .flow import segments_to_json, write_json
    from .segment import segment_table

    _, trial, segments = _trial_and_segments(args)
    print(segment_table(segments))
    if args.json:
        write_json(segments_to_json(segments), args.json)
    if args.plot:
        from .report.figures import plot_trial_overview, save_figure

        save_figure(plot_trial_overview(trial, segments.items), args.plot)
        print(f"wrote {args.plot}")
    return 0


def cmd_fit(args: argparse.Namespace) -> int:
    """``vesselid fit``: ingest, segment and fit; write the coefficients JSON and print them.

    Parameters
    ----------
    args : argparse.Namespace
        ``logs`` (log paths), ``vessel`` (vessel TOML), ``fs`` (resample rate [Hz] or None),
        ``segments`` (segments JSON to use instead of detecting, or None) and ``json``
        (coefficients JSON to write).

    Returns
    -------
    int
        0 (errors are raised and turned into an exit code by :func:`main`).
    """
    from .fit import fit_trial
    from .flow import write_json
    from .report import fits_to_dict

    vessel, trial, segments = _trial_and_segments(args)
    fits = fit_trial(trial, segments, vessel, model=getattr(args, "model", "auto"))
    write_json(fits_to_dict(fits), args.json)
    ok = sum(e.success for e in fits.estimates.values())
    print(f"fitted {len(fits.segment_fits)} segments; {ok} of {len(fits.estimates)} coefficients identified; wrote {args.json}")
    for e in fits.estimates.values():
        status = f"{e.value:.6g} +- {e.stderr:.2g} {e.unit}" if e.success else f"not identified: {e.message}"
        print(f"  {e.name:<10} {status}")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    """``vesselid report``: ingest, segment, fit and write the report folder.

    Parameters
    ----------
    args : argparse.Namespace
        ``logs`` (log paths), ``vessel`` (vessel TOML), ``fs`` (resample rate [Hz] or None),
        ``segments`` (segments JSON to use instead of detecting, or None) and ``out`` (report
        folder).

    Returns
    -------
    int
        0 (errors are raised and turned into an exit code by :func:`main`).
    """
    from .fit import fit_trial
    from .report import write_report

    vessel, trial, segments = _trial_and_segments(args)
    fits = fit_trial(trial, segments, vessel)
    paths = write_report(fits, args.out, trial=trial, segments=segments)
    print(f"wrote report to {args.out} ({paths.html})")
    return 0


def cmd_simulate(args: argparse.Namespace) -> int:
    """``vesselid simulate``: simulate the standard sea trial of a vessel and write it as a log.

    Parameters
    ----------
    args : argparse.Namespace
        ``vessel`` (vessel TOML), ``out`` (output log; its extension picks the format), ``seed``
        (noise seed) and ``noise`` (sensor noise level: ``low``, ``nominal`` or ``high``).

    Returns
    -------
    int
        0 (errors are raised and turned into an exit code by :func:`main`).
    """
    from .sim import sea_trial, simulate
    from .sim.effects import Effects
    from .sim.sensors import default_sensors
    from .sim.writers import write_log

    vessel = _vessel(args.vessel)
    result = simulate(vessel, sea_trial(vessel), Effects(), default_sensors(args.noise), seed=args.seed)
    out = write_log(result.log, args.out, vessel=vessel)
    print(f"wrote {out}: {result.truth['t'].iloc[-1]:.1f} s, {len(result.segments.items)} manoeuvre segments")
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    """``vesselid run``: every stage on a trial manifest (:func:`pipeline.run.run_manifest`).

    Parameters
    ----------
    args : argparse.Namespace
        ``manifest`` (trial TOML) and ``out`` (report folder, or None for
        ``reports/<trial name>``).

    Returns
    -------
    int
        0 (errors are raised and turned into an exit code by :func:`main`).
    """
    from .run import run_manifest

    out = run_manifest(args.manifest, args.out)
    print(f"wrote report to {out}")
    return 0


def _add_logs(p: argparse.ArgumentParser, vessel_required: bool = False) -> None:
    p.add_argument("logs", nargs="+", metavar="LOG",
                   help="log files (.csv .tlog .bin .ubx .nmea/.txt/.log .bag .db3 .mcap, or a ROS 2 bag folder)")
    p.add_argument("--vessel", required=vessel_required, metavar="VESSEL.toml", help="vessel config")


def build_parser() -> argparse.ArgumentParser:
    """The argparse parser of ``vesselid`` with every subcommand."""
    parser = argparse.ArgumentParser(prog="vesselid", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"vesselid {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser("ingest", help="read logs and print what was read and skipped")
    _add_logs(p)
    p.set_defaults(func=cmd_ingest)

    p = sub.add_parser("align", help="put logs on one clock; optionally write the trial as canonical CSV")
    _add_logs(p)
    p.add_argument("--fs", type=float, help="resample rate [Hz] (default: fastest state channel, at most 100)")
    p.add_argument("--out", metavar="TRIAL.csv", help="write the aligned trial (canonical CSV)")
    p.set_defaults(func=cmd_align)

    p = sub.add_parser("segment", help="detect coast-downs, steps, decays, zig-zags; print the table")
    _add_logs(p)
    p.add_argument("--fs", type=float, help="resample rate [Hz]")
    p.add_argument("--json", metavar="SEGMENTS.json", help="write the segments (for fit --segments)")
    p.add_argument("--plot", metavar="PNG", help="plot the trial with the segments shaded")
    p.set_defaults(func=cmd_segment)

    p = sub.add_parser("fit", help="ingest, segment and fit; write coefficients JSON")
    _add_logs(p, vessel_required=True)
    p.add_argument("--fs", type=float, help="resample rate [Hz]")
    p.add_argument("--segments", metavar="SEGMENTS.json", help="use these segments instead of detecting")
    p.add_argument("--json", required=True, metavar="OUT.json", help="coefficients JSON to write")
    p.add_argument("--model", default="auto", choices=["auto", "linear", "quadratic"],
                   help="damping structure per DOF: chosen by held-out error (auto), or forced")
    p.set_defaults(func=cmd_fit)

    p = sub.add_parser("report", help="ingest, segment, fit and write the report folder")
    _add_logs(p, vessel_required=True)
    p.add_argument("--fs", type=float, help="resample rate [Hz]")
    p.add_argument("--segments", metavar="SEGMENTS.json", help="use these segments instead of detecting")
    p.add_argument("--out", required=True, metavar="DIR", help="report folder")
    p.set_defaults(func=cmd_report)

    try:
        from .autopilot.cli import add_autopilot_parser, add_waves_parser
    except ImportError:  # autopilot stage not installed in this checkout
        pass
    else:
        add_waves_parser(sub)
        add_autopilot_parser(sub)

    try:
        from .export.cli import add_export_parser
    except ImportError:
        pass
    else:
        add_export_parser(sub)

    try:
        from .diagnose.cli import add_diagnose_parser
    except ImportError:
        pass
    else:
        add_diagnose_parser(sub)

    p = sub.add_parser("simulate", help="simulate a sea trial of a vessel and write it as a log file")
    p.add_argument("--vessel", required=True, metavar="VESSEL.toml", help="vessel config with [damping] or [nomoto]")
    p.add_argument("--out", required=True, metavar="LOG",
                   help="output log; the extension picks the format (.csv .tlog .bin .ubx .nmea .bag .db3 .mcap, "
                        "none: ROS 2 bag folder)")
    p.add_argument("--seed", type=int, default=0, help="noise seed")
    p.add_argument("--noise", default="nominal", choices=["low", "nominal", "high"], help="sensor noise level")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("run", help="run every stage on a trial manifest and write the report folder")
    p.add_argument("manifest", metavar="TRIAL.toml", help="trial manifest")
    p.add_argument("--out", metavar="DIR", help="report folder (default reports/<trial name>)")
    p.set_defaults(func=cmd_run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``vesselid`` console script.

    Parameters
    ----------
    argv : Sequence[str], optional
        Command-line arguments without the program name; default ``sys.argv[1:]``.

    Returns
    -------
    int
        Exit code: the command's (0 on success), ``EXIT_BAD_INPUT`` (2) on a pipeline, OS or
        value error (printed as ``error: ...``), 130 when interrupted.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except VesselidError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except (OSError, ValueError) as exc:
        print(f"error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
