"""Nomoto identification on ships vesselid was not tuned on: Fossen's PythonVehicleSimulator.

Ships (PythonVehicleSimulator's own classes and equations; nothing of it is copied here): the
frigate (Norrbin model, rudder servo with 1 s lag and 10 deg/s rate limit, U = 8 m/s), the
Clarke83 ship (linear 3-DOF sway-yaw model: second-order Nomoto with complex poles and a zero;
1 s rudder lag), and the tanker (nonlinear, shallow water, rudder rate limit 5 deg/s; 20 and
25 m depth). Manoeuvres: rudder steps (hold, +a, hold, -a, ...), a closed-loop a/a zig-zag and
sinusoids at two frequencies (one log: 3 periods at 2/T, a 10 T hold, 3 periods at 0.5/T). Each is run once per ship with the simulator's own ``dynamics`` at
20 Hz (its forward Euler; a finer step where 20 Hz is no multiple of the log rate) and logged at
5 Hz (``--rate``, 1-100 Hz; the command is updated at the log rate and held) as a canonical CSV, one
file or ``--split N`` consecutive run files (``--split-gap S``: each later file's clock S s on, a
logger switched off between files): heading (wrapped), yaw rate,
speed and the rudder, logged either as the servo's measured angle (``measured``: noisy, ramps) or
as the command (``commanded``: clean steps). Each seed then adds its own sensor noise (compass
0.2 deg, gyro 0.05 deg/s, rudder sensor 0.1 deg) and, with ``waves``, a narrow-band wave-induced
yaw (0.5 deg std around 0.6 rad/s, on heading and yaw rate).

Truth: the simulator's own linearisation about its straight-line steady state (finite differences
of its ``dynamics`` in sway velocity, yaw rate and rudder) reduced to ``r/delta = (b1 s + b0)/(s^2
+ a1 s + a0)``: ``K = b0/a0``, first-order equivalent ``T = T1 + T2 - T3 = a1/a0 - b1/b0``.

Each log goes through vesselid as a new user's would: :func:`pipeline.flow.load_trial` (CSV reader
and aligner), :func:`pipeline.segment.detect_segments`, :func:`pipeline.fit.fit_trial` with a
vessel config that gives only its name. Peers on the same logs: a plain 30-line scipy output-error
fit (first-order Nomoto with bias, heading simulated by ``scipy.signal.lsim`` from the logged
rudder, ``scipy.optimize.least_squares``) and, on the sinusoid pair, the seeds' two-frequency
amplitude method.

Per row (ship, manoeuvre, rudder log, waves): median and worst relative error of K and T over the
seeds, 95 % CI coverage, the number of estimates more than 20 % off that were marked success,
and the peers' median errors. A second table gives, per row and pooled over the rows, the coverage of the
estimates marked success with its Clopper-Pearson 95 % interval and the root mean square of their z
(:func:`coverage_table`): one row's 20 / 20 is what a true 95 % gives 36 % of the time, so coverage is judged
pooled and by the z rms, per row only where its interval excludes 95 %.

Run: ``.venv/bin/python benchmarks/independent.py [--seeds N] [--ships a,b] [--manoeuvres a,b]``.
PythonVehicleSimulator is found at ``$PVS_PATH`` (default ``/work/pvs/src``); without it the script
prints why and exits 0. Results are written to benchmarks/RESULTS.md under
"## Independent simulator (PythonVehicleSimulator, Nomoto)".
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import scipy.optimize  # noqa: E402
import scipy.signal  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.errors import VesselidError  # noqa: E402
from benchmarks.baselines import nomoto_amplitude_method, sinusoid_amplitude  # noqa: E402
from pipeline.fit import fit_trial  # noqa: E402
from pipeline.fit.combine import COMBINATION_RULES, combination_rules  # noqa: E402
from pipeline.flow import load_trial  # noqa: E402
from pipeline.segment import detect_segments  # noqa: E402
from pipeline.vessel import parse_vessel  # noqa: E402

D2R = math.pi / 180.0
H_SIM = 0.05          # integration step [s] (the simulator's Euler)
FS_LOG = 5.0          # default log rate [Hz] (``--rate``)
SECTION = "## Independent simulator (PythonVehicleSimulator, Nomoto)"
NOISE = {"psi": 0.2 * D2R, "r": 0.05 * D2R, "delta": 0.1 * D2R}
WAVE_STD, WAVE_OMEGA = 0.5 * D2R, 0.6
SEG_PARAMS = ("K", "T", "T1", "T2", "T3", "T12", "T1T2", "t_servo", "b")


def load_pvs():
    """Import PythonVehicleSimulator's vehicles from ``$PVS_PATH``; None (with a message) when absent."""
    path = os.environ.get("PVS_PATH", "/work/pvs/src")
    if not Path(path, "python_vehicle_simulator").is_dir():
        print(f"PythonVehicleSimulator not found at {path!r} (set PVS_PATH): benchmark skipped")
        return None
    sys.path.insert(0, path)
    import python_vehicle_simulator.vehicles as vehicles

    return vehicles


@dataclass(frozen=True)
class Ship:
    name: str
    make: object          # () -> vehicle
    amplitude: float      # rudder amplitude [rad] for steps / zig-zag / sinusoid
    zigzag_psi: float     # zig-zag heading switch [rad]


def ships(v) -> dict[str, Ship]:
    return {
        "frigate": Ship("frigate", lambda: v.frigate("stepInput", U=8.0), 10 * D2R, 10 * D2R),
        "clarke83": Ship("clarke83", lambda: v.shipClarke83(), 10 * D2R, 10 * D2R),
        "tanker20": Ship("tanker20", lambda: v.tanker(depth=20.0), 10 * D2R, 10 * D2R),
        "tanker25": Ship("tanker25", lambda: v.tanker(depth=25.0), 10 * D2R, 10 * D2R),
    }


