"""Trial shapes: the same manoeuvres logged the way real boats log them, through the whole pipeline.

One AAUSHIP identification day (surge, sway and yaw steps and coast-downs; roll and pitch free
decays; rudder steps and a zig-zag), simulated once per sensor suite and logged at 1, 2, 5, 10
and 50 Hz, is written in every combination of

- layout: ``one file`` (the whole day in one CSV) or ``file per run`` (the day split into its three
  recordings, one CSV each);
- sensor suite: ``body velocities`` (IMU, attitude, a DVL-like u and v, GNSS) or ``GNSS only``
  (IMU and attitude at the logging rate, GNSS lat/lon/sog/cog at min(rate, 5) Hz with no body
  velocity: u and v are derived from GNSS and heading. In one file the logger holds the last
  fix in every IMU row and writes the receiver's fix time in a ``t_fix`` column (``--no-fix-time``
  leaves it out: held fixes are then told by their values only); per run the GNSS is in its own file next to the IMU file, each stamped
  with ISO UTC times);

and read back with ``load_trial`` -> ``segment_trial`` -> ``fit_trial`` -> ``diagnose``. For every
shape it reports the runs found, each identified coefficient's error in standard errors against
the simulator's truth (target: within 2), which coefficients were not identified and why, and
the diagnosis verdict (target on clean data: none).

Independent data: Fossen's PythonVehicleSimulator frigate (Norrbin model with rudder dynamics,
``PVS_PATH``, default ``/work/pvs/src``; skipped with a message when absent) is driven by rudder
steps and a zig-zag, written to CSV by this script (not by vesselid's writers) at the same rates,
one file and one file per run, and fitted; K and T at each rate are compared with the 50 Hz
estimate (its peer in the same run) and with the frigate's own K and T.

Several seeds (``--seeds 1-20``): every shape is simulated and fitted once per seed (the simulator's
process and sensor noise differ, the manoeuvres do not), and a second table gives, per rate, sensor
suite and coefficient, how often its error is within 2 standard errors (about 95 % expected by chance
when the estimate is unbiased and its standard error right), with the mean and spread of the z values
(a bias shows as a mean away from 0, a wrong standard error as a spread away from 1).

Usage::

    .venv/bin/python benchmarks/trial_shapes.py [--rates 1 2 5 10 50] [--no-diagnose] [--out DIR]
    .venv/bin/python benchmarks/trial_shapes.py --seeds 1-20 --no-diagnose --layouts "one file" --workers 2
    .venv/bin/python benchmarks/trial_shapes.py --summary-of run1.json run2.json   # the seeds table again
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.errors import VesselidError  # noqa: E402
from pipeline.fit import fit_trial  # noqa: E402
from pipeline.flow import load_trial, segment_trial  # noqa: E402
from pipeline.sim import sea_trial, simulate  # noqa: E402
from pipeline.sim.sensors import SensorSpec  # noqa: E402
from pipeline.sim.writers import write_log  # noqa: E402
from pipeline.vessel import load_vessel, parse_vessel  # noqa: E402

VESSEL = load_vessel(ROOT / "vessel_configs" / "aauship.toml")
D = np.diag(VESSEL.damping)
TRUTH = {"X_u": -D[0], "Y_v": -D[1], "K_p": -D[2], "M_q": -D[3], "N_r": -D[4],
         "K_nomoto": VESSEL.rudder["yaw_moment"] / D[4], "T_nomoto": VESSEL.inertia[2] / D[4]}
RATES = (1, 2, 5, 10, 50)
GNSS_MAX_HZ = 5.0
T0_UTC = pd.Timestamp("2024-05-05T09:00:00Z")
PVS_PATH = os.environ.get("PVS_PATH", "/work/pvs/src")


# --------------------------------------------------------------------------- sensor suites
def sensors(rate: float, body_velocities: bool) -> tuple[SensorSpec, ...]:
    """Nominal-noise sensors logged at ``rate`` [Hz]; GNSS at most ``GNSS_MAX_HZ``."""
    gnss_rate = min(rate, GNSS_MAX_HZ)
    suite = [SensorSpec("imu", ("p", "q", "r", "ax", "ay", "az"), rate,
                        noise={"p": 0.002, "q": 0.002, "r": 0.002, "ax": 0.05, "ay": 0.05, "az": 0.05}),
             SensorSpec("attitude", ("phi", "theta", "psi"), rate, noise={"phi": 0.002, "theta": 0.002, "psi": 0.002}),
             SensorSpec("gnss", ("lat", "lon", "sog", "cog"), gnss_rate,
                        noise={"lat": 0.3, "lon": 0.3, "sog": 0.02, "cog": 0.01})]
    if body_velocities:
        suite.append(SensorSpec("dvl", ("u", "v"), rate, noise={"u": 0.005, "v": 0.005}))
    return tuple(suite)


def _split_times(res) -> list[float]:
    """Split instants between the day's three recordings: mid-rest before roll decays and rudder steps."""
    segs = res.segments.items
    first_decay = min(s.t_start for s in segs if s.kind == "free_decay")
    first_rudder = min(s.t_start for s in segs if s.input_channel == "delta")
    last_before = lambda t: max(s.t_end for s in segs if s.t_end <= t + 1e-9)  # noqa: E731
    return [0.5 * (last_before(first_decay) + first_decay), 0.5 * (last_before(first_rudder) + first_rudder)]


