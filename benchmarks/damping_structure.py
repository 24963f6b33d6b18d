"""Damping structure selection and quadratic-damping recovery, against simulated truth.

Three vessels (AAUSHIP 1.1 m, a 2 m catamaran, a 5 m workboat) with quadratic damping in every
DOF, simulated by vesselid's 5-DOF simulator through its sensor models (GNSS/filter speed, IMU,
AHRS; nominal noise) -- surge and yaw steps + coast-downs at two levels and roll decays released
both ways -- then fitted by :func:`pipeline.fit.structure.select_structure` on the schedule's
segments. Measured per DOF: how often the quadratic structure is selected, whether each term of
the quadratic fit is within 3 standard errors of the truth, and the 95 % CI coverage. The same
vessels with linear-only truth give the false-selection rate.

Independent truth (not made by vesselid's simulator): Fossen's PythonVehicleSimulator Otter USV
(linear surge damping; yaw with ``10 D_r |r| r`` plus strip-theory cross-flow drag), coast-downs
in surge and yaw simulated by PVS's own dynamics and kinematics stepped as its main loop does
(forward Euler, 100 Hz) after 30 s at rest (heave and pitch settled), logged at 20 Hz with white
noise, relative to the drift speed the Otter settles at under its payload trim (a constant force
the one-DOF model has no term for). Truth: ``X_u = -D[0,0]``; ``N_r = -D[5,5]``, ``N_|r|r = -10 D[5,5] + N_cf`` with
``N_cf`` from PVS's ``crossFlowDrag`` at ``r = 1``. Skipped with a message when PVS is absent
(``PVS_PATH``, default ``/work/pvs/src``).

Usage::

    .venv/bin/python benchmarks/damping_structure.py [--seeds 30] [--linear-seeds 10] [--otter-seeds 10]
        [--workers 2] [--json OUT] [--markdown OUT] [--partial RUNS.jsonl]

``--partial`` appends every finished trial to a JSON-lines file and skips those it already holds, so a
long run can be stopped and resumed, or extended (more seeds, the Otter rows) without redoing the rest.
The Otter rows are also compared with the best one-DOF description of PVS's motion (the same model fitted
to the noise-free records), and a noise-free attribution (PVS at a 10x finer Euler step, the DOF's
mass-matrix coupling removed, both) says where that description parts from the Otter's nominal terms.

Standard errors are the joint fit's Newey-West (HAC) sandwich (:mod:`pipeline.fit.robust_covariance`);
CI coverage uses the t quantile with the fit's residual degrees of freedom. Pooled coverage over all
term rows is given with its Clopper-Pearson 95 % interval (30 trials cannot tell 95 % from 90 % or
100 % in a single row).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.atomic import atomic_write_text  # noqa: E402
from pipeline.align.align import align  # noqa: E402
from pipeline.fit.quadratic import TERM_NAMES, DofRecord, dof_records, fit_dof  # noqa: E402
from pipeline.fit.structure import select_structure, select_structures  # noqa: E402
from pipeline.records import Segment, Trial  # noqa: E402
from pipeline.sim import simulate  # noqa: E402
from pipeline.sim.simulate import resample  # noqa: E402
from pipeline.sim.manoeuvres import chain, free_decay, step_and_coast  # noqa: E402
from pipeline.vessel import load_vessel, parse_vessel  # noqa: E402

PVS = Path(os.environ.get("PVS_PATH", "/work/pvs/src"))
DOFS = ("surge", "yaw", "roll")
IDX = {"surge": 0, "sway": 1, "roll": 2, "pitch": 3, "yaw": 4}
#: Steady speeds (surge m/s, yaw rad/s) of the two step levels, and the roll release angle [rad].
LEVELS = {"aauship": ((0.8, 1.5), (0.3, 0.6), 0.3), "catamaran_2m": ((1.0, 2.0), (0.3, 0.7), 0.25),
          "workboat_5m": ((1.5, 3.0), (0.2, 0.4), 0.2)}


def vessels() -> dict:
    """Truth vessels with quadratic damping (D2 in DOF order u v p q r)."""
    aau = load_vessel(ROOT / "vessel_configs" / "aauship.toml")
    out = {"aauship": replace(aau, quadratic_damping=np.array([12.7, 60.0, 0.05, 3.0, 0.3]))}
    out["catamaran_2m"] = parse_vessel({
        "name": "catamaran_2m", "rigid_body": {"mass": 30.0, "inertia": [2.0, 6.0, 8.0], "cg": [0, 0, 0]},
        "added_mass": {"surge": 3.0, "sway": 20.0, "yaw": 4.0}, "restoring": {"roll": 300.0, "pitch": 1500.0},
        "damping": {"diagonal": [8.0, 40.0, 4.0, 20.0, 6.0], "quadratic": [15.0, 80.0, 2.0, 10.0, 5.0]}})
    out["workboat_5m"] = parse_vessel({
        "name": "workboat_5m", "rigid_body": {"mass": 1200.0, "inertia": [400.0, 2500.0, 3000.0], "cg": [0, 0, 0]},
        "added_mass": {"surge": 100.0, "sway": 800.0, "roll": 80.0, "yaw": 900.0},
        "restoring": {"roll": 8000.0, "pitch": 60000.0},
        "damping": {"diagonal": [120.0, 900.0, 300.0, 3000.0, 1500.0],
                    "quadratic": [150.0, 1500.0, 200.0, 2000.0, 1500.0]}})
    return out


def schedule(v, name: str):
    (u1, u2), (r1, r2), phi0 = LEVELS[name]
    d, d2 = np.diag(v.damping), np.asarray(v.quadratic_damping, float)
    m = np.diag(v.mass_matrix())
    items = []
    for dof, i, speeds in (("surge", 0, (u1, u2)), ("yaw", 4, (r1, r2))):
        tc = m[i] / (d[i] + d2[i] * speeds[0])
        hold = max(6 * tc, 5.0)
        items += [step_and_coast(dof, float(d[i] * s + d2[i] * s * s), hold, hold) for s in speeds]
    zeta_wn = d[2] / (2 * m[2])
    length = min(max(5.0 / max(zeta_wn, 1e-3), 3.0), 40.0)
    items += [free_decay("roll", phi0, length), free_decay("roll", -phi0, length)]
    rest = float(max(5.0, 3 * np.max(m[[0, 4]] / d[[0, 4]])))
    return chain(*items, rest_s=rest)


#: Simulated truth per (vessel, quadratic damping), reused across seeds in one process.
_TRUTH: dict = {}


def simulated(v, name: str, seed: int):
    """``simulate(v, schedule(v, name), seed=seed)``; the truth is integrated once per vessel and
    re-sampled with each seed's sensor noise (identical to a fresh simulation without waves)."""
    key = (name, tuple(np.asarray(v.quadratic_damping if v.quadratic_damping is not None else np.zeros(5), float)))
    if key not in _TRUTH:
        _TRUTH[key] = simulate(v, schedule(v, name), seed=seed, dt=0.01)
    return resample(_TRUTH[key], seed)


