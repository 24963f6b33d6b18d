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
from .data import (SETTLED_TOLERANCE, gain_formulation, input_levels, noise_sigma, pick_channel, segment_label,
                   segment_samples, steady_before)
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
    span = whole_record_window(trial, segment)
    if span is not None:
        try:
            sf = fit_nomoto_window(trial, segment, *span)
        except FitError as exc:
            fallback = str(exc)
        else:
            return sf
        sf = fit_rudder_step_response(trial, segment)
        return replace(sf, message=f"whole-record fit not possible ({fallback}): step response fitted; "
                                   f"{sf.message}")
    return fit_rudder_step_response(trial, segment)


def whole_record_window(trial: Trial, segment: Segment) -> tuple[float, float] | None:
    """The window [s, trial clock] the whole-record Nomoto fit uses for a yaw segment, or None.

    Zig-zags and sinusoids: the segment. A rudder step: from the start of its steady lead-in
    (:func:`pipeline.fit.nomoto_segment.rudder_step_lead_in`) to its end, when the log has a
    compass or a measured (not held) rudder; a held command with only the yaw rate gets the exact
    closed-form step response instead (None).

    Parameters
    ----------
    trial : Trial
        The trial.
    segment : Segment
        A yaw segment.
    """
    if segment.kind in ("zigzag", "sinusoid"):
        return float(segment.t_start), float(segment.t_end)
    if segment.kind != "rudder_step" or not (trial.has("delta") and (trial.has("psi") or trial.has("r"))):
        return None
    before, after, _ = input_levels(trial, segment)
    rudder = trial.window(segment.t_start, segment.t_end)["delta"].to_numpy(dtype=float)
    # The closed form is exact for a held command and a yaw-rate record; a compass (the
    # heading's excitation) or a measured servo angle (ramps) needs the whole-record fit.
    whole = trial.has("psi") or not is_command_like(rudder[np.isfinite(rudder)])
    if whole and math.isfinite(after - before) and after != before:
        return rudder_step_lead_in(trial, segment), float(segment.t_end)
    return None


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
    if steady is not False:
        held, held_note = rudder_hold_settled(trial, segment, g["T"])
        if held is False or steady is None:
            steady, steady_note = held, (held_note if held is False else f"{steady_note}; {held_note}")
    form = gain_formulation(steady, after)
    if steady is None and form == "change":
        # A return to zero read in change form needs the turn before it steady; when neither the yaw
        # rate nor the rudder's history can show that, K is not claimed (a turn still settling would
        # be read as a smaller K: 0.32 for 1.71 after a zig-zag).
        form = "none"
        steady_note = f"steadiness before the step could not be shown ({steady_note})"
    notes = check_first_order_length(segment, t, g["T"], g["y_ss"] - g["y0"], noise_sigma(r))
    notes += [n for n in (level_note, f"{dropped} non-finite samples dropped" if dropped else "") if n]
    lo_T, hi_T = time_constant_bounds(t)
    if form == "none":
        notes.insert(0, f"K not identified, T only (unsure whether the turn before the step was steady: "
                        f"{steady_note}; the rudder returns to zero)")
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


def rudder_hold_settled(trial: Trial, segment: Segment, T: float) -> tuple[bool | None, str]:
    """Had the previous rudder change died out when this step began? (first-order yaw transient)

    The rudder held at ``segment.input_before`` for ``H`` seconds after a change of ``d_prev``
    leaves a transient of ``exp(-H/T) |d_prev|`` in rudder units in a first-order yaw rate
    (Nomoto). Compared with this step's change ``|d|`` it is the unsettled fraction of the
    response that a gain read from the change carries one-for-one; the vessel counts as settled
    when the fraction is at most ``SETTLED_TOLERANCE``. This reads the rudder, not the noisy yaw
    rate, so it decides where too few yaw-rate samples precede the step (a low logging rate or a
    step right after a zig-zag).

    Parameters
    ----------
    trial : Trial
        The trial, with the rudder ``delta`` [rad].
    segment : Segment
        A ``rudder_step``; ``input_before`` / ``input_after`` are the rudder levels [rad].
    T : float
        Time constant [s] (the step's own estimate).

    Returns
    -------
    settled : bool or None
        None when the hold reaches the start of the record or a gap (the change before it is not
        in the log) or there is no rudder channel or time constant.
    note : str
        The evidence, for messages.
    """
    if not (trial.has("delta") and math.isfinite(T) and T > 0):
        return None, "rudder hold before the step not checked"
    t = trial.t
    delta = trial.data["delta"].to_numpy(dtype=float)
    i0 = int(np.searchsorted(t, segment.t_start))
    change = abs(segment.input_after - segment.input_before)
    lo = max(i0 - 50, 0)
    noise = noise_sigma(delta[lo:i0]) if i0 - lo > 4 else 0.0
    tol = max(4 * (noise if math.isfinite(noise) else 0.0), 0.05 * change, 1e-9)
    k = i0 - 1
    while k >= 0 and np.isfinite(delta[k]) and abs(delta[k] - segment.input_before) <= tol:
        k -= 1
    t_hold = float(t[min(k + 1, i0 - 1)]) if i0 > 0 else float(segment.t_start)
    held = float(segment.t_start) - t_hold
    in_gap = k >= 0 and any(g.t_start <= t[k] <= g.t_end for g in trial.gaps)
    if k < 0 or not np.isfinite(delta[k]) or in_gap:
        return None, f"rudder held {held:.3g} s before the step since the start of the record or a gap"
    earlier = delta[(t >= t_hold - 3 * T) & (t < t_hold)]
    earlier = earlier[np.isfinite(earlier)]
    d_prev = float(np.max(np.abs(earlier - segment.input_before))) if earlier.size else abs(delta[k] - segment.input_before)
    fraction = math.exp(-held / T) * d_prev / max(change, 1e-12)
    settled = fraction <= SETTLED_TOLERANCE
    return settled, (f"rudder held {held:.3g} s = {held / T:.2g} T before the step after a change of "
                     f"{math.degrees(d_prev):.3g} deg: {'settled' if settled else 'not settled'} "
                     f"(transient left {fraction:.2g} of the response, limit {SETTLED_TOLERANCE:g})")