# --------------------------------------------------------------------------- simulation
def sim_step(fs: float) -> tuple[float, int]:
    """Integration step [s] and samples per log sample for the log rate ``fs`` [Hz].

    ``H_SIM`` (the simulator's 20 Hz Euler) where the log rate divides it (1, 2, 4, 5, 10, 20 Hz:
    every default figure unchanged), else the largest step below it that puts a whole number of
    steps in one log interval (50 Hz: 0.02 s, 100 Hz: 0.01 s).
    """
    if not (math.isfinite(fs) and fs > 0):
        raise ValueError(f"error: log rate must be a positive number of Hz, found {fs!r}")
    every = max(1, math.ceil(1.0 / (fs * H_SIM) - 1e-9))
    h = 1.0 / (fs * every)
    return (H_SIM if abs(h - H_SIM) < 1e-12 else h), every


def settle(vehicle, seconds: float = 3000.0) -> np.ndarray:
    """Straight-line steady state of the simulator at zero rudder."""
    nu = np.array(vehicle.nu, float)
    ua = np.zeros(1)
    eta = np.zeros(6)
    for _ in range(int(seconds / H_SIM)):
        nu, ua = vehicle.dynamics(eta, nu, ua, np.zeros(1), H_SIM)
    return nu


def linearise(vehicle, nu0: np.ndarray) -> dict[str, float]:
    """The simulator's own linear sway-yaw model about ``nu0`` -> K, T1+T2, T1 T2, T3, T equivalent."""
    eta = np.zeros(6)

    def f(v, r, d):
        nu = np.array(nu0, float)
        nu[1], nu[5] = v, r
        h = 1e-3
        nu1, _ = vehicle.dynamics(eta, nu, np.array([d]), np.array([d]), h)
        return (nu1 - nu) / h

    eps = (1e-4, 1e-6, 1e-5)
    base = np.array([nu0[1], nu0[5], 0.0])
    cols = []
    for j, e in enumerate(eps):
        xp, xm = base.copy(), base.copy()
        xp[j] += e
        xm[j] -= e
        cols.append((f(*xp) - f(*xm)) / (2 * e))
    jac = np.column_stack(cols)[[1, 5]]    # rows v_dot, r_dot; columns v, r, delta
    a, b = jac[:, :2], jac[:, 2:]
    if abs(a[0, 0]) < 1e-12 and abs(a[0, 1]) < 1e-12 and abs(b[0, 0]) < 1e-12:
        # Yaw-only model (frigate): r_dot = a r + b delta.
        K, T = -b[1, 0] / a[1, 1], -1.0 / a[1, 1]
        return {"K": K, "T": T, "T1": T, "T2": 0.0, "T3": 0.0, "order": 1}
    num, den = scipy.signal.ss2tf(a, b, np.array([[0.0, 1.0]]), np.zeros((1, 1)))
    num = num[0][-2:]
    a1, a0 = den[1], den[2]
    b1, b0 = num
    K = b0 / a0
    T3 = b1 / b0
    return {"K": K, "T": a1 / a0 - T3, "T1pT2": a1 / a0, "T1T2": 1.0 / a0, "T3": T3, "order": 2,
            "complex_poles": bool(a1**2 < 4 * a0)}


