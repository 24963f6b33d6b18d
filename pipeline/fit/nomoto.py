"""First-order Nomoto model fitted to a rudder step (Nomoto et al. 1957; Fossen 2021, sec. 7.2).

``T r_dot + r = K (delta - b)`` with the rudder stepped from ``delta_b`` to ``delta_a`` at ``t0``
(``b`` is the rudder bias of :func:`pipeline.model.nomoto_rhs`: a constant yaw disturbance). Two
readings of the same response identify ``K`` [1/s] and ``T`` [s]:

- ``level`` (the textbook form, needs ``b = 0``):
  ``r(t) = K delta_a + (r0 - K delta_a) exp(-(t - t0)/T)``
- ``change`` (needs the yaw rate steady at ``r0`` before the step; ``b`` cancels, and a rudder
  return to zero, ``delta_a = 0``, still gives ``K``):
  ``r(t) = r0 + K (delta_a - delta_b) (1 - exp(-(t - t0)/T))``

Both are the same curve from a straight course (``delta_b = 0``, ``r0 = 0``, ``b = 0``). The yaw rate
before the step decides (:func:`pipeline.fit.data.gain_formulation`): ``change`` when it was steady,
``level`` otherwise; a return to zero from an unsteady turn identifies ``T`` only.
``K`` and ``T`` need no mass data, so a rudder ship whose config gives only ``name`` is identified.
"""

from __future__ import annotations

import math

import numpy as np

from dataclasses import replace

from ..errors import FitError
from ..records import Segment, SegmentFit, Trial
from ..segment.rudder import is_command_like
from .data import (gain_formulation, input_levels, noise_sigma, pick_channel, segment_label, segment_samples,
                   steady_before)
from .first_order import (MIN_SAMPLES, STEP_PARAMS, check_first_order_length, guess_step, step_jacobian, step_response,
                          time_constant_bounds)
from .least_squares import fit_least_squares
from .nomoto_segment import fit_nomoto_window, rudder_step_lead_in
from .segment_fit import build_segment_fit

PARAMS = ("r0", "K", "T")


def nomoto_step(t: np.ndarray, r0: float, K: float, T: float, delta_after: float) -> np.ndarray:
    """Yaw rate after a rudder step, level form: ``K delta_a + (r0 - K delta_a) exp(-t/T)`` [rad/s].

    Parameters
    ----------
    t : numpy.ndarray
        Time since the rudder step [s].
    r0 : float
        Yaw rate at ``t = 0`` [rad/s].
    K : float
        Nomoto gain [1/s].
    T : float
        Nomoto time constant [s].
    delta_after : float
        Rudder angle after the step [rad].
    """
    return K * delta_after + (r0 - K * delta_after) * np.exp(-np.asarray(t, float) / T)


def nomoto_step_jacobian(t: np.ndarray, r0: float, K: float, T: float, delta_after: float) -> np.ndarray:
    """Jacobian of :func:`nomoto_step` with respect to ``(r0, K, T)``, shape (n, 3).

    Parameters
    ----------
    t : numpy.ndarray
        Time since the rudder step [s].
    r0 : float
        Yaw rate at ``t = 0`` [rad/s].
    K : float
        Nomoto gain [1/s].
    T : float
        Nomoto time constant [s].
    delta_after : float
        Rudder angle after the step [rad].

    Returns
    -------
    numpy.ndarray
        Columns ``dr/dr0`` [-], ``dr/dK`` [rad] and ``dr/dT`` [rad/s^2].
    """
    e = np.exp(-np.asarray(t, float) / T)
    return np.column_stack([e, delta_after * (1.0 - e), (r0 - K * delta_after) * e * t / T**2])


def nomoto_step_change(t: np.ndarray, r0: float, K: float, T: float, delta_change: float) -> np.ndarray:
    """Yaw rate after a rudder step, change form: ``r0 + K delta_change (1 - exp(-t/T))`` [rad/s].

    Parameters
    ----------
    t : numpy.ndarray
        Time since the rudder step [s].
    r0 : float
        Yaw rate at ``t = 0``, steady before the step [rad/s].
    K : float
        Nomoto gain [1/s].
    T : float
        Nomoto time constant [s].
    delta_change : float
        Rudder change ``delta_after - delta_before`` [rad].
    """
    return r0 + K * delta_change * (1.0 - np.exp(-np.asarray(t, float) / T))