def _piece(log, a: float, b: float, name: str):
    """Channels of ``log`` with a <= t < b, on a clock starting at the piece's first sample."""
    chans = {}
    for n, c in log.channels.items():
        keep = (c.t >= a) & (c.t < b)
        chans[n] = replace(c, t=c.t[keep] - a, values=c.values[keep])
    return replace(log, source=name, channels={n: c for n, c in chans.items() if len(c.t)})


GNSS = ("lat", "lon", "sog", "cog")


def _held_csv(log, path: Path, fix_time: bool = True) -> Path:
    """One IMU-rate CSV in which the logger repeats the last GNSS fix in every row.

    With ``fix_time`` the logger also writes the receiver's time of the fix held in each row
    (column ``t_fix``, as a GPS time of week would be), which tells held copies from new fixes.
    """
    imu_t = log.channels["r"].t
    cols = {"t": imu_t}
    for n, c in log.channels.items():
        if n in GNSS:
            idx = np.searchsorted(c.t, imu_t + 1e-9, side="right") - 1
            cols[n] = np.where(idx >= 0, c.values[np.clip(idx, 0, None)], np.nan)
            if fix_time and "t_fix" not in cols:
                cols["t_fix"] = np.where(idx >= 0, c.t[np.clip(idx, 0, None)], np.nan)
        else:
            cols[n] = np.interp(imu_t, c.t, c.values) if not n.startswith(("delta", "tau")) else \
                c.values[np.clip(np.searchsorted(c.t, imu_t + 1e-9, side="right") - 1, 0, None)]
    pd.DataFrame(cols).to_csv(path, index=False, float_format="%.10g")
    return path


def _iso_csv(log, names, path: Path, start: pd.Timestamp) -> Path:
    """Channels ``names`` of ``log`` in one CSV stamped with ISO UTC times (a logger's wall clock)."""
    t = np.unique(np.concatenate([log.channels[n].t for n in names if n in log.channels]))
    cols = {"time": [(start + pd.Timedelta(seconds=float(x))).isoformat() for x in t]}
    for n in names:
        if n in log.channels:
            c = log.channels[n]
            col = np.full(len(t), np.nan)
            col[np.searchsorted(t, c.t)] = c.values
            cols[n] = col
    pd.DataFrame(cols).to_csv(path, index=False, float_format="%.10g")
    return path


def write_shape(res, layout: str, body_velocities: bool, folder: Path, fix_time: bool = True) -> list[Path]:
    """Write one simulated day in one shape; returns the files (``fix_time``: see :func:`_held_csv`)."""
    folder.mkdir(parents=True, exist_ok=True)
    log = res.log
    if layout == "one file":
        if body_velocities:
            return [write_log(log, folder / "day.csv")]
        return [_held_csv(log, folder / "day.csv", fix_time)]
    cuts = [0.0] + _split_times(res) + [math.inf]
    out = []
    for k, (a, b) in enumerate(zip(cuts[:-1], cuts[1:])):
        piece = _piece(log, a, b, f"run{k}")
        if body_velocities:
            out.append(write_log(piece, folder / f"run{k}.csv"))
        else:
            start = T0_UTC + pd.Timedelta(seconds=a + 3600 * k)
            imu = [n for n in piece.channels if n not in GNSS]
            out.append(_iso_csv(piece, imu, folder / f"run{k}_imu.csv", start))
            out.append(_iso_csv(piece, GNSS, folder / f"run{k}_gnss.csv", start))
    return out


