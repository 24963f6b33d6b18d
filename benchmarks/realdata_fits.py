"""Fit the measured decays and steps in ``../shared/realdata`` with the project's fit functions and
compare them with the values their authors published.

Data sets (each folder's SOURCE.md says where the numbers come from):

- ``aauship-2014-trials``: AAUSHIP 1 roll and pitch free decays (Vicon, 100 Hz), surge coast-downs
  and step + coast-downs (GPS, 1 Hz), yaw-rate decays (gyro). Published: K_p, M_q, K_phi, M_theta,
  X_u, N_r of the thesis's damping and restoring matrices.
- ``aauship-2017-thrust-speed``: bollard pull and steady speed against thruster command. Gives
  tau(u) = D(u) u, compared with the 2014 decay-based X_u, and an added-mass estimate
  m_eff = D T against the 2014 coast-downs.
- ``nemi-catamaran-usv-2022``: surge-speed and yaw-rate steps of a twin-thruster catamaran
  (100 Hz). Published: first-order (P1D) time constants 2.63 s (surge) and 1.20 s (yaw rate).

Every fit goes through :mod:`pipeline.fit` (``fit_free_decay``, ``fit_coast_down``, ``fit_step``,
``combine`` and the damping relations); where a project fit refuses a record (the 1 Hz GPS
coast-downs have fewer than ``MIN_SAMPLES`` points) the same model function is fitted with
:func:`pipeline.fit.fit_least_squares` and the table says so. Residual whiteness
(:mod:`pipeline.fit.residual_tests`) is reported per data set.

The real data are for internal testing only: they are read in place, never copied; the script
prints a note and exits 0 when the folder is absent.

Usage::

    .venv/bin/python benchmarks/realdata_fits.py [--realdata DIR] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.errors import FitError  # noqa: E402
from pipeline.fit import combine, fit_coast_down, fit_free_decay, fit_least_squares, fit_step  # noqa: E402
from pipeline.fit.combine import Contribution  # noqa: E402
from pipeline.fit.damping import damping_from_decay  # noqa: E402
from pipeline.fit.first_order import (DECAY_PARAMS, STEP_PARAMS, decay, decay_jacobian, guess_decay,  # noqa: E402
                                      guess_step, step_jacobian, step_response)
from pipeline.fit.residual_tests import residual_test  # noqa: E402
from pipeline.fit.segment_fit import build_segment_fit  # noqa: E402
from pipeline.records import Estimate, Segment, SegmentFit, Trial  # noqa: E402
from pipeline.vessel import parse_vessel  # noqa: E402

#: Where the shared real data live (``../shared/realdata`` from the repository), unless overridden.
DEFAULT_REALDATA = Path(os.environ.get("VESSELID_REALDATA", ROOT.parent / "shared" / "realdata"))

#: AAUSHIP 1 as the thesis models it: m = 13 kg, inertia from the component layout, no added mass.
#: The CG offset is left out so that M[i, i] is the thesis's I_x, I_y, I_z (its single-DOF fits use
#: them as they are).
AAUSHIP = parse_vessel({"name": "aauship-2014", "rigid_body": {"mass": 13.0, "inertia": [0.06541, 1.08921, 1.10675]},
                        "restoring": {"roll": 6.9736, "pitch": 131.8316}})
#: Thruster command magnitude [%] up to which the catamaran barely responds (its dead band).
DEAD_BAND = 20.0
#: The thesis's numbers (SOURCE.md of aauship-2014-trials).
PUBLISHED = {"K_p": -0.1094, "M_q": -7.2030, "K_phi": 6.9736, "M_theta": 131.8316, "X_u": -2.86, "N_r": -0.26285,
             "sigma_roll_starboard": 0.7242, "wd_roll_starboard": 10.13, "sigma_roll_port": 0.9482,
             "wd_roll_port": 10.45, "sigma_pitch_bow": 3.45, "wd_pitch_bow": 10.29, "sigma_pitch_stern": 3.163,
             "wd_pitch_stern": 10.69, "s_surge": 0.22, "T_surge_nemi": 2.630, "T_yaw_nemi": 1.201}


@dataclass(frozen=True)
class Row:
    """One compared quantity.

    Attributes
    ----------
    dataset : str
        Data set folder.
    quantity : str
        What is compared.
    unit : str
        SI unit.
    value, stderr : float
        Our estimate and standard error (NaN when not identified).
    n : int
        Runs or segments combined.
    published : float
        The authors' value (NaN when they give none).
    note : str
        How it was obtained, consistency, why it differs.
    """

    dataset: str
    quantity: str
    unit: str
    value: float
    stderr: float
    n: int
    published: float
    note: str = ""

    @property
    def sigmas(self) -> float:
        """(ours - published) / stderr."""
        if not (math.isfinite(self.value) and math.isfinite(self.published) and self.stderr > 0):
            return math.nan
        return (self.value - self.published) / self.stderr


def _row(dataset: str, quantity: str, est: Estimate, published: float = math.nan, note: str = "") -> Row:
    text = "; ".join(m for m in (note, est.message) if m)
    return Row(dataset, quantity, est.unit, est.value, est.stderr, est.n_segments, published, text)


# --------------------------------------------------------------------------- data helpers
def series(path: Path, kinds: Sequence[str] = ("measured",)) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """``(series, kind, x, y)`` of a digitised ``series,kind,x,y`` CSV, in file order.

    Parameters
    ----------
    path : Path
        CSV file.
    kinds : sequence of str
        Kinds kept (``measured``, ``average``; ``fit`` curves are the authors' models, not data).
    """
    df = pd.read_csv(path)
    out = []
    for (name, kind), g in df.groupby(["series", "kind"], sort=False):
        if kind in kinds:
            x, y = g.iloc[:, 2].to_numpy(float), g.iloc[:, 3].to_numpy(float)
            order = np.argsort(x, kind="stable")
            out.append((str(name), str(kind), x[order], y[order]))
    return out


def make_trial(name: str, t: np.ndarray, **channels: np.ndarray) -> Trial:
    """A Trial on the record's own sample times (digitised plots are not resampled: no invented data).

    Parameters
    ----------
    name : str
        Trial name.
    t : numpy.ndarray
        Sample times [s].
    **channels : numpy.ndarray
        Canonical channels in SI units.
    """
    keep = np.concatenate([[True], np.diff(t) > 0])
    data = pd.DataFrame({"t": t[keep], **{k: np.asarray(v, float)[keep] for k, v in channels.items()}})
    dt = float(np.median(np.diff(data["t"]))) if len(data) > 1 else 1.0
    return Trial(name, data, 1.0 / dt)


def _first_order_fallback(trial: Trial, segment: Segment, channel: str, step: bool) -> SegmentFit:
    """The project's first-order model fitted without the MIN_SAMPLES guard (sparse 1 Hz GPS)."""
    rows = trial.window(segment.t_start, segment.t_end)
    t = rows["t"].to_numpy() - segment.t_start
    y = rows[channel].to_numpy()
    ok = np.isfinite(y)
    t, y = t[ok], y[ok]
    if step:
        g = guess_step(t, y)
        res = fit_least_squares(lambda tt, p: step_response(tt, *p), lambda tt, p: step_jacobian(tt, *p), t, y,
                                [g["y0"], g["y_ss"], g["T"]], STEP_PARAMS, [-np.inf, -np.inf, 1e-3], [np.inf] * 3)
        return build_segment_fit(segment, "first_order_step", channel, t, y, res, ("T",))
    g = guess_decay(t, y)
    res = fit_least_squares(lambda tt, p: decay(tt, *p), lambda tt, p: decay_jacobian(tt, *p), t, y,
                            [g["y0"], g["T"]], DECAY_PARAMS, [-np.inf, 1e-3], [np.inf, np.inf])
    return build_segment_fit(segment, "first_order_decay", channel, t, y, res, ("T",))


def fit_first_order(trial: Trial, segment: Segment, channel: str) -> tuple[SegmentFit, str]:
    """``fit_coast_down``/``fit_step``; on a too-short refusal the same model without the guard.

    Parameters
    ----------
    trial : Trial
        Trial.
    segment : Segment
        ``coast_down`` or ``step``.
    channel : str
        Velocity channel, for the fallback.

    Returns
    -------
    SegmentFit, str
        The fit and a note when the fallback was used.
    """
    fitter = fit_coast_down if segment.kind == "coast_down" else fit_step
    try:
        return fitter(trial, segment), ""
    except FitError as exc:
        if "too short" not in str(exc) or "samples" not in str(exc):
            raise
        return (_first_order_fallback(trial, segment, channel, segment.kind == "step"),
                "project fit refuses < 20 samples (1 Hz GPS): same model via fit_least_squares")


def _whiteness(fits: Iterable[SegmentFit]) -> str:
    tests = [residual_test(sf.y - sf.y_fit) for sf in fits if sf.y.size]
    tests = [t for t in tests if t.max_lag > 0]
    if not tests:
        return "residual tests not run (too few samples)"
    white = sum(t.white for t in tests)
    return f"residuals white in {white} of {len(tests)} runs"


# --------------------------------------------------------------------------- AAUSHIP 2014
def aauship_decays(folder: Path) -> list[Row]:
    """Roll and pitch free decays: sigma, omega_d per direction, and K_p, M_q, K_phi, M_theta.

    Parameters
    ----------
    folder : Path
        ``aauship-2014-trials``.
    """
    ds = folder.name
    rows: list[Row] = []
    for dof, angle, inertia_name, d_name, c_name, files in (
            ("roll", "phi", "I_x", "K_p", "K_phi", (("starboard", "roll_free_decay_starboard_down_vicon.csv"),
                                                    ("port", "roll_free_decay_port_down_vicon.csv"))),
            ("pitch", "theta", "I_y", "M_q", "M_theta", (("bow", "pitch_free_decay_bow_down_vicon.csv"),
                                                         ("stern", "pitch_free_decay_stern_down_vicon.csv")))):
        inertia = AAUSHIP.effective_mass(dof)
        d_items, c_items, all_fits = [], [], []
        for side, fname in files:
            per_side = {"sigma": [], "wd": []}
            avg = {}
            for name, kind, t, y in series(folder / "csv" / fname, ("measured", "average")):
                trial = make_trial(f"{dof}-{side}-{name}", t, **{angle: np.radians(y)})
                seg = Segment("free_decay", dof, 0.0, float(t[-1]), label=f"{side} {name}")
                try:
                    sf = fit_free_decay(trial, seg)
                except FitError as exc:
                    per_side["sigma"].append(Contribution(math.nan, math.nan, name, ok=False, reason=str(exc)))
                    continue
                zeta, wn = sf.params["zeta"], sf.params["wn"]
                cov = sf.covariance[np.ix_([1, 2], [1, 2])]
                sig = zeta * wn
                se_sig = math.sqrt(max(np.array([wn, zeta]) @ cov @ np.array([wn, zeta]), 0.0))
                r = math.sqrt(max(1 - zeta**2, 0.0))
                g_wd = np.array([-wn * zeta / r, r])
                wd, se_wd = wn * r, math.sqrt(max(g_wd @ cov @ g_wd, 0.0))
                dof_fit = max(sf.y.size - len(sf.param_names), 1)
                if kind == "average":
                    avg = {"sigma": (sig, se_sig), "wd": (wd, se_wd)}
                    continue
                all_fits.append(sf)
                per_side["sigma"].append(Contribution(sig, se_sig, name, dof_fit, sf.success, sf.message))
                per_side["wd"].append(Contribution(wd, se_wd, name, dof_fit, sf.success, sf.message))
                d, se_d = damping_from_decay(inertia, sf)
                d_items.append(Contribution(-d, se_d, f"{side} {name}", dof_fit, sf.success, sf.message))
                g_c = np.array([0.0, 2 * wn * inertia])  # C = wn^2 I
                c_items.append(Contribution(wn**2 * inertia, math.sqrt(max(g_c @ cov @ g_c, 0.0)), f"{side} {name}",
                                            dof_fit, sf.success, sf.message))
            for q, unit in (("sigma", "1/s"), ("wd", "rad/s")):
                est = combine(f"{q}_{dof}_{side}", unit, "damped oscillation on each run", per_side[q])
                pub = PUBLISHED[f"{q}_{dof}_{side}"]
                a = avg.get(q)
                note = (f"authors' average curve gives {a[0]:.4g} +- {a[1]:.2g}" if a else "")
                rows.append(_row(ds, f"{'sigma = zeta wn' if q == 'sigma' else 'omega_d'} {dof}, {side} down",
                                 est, pub, note))
        est = combine(d_name, "kg m^2/s", f"-2 zeta wn {inertia_name}", d_items)
        rows.append(_row(ds, f"{d_name} = -2 zeta wn {inertia_name} ({inertia_name} = {inertia:g} kg m^2)", est,
                         PUBLISHED[d_name], _whiteness(all_fits)))
        est = combine(c_name, "N m/rad", f"wn^2 {inertia_name}", c_items)
        rows.append(_row(ds, f"{c_name} = wn^2 {inertia_name}", est, PUBLISHED[c_name]))
    return rows


def aauship_surge_yaw(folder: Path) -> list[Row]:
    """Surge coast-downs and step + coast-downs (X_u, T), and yaw-rate decays (N_r).

    Parameters
    ----------
    folder : Path
        ``aauship-2014-trials``.
    """
    ds = folder.name
    rows: list[Row] = []
    m = AAUSHIP.effective_mass("surge")
    # Coast-downs: the thrust is cut at t = 0.
    t_items, fits, notes = [], [], set()
    for name, _, t, u in series(folder / "csv" / "surge_decay_gps.csv"):
        trial = make_trial(f"surge-{name}", t, u=u)
        seg = Segment("coast_down", "surge", 0.0, float(t[-1]), "tau_x", 1.0, 0.0, label=name)
        try:
            sf, note = fit_first_order(trial, seg, "u")
        except FitError as exc:
            t_items.append(Contribution(math.nan, math.nan, name, ok=False, reason=str(exc)))
            continue
        notes.add(note)
        fits.append(sf)
        t_items.append(Contribution(sf.params["T"], sf.stderr["T"], name, max(sf.y.size - 2, 1), sf.success,
                                    sf.message))
    t_est = combine("T_surge", "s", "first-order coast-down", t_items)
    rows.append(_row(ds, "surge decay rate s = 1/T (coast-downs)", _reciprocal(t_est, "1/s"), PUBLISHED["s_surge"],
                     "; ".join(n for n in notes if n)))
    xu = _reciprocal(t_est, "kg/s", scale=-m)
    rows.append(_row(ds, f"X_u = -m/T (m = {m:g} kg, no added mass, as the thesis)", xu, PUBLISHED["X_u"],
                     _whiteness(fits)))
    # Step then coast-down: the cut is where the speed peaks (no thrust log).
    step_items, coast_items = [], []
    for name, _, t, u in series(folder / "csv" / "surge_step_and_decay_gps.csv"):
        trial = make_trial(f"surge-step-{name}", t, u=u)
        cut = float(t[int(np.argmax(u))])
        for kind, a, b, items in (("step", 0.0, cut, step_items), ("coast_down", cut, float(t[-1]), coast_items)):
            seg = Segment(kind, "surge", a, b, "tau_x", 0.0 if kind == "step" else 1.0,
                          1.0 if kind == "step" else 0.0, label=name)
            try:
                sf, _ = fit_first_order(trial, seg, "u")
                items.append(Contribution(sf.params["T"], sf.stderr["T"], name, max(sf.y.size - 3, 1), sf.success,
                                          sf.message))
            except FitError as exc:
                items.append(Contribution(math.nan, math.nan, name, ok=False, reason=str(exc)))
    for label, items in (("step (0 -> 1.8 m/s)", step_items), ("coast-down after the step", coast_items)):
        est = combine("T_surge", "s", "first-order", items)
        rows.append(_row(ds, f"surge time constant T, {label} (cut at the speed peak)", est, math.nan,
                         f"a linear model has one T: the coast-downs give {1 / PUBLISHED['s_surge']:.3g} s (thesis)"))
    # Yaw-rate decays after spinning up with the bow thrusters or the main propellers.
    izz = AAUSHIP.effective_mass("yaw")
    for label, fname in (("bow thrusters", "yaw_rate_decay_bow_thrusters.csv"),
                         ("main propellers", "yaw_rate_decay_main_propellers.csv")):
        items, yfits = [], []
        for name, _, t, r in series(folder / "csv" / fname):
            trial = make_trial(f"yaw-{name}", t, r=np.radians(r))
            seg = Segment("coast_down", "yaw", 0.0, float(t[-1]), "tau_n", 1.0, 0.0, label=name)
            try:
                sf, _ = fit_first_order(trial, seg, "r")
            except FitError as exc:
                items.append(Contribution(math.nan, math.nan, name, ok=False, reason=str(exc)))
                continue
            yfits.append(sf)
            items.append(Contribution(sf.params["T"], sf.stderr["T"], name, max(sf.y.size - 2, 1), sf.success,
                                      sf.message))
        t_est = combine("T_yaw", "s", "first-order yaw-rate decay", items)
        nr = _reciprocal(t_est, "kg m^2/s", scale=-izz)
        rows.append(_row(ds, f"N_r = -I_z/T, decays after {label} (I_z = {izz:g} kg m^2)", nr, PUBLISHED["N_r"],
                         _whiteness(yfits)))
    return rows


def _reciprocal(est: Estimate, unit: str, scale: float = 1.0) -> Estimate:
    """``scale / T`` of a time-constant Estimate, error propagated (``se = |scale| se_T / T^2``)."""
    if not est.success or not math.isfinite(est.value):
        return replace(est, unit=unit)
    v = scale / est.value
    se = abs(scale) * est.stderr / est.value**2
    lo, hi = sorted((scale / est.ci95[0], scale / est.ci95[1])) if all(map(math.isfinite, est.ci95)) else (
        math.nan, math.nan)
    return replace(est, value=v, stderr=se, ci95=(lo, hi), unit=unit,
                   per_segment=tuple(scale / x for x in est.per_segment))


# --------------------------------------------------------------------------- AAUSHIP 2017
def aauship_thrust_speed(folder: Path, folder_2014: Path | None) -> list[Row]:
    """Steady speed against bollard thrust: D(u) = F/u, a drag curve, and m_eff against 2014.

    The bollard force at a command is paired with the steady speed at the same command (SOURCE.md).
    ``F = d1 u + d2 u|u|`` is fitted by least squares; with the drag curve, the 2014 coast-downs
    (``m u_dot = -d1 u - d2 u^2``, closed form) give the effective mass and ``X_udot = -(m_eff - m)``.

    Parameters
    ----------
    folder : Path
        ``aauship-2017-thrust-speed``.
    folder_2014 : Path or None
        ``aauship-2014-trials`` for the coast-downs (skipped when None).
    """
    ds = folder.name
    bollard = pd.read_csv(folder / "bollard_forward.csv")
    bollard = bollard[bollard["note"].str.startswith("measured")]
    runs = pd.read_csv(folder / "speed_runs_5p6m.csv")
    runs = runs[runs["note"].isna()]  # the last two rows are ambiguous (SOURCE.md)
    force = np.interp(runs["signal"].to_numpy(float), bollard["signal"].to_numpy(float),
                      bollard["force_N"].to_numpy(float))
    u = runs["speed_mps"].to_numpy(float)
    rows: list[Row] = []
    # Secant damping F/u per command level.
    for sig in sorted(set(runs["signal"])):
        sel = runs["signal"].to_numpy() == sig
        uu = u[sel]
        f = float(force[sel][0])
        mean = float(uu.mean())
        se_u = float(uu.std(ddof=1) / math.sqrt(uu.size)) if uu.size > 1 else 0.05 * mean
        d = f / mean
        rows.append(Row(ds, f"secant D = F/u_ss at command {sig:g} ({f:g} N bollard, u = {mean:.3f} m/s)", "kg/s",
                        -d, d * se_u / mean, int(uu.size), PUBLISHED["X_u"],
                        "Fossen sign (-F/u); "
                        + ("speed error from the repeats" if uu.size > 1 else "one run: 5% speed error assumed")))
    # Drag curve F = d1 u + d2 u|u|.
    a = np.column_stack([u, u * np.abs(u)])
    coef, res, *_ = np.linalg.lstsq(a, force, rcond=None)
    dof = max(u.size - 2, 1)
    s2 = float(np.sum((a @ coef - force) ** 2)) / dof
    cov = np.linalg.inv(a.T @ a) * s2
    for i, (name, unit) in enumerate((("X_u (linear term of F = d1 u + d2 u|u|)", "kg/s"),
                                      ("X_uu (quadratic term)", "kg/m"))):
        rows.append(Row(ds, name, unit, -float(coef[i]), float(math.sqrt(cov[i, i])), int(u.size),
                        PUBLISHED["X_u"] if i == 0 else math.nan,
                        "bollard thrust paired with steady speed; 4 command levels"))
    if folder_2014 is None or not (folder_2014 / "csv" / "surge_decay_gps.csv").is_file():
        return rows
    # Effective mass from the 2014 coast-downs under the 2017 drag curve: u(t) of m u_dot = -d1 u - d2 u^2.
    d1, d2 = float(coef[0]), float(coef[1])
    contribs = []
    for name, _, t, uu in series(folder_2014 / "csv" / "surge_decay_gps.csv"):
        keep = t >= 0
        tt, yy = t[keep], uu[keep]
        if tt.size < 4:
            continue

        def model(x: np.ndarray, p: np.ndarray) -> np.ndarray:
            return _quadratic_coast(x, p[0], p[1], d1, d2)

        def jac(x: np.ndarray, p: np.ndarray) -> np.ndarray:
            h = 1e-6 * np.maximum(np.abs(p), 1e-3)
            cols = [(model(x, p + np.eye(2)[j] * h[j]) - model(x, p - np.eye(2)[j] * h[j])) / (2 * h[j])
                    for j in range(2)]
            return np.column_stack(cols)

        fit = fit_least_squares(model, jac, tt, yy, [float(yy[0]), 13.0], ("u0", "m_eff"), [0.0, 0.1],
                                [np.inf, 1e4])
        if fit.converged and math.isfinite(fit.stderr[1]):
            contribs.append(Contribution(float(fit.values[1]), float(fit.stderr[1]), name, fit.dof))
    m_eff = combine("m_eff", "kg", "2014 coast-downs under the 2017 drag curve", contribs)
    rows.append(_row(ds, "effective surge mass m_eff (2014 coast-downs, 2017 drag curve)", m_eff, math.nan,
                     "thesis: m = 13 kg, no added mass"))
    if m_eff.success:
        rows.append(Row(ds, "X_udot = -(m_eff - m)", "kg", -(m_eff.value - 13.0), m_eff.stderr, m_eff.n_segments,
                        math.nan, "a surge added mass of a slender hull is 5-10% of m, i.e. -0.7 to -1.3 kg"))
    return rows


def _quadratic_coast(t: np.ndarray, u0: float, m: float, d1: float, d2: float) -> np.ndarray:
    """Speed of ``m u_dot = -d1 u - d2 u^2`` from ``u0`` [m/s] (closed form; d1 -> 0 and d2 -> 0 limits)."""
    t = np.asarray(t, float)
    a, b = d1 / m, d2 / m
    if abs(a) < 1e-12:
        return u0 / (1 + b * u0 * t)
    e = np.exp(-a * t)
    return a * u0 * e / (a + b * u0 * (1 - e))


# --------------------------------------------------------------------------- Nemi catamaran
def nemi(folder: Path) -> list[Row]:
    """First-order time constants of every surge and yaw-rate step of the catamaran.

    Parameters
    ----------
    folder : Path
        ``nemi-catamaran-usv-2022``.
    """
    ds = folder.name
    rows: list[Row] = []
    for dof, fname, cmd_col, y_col, channel, pub in (
            ("surge", "surge_speed_steps_full_100Hz.csv", "cmd_mean_thrust_pct", "u_meas_mps", "u",
             PUBLISHED["T_surge_nemi"]),
            ("yaw", "yaw_rate_steps_full_100Hz.csv", "cmd_diff_thrust_pct", "r_meas_radps", "r",
             PUBLISHED["T_yaw_nemi"])):
        df = pd.read_csv(folder / fname)
        t = df["t_s"].to_numpy(float)
        cmd = df[cmd_col].to_numpy(float)
        y = df[y_col].to_numpy(float)
        trial = make_trial(f"nemi-{dof}", t, **{channel: y, "tau_x" if dof == "surge" else "tau_n": cmd})
        changes = np.flatnonzero(np.diff(cmd) != 0) + 1
        bounds = list(zip(changes, list(changes[1:]) + [t.size - 1]))
        powered, passive, linear, levels = [], [], [], []
        for i, j in bounds:
            before, after = float(cmd[i - 1]), float(cmd[i])
            kind = "coast_down" if after == 0 else "step"
            seg = Segment(kind, dof, float(t[i]), float(t[j - 1]) if j < t.size - 1 else float(t[j]),
                          "tau_x" if dof == "surge" else "tau_n", before, after,
                          label=f"{before:+g}% -> {after:+g}%")
            where = f"{dof} T, {seg.label} at t = {seg.t_start:.1f} s"
            try:
                sf, _ = fit_first_order(trial, seg, channel)
            except FitError as exc:
                reason = str(exc).split(": ", 1)[-1]
                (passive if kind == "coast_down" else powered).append(
                    Contribution(math.nan, math.nan, seg.label, ok=False, reason=reason))
                rows.append(Row(ds, where, "s", math.nan, math.nan, 0, math.nan, f"not fitted: {reason}"))
                continue
            c = Contribution(sf.params["T"], sf.stderr["T"], seg.label, max(sf.y.size - 3, 1), sf.success, sf.message)
            (passive if kind == "coast_down" else powered).append(c)
            # The authors' linear range: neither level inside the dead band (|command| <= 20 %).
            if kind == "step" and abs(after) > DEAD_BAND and (before == 0 or abs(before) > DEAD_BAND):
                linear.append(c)
            if kind == "step" and "y_ss" in sf.params:
                levels.append(f"{after:+g}%: {sf.params['y_ss']:.3g}")
            tests = residual_test(sf.y - sf.y_fit)
            doubts = [m for m in sf.message.split("; ") if "spans only" in m or "not identified" in m]
            if seg.duration < sf.params["T"]:
                doubts.append(f"the segment ({seg.duration:.1f} s) is shorter than T: T is an extrapolation")
            rows.append(Row(ds, where, "s", sf.params["T"], sf.stderr["T"], 1,
                            pub if kind == "step" else math.nan,
                            "; ".join([("FAILED: " if not sf.success else "")
                                       + ("coast (zero command)" if kind == "coast_down" else "powered step")]
                                      + doubts
                                      + ["white residuals" if tests.white else
                                         f"coloured residuals (Ljung-Box p = {tests.ljung_box_p:.1g})"])))
        est = combine(f"T_{dof}", "s", "first-order step, every powered step", powered)
        unit = "m/s" if dof == "surge" else "rad/s"
        rows.append(_row(ds, f"{dof} T, inverse-variance mean of every powered step", est, pub,
                         f"steady levels ({unit}) {', '.join(levels)}"))
        est = combine(f"T_{dof}", "s", "first-order step outside the dead band", linear)
        rows.append(_row(ds, f"{dof} T, mean of the steps outside the dead band (|command| > {DEAD_BAND:g} %)", est,
                         pub))
        if passive:
            est = combine(f"T_{dof}_coast", "s", "first-order decay at zero command", passive)
            rows.append(_row(ds, f"{dof} T at zero command (passive decay)", est, math.nan))
    return rows


# --------------------------------------------------------------------------- driver
def all_rows(realdata: Path) -> list[Row]:
    """Every comparison for the data sets present under ``realdata``.

    Parameters
    ----------
    realdata : Path
        The shared real-data folder.
    """
    rows: list[Row] = []
    a14 = realdata / "aauship-2014-trials"
    if (a14 / "csv").is_dir():
        rows += aauship_decays(a14) + aauship_surge_yaw(a14)
    a17 = realdata / "aauship-2017-thrust-speed"
    if a17.is_dir():
        rows += aauship_thrust_speed(a17, a14 if a14.is_dir() else None)
    nm = realdata / "nemi-catamaran-usv-2022"
    if nm.is_dir():
        rows += nemi(nm)
    return rows


def _fmt(v: float, se: float) -> str:
    if not math.isfinite(v):
        return "not identified"
    if not math.isfinite(se) or se <= 0:
        return f"{v:.4g}"
    digits = max(0, -int(math.floor(math.log10(se))) + 1)
    return f"{v:.{digits}f} ± {se:.2g}"


def markdown(rows: Sequence[Row]) -> str:
    """The comparison as a Markdown table.

    Parameters
    ----------
    rows : sequence of Row
        From :func:`all_rows`.
    """
    out = ["| data set | quantity | unit | ours ± 1σ | n | published | Δ/σ | notes |",
           "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        pub = f"{r.published:.4g}" if math.isfinite(r.published) else "—"
        ds = f"{r.sigmas:+.1f}" if math.isfinite(r.sigmas) else "—"
        note = r.note if len(r.note) <= 220 else r.note[:217] + "..."
        # A pipe inside a cell (|command|, u|u|) would end the cell.
        quantity, note = r.quantity.replace("|", "\\|"), note.replace("|", "\\|")
        out.append(f"| {r.dataset} | {quantity} | {r.unit} | {_fmt(r.value, r.stderr)} | {r.n} | {pub} | {ds} | "
                   f"{note} |")
    return "\n".join(out)


def main(argv: Sequence[str] | None = None) -> int:
    """Print the comparison table; exit 0 (also when the real data are absent)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--realdata", type=Path, default=DEFAULT_REALDATA, help="shared real-data folder")
    ap.add_argument("--json", type=Path, help="also write the rows as JSON here")
    args = ap.parse_args(argv)
    if not args.realdata.is_dir():
        print(f"real data not found at {args.realdata}: nothing to fit (set --realdata or VESSELID_REALDATA)")
        return 0
    t0 = time.perf_counter()
    rows = all_rows(args.realdata)
    print(markdown(rows))
    print(f"\n{len(rows)} rows in {time.perf_counter() - t0:.1f} s from {args.realdata}")
    if args.json:
        args.json.write_text(json.dumps([{**asdict(r), "sigmas": r.sigmas} for r in rows], indent=2,
                                        default=float) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