def nomoto_step_change_jacobian(t: np.ndarray, r0: float, K: float, T: float, delta_change: float) -> np.ndarray:
    """Jacobian of :func:`nomoto_step_change` with respect to ``(r0, K, T)``, shape (n, 3).

    Parameters
    ----------
    t : numpy.ndarray
        Time since the rudder step [s].
    r0 : float
        Yaw rate at ``t = 0``, steady before the step [rad/s].
    K : float
        Nomoto gain [1/s].
    T : float
        Nomoto time constant [s].
    delta_change : float
        Rudder change ``delta_after - delta_before`` [rad].

    Returns
    -------
    numpy.ndarray
        Columns ``dr/dr0`` [-], ``dr/dK`` [rad] and ``dr/dT`` [rad/s^2].
    """
    t = np.asarray(t, float)
    e = np.exp(-t / T)
    return np.column_stack([np.ones_like(t), delta_change * (1.0 - e), -K * delta_change * e * t / T**2])


def guess_nomoto_step(t: np.ndarray, r: np.ndarray, delta_after: float, delta_before: float = 0.0,
                      formulation: str = "level") -> dict[str, float]:
    """Closed-form start for the Nomoto step: the integral-regression step guess
    (:func:`pipeline.fit.first_order.guess_step`) read as ``K = r_ss / delta_a`` (``level``) or
    ``K = (r_ss - r0) / (delta_a - delta_b)`` (``change``).

    Parameters
    ----------
    t, r : numpy.ndarray
        Time since the rudder step [s] and yaw rate [rad/s].
    delta_after, delta_before : float
        Rudder angle after and before the step [rad].
    formulation : str
        ``level`` or ``change``.

    Returns
    -------
    dict
        ``r0`` [rad/s], ``K`` [1/s], ``T`` [s].
    """
    g = guess_step(t, r)
    if formulation == "change":
        K = (g["y_ss"] - g["y0"]) / (delta_after - delta_before)
    else:
        K = g["y_ss"] / delta_after
    return {"r0": g["y0"], "K": K, "T": g["T"]}


def fit_rudder_step(trial: Trial, segment: Segment) -> SegmentFit:
    """Fit the Nomoto model to a rudder step: whole-record fit over the step and its steady lead-in.

    The step is fitted as a record (:func:`pipeline.fit.nomoto_segment.fit_nomoto_window`) from
    the start of the steady rudder hold before it (:func:`pipeline.fit.nomoto_segment.rudder_step_lead_in`,
    at most the step's own length back) to the segment's end: the logged rudder drives the model,
    so a servo ramp (measured rudder) or a servo lag and rate limit (logged command, estimated)
    are part of the model rather than a bias of K and T, and the heading carries the excitation of
    a slow ship whose yaw rate hardly leaves the gyro noise. When that fit cannot be made (no
    heading and too few samples, a gap in the rudder), or when the log holds only the yaw rate and a
    held rudder command (the closed form is exact there), the closed-form step response is fitted to
    the yaw rate instead (:func:`fit_rudder_step_response`).

    Parameters
    ----------
    trial : Trial
        Trial holding the yaw rate ``r`` and/or heading ``psi`` and the rudder ``delta``.
    segment : Segment
        A ``rudder_step`` segment in yaw.

    Returns
    -------
    SegmentFit
        Model ``nomoto_oe``/``nomoto_pem`` (see :func:`pipeline.fit.nomoto_segment.fit_nomoto_segment`),
        or that of :func:`fit_rudder_step_response`.

    Raises
    ------
    FitError
        Wrong DOF, missing channels, no rudder change, too few samples.
    """
    where = segment_label(segment)
    if segment.dof != "yaw":
        raise FitError(f"{where}: expected a rudder_step in yaw, found DOF {segment.dof!r}")
    if trial.has("delta") and (trial.has("psi") or trial.has("r")):
        before, after, _ = input_levels(trial, segment)
        rudder = trial.window(segment.t_start, segment.t_end)["delta"].to_numpy(dtype=float)
        # The closed form is exact for a held command and a yaw-rate record; a compass (the
        # heading's excitation) or a measured servo angle (ramps) needs the whole-record fit.
        whole = trial.has("psi") or not is_command_like(rudder[np.isfinite(rudder)])
        if whole and math.isfinite(after - before) and after != before:
            try:
                sf = fit_nomoto_window(trial, segment, rudder_step_lead_in(trial, segment), segment.t_end)
            except FitError as exc:
                fallback = str(exc)
            else:
                return sf
            sf = fit_rudder_step_response(trial, segment)
            return replace(sf, message=f"whole-record fit not possible ({fallback}): step response fitted; "
                                       f"{sf.message}")
    return fit_rudder_step_response(trial, segment)