def fit_case(v, name: str, seed: int) -> dict:
    res = simulated(v, name, seed)
    trial = align([res.log], vessel=v)
    out = {}
    for dof in DOFS:
        recs = dof_records(trial, res.segments.items, dof)
        ch = select_structure(recs, dof, 1 / trial.fs, v.effective_mass(dof))
        q = ch.fits["quadratic"]
        lin, quad = TERM_NAMES[dof]
        truth = {lin: -float(np.diag(v.damping)[IDX[dof]]),
                 quad: -float(np.asarray(v.quadratic_damping if v.quadratic_damping is not None else np.zeros(5))[IDX[dof]])}
        terms = {}
        for n in (lin, quad):
            val, se, _ = q.terms[n]
            half = stats.t.ppf(0.975, q.dof_resid) * se
            terms[n] = {"value": val, "stderr": se, "truth": truth[n], "within3": abs(val - truth[n]) < 3 * se,
                        "covered": abs(val - truth[n]) <= half}
        out[dof] = {"selected": ch.selected, "heldout": ch.heldout_rmse, "terms": terms}
    return out


def _pvs_run(boat, nu_set: np.ndarray, dt: float, settle_s: float, run_s: float) -> np.ndarray:
    """PVS's own dynamics and kinematics (``vehicle.dynamics``, ``gnc.attitudeEuler``), stepped as its
    main loop steps them, after ``settle_s`` seconds at rest so that heave and pitch start in
    equilibrium (PVS's ``simulate`` always starts from eta = 0); returns nu after the release."""
    from python_vehicle_simulator.lib.gnc import attitudeEuler

    eta, nu, u_act = np.zeros(6), np.zeros(6), np.zeros(2)
    for _ in range(int(settle_s / dt)):
        nu, u_act = boat.dynamics(eta, nu, u_act, np.zeros(2), dt)
        eta = attitudeEuler(eta, nu, dt)
    drift = nu.copy()
    nu = nu.copy()
    nu[np.flatnonzero(nu_set)] = nu_set[np.flatnonzero(nu_set)] + drift[np.flatnonzero(nu_set)]
    out = np.empty((int(run_s / dt), 6))
    for i in range(out.shape[0]):
        out[i] = nu
        nu, u_act = boat.dynamics(eta, nu, u_act, np.zeros(2), dt)
        eta = attitudeEuler(eta, nu, dt)
    # The Otter's payload trims it so that it drifts at a constant speed at rest (0.08 m/s in surge):
    # the coast-down is taken relative to that drift, which the one-DOF model has no term for.
    return out - drift


