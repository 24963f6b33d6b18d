"""The ``vesselid`` command line: one subcommand per stage, in flow order, plus ``run``.

Every command has ``--help``, returns 0 on success, and on bad input prints ``error: ...`` (what
was expected and what was found) to stderr and returns a non-zero code, never a traceback.

Start-up stays fast: a stage is imported only when its command runs. The subcommands that live in
their stage's package (``LAZY_COMMANDS``) get their full parser only when named on the command
line; otherwise a one-line entry lists them in ``vesselid --help``.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import sys
import warnings
from pathlib import Path
from typing import Iterator, Sequence

from . import __version__
from .errors import VesselidError

EXIT_BAD_INPUT = 2

#: Subcommands whose parser lives in their stage's package: name -> (module, function that adds the
#: parser, the one-line help ``vesselid --help`` lists; the module's own parser must say the same).
LAZY_COMMANDS: dict[str, tuple[str, str, str]] = {
    "waves": ("pipeline.autopilot.cli", "add_waves_parser",
              "fit the second-order wave model to a wave-induced heading record"),
    "autopilot": ("pipeline.autopilot.cli", "add_autopilot_parser",
                  "PD heading autopilot and discrete Kalman filter from the identified Nomoto model"),
    "diagnose": ("pipeline.diagnose.cli", "add_diagnose_parser",
                 "where and why the identified model disagrees with the boat, and what would fix it"),
    "export": ("pipeline.export.cli", "add_export_parser",
               "write the identified model for Gazebo/VRX, PythonVehicleSimulator, ArduPilot or ROS 2"),
    "batch": ("pipeline.catalog.cli", "add_batch_parser",
              "process every trial manifest under a folder in parallel (Dask) into the catalogue"),
    "catalog": ("pipeline.catalog.cli", "add_catalog_parser",
                "list, show, compare, trend and export the trials in the catalogue"),
}


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
    from .align import group_runs, grouping_text
    from .errors import AlignError
    from .flow import read_logs
    from .manifest import scan_logs

    files, left_out = scan_logs(args.logs)
    logs = read_logs(files, _vessel(args.vessel))
    for note in left_out:
        print(note)
    for log in logs:
        print(log.summary.text())
        for name, ch in sorted(log.channels.items()):
            print(f"  {name:<12} {len(ch.t):>8} samples  {ch.t[0]:10.3f} .. {ch.t[-1]:10.3f} s  [{ch.unit}]  from {ch.source}")
    try:
        print(grouping_text(group_runs(logs)))
    except AlignError as exc:
        print(f"runs: the logs cannot be grouped: {exc}")
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
    from .flow import load_trial, runs_text
    from .records import Channel, IngestSummary, RawLog
    from .sim.writers.csv_writer import write_csv_log

    if args.out:
        from .atomic import check_output_file

        check_output_file(args.out, "--out")
    from .flow import progress

    with progress(1, "vesselid align") as bar:
        bar.set_postfix_str("ingest + align")
        trial = load_trial(args.logs, _vessel(args.vessel), fs=args.fs)
        bar.update()
    print(runs_text(trial))
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


def _inputs(args: argparse.Namespace) -> list[str]:
    """Input files named on the command line (vessel, segments, logs), for the provenance."""
    out = [getattr(args, k) for k in ("vessel", "segments") if getattr(args, k, None)]
    return out + list(getattr(args, "logs", []))


def print_summary(fits, warnings=(), out=None) -> None:
    """The end-of-command table: D diagonal, Nomoto K and T, model structure, flags; then warnings once.

    Parameters
    ----------
    fits : pipeline.records.Fits
        Fit results.
    warnings : Sequence[str]
        Warnings to print (already short), each once.
    out : file, optional
        Where to print; default ``sys.stdout``.
    """
    from .report.quality import segment_quality
    from .report.summary import summary_rows

    out = out or sys.stdout
    rows = summary_rows(fits, [segment_quality(sf) for sf in fits.segment_fits])
    print(f"{'quantity':<16} {'value +- std. error':<26} {'95% CI':<28} {'unit':<10} flags", file=out)
    for r in rows:
        if not r.name:
            print(f"{r.label:<16} {r.value}", file=out)
            continue
        value = r.value.replace("±", "+-")
        print(f"{r.label:<16} {value:<26} {r.ci:<28} {r.unit:<10} {'; '.join(r.flags)}".rstrip(), file=out)
    for w in dict.fromkeys(warnings):
        print(f"warning: {w}", file=sys.stderr)


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

    from .atomic import check_output_file

    for flag, path in (("--json", args.json), ("--plot", args.plot), ("--review", args.review)):
        if path:
            check_output_file(path, flag)
    if args.review:
        from .report.review import require_plotly

        require_plotly()  # the optional dependency is checked before any work
    _, trial, segments = _trial_and_segments(args)
    print(segment_table(segments))
    if args.json:
        write_json(segments_to_json(segments), args.json)
    if args.plot:
        from .report.figures import plot_trial_overview, save_figure

        save_figure(plot_trial_overview(trial, segments.items), args.plot)
        print(f"wrote {args.plot}")
    if args.review:
        from .atomic import atomic_write_text
        from .report.review import segment_review_html

        atomic_write_text(args.review, segment_review_html(trial, segments, segments_json=segments_to_json(segments)))
        print(f"wrote {args.review} (open it in a browser; it offers the segments.json that --segments reads)")
    return 0


def cmd_fit(args: argparse.Namespace) -> int:
    """``vesselid fit``: ingest, segment and fit; write the coefficients JSON and print the summary.

    Parameters
    ----------
    args : argparse.Namespace
        ``logs`` (log paths), ``vessel`` (vessel TOML), ``fs`` (resample rate [Hz] or None),
        ``segments`` (segments JSON to use instead of detecting, or None) and ``json``
        (coefficients JSON to write), ``review`` (interactive segment review HTML, or None).

    Returns
    -------
    int
        0 (errors are raised and turned into an exit code by :func:`main`).
    """
    from .atomic import check_output_file
    from .flow import run_flow, segments_from_json
    from .report import fits_to_dict
    from .report.quality import segment_quality
    from .report.summary import findings
    from .flow import write_json

    check_output_file(args.json, "--json")
    if args.review:
        from .report.review import require_plotly

        check_output_file(args.review, "--review")
        require_plotly()
    vessel = _vessel(args.vessel)
    segments = segments_from_json(args.segments) if args.segments else None
    result = run_flow(args.logs, vessel, None, fs=args.fs, segments=segments, stop_after="fit",
                      model=args.model)
    fits = result.fits
    write_json(fits_to_dict(fits), args.json)
    if args.review:
        from .atomic import atomic_write_text
        from .flow import segments_to_json
        from .report.review import segment_review_html

        atomic_write_text(args.review, segment_review_html(result.trial, result.segments, fits,
                                                           segments_to_json(result.segments)))
    params = fits.to_fit_result().params
    ok = sum(p.success for p in params.values())
    print(f"fitted {len(fits.segment_fits)} segments; {ok} of {len(params)} coefficients identified; "
          f"wrote {args.json} (details and messages there)")
    found = findings(fits, [segment_quality(sf, result.trial) for sf in fits.segment_fits])
    print_summary(fits, found.warnings)
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    """``vesselid report``: every stage (as ``vesselid run``) on logs and a vessel config, into a folder.

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
    from .atomic import check_output_folder
    from .flow import make_provenance, run_flow, segments_from_json

    check_output_folder(args.out)
    vessel = _vessel(args.vessel)
    segments = segments_from_json(args.segments) if args.segments else None
    result = run_flow(args.logs, vessel, args.out, fs=args.fs, segments=segments,
                      provenance=make_provenance(_inputs(args), args.argv))
    _print_run(result)
    return 0