def rudder_program(kind: str, ship: Ship, T: float, K: float):
    """Command generator ``(t, psi) -> delta_c`` and the duration [s].

    ``T`` is the ship's slowest time scale (``T1 + T2`` for a second-order ship), ``K`` the signed
    linear gain (the zig-zag switches on the heading the rudder drives).
    """
    a = ship.amplitude
    sign = 1.0 if K > 0 else -1.0
    if kind == "steps":
        hold = max(6 * T, 60.0)
        pattern = [0.0, a, 0.0, -a, 0.0, 0.5 * a, 0.0]
        return (lambda t, psi, st: pattern[min(int(t // hold), len(pattern) - 1)]), hold * len(pattern)
    if kind == "zigzag":
        def zig(t, psi, st):
            if t < 30.0:
                return 0.0
            if st.get("d") is None:
                st["d"] = a
            turned = sign * psi
            if st["d"] > 0 and turned > ship.zigzag_psi:
                st["d"] = -a
            elif st["d"] < 0 and turned < -ship.zigzag_psi:
                st["d"] = a
            return st["d"]
        half_cycle = 2 * ship.zigzag_psi / (abs(K) * a) + T
        return zig, 30.0 + 7 * half_cycle
    if kind == "sinusoid":
        # Both frequencies in one trial, as a user runs them: 3 periods at 2/T, a 10 T hold at
        # midships (the segmenter joins varying stretches separated by less than their own
        # length), 3 periods at 0.5/T, a 4 T hold.
        (t0a, t0b, w_fast), (t1a, t1b, w_slow), _ = sinusoid_parts(T)

        def sine_pair(t, psi, st):
            if t0a <= t < t0b:
                return a * math.sin(w_fast * (t - t0a))
            if t1a <= t < t1b:
                return a * math.sin(w_slow * (t - t1a))
            return 0.0
        return sine_pair, sinusoid_parts(T)[2]
    if kind.startswith("sinusoid"):
        w = (0.5 if kind.endswith("slow") else 2.0) / T
        periods = 3
        return (lambda t, psi, st: a * math.sin(w * t)), periods * 2 * math.pi / w
    raise ValueError(kind)


def sinusoid_parts(T: float) -> tuple[tuple[float, float, float], tuple[float, float, float], float]:
    """The sinusoid pair's fast and slow parts as (start [s], end [s], frequency [rad/s]) and the
    duration [s], for the time scale ``T`` [s]: 3 periods at 2/T, a 10 T hold, 3 periods at 0.5/T,
    a 4 T hold."""
    w_fast, w_slow = 2.0 / T, 0.5 / T
    fast = (0.0, 3 * 2 * math.pi / w_fast, w_fast)
    t1a = fast[1] + 10 * T
    slow = (t1a, t1a + 3 * 2 * math.pi / w_slow, w_slow)
    return fast, slow, slow[1] + 4 * T


def time_scale(truth: dict) -> float:
    """The ship's slowest time scale [s]: T, or T1 + T2 for a second-order ship."""
    return abs(truth["T"]) if truth["order"] == 1 else abs(truth["T1pT2"])


def simulate(ship: Ship, kind: str, truth: dict, fs: float = FS_LOG) -> dict[str, np.ndarray]:
    """Noise-free log at ``fs`` [Hz]: t, psi (unwrapped), r, u, delta_c, delta (servo)."""
    vehicle = ship.make()
    nu = settle(vehicle)
    prog, duration = rudder_program(kind, ship, time_scale(truth), truth["K"])
    ua = np.zeros(1)
    eta = np.zeros(6)
    psi = 0.0
    st: dict = {}
    h_sim, every = sim_step(fs)
    rows = []
    n = int(duration / h_sim)
    dc = 0.0
    for k in range(n + 1):
        t = k * h_sim
        if k % every == 0:
            dc = prog(t, psi, st)       # a digital command, updated at the log rate and held
            rows.append((t, psi, nu[5], nu[0], dc, ua[0]))
        r_before = nu[5]
        nu, ua = vehicle.dynamics(eta, nu, ua, np.array([dc]), h_sim)
        # The heading is the integral of the simulator's own yaw rate, piecewise linear between its
        # Euler steps: the trapezoid. (psi += h r_new, PVS's own attitude update, makes the heading lead
        # the yaw rate by h/2 = 0.025 s: T shifted by -0.13 to -0.16 % on the frigate's slow sinusoid,
        # seeds 0-2, 2-4 of its standard errors.)
        psi += 0.5 * h_sim * (r_before + nu[5])
    arr = np.array(rows)
    return dict(zip(("t", "psi", "r", "u", "delta_c", "delta"), arr.T))


def wave_yaw(t: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Narrow-band wave-induced heading and yaw rate (30 random-phase components)."""
    w = WAVE_OMEGA * (1 + 0.2 * rng.standard_normal(30))
    ph = rng.uniform(0, 2 * math.pi, 30)
    amp = WAVE_STD * math.sqrt(2.0 / 30)
    psi_w = (amp * np.cos(np.outer(t, w) + ph)).sum(axis=1)
    r_w = (-amp * w * np.sin(np.outer(t, w) + ph)).sum(axis=1)
    return psi_w, r_w


def noisy_log(sim: dict, rudder: str, waves: bool, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """One seed's log: sensor noise, optional waves, rudder as measured angle or command."""
    t = sim["t"]
    psi = sim["psi"] + NOISE["psi"] * rng.standard_normal(t.size)
    r = sim["r"] + NOISE["r"] * rng.standard_normal(t.size)
    if waves:
        pw, rw = wave_yaw(t, rng)
        psi, r = psi + pw, r + rw
    if rudder == "measured":
        delta = sim["delta"] + NOISE["delta"] * rng.standard_normal(t.size)
    else:
        delta = sim["delta_c"].copy()
    psi = (psi + math.pi) % (2 * math.pi) - math.pi
    return {"t": t, "psi": psi, "r": r, "u": sim["u"], "delta": delta}


def write_csv(log: dict, path: Path) -> None:
    cols = ("t", "psi", "r", "u", "delta")
    np.savetxt(path, np.column_stack([log[c] for c in cols]), delimiter=",", header=",".join(cols), comments="",
               fmt="%.9g")


def write_split(log: dict, workdir: Path, tag: str, split: int, gap_s: float = 0.0) -> list[Path]:
    """The log as ``split`` consecutive CSV files of (nearly) equal length, as a trial day's run
    files: each keeps the logger's clock (``t`` continues), no sample is repeated or dropped. With
    ``gap_s`` [s] > 0 file k's clock is ``k * gap_s`` later (a logger switched off between files:
    separate runs, and a manoeuvre a boundary cuts is dropped with a note)."""
    if split < 1:
        raise ValueError(f"error: --split must be at least 1, found {split}")
    if not gap_s >= 0:
        raise ValueError(f"error: --split-gap must be at least 0 s, found {gap_s}")
    if split == 1:
        path = workdir / f"{tag}.csv"
        write_csv(log, path)
        return [path]
    bounds = np.linspace(0, log["t"].size, split + 1).round().astype(int)
    paths = []
    for i, (lo, hi) in enumerate(zip(bounds[:-1], bounds[1:])):
        path = workdir / f"{tag}_part{i + 1}.csv"
        part = {k: v[lo:hi] for k, v in log.items()}
        write_csv(dict(part, t=part["t"] + i * gap_s), path)
        paths.append(path)
    return paths


# --------------------------------------------------------------------------- estimators
def vesselid_fit(log: dict, workdir: Path, tag: str, split: int = 1, gap_s: float = 0.0) -> dict:
    """The user's path: CSV file(s) -> load_trial -> detect_segments -> fit_trial (name-only vessel)."""
    paths = write_split(log, workdir, tag, split, gap_s)
    vessel = parse_vessel({"name": "pvs_ship"})
    try:
        trial = load_trial(paths)
        segs = detect_segments(trial)
        fits = fit_trial(trial, segs, vessel, extend=False)
    except VesselidError as exc:
        return {"error": str(exc)}
    except Exception as exc:  # noqa: BLE001 - a crash is a result of the benchmark, recorded per run
        return {"error": f"crash: {type(exc).__name__}: {exc}"}
    out = {"kinds": [s.kind for s in segs.items if s.dof == "yaw"],
           # Every file counted: the runs found (files that continue one clock are one run), each
           # run's segments, and what the detector dropped at a file boundary (Segments.notes).
           "runs": [{"files": [Path(f).name for f in run.sources],
                     "segments": sum(trial.run_index(s.t_start) == k for s in segs.items)}
                    for k, run in enumerate(trial.run_list())],
           "segment_notes": list(segs.notes),
           "segments": [{"kind": sf.segment.kind, "model": sf.model, "success": sf.success,
                         "params": {n: sf.params[n] for n in SEG_PARAMS if n in sf.params},
                         "stderr": {n: sf.stderr[n] for n in SEG_PARAMS if n in sf.stderr},
                         "message": sf.message[:3000]}
                        for sf in fits.segment_fits if sf.segment.dof == "yaw"]}
    for key, name in (("K", "K_nomoto"), ("T", "T_nomoto")):
        est = fits.estimates.get(name)
        if est is None:
            out[key] = None
            continue
        out[key] = {"value": est.value, "stderr": est.stderr, "ci": est.ci95, "success": est.success,
                    "message": est.message[:800]}
    return out


def scipy_oe(log: dict) -> tuple[float, float]:
    """Peer: plain first-order Nomoto output-error fit of the heading (scipy only)."""
    t, psi, delta = log["t"], np.unwrap(log["psi"]), log["delta"]

    def sim(p):
        K, T, b, psi0, r0 = p
        sys_ = scipy.signal.StateSpace([[0, 1], [0, -1 / T]], [[0], [K / T]], [[1, 0]], [[0]])
        _, y, _ = scipy.signal.lsim(sys_, delta - b, t - t[0], X0=[psi0, r0], interp=False)
        return y

    r_ss = np.median(np.abs(log["r"])) + 1e-6
    p0 = [r_ss / (np.median(np.abs(delta)) + 1e-3), 20.0, 0.0, psi[0], log["r"][0]]
    res = scipy.optimize.least_squares(lambda p: sim(p) - psi, p0, bounds=([-np.inf, 0.1, -0.5, -np.inf, -1],
                                                                       [np.inf, 5000, 0.5, np.inf, 1]))
    return float(res.x[0]), float(res.x[1])


def attainable(sim: dict, truth: dict) -> tuple[float, float]:
    """The best a linear model of the right structure can do on this manoeuvre: K, T (equivalent).

    The simulator's noise-free yaw rate is fitted, by output error from its own noise-free servo
    angle and a rudder bias, with the linear structure of the truth (first order for a first-order
    ship; ``K (T3 s + 1)/(T1 T2 s^2 + (T1 + T2) s + 1)`` otherwise), started at the truth. What is
    left between this and the linearisation is the ship's nonlinearity at the manoeuvre's amplitude
    (rudder lift, speed change in turns), which no linear identification removes.
    """
    t, r, d = sim["t"], sim["r"], sim["delta"]
    if truth["order"] == 1:
        num = lambda p: [p[0]]  # noqa: E731
        den = lambda p: [p[1], 1.0]  # noqa: E731
        p0 = [truth["K"], truth["T"], 0.0]
    else:
        num = lambda p: [p[0] * p[3], p[0]]  # noqa: E731
        den = lambda p: [p[2], p[1], 1.0]  # noqa: E731
        p0 = [truth["K"], truth["T1pT2"], truth["T1T2"], truth["T3"], 0.0]

    def resid(p):
        ss = scipy.signal.lti(num(p), den(p)).to_ss()
        x0 = -np.linalg.solve(ss.A, ss.B[:, 0] * (d[0] - p[-1]))
        _, y, _ = scipy.signal.lsim(ss, d - p[-1], t, X0=x0, interp=True)
        return (y - r) / np.std(r)

    try:
        p = scipy.optimize.least_squares(resid, p0, x_scale=np.abs(p0) + 1e-3).x
    except (ValueError, np.linalg.LinAlgError):
        return math.nan, math.nan
    return float(p[0]), float(p[1] if truth["order"] == 1 else p[1] - p[3])


# --------------------------------------------------------------------------- coast-downs
U_NOISE = 0.02        # speed-over-ground noise [m/s]


def coastdown_truth(v) -> dict:
    """Clarke83's own surge model (PythonVehicleSimulator ``clarke83``): X_u, m - X_udot and the config."""
    from python_vehicle_simulator.lib.models import clarke83

    ship = v.shipClarke83()
    M, N = clarke83(3.0, ship.L, ship.B, ship.T, ship.Cb, ship.R66, 0, ship.L)
    m = 1025.0 * ship.Cb * ship.L * ship.B * ship.T
    iz = m * ship.R66**2
    cfg = {"name": "clarke83", "rigid_body": {"mass": m, "inertia": [0.1 * iz, iz, iz]},
           "added_mass": {"surge": float(M[0, 0] - m), "sway": float(M[1, 1] - m), "yaw": float(M[2, 2] - iz)}}
    return {"X_u": -float(N[0, 0]), "m_eff": float(M[0, 0]), "config": cfg}


def simulate_coastdown(v, cut_s: float = 60.0, coast_s: float = 200.0, fs: float = FS_LOG) -> dict[str, np.ndarray]:
    """Clarke83 at its steady speed under the default thrust, thrust cut at ``cut_s``; rudder amidships."""
    ship = v.shipClarke83()
    nu = settle(ship, 10 * ship.L)      # surge time constant T_surge = L [s]: 10 of them
    ua, eta, psi = np.zeros(1), np.zeros(6), 0.0
    h_sim, every = sim_step(fs)
    rows = []
    thrust = ship.tau_X
    for k in range(int((cut_s + coast_s) / h_sim) + 1):
        t = k * h_sim
        ship.tau_X = thrust if t < cut_s else 0.0
        if k % every == 0:
            rows.append((t, psi, nu[5], nu[0]))
        nu, ua = ship.dynamics(eta, nu, ua, np.zeros(1), h_sim)
        psi += h_sim * nu[5]
    arr = np.array(rows)
    return dict(zip(("t", "psi", "r", "u"), arr.T)) | {"cut": cut_s}


def coastdown_one(task) -> dict:
    """One seed: noisy speed log -> vesselid X_u (config with the simulator's mass and added mass) and a peer."""
    sim, truth, seed = task
    rng = np.random.default_rng(1000 * seed + 29)
    t = sim["t"]
    log = {"t": t, "psi": sim["psi"] + NOISE["psi"] * rng.standard_normal(t.size),
           "r": sim["r"] + NOISE["r"] * rng.standard_normal(t.size),
           "u": sim["u"] + U_NOISE * rng.standard_normal(t.size), "delta": np.zeros(t.size)}
    out: dict = {"seed": seed}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"coast_{seed}.csv"
        write_csv(log, path)
        try:
            trial = load_trial([path])
            segs = detect_segments(trial)
            fits = fit_trial(trial, segs, parse_vessel(truth["config"]), extend=False)
            est = fits.estimates.get("X_u")
            out["segments"] = [s.kind for s in segs.items if s.dof == "surge"]
            if est is not None:
                out["X_u"] = {"value": est.value, "stderr": est.stderr, "ci": est.ci95, "success": est.success,
                              "message": est.message[:300]}
        except VesselidError as exc:
            out["error"] = str(exc)
    # Peer: exponential decay fitted with scipy to the speed after the (known) cut.
    m = t >= sim["cut"]
    tt, uu = t[m] - sim["cut"], log["u"][m]
    try:
        p, _ = scipy.optimize.curve_fit(lambda x, a, T, c: a * np.exp(-x / T) + c, tt, uu, p0=(uu[0], 30.0, 0.0))
        out["peer"] = -truth["m_eff"] / p[1]
    except (RuntimeError, ValueError):
        out["peer"] = math.nan
    return out


def coastdown_table(v, seeds: int, fs: float = FS_LOG) -> str:
    """Coast-down rows: X_u of Clarke83 over ``seeds`` seeds (markdown), logged at ``fs`` [Hz]."""
    truth = coastdown_truth(v)
    sim = simulate_coastdown(v, fs=fs)
    res = [coastdown_one((sim, truth, s)) for s in range(seeds)]
    x0 = truth["X_u"]
    errs, cover, ok, peer, wrong = [], [], 0, [], 0
    for r in res:
        peer.append(abs(rel(r.get("peer", math.nan), x0)))
        est = r.get("X_u")
        if est is None or not est["success"]:
            continue
        ok += 1
        e = rel(est["value"], x0)
        errs.append(e)
        cover.append(est["ci"][0] <= x0 <= est["ci"][1])
        wrong += abs(e) > 0.2
    errs_a = np.abs(np.array(errs)) if errs else np.array([math.nan])
    fails = [r.get("error") or (r.get("X_u") or {}).get("message", "no X_u estimate") for r in res
             if not (r.get("X_u") or {}).get("success")]
    lines = [f"Coast-downs (Clarke83, thrust cut from its steady {sim['u'][0]:.2f} m/s, 200 s logged at {fs:g} Hz, "
             f"speed noise {U_NOISE} m/s; config from the simulator's own mass and added mass; truth X_u = {x0:.6g} "
             f"kg/s, m - X_udot = {truth['m_eff']:.6g} kg):", "",
             "| ship | manoeuvre | X_u marked success | X_u err % (median signed / median abs / worst) | 95% CI coverage % "
             "| >20 % off marked success | scipy exponential-fit peer median abs err % |",
             "|---|---|---|---|---|---|---|",
             f"| clarke83 | coast-down | {ok} of {len(res)} | {pct(float(np.median(errs)) if errs else math.nan)} / "
             f"{pct(float(np.median(errs_a)))} / {pct(float(np.max(errs_a)))} | "
             f"{pct(float(np.mean(cover)) if cover else math.nan)} | {wrong} | {pct(float(np.nanmedian(peer)))} |"]
    if fails:
        lines += ["", f"First failure: {fails[0][:200]}"]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- the benchmark
def rel(v, truth):
    return (v - truth) / abs(truth) if v is not None and math.isfinite(v) else math.nan


def run_one(task) -> dict:
    """One seed of one row: noisy log(s) -> vesselid and the peers."""
    ship_name, kinds, sims, rudder, waves, seed, truth = task[:7]
    split = task[7] if len(task) > 7 else 1
    gap_s = task[8] if len(task) > 8 else 0.0
    rng = np.random.default_rng(1000 * seed + 17)
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for kind in kinds:
            log = noisy_log(sims[kind], rudder, waves == "yes", rng)
            run = {"kind": kind, "seed": seed}
            run["vesselid"] = vesselid_fit(log, Path(tmp), f"{ship_name}_{kind}_{seed}", split, gap_s)
            try:
                run["oe"] = scipy_oe(log)
            except (ValueError, np.linalg.LinAlgError):
                run["oe"] = (math.nan, math.nan)
            if kind == "sinusoid":
                psi_u = np.unwrap(log["psi"])
                for lo, hi, w in sinusoid_parts(time_scale(truth))[:2]:
                    m = (log["t"] >= lo) & (log["t"] < hi)
                    run.setdefault("amp_parts", []).append(
                        (sinusoid_amplitude(log["t"][m], psi_u[m], log["delta"][m]), w))
            runs.append(run)
    return runs


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--seed-start", type=int, default=0, help="first seed (to add seeds to an earlier run's --json)")
    ap.add_argument("--ships", default="frigate,clarke83,tanker20,tanker25")
    ap.add_argument("--manoeuvres", default="steps,zigzag,sinusoid")
    ap.add_argument("--rudder", default="measured,commanded")
    ap.add_argument("--waves", default="no,yes")
    ap.add_argument("--rows", default="",
                    help="only these rows, comma-separated ship:manoeuvre:rudder:waves (instead of the product)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--rate", type=float, default=FS_LOG,
                    help=f"log rate [Hz] (default {FS_LOG:g}); the command is updated at this rate and held")
    ap.add_argument("--split", type=int, default=1,
                    help="write each trial as N consecutive run files (default 1: one file)")
    ap.add_argument("--split-gap", type=float, default=0.0,
                    help="with --split: each later file's clock this many seconds on (default 0: the files "
                         "continue one clock, a logger that rotates its file)")
    ap.add_argument("--no-write", action="store_true", help="print only; do not touch RESULTS.md")
    ap.add_argument("--json", default="", help="also write every task's raw result to this JSON-lines file")
    ap.add_argument("--deadline-min", type=float, default=0.0,
                    help="stop after this many minutes and summarise the tasks done (0: no deadline)")
    ap.add_argument("--coastdowns", type=int, default=0,
                    help="run N seeds of the Clarke83 coast-down rows instead (surge damping X_u; appended to the "
                         "section by hand)")
    ap.add_argument("--from-jsonl", default="",
                    help="only summarise the tasks recorded in these JSON-lines files (comma-separated, from --json) "
                         "and write them")
    args = ap.parse_args(argv)
    if not (math.isfinite(args.rate) and args.rate > 0):
        ap.error(f"--rate: expected a positive log rate in Hz, found {args.rate!r}")
    if args.split < 1:
        ap.error(f"--split: expected at least 1 file, found {args.split}")
    if not (math.isfinite(args.split_gap) and args.split_gap >= 0):
        ap.error(f"--split-gap: expected a gap of at least 0 s, found {args.split_gap!r}")
    if args.from_jsonl:
        return summarise_jsonl(args)
    if args.coastdowns:
        v = load_pvs()
        if v is None:
            return 0
        print(coastdown_table(v, args.coastdowns, args.rate))
        return 0
    v = load_pvs()
    if v is None:
        return 0
    all_ships = ships(v)
    chosen = [all_ships[s] for s in args.ships.split(",")]
    rows_spec = []
    t0 = time.time()
    wanted = {tuple(r.split(":")) for r in args.rows.split(",") if r}
    if wanted:
        chosen = [all_ships[s] for s in dict.fromkeys(w[0] for w in sorted(wanted))]
    for ship in chosen:
        vehicle = ship.make()
        truth = linearise(vehicle, settle(vehicle))
        print(f"{ship.name}: truth K = {truth['K']:.5g} 1/s, T = {truth['T']:.5g} s "
              f"({'second order' if truth['order'] == 2 else 'first order'})", flush=True)
        for man in args.manoeuvres.split(","):
            if wanted and not any(w[:2] == (ship.name, man) for w in wanted):
                continue
            kinds = [man]
            sims = {kind: simulate(ship, kind, truth, args.rate) for kind in kinds}
            best = [attainable(sims[kind], truth) for kind in kinds]
            truth = dict(truth, attainable=[[rel(k, truth["K"]), rel(tt, truth["T"])] for k, tt in best])
            for rudder in args.rudder.split(","):
                for waves in args.waves.split(","):
                    if wanted and (ship.name, man, rudder, waves) not in wanted:
                        continue
                    rows_spec.append((ship.name, man, rudder, waves, truth,
                                      [(ship.name, kinds, sims, rudder, waves, seed, truth, args.split, args.split_gap)
                                       for seed in range(args.seed_start, args.seed_start + args.seeds)]))
    # Seed-major order: a run stopped at its deadline still has every row, with fewer seeds.
    order = [(r, args.seed_start + k) for k in range(args.seeds) for r in range(len(rows_spec))]
    tasks = [rows_spec[r][5][seed - args.seed_start] for r, seed in order]
    results: dict[int, list] = {r: [] for r in range(len(rows_spec))}
    jsonl = open(args.json, "w") if args.json else None
    deadline = t0 + 60.0 * args.deadline_min if args.deadline_min > 0 else math.inf

    def record(i: int, res) -> None:
        r = order[i][0]
        results[r].append(res)
        if jsonl is not None:
            spec = rows_spec[r]
            jsonl.write(json.dumps({"ship": spec[0], "man": spec[1], "rudder": spec[2], "waves": spec[3],
                                    "truth": spec[4], "seed": order[i][1], "rate": args.rate, "split": args.split,
                                    "split_gap": args.split_gap,
                                    "runs": res}, default=float) + "\n")
            jsonl.flush()
        print(f"task {i + 1}/{len(tasks)} done ({time.time() - t0:.0f} s)", flush=True)

    if args.workers > 1:
        import multiprocessing as mp

        pool = mp.get_context("fork").Pool(args.workers)
        for i, res in enumerate(pool.imap(run_one, tasks, chunksize=1)):
            record(i, res)
            if time.time() > deadline:
                print(f"deadline of {args.deadline_min} min reached: {i + 1} of {len(tasks)} tasks done", flush=True)
                break
        pool.terminate()
        pool.join()
    else:
        for i, task in enumerate(tasks):
            record(i, run_one(task))
            if time.time() > deadline:
                break
    if jsonl is not None:
        jsonl.close()
    rows = []
    for r, (ship_name, man, rudder, waves, truth, _) in enumerate(rows_spec):
        runs = [run for res in results[r] for run in res]
        rows.append(summarise({"ship": ship_name, "man": man, "rudder": rudder, "waves": waves, "truth": truth,
                               "runs": runs}))
        print(format_row(rows[-1]), flush=True)
    elapsed = time.time() - t0
    text = render(rows, args, elapsed, {spec[0]: spec[4] for spec in rows_spec})
    print(text)
    if not args.no_write:
        write_results(text)
    return 0


def summarise_jsonl(args) -> int:
    """Rows from the JSON lines of finished tasks (a run stopped before its end), rendered and written."""
    groups: dict[tuple, dict] = {}
    seen = set()
    lines = [line for path in args.from_jsonl.split(",") for line in open(path)]
    for line in lines:
        d = json.loads(line)
        key = (d["ship"], d["man"], d["rudder"], d["waves"])
        if key + (d["seed"],) in seen:
            continue  # the same task recorded by two runs (files given together)
        seen.add(key + (d["seed"],))
        g = groups.setdefault(key, {"ship": d["ship"], "man": d["man"], "rudder": d["rudder"], "waves": d["waves"],
                                    "truth": d["truth"], "runs": []})
        g["runs"].extend(d["runs"])
    rows = [summarise(g) for g in groups.values()]
    for r in rows:
        print(format_row(r), flush=True)
    text = render(rows, args, math.nan, {g["ship"]: g["truth"] for g in groups.values()})
    print(text)
    if not args.no_write:
        write_results(text)
    return 0


def summarise(res: dict) -> dict:
    truth = res["truth"]
    K0, T0 = truth["K"], truth["T"]
    errs = {"K": [], "T": []}
    cover = {"K": [], "T": []}
    zs = {"K": [], "T": []}
    wrong_success = 0
    unsure = {"K": [], "T": []}
    fails = []
    oe_err = {"K": [], "T": []}
    amp_err = {"K": [], "T": []}
    by_seed: dict[int, list] = {}
    rule_cover: dict[str, dict[str, list]] = {}
    for run in res["runs"]:
        vid = run["vesselid"]
        for key, tv in (("K", K0), ("T", T0)):
            est = vid.get(key) if "error" not in vid else None
            if est is None or not est["success"]:
                errs[key].append(math.nan)
                if est is not None and est["value"] is not None and math.isfinite(est["value"]):
                    unsure[key].append(rel(est["value"], tv))
                fails.append((est or {}).get("message", vid.get("error", "no estimate"))[:120])
                continue
            e = rel(est["value"], tv)
            errs[key].append(e)
            lo, hi = est["ci"]
            cover[key].append(lo <= tv <= hi)
            se = est.get("stderr")
            zs[key].append((est["value"] - tv) / se if se is not None and se > 0 else math.nan)
            if abs(e) > 0.2:
                wrong_success += 1
        for key, tv in (("K", K0), ("T", T0)):
            segs = [sg for sg in vid.get("segments", []) if sg["success"] and key in sg["params"]]
            rules = combination_rules([sg["params"][key] for sg in segs],
                                      [sg["stderr"].get(key, math.nan) for sg in segs])
            for rule, (_, _, (lo, hi)) in rules.items():
                rule_cover.setdefault(rule, {"K": [], "T": []})[key].append(lo <= tv <= hi)
        oe_err["K"].append(rel(run["oe"][0], K0))
        oe_err["T"].append(rel(run["oe"][1], T0))
        if "amp" in run:
            by_seed.setdefault(run["seed"], []).append(run["amp"])
        for part in run.get("amp_parts", []):
            by_seed.setdefault(run["seed"], []).append(part)
    for pair in by_seed.values():
        if len(pair) == 2:
            try:
                K, T = nomoto_amplitude_method(pair[0][0], pair[1][0], pair[0][1], pair[1][1])
                amp_err["K"].append(rel(K, abs(K0)) if K0 > 0 else rel(-K, K0))
                amp_err["T"].append(rel(T, T0))
            except VesselidError:
                amp_err["K"].append(math.nan)
                amp_err["T"].append(math.nan)

    def med(x):
        x = np.abs(np.array(x, float))
        x = x[np.isfinite(x)]
        return float(np.median(x)) if x.size else math.nan

    def worst(x):
        x = np.abs(np.array(x, float))
        x = x[np.isfinite(x)]
        return float(np.max(x)) if x.size else math.nan

    n = len(errs["K"])
    return {"ship": res["ship"], "man": res["man"], "rudder": res["rudder"], "waves": res["waves"],
            "n": n, "nK": int(np.isfinite(errs["K"]).sum()), "nT": int(np.isfinite(errs["T"]).sum()),
            "K_med": med(errs["K"]), "K_max": worst(errs["K"]), "T_med": med(errs["T"]), "T_max": worst(errs["T"]),
            "K_bias": float(np.nanmedian(errs["K"])) if np.isfinite(errs["K"]).any() else math.nan,
            "T_bias": float(np.nanmedian(errs["T"])) if np.isfinite(errs["T"]).any() else math.nan,
            "cov_K": float(np.mean(cover["K"])) if cover["K"] else math.nan,
            "cov_T": float(np.mean(cover["T"])) if cover["T"] else math.nan,
            "covered": {key: [int(sum(cover[key])), len(cover[key])] for key in ("K", "T")},
            "z": {key: [float(z) for z in zs[key]] for key in ("K", "T")},
            "wrong_success": wrong_success, "oe_K": med(oe_err["K"]), "oe_T": med(oe_err["T"]),
            "amp_K": med(amp_err["K"]), "amp_T": med(amp_err["T"]), "fails": fails[:2],
            "unsure_n": len(unsure["K"]) + len(unsure["T"]), "unsure_K": med(unsure["K"]), "unsure_T": med(unsure["T"]),
            "best": truth.get("attainable", []),
            "rules": {rule: {key: [int(sum(v[key])), len(v[key])] for key in ("K", "T")}
                      for rule, v in rule_cover.items()}}


def pct(x):
    return "-" if not math.isfinite(x) else f"{100 * x:.1f}"


def format_row(r: dict) -> str:
    return (f"| {r['ship']} | {r['man']} | {r['rudder']} | {r['waves']} | {r['nK']} / {r['nT']} of {r['n']} | "
            f"{pct(r['K_bias'])} / {pct(r['K_med'])} / {pct(r['K_max'])} | "
            f"{pct(r['T_bias'])} / {pct(r['T_med'])} / {pct(r['T_max'])} | {pct(r['cov_K'])} / {pct(r['cov_T'])} | "
            f"{r['wrong_success']} | {r['unsure_n']}: {pct(r['unsure_K'])} / {pct(r['unsure_T'])} | "
            f"{pct(r['oe_K'])} / {pct(r['oe_T'])} | {pct(r['amp_K'])} / {pct(r['amp_T'])} | "
            + ("; ".join(f"{signed(k)} / {signed(t)}" for k, t in r["best"]) or "-") + " |")


def signed(x):
    return "-" if x is None or not math.isfinite(x) else f"{100 * x:+.1f}"


HEADER = ("| ship | manoeuvre | rudder log | waves | K / T marked success | K err % (median signed / median abs / worst) | "
          "T err % (median signed / median abs / worst) | 95% CI coverage K / T % | >20 % off marked success | "
          "not success but a value (unsure): count, median abs err K / T % | "
          "scipy OE peer median abs err K / T % | amplitude method K / T % | "
          "best linear fit to the noise-free record K / T % |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|---|---|")


def render(rows: list[dict], args, elapsed: float, truths: dict) -> str:
    rows_given = f"--rows {args.rows}" if args.rows else (
        f"--ships {args.ships} --manoeuvres {args.manoeuvres} --rudder {args.rudder} --waves {args.waves}")
    cmd = (f"benchmarks/independent.py --seeds {args.seeds}"
           + (f" --seed-start {args.seed_start}" if args.seed_start else "")
           + f" {rows_given} --workers {args.workers}"
           + (f" --rate {args.rate:g}" if getattr(args, "rate", FS_LOG) != FS_LOG else "")
           + (f" --split {args.split}" if getattr(args, "split", 1) != 1 else "")
           + (f" --split-gap {args.split_gap:g}" if getattr(args, "split_gap", 0.0) else "")
           + (f" --deadline-min {args.deadline_min:g}" if args.deadline_min > 0 else ""))
    truth_lines = []
    for name, tr in truths.items():
        extra = (f", T1 + T2 = {tr['T1pT2']:.4g} s, T1 T2 = {tr['T1T2']:.4g} s^2, T3 = {tr['T3']:.4g} s"
                 f"{' (complex poles)' if tr.get('complex_poles') else ''}" if tr["order"] == 2 else "")
        truth_lines.append(f"- {name}: K = {tr['K']:.5g} 1/s, T = {tr['T']:.5g} s{extra}")
    took = (f"{elapsed / 60:.1f} min on 2 shared cores" if math.isfinite(elapsed)
            else f"stopped before its end; summarised with --from-jsonl from the tasks finished")
    lines = [SECTION, "", f"Command: `PYTHONPATH=. .venv/bin/python {cmd}` ({took}).",
             "", "Truth (the simulator's own linearisation at its straight-line steady state):", ""] + truth_lines + [
             "", HEADER] + [format_row(r) for r in rows]
    lines += ["", "Combination rules on the same per-segment fits (every run with a usable segment, marked success "
              "or not; `dl_prediction` is what vesselid reports for K and T (windows not overlapping), pipeline/fit/combine.py `combination_rules`): "
              "95 % CI coverage of the linearisation, K / T, in % (runs):", "",
              "| ship | manoeuvre | rudder log | waves | " + " | ".join(COMBINATION_RULES) + " |",
              "|---|---|---|---|" + "---|" * len(COMBINATION_RULES)]
    total = {rule: {"K": [0, 0], "T": [0, 0]} for rule in COMBINATION_RULES}
    for r in rows:
        cells = []
        for rule in COMBINATION_RULES:
            c = r.get("rules", {}).get(rule, {"K": [0, 0], "T": [0, 0]})
            for key in ("K", "T"):
                total[rule][key][0] += c[key][0]
                total[rule][key][1] += c[key][1]
            cells.append(" / ".join(pct(c[k][0] / c[k][1]) if c[k][1] else "-" for k in ("K", "T"))
                         + f" ({c['K'][1]})")
        lines.append(f"| {r['ship']} | {r['man']} | {r['rudder']} | {r['waves']} | " + " | ".join(cells) + " |")
    lines.append("| all | | | | " + " | ".join(
        " / ".join(pct(total[rule][k][0] / total[rule][k][1]) if total[rule][k][1] else "-" for k in ("K", "T"))
        + f" ({total[rule]['K'][1]} / {total[rule]['T'][1]})" for rule in COMBINATION_RULES) + " |")
    lines += ["", *coverage_table(rows)]
    fails = [f"- {r['ship']} {r['man']} {r['rudder']} {r['waves']}: {r['fails'][0]}" for r in rows if r["fails"]]
    if fails:
        lines += ["", "First failure message per row (not identified / not marked success):", ""] + fails
    return "\n".join(lines) + "\n"


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Clopper-Pearson (exact binomial) interval of a coverage ``k / n`` at ``level`` (nan, nan for n = 0)."""
    if n <= 0:
        return math.nan, math.nan
    from scipy.stats import beta

    a = 1.0 - level
    lo = float(beta.ppf(a / 2, k, n - k + 1)) if k > 0 else 0.0
    hi = float(beta.ppf(1 - a / 2, k + 1, n - k)) if k < n else 1.0
    return lo, hi


def z_rms(z) -> float:
    """Root mean square of the finite z = (value - truth) / standard error (nan when none)."""
    z = np.asarray(z, float)
    z = z[np.isfinite(z)]
    return float(np.sqrt(np.mean(z**2))) if z.size else math.nan


def coverage_cell(k: int, n: int, z) -> str:
    """``k/n (lo-hi %) z rms`` for one coefficient; the interval flagged where it excludes 95 %."""
    if n == 0:
        return "- | -"
    lo, hi = clopper_pearson(k, n)
    flag = " **below 95**" if hi < 0.95 else (" **above 95**" if lo > 0.95 else "")
    zr = z_rms(z)
    return f"{k}/{n} ({100 * lo:.0f}-{100 * hi:.0f}){flag} | " + ("-" if not math.isfinite(zr) else f"{zr:.2f}")


def coverage_table(rows: list[dict]) -> list[str]:
    """Per row and pooled over the rows: how many K and T marked success the 95 % interval holds, the
    Clopper-Pearson 95 % interval of that coverage, and the root mean square of their z.

    One row's 20 / 20 is what a true 95 % coverage gives 36 % of the time: coverage is judged pooled and by
    the z rms (1 for an error that is right; well below 1 for a bound), per row only where its interval
    excludes 95 %.
    """
    out = ["Coverage of the estimates marked success: covered / count (Clopper-Pearson 95 % interval of the "
           "coverage, %; flagged where it excludes 95 %) and the root mean square of z = (value - truth) / "
           "standard error (1 for an error that is right, below 1 for a bound):", "",
           "| ship | manoeuvre | rudder log | waves | K covered | K z rms | T covered | T z rms |",
           "|---|---|---|---|---|---|---|---|"]
    tot = {key: [0, 0, []] for key in ("K", "T")}
    for r in rows:
        cells = []
        for key in ("K", "T"):
            k, n = r.get("covered", {}).get(key, [0, 0])
            z = r.get("z", {}).get(key, [])
            tot[key][0] += k
            tot[key][1] += n
            tot[key][2] += list(z)
            cells.append(coverage_cell(k, n, z))
        out.append(f"| {r['ship']} | {r['man']} | {r['rudder']} | {r['waves']} | " + " | ".join(cells) + " |")
    out.append("| all rows | | | | " + " | ".join(coverage_cell(*tot[key]) for key in ("K", "T")) + " |")
    return out


def write_results(text: str) -> None:
    path = ROOT / "benchmarks" / "RESULTS.md"
    old = path.read_text() if path.exists() else ""
    if SECTION in old:
        head, rest = old.split(SECTION, 1)
        nxt = rest.find("\n## ")
        tail = rest[nxt + 1:] if nxt >= 0 else ""
        new = head + text + ("\n" + tail if tail else "")
    else:
        new = old.rstrip() + "\n\n" + text
    tmp = path.with_suffix(".md.tmp")
    tmp.write_text(new)
    tmp.replace(path)


if __name__ == "__main__":
    raise SystemExit(main())