def otter_vessel(boat):
    """A vesselid config of the PVS Otter (mass, inertia about the CG, CG, added mass, damping
    diagonal), as a user would write it from the boat's data sheet; products of inertia are left
    out, as the config has none."""
    S = boat.S_rg
    ma = np.diag(boat.MA)
    d = np.diag(boat.D)
    return parse_vessel({
        "name": "otter_pvs", "rigid_body": {"mass": float(boat.m_total), "inertia": [float(boat.Ig[i, i]) for i in range(3)],
                                            "cg": [float(S[2, 1]), float(S[0, 2]), float(S[1, 0])]},
        "added_mass": {"surge": float(ma[0]), "sway": float(ma[1]), "roll": float(ma[3]), "pitch": float(ma[4]),
                       "yaw": float(ma[5])},
        "restoring": {"roll": float(boat.G[3, 3]), "pitch": float(boat.G[4, 4])},
        "damping": {"diagonal": [float(d[i]) for i in (0, 1, 3, 4, 5)]}})


#: Otter coast-downs: DOF -> (index in PVS's nu, start speeds, white noise sd, channel).
OTTER_RUNS = {"surge": (0, (1.0, 2.0), 0.01, "u"), "yaw": (5, (0.3, 0.6), 0.002, "r")}


def otter_coasts(dof: str, dt: float = 0.01, fs_log: float = 20.0, uncoupled: bool = False,
                 level_payload: bool = False) -> list[np.ndarray]:
    """Noise-free PVS Otter coast-downs of ``dof`` sampled at ``fs_log`` (one array per start speed);
    ``uncoupled`` zeroes the mass matrix entries that couple the DOF with the others;
    ``level_payload`` rotates the payload's weight into body axes by roll and yaw only (PVS's
    ``Rzyx`` with pitch 0 inside its Otter module, for this call), which removes the surge force
    ``-m_p g sin(theta)`` that no buoyancy term of PVS's Otter balances."""
    from python_vehicle_simulator.vehicles.otter import otter

    module = sys.modules[otter.__module__]
    nu_i, starts, _, _ = OTTER_RUNS[dof]
    if level_payload:
        rzyx = module.Rzyx
        module.Rzyx = lambda phi, theta, psi: rzyx(phi, 0.0, psi)
        try:
            return otter_coasts(dof, dt, fs_log, uncoupled)
        finally:
            module.Rzyx = rzyx
    out = []
    for x0 in starts:
        boat = otter("stepInput", 0.0, 0.0, 0.0, 0.0)
        if uncoupled:
            keep = boat.M[nu_i, nu_i]
            boat.M[nu_i, :] = 0.0
            boat.M[:, nu_i] = 0.0
            boat.M[nu_i, nu_i] = keep
            boat.Minv = np.linalg.inv(boat.M)
        nu_set = np.zeros(6)
        nu_set[nu_i] = x0
        nu = _pvs_run(boat, nu_set, dt, 30.0, 30.0)
        keep_i = np.arange(0, nu.shape[0], int(round(1 / (dt * fs_log))))
        out.append(nu[keep_i, nu_i])
    return out