def _print_run(result) -> None:
    paths = result.report
    print_summary(result.fits, paths.warnings)
    for stage, why in result.skipped.items():
        print(f"warning: {stage} skipped: {why}", file=sys.stderr)
    print(f"wrote {paths.out_dir}/ (open {paths.html})")


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

    from .atomic import check_output_file
    from .flow import progress

    check_output_file(args.out, "--out") if Path(args.out).suffix else None
    vessel = _vessel(args.vessel)
    with progress(2, "vesselid simulate") as bar:
        bar.set_postfix_str("simulate")
        result = simulate(vessel, sea_trial(vessel), Effects(), default_sensors(args.noise), seed=args.seed)
        bar.update()
        bar.set_postfix_str(f"write {Path(args.out).suffix or 'ROS 2 bag'}")
        out = write_log(result.log, args.out, vessel=vessel)
        bar.update()
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

    if args.out:
        from .atomic import check_output_folder

        check_output_folder(args.out)
    _print_run(run_manifest(args.manifest, args.out, argv=getattr(args, "argv", None)))
    return 0


def _add_logs(p: argparse.ArgumentParser, vessel_required: bool = False) -> None:
    p.add_argument("logs", nargs="+", metavar="LOG",
                   help="log files (.csv .tlog .bin .ubx .nmea/.txt/.log .bag .db3 .mcap, or a ROS 2 bag folder)")
    p.add_argument("--vessel", required=vessel_required, metavar="VESSEL.toml", help="vessel config")