# --------------------------------------------------------------------------- one shape
def statistical_stderr(est) -> float:
    """The standard error of ``est`` before the terms the fit stage adds in quadrature [its unit].

    The Nomoto K and T carry a model-structure term and a speed term (``fit/nomoto_quality.py``),
    each noted as ``standard error A -> B``, the newest first; ``A`` of the last such note is the
    statistical error of the combination. Without such a note it is ``est.stderr``.
    """
    stat = est.stderr
    for part in est.message.split("; "):
        head = part.split(" -> ", 1)[0]
        if head.startswith("standard error ") and " -> " in part:
            try:
                stat = float(head[len("standard error "):])
            except ValueError:
                continue
    return stat


def run_shape(files, diagnose_it: bool, vessel=VESSEL, truth=TRUTH) -> dict:
    t0 = time.perf_counter()
    out: dict = {"error": ""}
    try:
        trial = load_trial(files, vessel)
        segs = segment_trial(trial)
        fits = fit_trial(trial, segs, vessel, extend=False)
    except VesselidError as exc:
        out["error"] = str(exc)
        return out
    out["runs"] = len(trial.runs)
    out["segments"] = len(segs.items)
    z, missing = {}, {}
    for name, true in truth.items():
        est = fits.estimates.get(name)
        if est is None or not est.success or not est.stderr > 0:
            missing[name] = (est.message if est is not None else "no segment")[:90]
            continue
        stat = statistical_stderr(est)
        z[name] = ((est.value - true) / est.stderr, est.value, est.stderr, (est.value - true) / stat)
    out["z"], out["missing"] = z, missing
    out["effect"] = "-"
    if diagnose_it:
        from pipeline.diagnose import diagnose

        try:
            rep = diagnose(trial, vessel, fits=fits)
            out["effect"] = rep.effect or "none"
            if rep.unexplained:
                out["effect"] += " (unexplained: " + ", ".join(f"{u.dof} {u.channel} {u.gap:.1f}"
                                                               for u in rep.unexplained) + ")"
        except VesselidError as exc:
            out["effect"] = f"error: {str(exc)[:80]}"
    out["seconds"] = time.perf_counter() - t0
    return out


# --------------------------------------------------------------------------- PVS frigate
def pvs_frigate_day(dt: float = 0.02):
    """Drive PVS's frigate with rudder steps and a zig-zag; truth on a fine grid (None when absent)."""
    if not Path(PVS_PATH).is_dir():
        return None
    sys.path.insert(0, PVS_PATH)
    try:
        from python_vehicle_simulator.vehicles.frigate import frigate
    except ImportError:
        return None
    ship = frigate("stepInput", U=6.0)
    # Run 1: rudder steps +-10 deg held 150 s (7 T); run 2: a 10/10 zig-zag.
    t_run = np.arange(0.0, 420.0, dt)
    records = []
    for run in range(2):
        nu = np.array([6.0, 0, 0, 0, 0, 0], float)
        u_act = np.array([0.0])
        psi = 0.0
        rows = []
        cmd = 0.0
        for t in t_run:
            if run == 0:
                cmd = math.radians(10) if 30 <= t < 180 else (math.radians(-10) if 240 <= t < 390 else 0.0)
            else:
                if t < 30:
                    cmd = 0.0
                elif cmd == 0.0:
                    cmd = math.radians(10)
                elif cmd > 0 and psi > math.radians(10):
                    cmd = math.radians(-10)
                elif cmd < 0 and psi < math.radians(-10):
                    cmd = math.radians(10)
            rows.append((t, nu[5], psi, cmd, u_act[0]))
            nu, u_act = ship.dynamics(np.zeros(6), nu, u_act, np.array([cmd]), dt)
            psi += dt * nu[5]
        records.append(pd.DataFrame(rows, columns=["t", "r", "psi", "delta_cmd", "delta_actual"]))
    return ship, records