def _otter_fit(dof: str, ys: list[np.ndarray], fs_log: float, sigma: float):
    """One-DOF quadratic fit of noise-free Otter records (the best one-DOF description of them)."""
    from python_vehicle_simulator.vehicles.otter import otter

    boat = otter("stepInput", 0.0, 0.0, 0.0, 0.0)
    nu_i, _, _, ch = OTTER_RUNS[dof]
    recs = [DofRecord(f"coast {i}", "coast_down", y, {}, sigma, "rate", ch) for i, y in enumerate(ys)]
    fit = fit_dof(recs, dof, 1 / fs_log, float(boat.M[nu_i, nu_i]), "quadratic")
    return {n: v[0] for n, v in fit.terms.items()}


def _otter_fit_linear(dof: str, ys: list[np.ndarray], fs_log: float, sigma: float) -> float:
    """The linear term of the linear structure fitted to noise-free Otter records."""
    from python_vehicle_simulator.vehicles.otter import otter

    boat = otter("stepInput", 0.0, 0.0, 0.0, 0.0)
    nu_i, _, _, ch = OTTER_RUNS[dof]
    recs = [DofRecord(f"coast {i}", "coast_down", y, {}, sigma, "rate", ch) for i, y in enumerate(ys)]
    return fit_dof(recs, dof, 1 / fs_log, float(boat.M[nu_i, nu_i]), "linear").terms[TERM_NAMES[dof][0]][0]


def otter_attribution() -> dict | None:
    """Noise-free one-DOF fits of the Otter's coast-downs with PVS as it is, with a 10x finer Euler
    step, with the DOF's mass-matrix coupling removed, and both: where the one-DOF model's terms
    part from the Otter's nominal ones."""
    if not (PVS / "python_vehicle_simulator").is_dir():
        return None
    sys.path.insert(0, str(PVS))
    out = {}
    for dof in OTTER_RUNS:
        sd = OTTER_RUNS[dof][2]
        runs = [("PVS as is (Euler 100 Hz)", 0.01, False, False), ("Euler 1 kHz", 0.001, False, False),
                ("coupling removed", 0.01, True, False), ("both", 0.001, True, False)]
        if dof == "surge":
            runs.append(("payload weight not pitched (no surge force from pitch)", 0.01, False, True))
        out[dof] = {}
        for label, dt, unc, lev in runs:
            ys = otter_coasts(dof, dt, uncoupled=unc, level_payload=lev)
            out[dof][label] = {**_otter_fit(dof, ys, 20.0, sd), "linear structure": _otter_fit_linear(dof, ys, 20.0, sd)}
    return out


def otter_payload_inertia() -> tuple[float, float, float]:
    """The Otter's pitched payload as surge inertia, quasi-static: a surge acceleration pitches the
    boat by ``theta = -M_qu u_dot / G_qq`` and the payload's weight pushes in surge with
    ``-m_p g theta``, i.e. an extra inertia ``m_p g |M_uq| / G_qq`` [kg]. Returns it, its share of
    ``M_uu`` and the ``X_u`` a one-DOF fit with ``M_uu`` then finds (``-D_uu M_uu / (M_uu + extra)``)."""
    from python_vehicle_simulator.vehicles.otter import otter

    boat = otter("stepInput", 0.0, 0.0, 0.0, 0.0)
    extra = float(boat.mp * boat.g * abs(boat.M[0, 4]) / boat.G[4, 4])
    m = float(boat.M[0, 0])
    return extra, extra / m, float(-boat.D[0, 0] * m / (m + extra))