def command_name(argv: Sequence[str]) -> str:
    """The subcommand named in ``argv`` (the first word that is not an option), or ``""``.

    Parameters
    ----------
    argv : Sequence[str]
        Arguments without the program name.
    """
    return next((a for a in argv if not a.startswith("-")), "")


def _add_stage_parser(sub, name: str, full: bool) -> None:
    module, function, help_text = LAZY_COMMANDS[name]
    if full:
        getattr(importlib.import_module(module), function)(sub)
    else:
        sub.add_parser(name, help=help_text)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The argparse parser of ``vesselid``.

    Parameters
    ----------
    command : str, optional
        The subcommand about to run: only its stage package is imported for its parser, the
        others in ``LAZY_COMMANDS`` are listed by name and help only. None (default): every
        subcommand's full parser.
    """
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
    p.add_argument("--review", metavar="HTML", help="interactive review page (needs plotly: "
                                                    "pip install 'vesselid[review]')")
    p.set_defaults(func=cmd_segment)

    p = sub.add_parser("fit", help="ingest, segment and fit; write coefficients JSON")
    _add_logs(p, vessel_required=True)
    p.add_argument("--fs", type=float, help="resample rate [Hz]")
    p.add_argument("--segments", metavar="SEGMENTS.json", help="use these segments instead of detecting")
    p.add_argument("--json", required=True, metavar="OUT.json", help="coefficients JSON to write")
    p.add_argument("--review", metavar="HTML", help="interactive segment review with each fit's fit %% "
                                                    "(needs plotly: pip install 'vesselid[review]')")
    p.add_argument("--model", default="auto", choices=["auto", "linear", "quadratic"],
                   help="damping structure per DOF: chosen by held-out error (auto), or forced")
    p.set_defaults(func=cmd_fit)

    p = sub.add_parser("report", help="ingest, segment, fit and write the report folder")
    _add_logs(p, vessel_required=True)
    p.add_argument("--fs", type=float, help="resample rate [Hz]")
    p.add_argument("--segments", metavar="SEGMENTS.json", help="use these segments instead of detecting")
    p.add_argument("--out", required=True, metavar="DIR", help="report folder")
    p.set_defaults(func=cmd_report)

    for name in LAZY_COMMANDS:
        _add_stage_parser(sub, name, command is None or command == name)

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


@contextlib.contextmanager
def quiet_numerics() -> Iterator[None]:
    """A context in which floating-point ``RuntimeWarning``s (numpy, scipy) are not printed.

    A fit's trial steps (a solver's step where ``log`` is undefined, a mean over an empty window)
    raise them; the code checks its results for finiteness and says what it concludes in the
    estimates' messages. Printed as they are, they would put a Python warning class and a source
    line in front of the user that say nothing about the trial. Other warning categories print as
    before; the previous filters are restored on exit.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        yield


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
    argv = [str(a) for a in (sys.argv[1:] if argv is None else argv)]
    parser = build_parser(command_name(argv))
    args = parser.parse_args(argv)
    args.argv = argv  # the command line for the report footer
    try:
        with quiet_numerics():
            return int(args.func(args) or 0)
    except VesselidError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:
        # Every OSError carries the file it concerns; say which and why, without the class name.
        where = exc.filename or "an input or output file"
        print(f"error: {where}: {exc.strerror or exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except ValueError as exc:
        # A bad value no reader caught: name the command's inputs, since the value names none.
        named = ", ".join(_inputs(args)) or getattr(args, "manifest", "") or "the input"
        print(f"error: {args.command}: unexpected value in {named}: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
