"""Added mass from steps whose thrust is known (a thruster map in the vessel config).

For one DOF of ``M nu_dot + D nu = tau`` (Fossen 2021, sec. 6.4) a thrust step from ``F_b`` to
``F_a`` gives a first-order response ``y_ss + (y0 - y_ss) exp(-t/T)`` with

    D     = (F_a - F_b) / (y_ss - y0)      (steady states; D = F_a / y_ss when not steady before)
    m_eff = D T                            (the time constant is m_eff / D)
    m_A   = m_eff - M_RB[i, i]             X_udot = -m_A   (Fossen's sign: negative)

The thrust comes from :mod:`pipeline.fit.thrusters` (``[thrusters]`` in the vessel TOML), so
neither the mass nor the added mass of the config is used: this is the one place where the data
say how heavy the vessel moves. The standard error is propagated (delta method) from the step fit's
covariance of ``(y0, y_ss, T)`` and the thruster map's ``relative_stderr``; repeated steps are
combined by inverse variance (:func:`pipeline.fit.combine.combine`).
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from ..errors import FitError
from ..records import DOF_NAMES, DOFS, Estimate, Fits, Trial
from ..vessel import Vessel
from .combine import Contribution, combine, failed_estimate
from .damping import propagate, sub_covariance
from .data import gain_formulation, input_levels, segment_label
from .first_order import step_steadiness
from .thrusters import ThrusterMap, parse_thrusters

#: DOF -> (added-mass derivative, steady-state damping derivative, mass unit, damping unit).
NAMES: Mapping[str, tuple[str, str, str, str]] = {
    "surge": ("X_udot", "X_u_thrust", "kg", "kg/s"),
    "sway": ("Y_vdot", "Y_v_thrust", "kg", "kg/s"),
    "yaw": ("N_rdot", "N_r_thrust", "kg m^2", "kg m^2/s"),
}


def effective_mass_from_step(y0: float, y_ss: float, T: float, cov: np.ndarray, thrust_before: float,
                             thrust_after: float, formulation: str,
                             relative_stderr: float = 0.0) -> tuple[float, float, float, float]:
    """Steady-state damping and effective mass of one thrust step, with standard errors.

    Parameters
    ----------
    y0, y_ss : float
        Fitted initial and steady response [m/s or rad/s].
    T : float
        Fitted time constant [s].
    cov : numpy.ndarray, shape (3, 3)
        Covariance of ``(y0, y_ss, T)``.
    thrust_before, thrust_after : float
        Thrust before and after the step [N or N m].
    formulation : str
        ``change`` (``D = dF / dy``) or ``level`` (``D = F_a / y_ss``), see
        :func:`pipeline.fit.data.gain_formulation`.
    relative_stderr : float
        1-sigma relative uncertainty of the thrust [-].

    Returns
    -------
    D, se_D : float
        Damping [kg/s or kg m^2/s].
    m_eff, se_m : float
        Effective mass ``D T`` [kg or kg m^2].
    """
    if formulation == "change":
        dy = y_ss - y0
        force = thrust_after - thrust_before
        d = force / dy
        grad_d = np.array([force / dy**2, -force / dy**2, 0.0])
    else:
        d = thrust_after / y_ss
        force = thrust_after
        grad_d = np.array([0.0, -thrust_after / y_ss**2, 0.0])
    m = d * T
    grad_m = grad_d * T + np.array([0.0, 0.0, d])
    # The thrust scale error is common to D and m_eff: it adds in quadrature, fully correlated.
    se_d = math.hypot(propagate(grad_d, cov), abs(d) * relative_stderr)
    se_m = math.hypot(propagate(grad_m, cov), abs(m) * relative_stderr)
    return float(d), se_d, float(m), se_m


def fit_added_mass(fits: Fits, trial: Trial, vessel: Vessel) -> dict[str, Estimate]:
    """Added mass (and steady-state damping) for every DOF with a thruster map.

    Parameters
    ----------
    fits : Fits
        Fits whose ``segment_fits`` hold the ``first_order_step`` fits of the steps.
    trial : Trial
        The trial (input levels and steadiness before each step).
    vessel : Vessel
        Rigid-body mass (``M_RB``) and ``extra['thrusters']``.

    Returns
    -------
    dict[str, Estimate]
        ``X_udot``/``Y_vdot``/``N_rdot`` [kg, kg, kg m^2] (Fossen: ``-m_A``) and
        ``X_u_thrust``/``Y_v_thrust``/``N_r_thrust`` (``-D`` from the steady states) per mapped
        DOF; failed Estimates that say why when no usable step exists. Empty without thruster maps.

    Raises
    ------
    ConfigError
        A malformed ``[thrusters]`` table.
    """
    maps = parse_thrusters(vessel.extra.get("thrusters"), f"{vessel.path or vessel.name} [thrusters]")
    out: dict[str, Estimate] = {}
    for dof, tmap in maps.items():
        out.update(_dof_added_mass(fits, trial, vessel, dof, tmap))
    return out


def _dof_added_mass(fits: Fits, trial: Trial, vessel: Vessel, dof: str, tmap: ThrusterMap) -> dict[str, Estimate]:
    am_name, d_name, m_unit, d_unit = NAMES[dof]
    i = DOFS.index(next(v for v, n in DOF_NAMES.items() if n == dof))
    method = (f"added mass m_A = D T - M_RB[{i},{i}] from thrust steps: D = dF/dy_ss from the {tmap.describe()} "
              f"(bollard/thrust map: thrust at speed may be lower), T from the first-order step fit; "
              f"{am_name} = -m_A (Fossen)")
    d_method = (f"steady-state damping D = dF/dy_ss from thrust steps ({tmap.describe()}); "
                f"{d_name} = -D (compare with the time-constant-based value, which assumes M)")
    if not vessel.has_rigid_body:
        why = (f"vessel config {vessel.name!r} has no rigid_body mass and inertia: m_A = m_eff - M_RB needs M_RB "
               f"(the effective mass itself is still in the message of {d_name})")
        m_rb = math.nan
    else:
        why = ""
        m_rb = float(vessel.rigid_body_mass_matrix()[i, i])
    am_items, d_items, m_eff_notes = [], [], []
    steps = [sf for sf in fits.segment_fits if sf.segment.kind == "step" and sf.segment.dof == dof]
    for sf in steps:
        seg = sf.segment
        label = segment_label(seg)
        if seg.input_channel != tmap.input:
            reason = (f"input {seg.input_channel!r} is not the thruster map's input {tmap.input!r}")
            am_items.append(Contribution(math.nan, math.nan, label, ok=False, reason=reason))
            d_items.append(Contribution(math.nan, math.nan, label, ok=False, reason=reason))
            continue
        if not sf.success or sf.model != "first_order_step":
            reason = sf.message or "step fit failed"
            am_items.append(Contribution(math.nan, math.nan, label, ok=False, reason=reason))
            d_items.append(Contribution(math.nan, math.nan, label, ok=False, reason=reason))
            continue
        before, after, _ = input_levels(trial, seg)
        try:
            f_b, f_a = float(tmap.thrust(before)), float(tmap.thrust(after))
        except FitError as exc:
            am_items.append(Contribution(math.nan, math.nan, label, ok=False, reason=str(exc)))
            d_items.append(Contribution(math.nan, math.nan, label, ok=False, reason=str(exc)))
            continue
        steady, note = step_steadiness(trial, sf)
        form = gain_formulation(steady, f_a)
        if form == "none" or f_a == f_b:
            reason = (f"{note} and the thrust returns to zero: D not identified" if form == "none"
                      else f"no thrust change ({f_b:.4g} -> {f_a:.4g} {tmap.unit})")
            am_items.append(Contribution(math.nan, math.nan, label, ok=False, reason=reason))
            d_items.append(Contribution(math.nan, math.nan, label, ok=False, reason=reason))
            continue
        cov = sub_covariance(sf, ("y0", "y_ss", "T"))
        d, se_d, m, se_m = effective_mass_from_step(sf.params["y0"], sf.params["y_ss"], sf.params["T"], cov,
                                                    f_b, f_a, form, tmap.relative_stderr)
        dof_fit = max(sf.y.size - len(sf.param_names), 1)
        d_items.append(Contribution(-d, se_d, label, dof_fit))
        m_eff_notes.append(f"{label}: m_eff = {m:.4g} +- {se_m:.2g} {m_unit}, D = {d:.4g} {d_unit}")
        if why:
            am_items.append(Contribution(math.nan, math.nan, label, ok=False, reason=why))
        else:
            am_items.append(Contribution(-(m - m_rb), se_m, label, dof_fit))
    if not steps:
        msg = (f"no {dof} step in the trial: run {dof} thrust steps held 5 time constants "
               f"(command logged on {tmap.input})")
        return {am_name: failed_estimate(am_name, m_unit, method, msg),
                d_name: failed_estimate(d_name, d_unit, d_method, msg)}
    notes = list(m_eff_notes)
    cfg = vessel.added_mass.get(dof)
    am = combine(am_name, m_unit, method, am_items, notes)
    if cfg is not None and am.success and am.stderr > 0:
        z = (-am.value - cfg) / am.stderr
        flag = "consistent" if abs(z) < 3 else "INCONSISTENT"
        am = _with_note(am, f"config [added_mass] {dof} = {cfg:g} {m_unit}: {flag} ({z:+.1f} sigma)")
    # m_A < 0 is unphysical: the thrust map overstates the thrust, or the mass is wrong.
    if am.success and am.value > 3 * am.stderr:
        am = _with_note(am, "negative added mass (m_eff < M_RB): the thrust map overstates the thrust at "
                            "speed, or rigid_body.mass is too large")
    return {am_name: am, d_name: combine(d_name, d_unit, d_method, d_items)}


def _with_note(est: Estimate, note: str) -> Estimate:
    from dataclasses import replace

    return replace(est, message="; ".join(m for m in (est.message, note) if m))

