"""``vesselid batch`` and ``vesselid catalog ...``: the command-line handlers of the catalogue.

Registered in :mod:`pipeline.cli` by :func:`add_batch_parser` and :func:`add_catalog_parser`.
"""

from __future__ import annotations

import argparse
import math
import shlex
from pathlib import Path

from ..text_format import number
from .errors import CatalogError
from .schema import DEFAULT_CATALOG


def _open(path: str):
    """The catalogue at ``path`` (DuckDB and pandas load here, when a command runs)."""
    from .store import Catalog

    return Catalog(path)


def _is_missing(x) -> bool:
    import pandas as pd

    return bool(pd.isna(x))


def _timestamp(x):
    import pandas as pd

    return pd.Timestamp(x)


def _add_catalog_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--catalog", default=DEFAULT_CATALOG, metavar="PATH",
                   help=f"catalogue file (DuckDB; default {DEFAULT_CATALOG} in the working folder)")


def add_batch_parser(subparsers) -> argparse.ArgumentParser:
    """Register the ``batch`` subcommand.

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
        "batch", help="process every trial manifest under a folder in parallel (Dask) into the catalogue",
        description="Find every trial manifest (a TOML with 'logs') under TRIALS_DIR, run the pipeline on each in "
                    "parallel on Dask (a local cluster, or --scheduler), write one report folder per trial and "
                    "store each trial in the catalogue. Trials already catalogued with the same files and vesselid "
                    "version are skipped unless --force; a failing trial is recorded with its error.")
    p.add_argument("trials_dir", metavar="TRIALS_DIR", help="folder searched recursively for trial manifests")
    _add_catalog_option(p)
    p.add_argument("--workers", type=int, default=2, metavar="N", help="worker processes of the local cluster (default 2)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="use an existing dask.distributed scheduler (tcp://host:8786); its workers must see the same paths")
    p.add_argument("--force", action="store_true", help="process trials again even when already catalogued")
    p.add_argument("--reports", metavar="DIR", help="root of the per-trial report folders (default: reports/ beside "
                                                    "the catalogue); the catalogue pages go to DIR/catalog/")
    p.add_argument("--quick", action="store_true",
                   help="single-DOF fits and the report only (no joint grey-box fit, autopilot or diagnosis)")
    p.set_defaults(func=cmd_batch)
    return p


def cmd_batch(args: argparse.Namespace) -> int:
    """``vesselid batch``: run :func:`pipeline.catalog.batch.run_batch` and print what it did.

    Parameters
    ----------
    args : argparse.Namespace
        ``trials_dir``, ``catalog``, ``workers``, ``scheduler``, ``force``, ``reports``, ``quick``.

    Returns
    -------
    int
        0 when every trial was processed or skipped, 1 when some failed (each recorded with its error).
    """
    from ..terminal import show_progress
    from .batch import run_batch
    from .html import write_catalog_pages

    parts = ["vesselid", "batch", args.trials_dir, "--catalog", args.catalog]
    parts += ["--scheduler", args.scheduler] if args.scheduler else ["--workers", str(args.workers)]
    parts += [flag for flag, on in (("--force", args.force), ("--quick", args.quick)) if on]
    parts += ["--reports", args.reports] if args.reports else []
    command = " ".join(shlex.quote(str(a)) for a in parts)

    def said(record) -> None:
        t = record.trial
        state = "ok" if record.ok else f"failed: {t.get('error')}"
        print(f"catalogued {record.identity.name} ({record.identity.trial_id}): {state}", flush=True)

    summary = run_batch(args.trials_dir, args.catalog, args.reports, args.workers, args.scheduler, args.force,
                        args.quick, command, on_result=said, progress=show_progress())
    reports = Path(args.reports) if args.reports else Path(args.catalog).resolve().parent / "reports"
    with _open(args.catalog) as cat:
        pages = write_catalog_pages(cat, reports / "catalog")
    print(f"{summary.found} trial(s) found: {len(summary.ok)} processed, {len(summary.failed)} failed, "
          f"{len(summary.skipped)} skipped (already catalogued; --force to redo) in {summary.wall_s:.1f} s on "
          f"{summary.workers} worker(s); catalogue {args.catalog}; pages {pages[0]}")
    return 1 if summary.failed else 0


def add_catalog_parser(subparsers) -> argparse.ArgumentParser:
    """Register the ``catalog`` subcommand and its actions.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``vesselid`` subcommand registry.

    Returns
    -------
    argparse.ArgumentParser
        The subcommand's parser.
    """
    p = subparsers.add_parser("catalog", help="list, show, compare, trend and export the trials in the catalogue",
                              description="Read the trial catalogue written by 'vesselid batch'. Trials are named "
                                          "by their manifest name or their id (a unique prefix of 4+ digits).")
    sub = p.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True
    q = sub.add_parser("list", help="trials per vessel")
    _add_catalog_option(q)
    q.add_argument("--vessel", help="only this vessel")
    q.set_defaults(func=cmd_catalog_list)
    q = sub.add_parser("show", help="one trial: files, runs, segments, coefficients, diagnosis")
    q.add_argument("trial", metavar="TRIAL", help="trial name or id")
    _add_catalog_option(q)
    q.set_defaults(func=cmd_catalog_show)
    q = sub.add_parser("compare", help="two trials coefficient by coefficient (difference, std. error, z, Holm flag)")
    q.add_argument("trial_a", metavar="TRIAL_A")
    q.add_argument("trial_b", metavar="TRIAL_B")
    _add_catalog_option(q)
    q.add_argument("--alpha", type=float, default=0.05, help="family-wise error rate of the Holm correction")
    q.set_defaults(func=cmd_catalog_compare)
    q = sub.add_parser("trend", help="one coefficient over the trials of each vessel, with a fitted drift")
    q.add_argument("coefficient", metavar="COEFFICIENT", help="coefficient name (X_u, K_nomoto, ...)")
    _add_catalog_option(q)
    q.add_argument("--vessel", help="only this vessel")
    q.add_argument("--plot", metavar="PNG", help="write the plot (one file per vessel: PNG name + '-<vessel>')")
    q.add_argument("--alpha", type=float, default=0.05, help="significance level of the drift test")
    q.set_defaults(func=cmd_catalog_trend)
    q = sub.add_parser("export", help="every coefficient of every trial to CSV or Parquet")
    _add_catalog_option(q)
    q.add_argument("--out", required=True, metavar="FILE", help="output file (.csv or .parquet)")
    q.set_defaults(func=cmd_catalog_export)
    q = sub.add_parser("html", help="write the catalogue pages (index + one page per vessel with trends)")
    _add_catalog_option(q)
    q.add_argument("--out", required=True, metavar="DIR", help="folder for the pages")
    q.set_defaults(func=cmd_catalog_html)
    return p


def _f(x, digits: int = 5) -> str:
    """A number with ``digits`` significant digits for the terminal tables, ``-`` when missing."""
    return number(x, f".{digits}g", missing="-")


def cmd_catalog_list(args: argparse.Namespace) -> int:
    """``vesselid catalog list``: the trials, grouped by vessel.

    Parameters
    ----------
    args : argparse.Namespace
        ``catalog`` and ``vessel``.
    """
    with _open(args.catalog) as cat:
        df = cat.trials(args.vessel)
    if df.empty:
        print(f"no trials in {args.catalog}" + (f" for vessel {args.vessel}" if args.vessel else ""))
        return 0
    for vessel, g in df.groupby(df["vessel_name"].fillna("(unknown vessel)"), sort=True):
        print(f"{vessel}: {len(g)} trial(s)")
        for t in g.itertuples():
            date = "-" if _is_missing(t.started_utc) else _timestamp(t.started_utc).strftime("%Y-%m-%d %H:%M")
            state = "ok" if t.status == "ok" else f"FAILED: {t.error}"
            print(f"  {t.trial_id}  {t.name:<20} {date:<16}  vesselid {t.package_version:<8} {t.mode or '-':<5}  {state}")
    return 0


def cmd_catalog_show(args: argparse.Namespace) -> int:
    """``vesselid catalog show TRIAL``: everything stored about one trial.

    Parameters
    ----------
    args : argparse.Namespace
        ``catalog`` and ``trial``.
    """
    with _open(args.catalog) as cat:
        t = cat.resolve(args.trial)
        tid = t["trial_id"]
        files, runs = cat.table("files", tid), cat.table("runs", tid)
        segs, coefs = cat.table("segments", tid), cat.table("coefficients", tid)
        diag, gaps = cat.table("diagnoses", tid), cat.table("diagnosis_gaps", tid)
    date = "-" if _is_missing(t["started_utc"]) else _timestamp(t["started_utc"]).isoformat()
    print(f"trial {t['name']} ({tid}), vessel {t['vessel_name']} (config sha256 {str(t['vessel_hash'])[:12]}...)")
    print(f"  status {t['status']}" + (f": {t['error']}" if t["status"] != "ok" else ""))
    print(f"  date {date} [{t['date_source']}]; place {_f(t['lat'], 8)}, {_f(t['lon'], 8)} [{t['place_source']}]")
    print(f"  vesselid {t['package_version']}, mode {t['mode']}, processed {t['processed_at']} in {_f(t['duration_s'], 3)} s")
    print(f"  command: {t['command']}")
    print(f"  manifest {t['manifest_path']}; report {t['report_dir']}")
    print("files:")
    for f in files.itertuples():
        print(f"  {f.role:<8} {f.sha256[:16]}  {f.size_bytes:>10} B  {f.path}")
    for r in runs.itertuples():
        print(f"run {r.run_index}: {_f(r.duration_s, 5)} s at {_f(r.fs, 4)} Hz, {r.n_samples} samples, {r.n_gaps} gap(s)")
    print(f"segments: {len(segs)}" + "".join(f"\n  {s.kind:<12} {s.dof:<6} {_f(s.t_start, 5):>8} .. {_f(s.t_end, 5):<8} s"
                                             for s in segs.itertuples()))
    print("coefficients (value ± std. error [95% CI]):")
    for c in coefs.itertuples():
        if c.success:
            print(f"  {c.name:<14} {_f(c.value)} ± {_f(c.stderr, 2)} [{_f(c.ci_low)}, {_f(c.ci_high)}] {c.unit}  ({c.structure})")
        else:
            print(f"  {c.name:<14} not identified: {c.message[:100]}")
    for d in diag.itertuples():
        if _is_missing(d.gap_before):
            print(f"diagnosis: {d.message}")
        else:
            print(f"diagnosis: {d.status}" + (f", effect {d.effect} in {d.dof}" if d.effect else "")
                  + f", gap {_f(d.gap_before, 3)} -> {_f(d.gap_after, 3)} (shrink {_f(d.shrink, 3)})")
    for g in gaps.itertuples():
        print(f"  gap {g.dof}: {_f(g.gap, 3)} (noise floor {_f(g.noise_floor, 3)}, replay {_f(g.replay_gap, 3)})")
    return 0


def cmd_catalog_compare(args: argparse.Namespace) -> int:
    """``vesselid catalog compare A B``: coefficient differences with their uncertainty.

    Parameters
    ----------
    args : argparse.Namespace
        ``catalog``, ``trial_a``, ``trial_b``, ``alpha``.
    """
    from .stats import compare_trials

    with _open(args.catalog) as cat:
        df, text = compare_trials(cat, args.trial_a, args.trial_b, args.alpha)
    print(text)
    print(f"  {'coefficient':<14} {'A':>11} {'B':>11} {'B - A':>11} {'se':>9} {'z':>7} {'p':>9}  beyond  unit")
    for r in df.itertuples():
        if r.note:
            print(f"  {r.coefficient:<14} {_f(r.a):>11} {_f(r.b):>11}  {r.note}")
            continue
        print(f"  {r.coefficient:<14} {_f(r.a):>11} {_f(r.b):>11} {_f(r.diff, 4):>11} {_f(r.se_diff, 2):>9} "
              f"{_f(r.z, 3):>7} {_f(r.p, 2):>9}  {'YES' if r.beyond else 'no':<6}  {r.unit}")
    return 0


def cmd_catalog_trend(args: argparse.Namespace) -> int:
    """``vesselid catalog trend COEFFICIENT``: values per trial and the fitted drift per vessel.

    Parameters
    ----------
    args : argparse.Namespace
        ``catalog``, ``coefficient``, ``vessel``, ``plot``, ``alpha``.
    """
    from .stats import coefficient_trend, plot_trend

    with _open(args.catalog) as cat:
        trends = coefficient_trend(cat, args.coefficient, args.vessel, args.alpha)
    for tr in trends:
        print(f"{tr.vessel}: {tr.coefficient} over {len(tr.points)} trial(s); x = {tr.x_label}")
        for p in tr.points.itertuples():
            print(f"  {p.name:<20} x = {_f(p.x, 4):>7}  {_f(p.value)} ± {_f(p.stderr, 2)} {tr.unit}")
        if math.isfinite(tr.slope):
            verdict = "SIGNIFICANT drift" if tr.significant else "no significant drift"
            print(f"  drift {_f(tr.slope, 4)} ± {_f(tr.slope_se, 2)} {tr.unit} per {tr.x_unit} ({100 * tr.rel_slope:+.3g} ± "
                  f"{100 * tr.rel_slope_se:.2g} % per {tr.x_unit}), t-test p = {_f(tr.p_value, 3)}: {verdict} at "
                  f"{args.alpha:g}; {tr.note}")
        else:
            print(f"  {tr.note}")
        if args.plot:
            out = Path(args.plot)
            if len(trends) > 1:
                out = out.with_name(f"{out.stem}-{tr.vessel}{out.suffix or '.png'}")
            plot_trend(tr, out)
            print(f"  wrote {out}")
    return 0


def cmd_catalog_export(args: argparse.Namespace) -> int:
    """``vesselid catalog export --out FILE``: every coefficient of every trial, CSV or Parquet.

    Parameters
    ----------
    args : argparse.Namespace
        ``catalog`` and ``out``.
    """
    with _open(args.catalog) as cat:
        out = cat.export(args.out)
    print(f"wrote {out}")
    return 0


def cmd_catalog_html(args: argparse.Namespace) -> int:
    """``vesselid catalog html --out DIR``: the catalogue pages.

    Parameters
    ----------
    args : argparse.Namespace
        ``catalog`` and ``out``.
    """
    from .html import write_catalog_pages

    with _open(args.catalog) as cat:
        pages = write_catalog_pages(cat, args.out)
    print(f"wrote {len(pages)} page(s): {pages[0]}")
    return 0


__all__ = ["add_batch_parser", "add_catalog_parser", "CatalogError"]