def otter_case(seed: int) -> dict | None:
    """PVS Otter coast-downs in surge and yaw, noise added, fitted as a user's log would be (trial,
    segments and a vessel config of the Otter through ``select_structures``)."""
    if not (PVS / "python_vehicle_simulator").is_dir():
        return None
    sys.path.insert(0, str(PVS))
    from python_vehicle_simulator.lib.gnc import crossFlowDrag
    from python_vehicle_simulator.vehicles.otter import otter

    rng = np.random.default_rng(seed)
    fs_log = 20.0
    boat = otter("stepInput", 0.0, 0.0, 0.0, 0.0)
    vessel = otter_vessel(boat)
    out = {}
    for dof, (nu_i, starts, noise, ch) in OTTER_RUNS.items():
        clean = otter_coasts(dof, 0.01, fs_log)
        rows, segs, t0 = [], [], 0.0
        for y0 in clean:
            tt = t0 + np.arange(y0.size) / fs_log
            rows.append(pd.DataFrame({"t": tt, ch: y0 + rng.normal(0, noise, y0.size)}))
            segs.append(Segment("coast_down", dof, tt[0], tt[-1]))
            t0 = tt[-1] + 1 / fs_log
        trial = Trial(f"otter_{dof}", pd.concat(rows, ignore_index=True), fs_log)
        d = float(boat.D[nu_i, nu_i])
        n_cf = float(crossFlowDrag(boat.L, boat.B_pont, boat.T, np.array([0, 0, 0, 0, 0, 1.0]))[5])
        quad_truth = 0.0 if dof == "surge" else -10 * d + n_cf
        choice = select_structures(trial, segs, vessel)[dof]
        pseudo = _otter_fit(dof, clean, fs_log, noise)
        q = choice.fits["quadratic"]
        lin, quad = TERM_NAMES[dof]
        terms = {}
        for n, truth in ((lin, -d), (quad, quad_truth)):
            val, se, _ = q.terms[n]
            half = stats.t.ppf(0.975, q.dof_resid) * se
            terms[n] = {"value": val, "stderr": se, "truth": truth, "within3": abs(val - truth) < 3 * se,
                        "covered": abs(val - truth) <= half, "pseudo_truth": pseudo[n],
                        "covered_pseudo": abs(val - pseudo[n]) <= half, "within3_pseudo": abs(val - pseudo[n]) < 3 * se}
        out[dof] = {"selected": choice.selected, "heldout": dict(choice.heldout_rmse), "terms": terms,
                    "truth_structure": "linear" if dof == "surge" else "quadratic",
                    "unsure": "unsure:" in choice.message,
                    "note": next((m.strip() for m in choice.message.split(";") if "unsure:" in m), "")}
    return out


def _task(task: tuple) -> dict | None:
    """One trial: (vessel, truth structure, seed) -> fit_case's result (None when it failed, said on stderr)."""
    vname, truth, seed = task
    if vname == "otter":
        try:
            return otter_case(seed)
        except Exception as exc:  # a failed case is counted, not hidden
            print(f"otter seed {seed}: {type(exc).__name__}: {exc}", file=sys.stderr, flush=True)
            return None
    v = vessels()[vname]
    vt = v if truth == "quadratic" else replace(v, quadratic_damping=np.zeros(5))
    t0 = time.time()
    try:
        out = fit_case(vt, vname, seed)
    except Exception as exc:  # a failed case is counted, not hidden
        print(f"{vname} {truth} seed {seed}: {type(exc).__name__}: {exc}", file=sys.stderr, flush=True)
        out = None
    print(f"{vname} {truth} seed {seed} done ({time.time() - t0:.0f} s)", file=sys.stderr, flush=True)
    return out


def summarise(results: dict) -> dict:
    summary = {}
    for (vname, truth), runs in results.items():
        for dof in DOFS:
            rows = [r[dof] for r in runs if dof in r]
            if not rows:
                continue
            s = {"n": len(rows), "quadratic_selected": float(np.mean([r["selected"] == "quadratic" for r in rows]))}
            for n in TERM_NAMES[dof]:
                s[f"{n} within 3 SE"] = float(np.mean([r["terms"][n]["within3"] for r in rows]))
                s[f"{n} CI95 coverage"] = float(np.mean([r["terms"][n]["covered"] for r in rows]))
                z = np.array([(r["terms"][n]["value"] - r["terms"][n]["truth"]) / r["terms"][n]["stderr"] for r in rows])
                s[f"{n} z mean"] = float(np.mean(z))
                s[f"{n} z sd"] = float(np.std(z, ddof=1)) if z.size > 1 else math.nan
                s[f"{n} median rel. error"] = float(np.median([abs(r["terms"][n]["value"] / r["terms"][n]["truth"] - 1)
                                                               if r["terms"][n]["truth"] else abs(r["terms"][n]["value"])
                                                               for r in rows]))
            h = [r["heldout"] for r in rows if "quadratic" in r["heldout"]]
            s["median held-out RMS ratio quadratic/linear"] = float(np.median([x["quadratic"] / x["linear"] for x in h]))
            summary[f"{vname} | {truth} | {dof}"] = s
    return summary


