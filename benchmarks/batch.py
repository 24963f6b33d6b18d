"""Batch benchmark: 40 simulated trials (4 vessels x 10) through ``vesselid batch`` on 1 and 2 workers.

One vessel ("fouler") has its surge damping D[0,0] grown by 1 % per trial (compounded; trials a
week apart) to stand for hull fouling; the other three are unchanged. The script

1. writes the trial tree (short DataFlash logs with a GPS clock, :mod:`pipeline.catalog.synthetic`);
2. runs the batch with 1 worker and then with 2 workers, each into its own catalogue (same trials,
   so the comparison is like for like), and records wall time, trials per minute and the speed-up;
3. checks that both catalogues hold the same coefficients, and that the X_u trend (weighted drift,
   Birge-scaled, t-test at 5 %) is significant for the fouled vessel with a drift near -1 %/trial
   and not significant for the other three;
4. data the project's simulator did not make: every NMEA log of the CE6 boat
   (``../shared/realdata/ce6-boat-limfjord-2022``, when present; referenced in place, never copied)
   as one trial each, through the same batch, to show the catalogue's dates and places from real
   logs and how real failures are recorded.

Usage::

    .venv/bin/python benchmarks/batch.py [--trials 10] [--rate 10] [--full] [--out DIR] [--skip-realdata]

``--quick`` batches (single-DOF fits and report, no joint fit, autopilot or diagnosis) are the
default so the benchmark runs in minutes; ``--full`` runs every stage.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.catalog import Catalog  # noqa: E402
from pipeline.catalog.batch import run_batch  # noqa: E402
from pipeline.catalog.stats import coefficient_trend  # noqa: E402
from pipeline.catalog.synthetic import FLEET, write_fleet  # noqa: E402

# ../shared beside the checkout (or beside the worktrees' folder when run from a git worktree).
REALDATA = next((p / "shared" / "realdata" / "ce6-boat-limfjord-2022" for p in (ROOT.parent, ROOT.parents[1])
                 if (p / "shared" / "realdata" / "ce6-boat-limfjord-2022").is_dir()),
                ROOT.parent / "shared" / "realdata" / "ce6-boat-limfjord-2022")
SPACING_DAYS = 7.0


def fleet_trends(catalog: Path) -> list[dict]:
    """X_u trend per vessel, with the drift per trial (x is days; trials a week apart).

    Parameters
    ----------
    catalog : Path
        Catalogue file.
    """
    with Catalog(catalog) as cat:
        trends = coefficient_trend(cat, "X_u")
    return [{"vessel": t.vessel, "n": len(t.points), "rel_drift_per_trial": t.rel_slope * SPACING_DAYS,
             "rel_drift_se": t.rel_slope_se * SPACING_DAYS, "p": t.p_value, "chi2_red": t.chi2_red,
             "significant": t.significant} for t in trends]


def realdata_part(work: Path, workers: int, quick: bool, most: int) -> dict | None:
    """Catalogue every CE6 NMEA log as a trial (manifests in ``work``, logs referenced in place).

    Parameters
    ----------
    work : Path
        Scratch folder.
    workers : int
        Dask workers.
    quick : bool
        Quick batch.
    most : int
        At most this many logs (the first in path order), to keep the run short.
    """
    import tomli_w

    from pipeline.ingest.nmea import looks_like_nmea

    if not REALDATA.is_dir():
        return None
    logs = [p for p in sorted((REALDATA / "Estimations").rglob("*")) if p.is_file()
            and p.suffix.lower() in (".txt", ".log") and looks_like_nmea(p)][:most]
    root = work / "ce6-trials"
    for i, p in enumerate(logs):
        folder = root / f"ce6-{i:02d}"
        folder.mkdir(parents=True, exist_ok=True)
        name = f"ce6-{i:02d}-{p.parent.name}-{p.stem}".replace(" ", "_")
        (folder / "trial.toml").write_text(tomli_w.dumps({"name": name, "vessel": str(ROOT / "vessel_configs" / "ce6.toml"),
                                                          "logs": [str(p)]}))
    cat_path = work / "ce6.duckdb"
    s = run_batch(root, cat_path, work / "ce6-reports", workers=workers, quick=quick, command="benchmarks/batch.py")
    with Catalog(cat_path) as cat:
        dated = cat.query("SELECT count(*) AS n, count(started_utc) AS dated, count(lat) AS placed, "
                          "min(started_utc) AS first, max(started_utc) AS last FROM trials WHERE status = 'ok'").iloc[0]
        ts = cat.query("SELECT count(*) AS n, median(value) AS med FROM coefficients c JOIN trials t USING (trial_id) "
                       "WHERE c.name = 'T_surge' AND c.success").iloc[0]
        errs = cat.query("SELECT error FROM trials WHERE status = 'failed'")["error"].tolist()
    return {"logs": len(logs), "ok": len(s.ok), "failed": len(s.failed), "wall_s": s.wall_s,
            "dated": int(dated["dated"]), "placed": int(dated["placed"]), "first": str(dated["first"]),
            "last": str(dated["last"]), "t_surge_trials": int(ts["n"]), "t_surge_median": float(ts["med"] or math.nan),
            "errors": sorted({e.split(":")[0][:60] + ": " + e.split(":", 1)[-1][:90] for e in errs})[:5]}


def main(argv=None) -> int:
    """Run the benchmark and print a Markdown section for RESULTS.md.

    Parameters
    ----------
    argv : list[str], optional
        Command-line arguments.
    """
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=10, help="trials per vessel")
    ap.add_argument("--rate", type=float, default=10.0, help="highest sensor rate [Hz]")
    ap.add_argument("--full", action="store_true", help="every stage (default: --quick batches)")
    ap.add_argument("--out", help="keep the trials, catalogues and reports here (default: a temporary folder)")
    ap.add_argument("--skip-realdata", action="store_true", help="skip the CE6 real-log part")
    ap.add_argument("--json", help="also write the measured numbers as JSON")
    ap.add_argument("--realdata-max", type=int, default=12, help="at most this many CE6 logs")
    ap.add_argument("--reuse", action="store_true", help="reuse the trials already written under --out/trials")
    ap.add_argument("--only-realdata", action="store_true", help="run only the CE6 real-log part")
    args = ap.parse_args(argv)
    os.environ.setdefault("CI", "1")
    quick = not args.full
    work = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="vesselid-batch-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    if args.only_realdata:
        real = realdata_part(work, 2, quick, args.realdata_max)
        print(json.dumps(real, indent=2, default=str) if real else f"no real data at {REALDATA}")
        return 0
    t0 = time.perf_counter()
    from pipeline.catalog.batch import find_trials

    if args.reuse and (work / "trials").is_dir():
        manifests = find_trials(work / "trials")
    else:
        manifests = write_fleet(work / "trials", args.trials, FLEET, rate=args.rate)
    t_gen = time.perf_counter() - t0
    print(f"wrote {len(manifests)} trials in {t_gen:.0f} s under {work / 'trials'}", flush=True)
    runs = {}
    for workers in (1, 2):
        cat = work / f"w{workers}.duckdb"
        if cat.exists():
            cat.unlink()
        s = run_batch(work / "trials", cat, work / f"reports-w{workers}", workers=workers, quick=quick,
                      command=f"benchmarks/batch.py (workers={workers})")
        runs[workers] = {"wall_s": s.wall_s, "ok": len(s.ok), "failed": len(s.failed),
                         "per_min": 60 * len(s.ok) / s.wall_s, "errors": s.errors}
        print(f"{workers} worker(s): {len(s.ok)} ok, {len(s.failed)} failed in {s.wall_s:.0f} s "
              f"({runs[workers]['per_min']:.2f} trials/min)", flush=True)
    speedup = runs[1]["wall_s"] / runs[2]["wall_s"]
    with Catalog(work / "w1.duckdb") as c1, Catalog(work / "w2.duckdb") as c2:
        q = ("SELECT t.name, c.name AS coef, c.value FROM coefficients c JOIN trials t USING (trial_id) "
             "WHERE c.success ORDER BY 1, 2")
        a, b = c1.query(q), c2.query(q)
    same = a.shape == b.shape and bool(((a["value"] - b["value"]).abs() <= 1e-9 * a["value"].abs().clip(lower=1)).all())
    trends = fleet_trends(work / "w2.duckdb")
    real = None if args.skip_realdata else realdata_part(work, 2, quick, args.realdata_max)
    fouled = [f.name for f in FLEET if f.fouling_per_trial]
    found = all(t["significant"] for t in trends if t["vessel"] in fouled)
    flat = all(not t["significant"] for t in trends if t["vessel"] not in fouled)
    result = {"trials": len(manifests), "mode": "quick" if quick else "full", "rate_hz": args.rate, "generate_s": t_gen,
              "runs": runs, "speedup": speedup, "same_coefficients": same, "trends": trends,
              "fouling_found": found, "others_flat": flat, "realdata": real, "cpus": os.cpu_count()}
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2, default=str))
    print()
    print("## Batch (benchmarks/batch.py)")
    print()
    print(f"Command: `.venv/bin/python benchmarks/batch.py --trials {args.trials} --rate {args.rate:g}"
          f"{' --full' if args.full else ''}` on {os.cpu_count()} CPU cores (shared with other jobs while measured).")
    print(f"{len(manifests)} simulated trials (4 vessels x {args.trials}, DataFlash logs at {args.rate:g} Hz, "
          f"surge step + coast-down and rudder step, about 3 min each), {'quick' if quick else 'full'} batch mode.")
    print()
    print("| workers | trials ok | failed | wall time [s] | trials per minute |")
    print("|---|---|---|---|---|")
    for w, r in runs.items():
        print(f"| {w} | {r['ok']} | {r['failed']} | {r['wall_s']:.0f} | {r['per_min']:.2f} |")
    print()
    print(f"Speed-up from 2 workers: {speedup:.2f}x (wall time incl. hashing, cluster start and catalogue writes; "
          f"1 worker runs as a thread of the batch process, 2 workers as two processes). "
          f"Both catalogues hold identical coefficients: {same}.")
    print()
    print("X_u trend per vessel (weighted straight line over the trials, drift per trial relative to |mean X_u|, "
          "Birge-scaled error, t-test):")
    print()
    print("| vessel | trials | drift [%/trial] | std. error | p | reduced chi2 | significant (5 %) | truth |")
    print("|---|---|---|---|---|---|---|---|")
    for t in trends:
        truth = "fouling: -1 %/trial (X_u = -D[0,0])" if t["vessel"] in fouled else "flat"
        print(f"| {t['vessel']} | {t['n']} | {100 * t['rel_drift_per_trial']:+.3f} | {100 * t['rel_drift_se']:.3f} | "
              f"{t['p']:.2g} | {t['chi2_red']:.2f} | {'yes' if t['significant'] else 'no'} | {truth} |")
    print()
    print(f"Fouling trend found and significant: {found}; other vessels flat: {flat}.")
    if real is not None:
        print()
        print(f"Real logs (CE6 boat, Limfjord 2022, NMEA; not made by the project's simulator): {real['logs']} logs "
              f"batched as trials: {real['ok']} processed, {real['failed']} recorded as failed, in {real['wall_s']:.0f} s; "
              f"{real['dated']} dated and {real['placed']} placed from the logs ({real['first']} .. {real['last']}); "
              f"T_surge identified in {real['t_surge_trials']} (median {real['t_surge_median']:.3g} s).")
        for e in real["errors"]:
            print(f"  - failure recorded: {e}")
    if not args.out:
        shutil.rmtree(work, ignore_errors=True)
    return 0 if (found and flat and same) else 1


if __name__ == "__main__":
    sys.exit(main())
