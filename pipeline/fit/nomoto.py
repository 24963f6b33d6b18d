"""First-order Nomoto model fitted to a rudder step (Nomoto et al. 1957; Fossen 2021, sec. 7.2).

``T r_dot + r = K delta`` with the rudder stepped to ``delta_a`` at ``t0`` gives

    r(t) = K delta_a + (r0 - K delta_a) exp(-(t - t0)/T)

``K`` [1/s] and ``T`` [s] need no mass data, so a rudder ship whose config gives only ``name`` is
identified this way. The steady state is read as ``K delta_a``, i.e. the rudder bias ``b`` of
:func:`pipeline.model.nomoto_rhs` is taken as zero; a constant yaw disturbance biases ``K``.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import FitError
from ..records import Segment, SegmentFit, Trial
from .data import input_levels, noise_sigma, pick_channel, segment_label, segment_samples
from .first_order import MIN_SAMPLES, check_first_order_length, guess_step, time_constant_bounds
from .least_squares import fit_least_squares
from .segment_fit import build_segment_fit

PARAMS = ("r0", "K", "T")


def nomoto_step(t: np.ndarray, r0: float, K: float, T: float, delta: float) -> np.ndarray:
    """Yaw rate after a rudder step: ``K delta + (r0 - K delta) exp(-t/T)`` [rad/s].

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
    delta : float
        Rudder angle after the step [rad].
    """
    return K * delta + (r0 - K * delta) * np.exp(-np.asarray(t, float) / T)


def nomoto_step_jacobian(t: np.ndarray, r0: float, K: float, T: float, delta: float) -> np.ndarray:
    """Jacobian of :func:`nomoto_step` with respect to ``(r0, K, T)``, shape (n, 3)."""
    e = np.exp(-np.asarray(t, float) / T)
    return np.column_stack([e, delta * (1.0 - e), (r0 - K * delta) * e * t / T**2])


def guess_nomoto_step(t: np.ndarray, r: np.ndarray, delta: float) -> dict[str, float]:
    """Closed-form start for :func:`nomoto_step`: the integral-regression step guess with
    ``K = r_ss / delta``.

    Parameters
    ----------
    t, r : numpy.ndarray
        Time since the rudder step [s] and yaw rate [rad/s].
    delta : float
        Rudder angle after the step [rad], non-zero.

    Returns
    -------
    dict
        ``r0`` [rad/s], ``K`` [1/s], ``T`` [s].
    """
    g = guess_step(t, r)
    return {"r0": g["y0"], "K": g["y_ss"] / delta, "T": g["T"]}


def fit_rudder_step(trial: Trial, segment: Segment) -> SegmentFit:
    """Fit the first-order Nomoto model to a rudder step.

    Parameters
    ----------
    trial : Trial
        Trial holding the yaw rate ``r`` (and optionally ``delta``).
    segment : Segment
        A ``rudder_step`` segment in yaw; ``input_after`` is the rudder angle after the step [rad]
        (read from the trial's ``delta`` channel when the segment gives equal levels).

    Returns
    -------
    SegmentFit
        Model ``nomoto_step`` with parameters ``r0`` [rad/s], ``K`` [1/s], ``T`` [s].

    Raises
    ------
    FitError
        Missing yaw rate, zero rudder angle, too few samples, too short or no excitation.
    """
    where = segment_label(segment)
    if segment.dof != "yaw":
        raise FitError(f"{where}: expected a rudder_step in yaw, found DOF {segment.dof!r}")
    channel = pick_channel(trial, segment, ["r"])
    _, delta, level_note = input_levels(trial, segment)
    if not (math.isfinite(delta) and delta != 0.0):
        raise FitError(f"{where}: expected a non-zero rudder angle after the step (input_after), found {delta}")
    t, r, dropped = segment_samples(trial, segment, channel)
    if t.size < MIN_SAMPLES:
        check_first_order_length(segment, t, math.nan, math.nan, math.nan)
    p0 = guess_nomoto_step(t, r, delta)
    notes = [f"start (integral-regression guess): K = {p0['K']:.4g} 1/s, T = {p0['T']:.4g} s"]
    notes += check_first_order_length(segment, t, p0["T"], p0["K"] * delta - p0["r0"], noise_sigma(r))
    notes += [n for n in (level_note, f"{dropped} non-finite samples dropped" if dropped else "") if n]
    lo_T, hi_T = time_constant_bounds(t)
    res = fit_least_squares(lambda tt, p: nomoto_step(tt, *p, delta), lambda tt, p: nomoto_step_jacobian(tt, *p, delta),
                            t, r, [p0[n] for n in PARAMS], PARAMS, [-np.inf, -np.inf, lo_T], [np.inf, np.inf, hi_T])
    return build_segment_fit(segment, "nomoto_step", channel, t, r, res, ("K", "T"), notes)