def write_pvs(records, rate: float, layout: str, folder: Path, rng: np.random.Generator) -> list[Path]:
    """The frigate's runs as a user's logger writes them: r and heading with noise, the rudder command."""
    folder.mkdir(parents=True, exist_ok=True)
    frames = []
    for k, rec in enumerate(records):
        step = max(int(round(1.0 / (rate * 0.02))), 1)
        s = rec.iloc[::step].reset_index(drop=True)
        f = pd.DataFrame({"t": s["t"], "r": s["r"] + rng.normal(0, 2e-4, len(s)),
                          "psi_deg": np.degrees(np.angle(np.exp(1j * (s["psi"] + rng.normal(0, 1e-3, len(s)))))),
                          "delta": s["delta_cmd"]})
        frames.append(f)
    if layout == "file per run":
        paths = []
        for k, f in enumerate(frames):
            p = folder / f"frigate_run{k}.csv"
            f.to_csv(p, index=False, sep=";", float_format="%.8g")
            paths.append(p)
        return paths
    shift = frames[0]["t"].iloc[-1] + 60.0
    both = pd.concat([frames[0], frames[1].assign(t=frames[1]["t"] + shift)], ignore_index=True)
    p = folder / "frigate_day.csv"
    both.to_csv(p, index=False, sep=";", float_format="%.8g")
    return [p]


# --------------------------------------------------------------------------- main
LAYOUTS = ("one file", "file per run")


def seed_list(text: str) -> list[int]:
    """Seeds from ``"5"``, ``"1,4,9"`` or ``"1-20"`` (ranges inclusive)."""
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.strip().partition("-")
        out.extend(range(int(a), int(b) + 1) if b else [int(a)])
    return out


def run_day(seed: int, rate: float, bv: bool, layouts: tuple[str, ...], diagnose_it: bool,
            base: Path | None, fix_time: bool = True) -> list[dict]:
    """Simulate one day (``seed``, ``rate``, sensor suite) and run it through every layout."""
    res = simulate(VESSEL, sea_trial(VESSEL), sensors=sensors(rate, bv), seed=seed, actuator_rate=rate)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for layout in layouts:
            folder = (base or Path(tmp)) / f"s{seed}_{'bv' if bv else 'gnss'}_{rate:g}_{layout[:3]}"
            r = run_shape(write_shape(res, layout, bv, folder, fix_time), diagnose_it)
            r.update(seed=seed, rate=rate, layout=layout, sensors="body velocities" if bv else "GNSS only")
            rows.append(r)
    return rows


def calibration(zs: np.ndarray) -> dict:
    """How well z values over seeds fit an unbiased estimate with a right standard error.

    Parameters
    ----------
    zs : numpy.ndarray
        (estimate - truth) / standard error, one per seed [-].

    Returns
    -------
    dict
        ``within`` (count with ``|z| < 2``), ``n``, ``mean``, ``sd`` (NaN for one seed),
        ``p_within`` (one-sided binomial probability of so few within 2 SE when each is within
        with probability 0.9545, the normal's) and ``p_mean`` (two-sided t-test of mean z = 0;
        NaN for one seed).
    """
    from scipy import stats

    n = int(zs.size)
    k = int((np.abs(zs) < 2).sum())
    sd = float(zs.std(ddof=1)) if n > 1 else math.nan
    p_mean = float(stats.ttest_1samp(zs, 0.0).pvalue) if n > 1 and sd > 0 else math.nan
    return {"within": k, "n": n, "mean": float(zs.mean()), "sd": sd,
            "p_within": float(stats.binom.cdf(k, n, WITHIN_2SE)), "p_mean": p_mean}


#: Probability that a normal error lies within 2 standard deviations.
WITHIN_2SE = 0.9545