def fit_rudder_step_response(trial: Trial, segment: Segment) -> SegmentFit:
    """Fit the closed-form first-order Nomoto step response to the yaw rate of a rudder step.

    Parameters
    ----------
    trial : Trial
        Trial holding the yaw rate ``r`` (and optionally ``delta``).
    segment : Segment
        A ``rudder_step`` segment in yaw; ``input_before`` / ``input_after`` are the rudder angles
        [rad] (read from the trial's ``delta`` channel when the segment gives equal levels).

    Returns
    -------
    SegmentFit
        Model ``nomoto_step`` with parameters ``r0`` [rad/s], ``K`` [1/s], ``T`` [s]; or, for a
        rudder return to zero from an unsteady turn, ``first_order_step`` with ``y0``, ``y_ss``, ``T``
        (``K`` is then not identified, and the message says so).

    Raises
    ------
    FitError
        Missing yaw rate, no rudder change, too few samples, too short or no excitation.
    """
    where = segment_label(segment)
    if segment.dof != "yaw":
        raise FitError(f"{where}: expected a rudder_step in yaw, found DOF {segment.dof!r}")
    channel = pick_channel(trial, segment, ["r"])
    before, after, level_note = input_levels(trial, segment)
    change = after - before
    if not (math.isfinite(change) and change != 0.0):
        raise FitError(f"{where}: expected a rudder change (input_after != input_before), found "
                       f"{before} -> {after} rad")
    t, r, dropped = segment_samples(trial, segment, channel)
    if t.size < MIN_SAMPLES:
        check_first_order_length(segment, t, math.nan, math.nan, math.nan)
    g = guess_step(t, r)
    steady, steady_note = steady_before(trial, segment, channel, g["T"], g["y_ss"] - g["y0"])
    form = gain_formulation(steady, after)
    notes = check_first_order_length(segment, t, g["T"], g["y_ss"] - g["y0"], noise_sigma(r))
    notes += [n for n in (level_note, f"{dropped} non-finite samples dropped" if dropped else "") if n]
    lo_T, hi_T = time_constant_bounds(t)
    if form == "none":
        notes.insert(0, f"{steady_note} and the rudder returns to zero: K not identified, T only")
        res = fit_least_squares(lambda tt, p: step_response(tt, *p), lambda tt, p: step_jacobian(tt, *p), t, r,
                                [g["y0"], g["y_ss"], g["T"]], STEP_PARAMS, [-np.inf, -np.inf, lo_T],
                                [np.inf, np.inf, hi_T])
        return build_segment_fit(segment, "first_order_step", channel, t, r, res, ("T",), notes)
    p0 = guess_nomoto_step(t, r, after, before, form)
    reading = ("K from the rudder change (yaw rate steady before the step)" if form == "change"
               else "K = r_ss/delta_after (assumes no rudder bias)")
    notes[:0] = [f"start (integral-regression guess): K = {p0['K']:.4g} 1/s, T = {p0['T']:.4g} s",
                 f"{reading}; {steady_note}"]
    if form == "change":
        model, jac, arg = nomoto_step_change, nomoto_step_change_jacobian, change
    else:
        model, jac, arg = nomoto_step, nomoto_step_jacobian, after
    res = fit_least_squares(lambda tt, p: model(tt, *p, arg), lambda tt, p: jac(tt, *p, arg),
                            t, r, [p0[n] for n in PARAMS], PARAMS, [-np.inf, -np.inf, lo_T], [np.inf, np.inf, hi_T])
    return build_segment_fit(segment, "nomoto_step", channel, t, r, res, ("K", "T"), notes)