def clopper_pearson(k: int, n: int) -> tuple[float, float]:
    """Exact 95 % interval of a binomial proportion k/n."""
    lo = float(stats.beta.ppf(0.025, k, n - k + 1)) if k > 0 else 0.0
    hi = float(stats.beta.ppf(0.975, k + 1, n - k)) if k < n else 1.0
    return lo, hi


def pooled(results: dict) -> list[str]:
    """Pooled CI coverage, within-3-SE share and selection rate per truth, with exact intervals."""
    lines = []
    for truth in ("quadratic", "linear"):
        runs = [(v, r) for (v, t), rs in results.items() if t == truth for r in rs]
        if not runs:
            continue
        for label, pick in (("linear terms", 0), ("quadratic terms", 1), ("all terms", None)):
            cov = w3 = n = 0
            for _, r in runs:
                for dof in DOFS:
                    names = TERM_NAMES[dof] if pick is None else (TERM_NAMES[dof][pick],)
                    for nm in names:
                        t = r[dof]["terms"][nm]
                        cov += bool(t["covered"])
                        w3 += bool(t["within3"])
                        n += 1
            lo, hi = clopper_pearson(cov, n)
            lines.append(f"- {truth} truth, {label}: CI95 coverage {cov}/{n} = {cov / n:.1%} (95 % interval "
                         f"{lo:.1%}-{hi:.1%}); within 3 SE {w3 / n:.1%}")
        z = np.array([(t["value"] - t["truth"]) / t["stderr"] for _, r in runs for dof in DOFS
                      for t in r[dof]["terms"].values()])
        lines.append(f"- {truth} truth, all terms: z = (estimate - truth) / SE has mean {z.mean():+.3f} and SD "
                     f"{z.std(ddof=1):.3f} over {z.size} intervals (1 for standard errors that are right); "
                     f"|z| > 3 in {int(np.sum(np.abs(z) > 3))}")
        sel = sum(r[dof]["selected"] == "quadratic" for _, r in runs for dof in DOFS)
        n = len(runs) * len(DOFS)
        lo, hi = clopper_pearson(sel, n)
        lines.append(f"- {truth} truth: quadratic selected in {sel}/{n} DOF fits = {sel / n:.1%} (95 % interval "
                     f"{lo:.1%}-{hi:.1%})")
    return lines


def row_chance(n: int, rows: int, coverage: float = 0.95) -> str:
    """How often a row of ``n`` trials falls outside 90-98 % CI coverage when the intervals are exactly
    right (true coverage ``coverage``), and the expected number of such rows among ``rows``."""
    below = float(stats.binom.cdf(math.ceil(0.9 * n) - 1, n, coverage))
    above = float(stats.binom.sf(math.floor(0.98 * n), n, coverage))
    return (f"With exactly right 95 % intervals, a row of {n} trials reads below 90 % with probability {below:.1%} "
            f"and above 98 % with probability {above:.1%}: of {rows} term rows, {rows * below:.1f} are expected "
            f"below 90 % and {rows * above:.1f} above 98 % by chance alone.")


