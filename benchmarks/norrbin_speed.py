"""Norrbin selection and K, T over speed on PythonVehicleSimulator's frigate (data vesselid did not make).

PVS's ``frigate`` is Norrbin's model ``T r_dot + n3 r^3 + r = K delta`` with K, T and n3 interpolated
over speed (6, 9, 12 m/s: K = 0.08, 0.18, 0.23 1/s; T = 20, 27, 21 s; n3 = 0.4, 0.6, 0.3 s^2/rad^2),
its rudder rate-limited (10 deg/s) and saturated (30 deg). Per speed and seed: rudder steps of
+-20 deg (two records), stepped by PVS's own ``dynamics`` (forward Euler, 10 Hz as its main loop), the
actual rudder angle logged, heading and yaw rate logged at 10 Hz with white noise (PVS integrates by
forward Euler at 0.1 s, so its discrete-time T is about T - 0.05 s). Fitted by
:func:`pipeline.fit.norrbin.select_norrbin` per speed and :func:`pipeline.fit.nomoto_speed.fit_nomoto_speeds`
over speeds; compared with PVS's K(U), T(U), n3(U). Skipped with a message when PVS is absent (``PVS_PATH``).

Usage::

    .venv/bin/python benchmarks/norrbin_speed.py [--seeds 3] [--speeds 6,7.5,9,10.5,12] [--markdown OUT]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.atomic import atomic_write_text  # noqa: E402
from pipeline.fit.nomoto_records import NomotoRecord  # noqa: E402
from pipeline.fit.nomoto_speed import fit_nomoto_speeds  # noqa: E402
from pipeline.fit.norrbin import select_norrbin  # noqa: E402

PVS = Path(os.environ.get("PVS_PATH", "/work/pvs/src"))
DT, FS_LOG, RUN_S = 0.1, 10.0, 300.0
NOISE_PSI, NOISE_R = math.radians(0.2), math.radians(0.05)


def truth(u: float) -> dict:
    """PVS frigate's K, T, n3 at speed ``u`` (its own interpolation)."""
    from python_vehicle_simulator.vehicles.frigate import frigate

    f = frigate("stepInput", u)
    return {"K": float(f.K), "T": float(f.T), "n3": float(f.n3)}


def records(u: float, seed: int) -> list[NomotoRecord]:
    """Two rudder-step records of the frigate at speed ``u``."""
    from python_vehicle_simulator.vehicles.frigate import frigate

    rng = np.random.default_rng(seed)
    out = []
    for sign in (1.0, -1.0):
        boat = frigate("stepInput", u)
        nu, u_act, psi = np.array([u, 0, 0, 0, 0, 0], float), np.zeros(1), 0.0
        n = int(RUN_S / DT)
        every = int(round(1 / (DT * FS_LOG)))
        t, d, ps, rs = [], [], [], []
        for i in range(n):
            tt = i * DT
            cmd = sign * math.radians(20.0) * (1.0 if 10.0 <= tt < 150.0 else (-1.0 if tt >= 150.0 else 0.0))
            if i % every == 0:
                t.append(tt)
                d.append(float(u_act[0]))
                ps.append(psi)
                rs.append(float(nu[5]))
            psi += DT * nu[5]
            nu, u_act = boat.dynamics(np.zeros(6), nu, u_act, np.array([cmd]), DT)
        t, d, ps, rs = (np.asarray(a, float) for a in (t, d, ps, rs))
        out.append(NomotoRecord(t=t, delta=d, psi=ps + rng.normal(0, NOISE_PSI, t.size),
                                r=rs + rng.normal(0, NOISE_R, t.size), name=f"U={u:g} {sign:+g}"))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--speeds", default="6,7.5,9,10.5,12")
    ap.add_argument("--markdown")
    args = ap.parse_args(argv)
    if not (PVS / "python_vehicle_simulator").is_dir():
        print("PythonVehicleSimulator not found (set PVS_PATH): nothing measured")
        return 0
    sys.path.insert(0, str(PVS))
    t0 = time.time()
    speeds = [float(s) for s in args.speeds.split(",")]
    rows, law_rows = [], []
    for seed in range(args.seeds):
        runs = {}
        for u in speeds:
            recs = records(u, 100 * seed + int(10 * u))
            runs[u] = recs
            ch = select_norrbin(recs)
            tr = truth(u)
            f = ch.fits["norrbin"]
            lin = ch.fits["nomoto"]
            rows.append({"seed": seed, "U": u, "selected": ch.selected, "truth": tr,
                         "K": (lin.value("K"), lin.error("K")), "T": (lin.value("T"), lin.error("T")),
                         "n3": (f.value("n3"), f.error("n3")), "rms": dict(ch.heldout_rmse), "p": ch.p_value})
            print(f"seed {seed} U {u:g}: {ch.selected} ({time.time() - t0:.0f} s)", file=sys.stderr, flush=True)
        m = fit_nomoto_speeds(runs, length=100.0)
        for u in speeds:
            kt, tr = m.at(u), truth(u)
            law_rows.append({"seed": seed, "U": u, "K": (kt["K"], kt["K_stderr"]), "T": (kt["T"], kt["T_stderr"]),
                             "truth": tr, "K_dep": m.K.speed_dependent, "T_dep": m.T.speed_dependent})
    lines = ["## Norrbin and K, T over speed (PythonVehicleSimulator frigate)", "",
             f"Command: `python benchmarks/norrbin_speed.py --seeds {args.seeds} --speeds {args.speeds}` "
             f"({(time.time() - t0) / 60:.1f} min). Truth: PVS frigate (Norrbin, K, T, n3 interpolated over speed). "
             "Per speed: linear Nomoto K, T (fit on its own records) and Norrbin n3, z = (estimate - truth) / SE; "
             "law: K(U) = k0 + k1 U, T(U) = t0 + t1 / U through the per-speed fits.", "",
             "| U [m/s] | Norrbin selected | K truth | K (median) | K within 3 SE | T truth | T (median) | T within 3 SE | "
             "n3 truth | n3 (median) | n3 within 3 SE | law K within 3 SE | law T within 3 SE |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for u in speeds:
        rr = [r for r in rows if r["U"] == u]
        ll = [r for r in law_rows if r["U"] == u]
        tr = rr[0]["truth"]

        def within(items, key):
            return np.mean([abs(x[key][0] - x["truth"][key]) < 3 * x[key][1] for x in items])

        lines.append(f"| {u:g} | {np.mean([r['selected'] == 'norrbin' for r in rr]):.0%} | {tr['K']:.4g} | "
                     f"{np.median([r['K'][0] for r in rr]):.4g} | {within(rr, 'K'):.0%} | {tr['T']:.4g} | "
                     f"{np.median([r['T'][0] for r in rr]):.4g} | {within(rr, 'T'):.0%} | {tr['n3']:.3g} | "
                     f"{np.median([r['n3'][0] for r in rr]):.3g} | {within(rr, 'n3'):.0%} | {within(ll, 'K'):.0%} | "
                     f"{within(ll, 'T'):.0%} |")
    lines += ["", f"K speed-dependent in {np.mean([r['K_dep'] for r in law_rows]):.0%} of seeds, T in "
              f"{np.mean([r['T_dep'] for r in law_rows]):.0%}."]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.markdown:
        atomic_write_text(args.markdown, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
