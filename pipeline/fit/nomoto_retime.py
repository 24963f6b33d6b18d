"""A Nomoto record re-timed on the distance sailed: the speed-scaled Nomoto model as a constant one.

Nomoto's K and T scale with the speed (``K = K' u / L``, ``T = T' L / u``); a ship whose speed
changes in its turns (PythonVehicleSimulator's Clarke83 ship speeds up by 2.9 % at 10 deg of rudder,
and has not settled in an 81 s hold) shows a slow creep on top of each step's transient, which a
constant-speed fit reads as a longer T on the steps into a turn than on those out of one. In the
distance-sailed time ``tau = integral of u / U0 dt`` the speed-scaled model is the constant model at
the reference speed ``U0`` (:func:`pipeline.model.nomoto.distance_time`), so the record is resampled
on a uniform ``tau`` grid (the heading interpolated, the yaw rate scaled by ``U0 / u`` to a rate per
distance, the rudder as the mean of the logged zero-order hold over each new interval) and fitted
by the project's constant-speed fit; its K and T are those at ``U0``. The model leaves out
``T0 U0 (du/dt) / u^2`` of the damping (a speed that still creeps within the time constant; -0.5 % in K
on tests/test_nomoto_retime.py's ship, whose speed rises 3 % at 60 s).

:func:`pool_time_constants` pools second-order segments' time constants with each segment's gain left
its own (a nuisance), so that a gain that differs between rudder amplitudes does not move T through the
correlations of the pooled (K, T1 + T2, T1 T2, T3) vector (:mod:`pipeline.fit.nomoto_pool`).

Use: :func:`pipeline.fit.nomoto_segment.retime_window` re-times a rudder step's window whose logged speed
departs from the trial's straight-run speed by more than ``SPEED_RETIME`` (1 %) where its held-out yaw rate
chooses the re-timed fit (:func:`pipeline.fit.nomoto_segment.choose_retiming`; when neither wins, the
difference is a term of K's and T's errors). Measured by ident36 (not
wired then): on PythonVehicleSimulator's Clarke83 ship the re-timing removes the speed's creep from the
noise-free steps (per-step T -0.5 to +1.7 %, against -0.1 to +23 % at constant speed), but every K moves
by -1 to -2 %, the rudder force's ``sin 2 delta`` at 10 deg that the ship's +2.9 % speed rise in its turns
had cancelled; the combined K is therefore read at zero rudder amplitude where the steps' amplitudes
differ (:mod:`pipeline.fit.nomoto_amplitude`; benchmarks/RESULTS.md, "Speed and rudder amplitude (ident38)").
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy import stats

from ..errors import FitError
from ..model.nomoto import distance_time
from ..records import SegmentFit
from .combine import CONSISTENCY_ALPHA, dersimonian_laird_psi, overlap_correlation
from .nomoto_pool import is_joint_follower, samples_window
from .nomoto_problem import unwrap_heading
from .nomoto_records import NomotoRecord


def retime_record(rec: NomotoRecord, u: np.ndarray, u_ref: float) -> NomotoRecord:
    """``rec`` resampled on a uniform grid of the distance-sailed time (module docstring).

    Parameters
    ----------
    rec : NomotoRecord
        The record: times [s] uniform, rudder [rad] held over each interval, heading [rad] and/or
        yaw rate [rad/s].
    u : numpy.ndarray
        Speed through the water at ``rec.t`` [m/s], positive and finite.
    u_ref : float
        Reference speed ``U0`` [m/s].

    Returns
    -------
    NomotoRecord
        Times ``t[0] + k h`` (``h`` the record's sample time) up to the last ``tau``: heading at the
        matching real times (linear interpolation), yaw rate ``r U0 / u`` [rad/s of tau], rudder the
        mean of the hold over each interval.

    Raises
    ------
    FitError
        ``u`` not of the record's length, or not positive and finite.
    """
    t = np.asarray(rec.t, float)
    u = np.asarray(u, float)
    if u.shape != t.shape:
        raise FitError(f"{rec.name}: re-timing on the distance sailed: expected a speed per sample ({t.size}), "
                       f"found {u.size}")
    try:
        tau = distance_time(t, u, u_ref)
    except ValueError as exc:
        raise FitError(f"{rec.name}: re-timing on the distance sailed: {exc}") from exc
    h = float(np.median(np.diff(t)))
    n = int(math.floor((tau[-1] - tau[0]) / h + 1e-9)) + 1
    grid = tau[0] + h * np.arange(n)
    t_of = np.interp(grid, tau, t)
    # The rudder is held over each logged interval: its integral over t is piecewise linear, exact.
    d = np.asarray(rec.delta, float)
    cum = np.concatenate([[0.0], np.cumsum(d[:-1] * np.diff(t))])
    t_end = np.interp(grid + h, tau, t, right=np.nan)
    mean = (np.interp(t_end, t, cum) - np.interp(t_of, t, cum)) / (t_end - t_of)
    last = ~np.isfinite(mean)
    mean[last] = np.interp(t_of[last], t, d)
    psi = r = None
    if rec.psi is not None:
        p = np.asarray(rec.psi, float)
        ok = np.isfinite(p)
        psi = np.full(n, np.nan)
        if ok.sum() >= 2:
            psi = np.interp(t_of, t[ok], unwrap_heading(p)[ok])
            # A missing stretch stays missing: the grid points nearest no logged sample.
            near = np.interp(t_of, t, ok.astype(float))
            psi[near < 1.0 - 1e-9] = np.nan
    if rec.r is not None:
        rr = np.asarray(rec.r, float) * (u_ref / u)
        r = np.interp(t_of, t, rr)
    return NomotoRecord(t=grid, delta=mean, psi=psi, r=r, name=rec.name)


#: The second-order time constants pooled with the gain left to each segment (a nuisance).
TIME_PARAMS = ("T12", "T1T2", "T3")


def pool_time_constants(fits: Sequence[SegmentFit], prediction: bool = True
                        ) -> tuple[float, float, float, float, int] | None:
    """T = T1 + T2 - T3 from the generalised least-squares mean of the segments' (T1 + T2, T1 T2, T3).

    The mean and its error follow :func:`pipeline.fit.nomoto_pool.pool_second_order` (overlapping windows'
    design effect; between-segment covariance by the multivariate DerSimonian-Laird rule where the
    segments disagree, the fixed-effect mean's error under it, Henmi & Copas 2010) on three constants
    instead of four.

    Each segment's gain is its own (a nuisance: a rudder force that is not linear in the angle, as
    Clarke83's ``sin 2 delta``, gives steps of different amplitude different K; pooled through one K,
    the vector's correlations move T). The marginal of a segment's estimate over the time constants is
    their block of its covariance, so pooling those blocks leaves every segment its own K.

    Parameters
    ----------
    fits : sequence of SegmentFit
        Second-order whole-record Nomoto segment fits.
    prediction : bool
        Where the segments disagree (chi-square p below ``CONSISTENCY_ALPHA``), add the
        between-segment spread (multivariate DerSimonian-Laird) to the error.

    Returns
    -------
    tuple of (float, float, float, float, int) or None
        T [s], its standard error [s], the chi-square p-value, the chi-square and the segments pooled;
        None unless two or more segments carry a usable covariance of the time constants.
    """
    xs, ws, kept = [], [], []
    for sf in fits:
        if is_joint_follower(sf):
            continue
        names = list(getattr(sf, "param_names", None) or ())
        cov = getattr(sf, "covariance", None)
        if cov is None or not all(n in names and n in sf.params for n in TIME_PARAMS):
            return None
        idx = [names.index(n) for n in TIME_PARAMS]
        c = np.asarray(cov, float)[np.ix_(idx, idx)]
        x = np.array([sf.params[n] for n in TIME_PARAMS], float)
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(x)) and np.all(np.diag(c) > 0)):
            return None
        xs.append(x)
        ws.append(np.linalg.pinv(0.5 * (c + c.T), rcond=1e-12, hermitian=True))
        kept.append(sf)
    k = len(xs)
    if k < 2:
        return None
    x = np.array(xs)
    info = sum(ws)
    cov = np.linalg.inv(info)
    theta = cov @ sum(w @ xi for w, xi in zip(ws, x))
    chi2 = float(sum((xi - theta) @ w @ (xi - theta) for w, xi in zip(ws, x)))
    dof = len(TIME_PARAMS) * (k - 1)
    p_value = float(stats.chi2.sf(chi2, dof))
    rho = overlap_correlation([samples_window(sf) for sf in kept])
    psi = np.zeros((3, 3))
    if p_value < CONSISTENCY_ALPHA:
        psi = dersimonian_laird_psi(x, ws)
        cov = cov + cov @ sum(w @ psi @ w for w in ws) @ cov
    cov = cov * float(rho.sum()) / k + (psi if prediction else 0.0)
    g = np.array([1.0, 0.0, -1.0])
    return float(g @ theta), math.sqrt(max(float(g @ cov @ g), 0.0)), p_value, chi2, k