def markdown(summary: dict, otter: list, cmd: str, seconds: float, results: dict | None = None,
             attribution: dict | None = None) -> str:
    lines = ["## Damping structure (linear vs linear + quadratic)", "",
             f"Command: `{cmd}` ({seconds / 60:.1f} min). Simulated by vesselid's 5-DOF simulator through its sensor "
             "models; fitted on the schedule's segments by `select_structure` (held-out choice with the diagnosis's "
             "significance rule). Term columns: share of trials with the quadratic fit's term within 3 SE of truth / "
             "95 % CI coverage (for linear truth the quadratic term's truth is 0).", "",
             "| vessel | truth | DOF | n | quadratic selected | linear term: within 3 SE / CI cov. | quadratic term: "
             "within 3 SE / CI cov. | z mean / SD (linear term; quadratic term) | held-out RMS quad/lin (median) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for key, s in summary.items():
        v, truth, dof = key.split(" | ")
        lin, quad = TERM_NAMES[dof]
        lines.append(f"| {v} | {truth} | {dof} | {s['n']} | {s['quadratic_selected']:.0%} | "
                     f"{s[f'{lin} within 3 SE']:.0%} / {s[f'{lin} CI95 coverage']:.0%} | "
                     f"{s[f'{quad} within 3 SE']:.0%} / {s[f'{quad} CI95 coverage']:.0%} | "
                     f"{s[f'{lin} z mean']:+.2f} / {s[f'{lin} z sd']:.2f}; {s[f'{quad} z mean']:+.2f} / "
                     f"{s[f'{quad} z sd']:.2f} | {s['median held-out RMS ratio quadratic/linear']:.3f} |")
    if otter:
        lines += ["", "Independent truth: PythonVehicleSimulator Otter coast-downs (PVS's own dynamics and "
                  "kinematics stepped as its main loop does, 100 Hz Euler, after 30 s at rest; logged at 20 Hz + "
                  "white noise, relative to the drift the payload trim causes), fitted through `select_structures` "
                  "with a vesselid config of the Otter (mass, inertia, CG, added mass, restoring, damping diagonal). "
                  "Nominal truth: the Otter's own D, its 10 D_r |r| r term and `crossFlowDrag` at r = 1. One-DOF "
                  "truth: the same one-DOF model fitted to the noise-free PVS records (the best one-DOF description "
                  "of PVS's motion). 'unsure' = the fit's message says `unsure:` (here: inertia coupling, "
                  "`pipeline/fit/coupling.py`; a misfit at the segment starts, `pipeline/fit/start_transient.py`, "
                  "was said in none).", "",
                  "| DOF | truth structure | n | quadratic selected | unsure | term | median value | nominal truth | "
                  "within 3 SE / CI95 (nominal) | one-DOF truth | within 3 SE / CI95 (one-DOF) |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for dof in ("surge", "yaw"):
            rows = [o[dof] for o in otter]
            sel = np.mean([r["selected"] == "quadratic" for r in rows])
            uns = np.mean([r.get("unsure", False) for r in rows])
            for n in TERM_NAMES[dof]:
                tt = [r["terms"][n] for r in rows]
                lines.append(f"| {dof} | {rows[0]['truth_structure']} | {len(rows)} | {sel:.0%} | {uns:.0%} | `{n}` | "
                             f"{np.median([t['value'] for t in tt]):.4g} | {tt[0]['truth']:.4g} | "
                             f"{np.mean([t['within3'] for t in tt]):.0%} / {np.mean([t['covered'] for t in tt]):.0%} | "
                             f"{tt[0]['pseudo_truth']:.4g} | {np.mean([t['within3_pseudo'] for t in tt]):.0%} / "
                             f"{np.mean([t['covered_pseudo'] for t in tt]):.0%} |")
        notes = sorted({o[d]["note"] for o in otter for d in ("surge", "yaw") if o[d].get("note")})
        if notes:
            lines += ["", "What the tool said (yaw): " + notes[0]]
    if attribution:
        lines += ["", "Where the one-DOF terms part from the Otter's nominal ones (noise-free fits of the same "
                  "coast-downs, PVS changed at run time only):", "",
                  "| DOF | PVS run | linear term | quadratic term | linear term, linear structure |",
                  "|---|---|---|---|---|"]
        for dof, runs in attribution.items():
            for label, terms in runs.items():
                vals = list(terms.values())
                lines.append(f"| {dof} | {label} | {vals[0]:.4g} | {vals[1]:.4g} | {vals[2]:.4g} |")
        if "surge" in attribution:
            extra, share, x_u = otter_payload_inertia()
            lines += ["", f"Surge, quasi-static: a surge acceleration pitches the Otter through `M[surge,pitch]`, and "
                      f"PVS turns the payload's weight with the pitch into a surge force `-m_p g sin(theta)` that no "
                      f"buoyancy term balances; together an extra surge inertia `m_p g |M_uq| / G_qq` = {extra:.3g} kg "
                      f"({share:.1%} of `M_uu`), so a one-DOF fit with the config's `M_uu` finds `X_u` = {x_u:.4g}."]
    elif otter is not None:
        lines += ["", "PythonVehicleSimulator not found (PVS_PATH): independent-truth rows skipped."]
    if results:
        lines += ["", "Pooled over vessels and DOFs (vesselid's simulator):", ""] + pooled(results)
        ns = [s["n"] for s in summary.values()]
        if ns:
            lines += ["", row_chance(int(np.median(ns)), 2 * len(ns))]
    return "\n".join(lines) + "\n"


def _jsonable(o):
    """numpy scalars for json.dumps."""
    return bool(o) if isinstance(o, np.bool_) else float(o)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=30, help="seeds per vessel with quadratic truth")
    ap.add_argument("--linear-seeds", type=int, default=10, help="seeds per vessel with linear truth")
    ap.add_argument("--otter-seeds", type=int, default=10, help="seeds of the PVS Otter runs")
    ap.add_argument("--vessels", default="aauship,catamaran_2m,workboat_5m")
    ap.add_argument("--workers", type=int, default=1, help="worker processes (at most 2 on the shared machine)")
    ap.add_argument("--json", help="write raw results here")
    ap.add_argument("--markdown", help="write the RESULTS.md section here")
    ap.add_argument("--partial", help="append each finished trial here (JSON lines) and skip the trials it "
                                      "already holds, so that a long run can be resumed in chunks")
    args = ap.parse_args(argv)
    t0 = time.time()
    tasks = [(vname, truth, seed) for vname in args.vessels.split(",")
             for truth, n in (("quadratic", args.seeds), ("linear", args.linear_seeds)) for seed in range(n)]
    results = {(v, t): [] for v, t, _ in tasks}
    tasks += [("otter", "pvs", seed) for seed in range(args.otter_seeds)]
    partial = Path(args.partial) if args.partial else None
    saved = {}
    if partial and partial.exists():
        for line in partial.read_text().splitlines():
            rec = json.loads(line)
            saved[tuple(rec["task"])] = rec["result"]
    todo = [t for t in tasks if tuple(t) not in saved]

    def keep(task, run):
        saved[tuple(task)] = run
        if partial:
            with partial.open("a") as fh:
                fh.write(json.dumps({"task": list(task), "result": run}, default=_jsonable) + "\n")

    if args.workers > 1:
        from concurrent.futures import ProcessPoolExecutor, as_completed
        with ProcessPoolExecutor(max_workers=args.workers) as ex:
            futures = {ex.submit(_task, t): t for t in todo}
            for fut in as_completed(futures):
                keep(futures[fut], fut.result())
    else:
        for t in todo:
            keep(t, _task(t))
    done = [saved[tuple(t)] for t in tasks]
    otter = [] if args.otter_seeds else None
    for (vname, truth, seed), run in zip(tasks, done):
        if vname == "otter":
            if run is None:
                print("PythonVehicleSimulator not found (PVS_PATH) or the Otter case failed", file=sys.stderr)
            else:
                otter.append(run)
        elif run is not None:
            results[(vname, truth)].append(run)
    summary = summarise(results)
    cmd = "python benchmarks/damping_structure.py " + " ".join(argv if argv is not None else sys.argv[1:])
    attribution = otter_attribution() if args.otter_seeds else None
    text = markdown(summary, otter, cmd.strip(), time.time() - t0, results, attribution)
    print(text)
    if args.markdown:
        atomic_write_text(args.markdown, text)
    if args.json:
        Path(args.json).write_text(json.dumps({"summary": summary, "otter": otter, "otter_attribution": attribution,
                                               "raw": {f"{k[0]}|{k[1]}": v for k, v in results.items()}},
                                              default=_jsonable, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