def seed_summary(rows: list[dict]) -> list[str]:
    """Markdown rows: per rate, sensors, layout and coefficient, the share within 2 SE over the seeds.

    For the Nomoto K and T, whose error the fit stage widens by a structure or speed term, a second
    row ``(statistical SE)`` gives the z values on the error before those terms.
    """
    groups: dict = defaultdict(lambda: defaultdict(list))
    missing: dict = defaultdict(lambda: defaultdict(int))
    widened = set()
    for r in rows:
        key = (r["rate"], r["sensors"], r["layout"])
        for name, zv in r.get("z", {}).items():
            groups[key][name].append(zv[0])
            if len(zv) > 3:
                groups[key][name + " (statistical SE)"].append(zv[3])
                if zv[3] != zv[0]:
                    widened.add(name)
        for name in r.get("missing", {}):
            missing[key][name] += 1
    lines = ["| rate Hz | sensors | layout | coefficient | seeds identified | within 2 SE | share | mean z | "
             "sd z | worst z | p (so few within) | p (mean z = 0) |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    totals: dict = defaultdict(lambda: [0, 0])
    names = [n for t in TRUTH for n in ((t, t + " (statistical SE)") if t in widened else (t,))]
    for key in sorted(groups):
        for name in names:
            zs = np.asarray(groups[key].get(name, []), float)
            if not zs.size:
                continue
            c = calibration(zs)
            totals[name][0] += c["within"]
            totals[name][1] += zs.size
            sd = f"{c['sd']:.2f}" if zs.size > 1 else "-"
            lines.append(f"| {key[0]:g} | {key[1]} | {key[2]} | {name} | {zs.size} (not: "
                         f"{missing[key][name.split(' ')[0]]}) | {c['within']}/{zs.size} | {c['within'] / zs.size:.0%} | "
                         f"{c['mean']:+.2f} | {sd} | {zs[np.argmax(np.abs(zs))]:+.1f} | {c['p_within']:.2g} | "
                         f"{c['p_mean']:.2g} |")
    lines += ["", "| coefficient | within 2 SE, all shapes and seeds | share |", "|---|---|---|"]
    lines += [f"| {n} | {k}/{m} | {k / m:.0%} |" for n, (k, m) in totals.items()]
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rates", type=float, nargs="+", default=list(RATES))
    ap.add_argument("--no-diagnose", action="store_true")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--seeds", type=seed_list, default=None,
                    help="several seeds, e.g. 1-20 or 1,3,7: adds the share-within-2-SE table")
    ap.add_argument("--layouts", nargs="+", choices=LAYOUTS, default=list(LAYOUTS))
    ap.add_argument("--sensors", nargs="+", choices=("gnss", "bv"), default=["gnss", "bv"])
    ap.add_argument("--workers", type=int, default=1, help="processes (at most 2 on a shared machine)")
    ap.add_argument("--no-fix-time", action="store_true",
                    help="GNSS-only one file: the logger writes no t_fix column (held fixes told by their values only)")
    ap.add_argument("--pvs-only", action="store_true", help="only the PythonVehicleSimulator frigate")
    ap.add_argument("--no-pvs", action="store_true", help="skip the PythonVehicleSimulator frigate")
    ap.add_argument("--out", type=Path, default=None, help="folder for the written logs (default: temporary)")
    ap.add_argument("--json", type=Path, default=None, help="write every shape's z values here")
    ap.add_argument("--summary-of", type=Path, nargs="+", default=None, metavar="JSON",
                    help="print the seeds table of earlier --json outputs (nothing is simulated)")
    args = ap.parse_args(argv)
    if args.summary_of:
        import json

        rows = [r for f in args.summary_of for r in json.loads(f.read_text())]
        print(f"{len(rows)} shapes from {', '.join(str(f) for f in args.summary_of)}\n")
        print("\n".join(seed_summary(rows)))
        return 0
    tmp = tempfile.TemporaryDirectory()
    base = args.out or Path(tmp.name)
    seeds = args.seeds or [args.seed]
    rows = []
    print("| seed | rate Hz | layout | sensors | runs | segs | within 2 SE | within 3 SE | worst (z) | not identified | "
          "diagnosis | s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    tasks = [(seed, rate, bv, tuple(args.layouts), not args.no_diagnose, args.out, not args.no_fix_time)
             for seed in seeds for bv in (False, True) if ("bv" if bv else "gnss") in args.sensors
             for rate in args.rates] if not args.pvs_only else []
    if args.workers > 1:
        with ProcessPoolExecutor(max_workers=args.workers) as pool:
            futures = [pool.submit(run_day, *task) for task in tasks]
            for fut in futures:
                for r in fut.result():
                    rows.append(r)
                    print(_row(r), flush=True)
    else:
        for task in tasks:
            for r in run_day(*task):
                rows.append(r)
                print(_row(r), flush=True)
    if args.json:
        import json

        from pipeline.atomic import atomic_write_text

        atomic_write_text(args.json, json.dumps(rows, indent=1, default=str))
    if len(seeds) > 1:
        print(f"\nSeeds {seeds[0]}..{seeds[-1]} ({len(seeds)}): share of seeds with the coefficient within 2 SE "
              f"of the truth (about 95 % expected by chance)\n")
        print("\n".join(seed_summary(rows)))
    if args.no_pvs:
        tmp.cleanup()
        return 0
    pvs = pvs_frigate_day()
    if pvs is None:
        print(f"\nPVS frigate: skipped (PythonVehicleSimulator not found at PVS_PATH={PVS_PATH})")
    else:
        ship, records = pvs
        vessel = parse_vessel({"name": "frigate"})
        truth = {"K_nomoto": float(ship.K), "T_nomoto": float(ship.T)}
        print(f"\nPVS frigate (Norrbin, K = {ship.K:.4g} 1/s, T = {ship.T:.4g} s, n3 = {ship.n3:.3g}, rudder rate "
              f"limit {ship.DdeltaMax} deg/s), written by this script as semicolon CSV with psi in degrees:\n")
        print("| rate Hz | layout | runs | K (1/s) | T (s) | K vs 50 Hz (z) | T vs 50 Hz (z) | K vs truth (z) | "
              "T vs truth (z) |")
        print("|---|---|---|---|---|---|---|---|---|")
        rng = np.random.default_rng(args.seed)
        peer: dict = {}
        results = []
        for layout in ("one file", "file per run"):
            for rate in sorted(args.rates, reverse=True):
                files = write_pvs(records, rate, layout, base / f"pvs_{rate:g}_{layout[:3]}", rng)
                r = run_shape(files, False, vessel, truth)
                r.update(rate=rate, layout=layout)
                if layout == "one file" and rate == max(args.rates):
                    peer = r.get("z", {})
                results.append(r)
        for r in results:
            print(_pvs_row(r, peer, truth), flush=True)
    tmp.cleanup()
    return 0


def _row(r: dict) -> str:
    if r.get("error"):
        return (f"| {r['seed']} | {r['rate']:g} | {r['layout']} | {r['sensors']} | error: {r['error'][:120]} "
                f"|||||||")
    z = r["z"]
    n2 = sum(abs(v[0]) < 2 for v in z.values())
    n3 = sum(abs(v[0]) < 3 for v in z.values())
    worst = max(z.items(), key=lambda kv: abs(kv[1][0]), default=None)
    worst_s = f"{worst[0]} {worst[1][0]:+.1f}" if worst else "-"
    miss = ", ".join(sorted(r["missing"])) or "-"
    return (f"| {r['seed']} | {r['rate']:g} | {r['layout']} | {r['sensors']} | {r['runs']} | {r['segments']} | {n2}/{len(z)} | "
            f"{n3}/{len(z)} | {worst_s} | {miss} | {r['effect']} | {r['seconds']:.0f} |")


def _pvs_row(r: dict, peer: dict, truth: dict) -> str:
    if r.get("error"):
        return f"| {r['rate']:g} | {r['layout']} | error: {r['error'][:120]} ||||||||"
    z = r.get("z", {})
    cells = []
    for name in ("K_nomoto", "T_nomoto"):
        cells.append(f"{z[name][1]:.4g} ± {z[name][2]:.2g}" if name in z else "not identified")
    vs_peer = []
    for name in ("K_nomoto", "T_nomoto"):
        if name in z and name in peer:
            d = (z[name][1] - peer[name][1]) / math.hypot(z[name][2], peer[name][2]) if r is not None else math.nan
            vs_peer.append(f"{d:+.1f}")
        else:
            vs_peer.append("-")
    vs_truth = [f"{z[n][0]:+.1f}" if n in z else "-" for n in ("K_nomoto", "T_nomoto")]
    return f"| {r['rate']:g} | {r['layout']} | {r.get('runs', '-')} | " + " | ".join(cells + vs_peer + vs_truth) + " |"


if __name__ == "__main__":
    sys.exit(main())
