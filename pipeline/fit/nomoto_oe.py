"""Whole-record Nomoto identification: continuous-time output-error (OE) and prediction-error (PEM)
fits of K and T (or the second-order T1, T2, T3) with a rudder bias (Nomoto et al. 1957; Ljung 1999).

Model (first order, :func:`pipeline.model.nomoto_rhs`)::

    psi_dot = r,    T r_dot + r = K (delta - b)

or second order (:func:`nomoto2_rhs`; Fossen 2021, sec. 7.2)::

    r / (delta - b) = K (1 + T3 s) / ((1 + T1 s)(1 + T2 s))

The continuous model is discretised exactly for a zero-order-hold rudder, per candidate parameter
vector, with the matrix exponential of the augmented matrix ``[[A, B], [0, 0]] h`` (Van Loan
1978; :func:`zoh_discretise`), and simulated over the whole record (steps, zig-zags, sinusoids or
closed-loop data: only the measured rudder is used). The ship's initial heading and yaw rate are
parameters of every record.

Noise models (``noise=``):

- ``"white"``: output error. Residuals ``y - y_sim`` per channel, weighted by the inverse of their
  estimated variance (the maximum-likelihood weighting for independent white channels).
- ``"waves"``: prediction error. The compass residual is passed through the steady-state Kalman
  innovations filter of the seed's second-order wave model plus white measurement noise
  (:mod:`pipeline.fit.nomoto_pem`), and ``sum e^2`` is minimised over K, T, b, the initial states
  and the wave parameters (omega_0, lambda, K_w/sqrt(R)) -- or with the wave parameters held from
  a PSD fit (``waves=WaveParams(...)``). Open-loop OE stays consistent under coloured noise but
  is inefficient and its white-noise error bars are wrong; with the right noise model the PEM
  estimate reaches the Cramer-Rao bound and its Jacobian covariance is right (Ljung 1999,
  sec. 9.3). In closed loop (an autopilot steering on the wave-contaminated compass) the direct
  method is consistent only with a correct noise model, so OE may be biased there and the PEM
  is not (Ljung 1999, sec. 13.4).
- ``"auto"``: OE first; if its compass residuals fail the whiteness test
  (:func:`pipeline.fit.residual_tests.residual_test`), the wave PEM, kept when its BIC is lower.

The yaw rate ``r`` (gyro) is used when given; it is modelled without the wave component (as the
seed and the simulator do), so a gyro that sees the wave-induced yaw is better left out
(``channels=("psi",)``).

Uncertainty: the Gauss-Newton covariance ``(J^T W J)^-1`` of the weighted residuals (the
Jacobian the solver uses too: exact for K, T, the bias and the initial states from the discrete
sensitivity equations of :mod:`pipeline.fit.nomoto_sensitivity`, central differences of the exact
simulation for the noise parameters, and of the servo's rudder angle run through the same
sensitivity equations for the servo parameters), scaled by
``RSS/(n - p)``; for the PEM this is the asymptotic covariance of Ljung (1999, sec. 9.3). The
residuals of every record and channel get the whiteness and input cross-correlation tests of
:mod:`pipeline.fit.residual_tests`.

References
----------
Nomoto, K., Taguchi, T., Honda, K., Hirano, S. (1957). On the steering qualities of ships.
International Shipbuilding Progress 4, 354-370.
Ljung, L. (1999). System Identification: Theory for the User, 2nd ed., Prentice Hall.
Fossen, T. I. (2021). Handbook of Marine Craft Hydrodynamics and Motion Control, 2nd ed., Wiley,
sec. 7.2 (Nomoto models) and 10.2.4 (wave model).
Van Loan, C. F. (1978). Computing integrals involving the matrix exponential. IEEE Trans. Autom.
Control 23(3), 395-404.
"""

from __future__ import annotations

import hashlib
import math
import time
from collections import OrderedDict
from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np
from scipy import optimize

from ..errors import FitError
from ..model.nomoto import Nomoto2Params, nomoto2_rhs, nomoto_matrices
from ..model.waves import WaveParams
from .data import noise_sigma
from .nomoto_pem import guess_wave_noise
from .nomoto_problem import (COLLAPSE_WEIGHT, DYNAMIC_PARAMS, MIN_SAMPLES, NOISE_MODELS, NOISE_PARAMS, Problem,
                             cancelled_mode, concentrated_nll, finish, plausible_ranges, prepare, reweighted_solve,
                             start_vector, unwrap_heading)
from .nomoto_records import NomotoFit, NomotoRecord
from .nomoto_start import first_order_start, guess_nomoto
from .nomoto_zoh import simulate_zoh, zoh_discretise
from .robust_covariance import hac_covariance

#: Re-exported for callers of the former single module (the model lives in :mod:`pipeline.model.nomoto`).
__all__ = ["DYNAMIC_PARAMS", "MIN_SAMPLES", "NOISE_MODELS", "NOISE_PARAMS", "Nomoto2Params", "NomotoFit",
           "NomotoRecord", "GainFloor", "SecondOrderNoGain", "fit_nomoto", "fit_nomoto_oe", "fit_nomoto_pem", "guess_nomoto", "nomoto2_rhs",
           "nomoto_matrices", "simulate_zoh", "zoh_discretise"]


def fit_nomoto(records: NomotoRecord | Sequence[NomotoRecord], order: int = 1, noise: str = "auto",
               waves: WaveParams | None = None, noise_var: float | None = None, bias: bool = True,
               channels: Sequence[str] | None = None, start: Mapping[str, float] | None = None,
               max_nfev: int = 100, servo: Sequence[str] = (), gain_floor: "GainFloor | None" = None,
               robust: bool = False) -> NomotoFit:
    """Fit the Nomoto model to whole records by output error or prediction error.

    Parameters
    ----------
    records : NomotoRecord or sequence of NomotoRecord
        One or more records of the same ship; K, T (T1..T3), b and the wave model are shared,
        the initial heading and yaw rate are per record.
    order : int
        1 (K, T), 2 (K, T1, T2, T3) or 3 (the second order as K, T12 = T1 + T2, T1T2 = T1 T2, T3,
        which also holds complex poles).
    noise : str
        ``"white"`` (OE), ``"waves"`` (PEM with the wave model) or ``"auto"`` (see module doc).
    waves : WaveParams, optional
        Hold omega_0 and lambda (and K_w, if ``noise_var`` is given too) fixed, e.g. from a PSD fit
        (``kw`` in this package's convention, :mod:`pipeline.model.waves`). Implies the PEM for
        ``noise="auto"``.
    noise_var : float, optional
        Compass noise variance per sample [rad^2], with ``waves``: the noise model is then fully
        known and only the ship is estimated.
    bias : bool
        Estimate the rudder bias b [rad].
    channels : sequence of str, optional
        Outputs to fit: ``"psi"`` and/or ``"r"``; default every one given in all records.
    start : Mapping[str, float], optional
        Start values by parameter name (``K``, ``T``, ``T1``..., and the initial states ``psi0``,
        ``r0``, ``rdot0``, named ``psi0[i]``... with several records, as in the fit's ``names``),
        overriding the closed-form guess. A higher order started from a first-order fit's initial
        states (``r0`` given, ``rdot0`` not) starts at that fit's initial yaw acceleration
        (:func:`_initial_states`), so the start is the first-order fit itself.
    max_nfev : int
        Maximum function evaluations per solver call.
    servo : sequence of str
        Rudder-servo parameters to estimate when ``delta`` is the logged *command*: ``t_servo``
        (first-order lag [s]) and/or ``rate_servo`` (rate limit [rad/s]); the ship is then driven
        by :func:`pipeline.model.nomoto.servo_response`. Empty: ``delta`` is the rudder angle.
    gain_floor : GainFloor, optional
        For the second order: the first-order fit of the same record and the in-sample gain the
        second order must reach within ``GainFloor.nfev`` evaluations to go on
        (:class:`GainFloor`); below it the fit stops with a :class:`SecondOrderNoGain` error.
    robust : bool
        With ``noise="white"``: Newey-West errors where the compass residuals are coloured
        (:func:`correlated_residual_errors`, as ``noise="auto"`` gives an output-error fit it keeps).

    Returns
    -------
    NomotoFit

    Raises
    ------
    FitError
        Bad records (non-uniform time, missing channels, non-finite rudder), an unknown order or
        noise model, or waves asked for without a compass channel; :class:`SecondOrderNoGain` when
        ``gain_floor`` stops a second-order fit.
    """
    t_start = time.perf_counter()
    recs = [records] if isinstance(records, NomotoRecord) else list(records)
    if not recs:
        raise FitError("fit_nomoto: expected at least one record, found none")
    if order not in DYNAMIC_PARAMS:
        raise FitError(f"fit_nomoto: expected order 1, 2 or 3, found {order!r}")
    if noise not in NOISE_MODELS:
        raise FitError(f"fit_nomoto: expected noise in {NOISE_MODELS}, found {noise!r}")
    if channels is None:
        channels = tuple(ch for ch in ("psi", "r") if all(getattr(r, ch) is not None for r in recs))
    channels = tuple(channels)
    if not channels or any(ch not in ("psi", "r") for ch in channels):
        raise FitError(f"fit_nomoto: expected channels among ('psi', 'r'), found {channels or 'none'}")
    if noise == "waves" and "psi" not in channels:
        raise FitError("fit_nomoto: the wave noise model acts on the compass: expected channel 'psi', found "
                       f"{channels}")
    if noise_var is not None and waves is None:
        raise FitError("fit_nomoto: noise_var is only used with fixed waves; give waves=WaveParams(...) too")
    if noise_var is not None and not noise_var > 0:
        raise FitError(f"fit_nomoto: expected noise_var > 0 [rad^2], found {noise_var}")
    preps = [prepare(r, i, channels) for i, r in enumerate(recs)]
    start = dict(start or {})

    # White-noise OE first: it starts the PEM, and it is the answer when the residuals are white.
    (K0, T0), b0, ics = first_order_start(preps, bias, channels)
    K0, T0, b0 = start.get("K", K0), start.get("T", T0), start.get("b", b0)
    ics = _initial_states(preps, ics, start, order, (K0, T0, b0), channels)
    if order == 3:
        candidates = [[K0, start.get("T12", 1.2 * T0), start.get("T1T2", 0.2 * T0**2), start.get("T3", 0.2 * T0)],
                      [K0, 2.0 * T0, 1.0 * T0**2, 1.0 * T0], [K0, 4.0 * T0, 4.0 * T0**2, 3.0 * T0]]
    elif order == 2:
        candidates = [[K0, start.get("T1", 1.1 * T0), start.get("T2", 0.1 * T0), start.get("T3", 0.2 * T0)],
                      [K0, T0, 0.05 * T0, 0.15 * T0], [K0, 1.5 * T0, 0.2 * T0, 0.7 * T0]]
    else:
        candidates = [[K0, T0], [K0, 0.3 * T0], [K0, 3.0 * T0]]
    # The same white-noise OE fit (same records, settings and starts) is asked for more than once
    # while a record is prepared (channel and servo choice, then the fit itself): it is made once.
    key = None if gain_floor is not None and order != 1 else (
        records_digest(recs), order, bias, channels, tuple(sorted(start.items())), max_nfev, tuple(servo))
    cached = _OE_CACHE.get(key) if key is not None else None
    if cached is not None:
        _OE_CACHE.move_to_end(key)
        prob, res, oe = cached
    else:
        best = None
        for dyn in candidates:
            prob = Problem(preps, order, bias, channels, "white", None, None, servo)
            if gain_floor is not None and order != 1:
                watch_gain(prob, gain_floor)
            res = reweighted_solve(prob, start_vector(prob, dyn, b0, ics, (), start), max_nfev, _collapse_stop(prob))
            # Starts are compared by the likelihood with the channel variances concentrated out: each
            # solve's cost is weighted by variances re-estimated from its own start, so costs are not.
            crit = concentrated_nll(prob, res.x)
            if best is None or crit < best[2]:
                best = (prob, res, crit)
            # A first-order fit that converged inside the plausible ranges needs no other start; the
            # second-order one can stop in a local minimum, so every start is tried.
            if order == 1 and _plausible(*best[:2]):
                break
        prob, res, _ = best
        oe = finish(prob, res, [res.stopped] if res.stopped else [])
        if key is not None:
            prob.clear_caches()
            _OE_CACHE[key] = (prob, res, oe)
            while len(_OE_CACHE) > OE_CACHE_SIZE:
                _OE_CACHE.popitem(last=False)
    if noise == "white" and robust and not _psi_white(oe):
        return _timed(correlated_residual_errors(prob, res.x, oe), t_start)
    if noise == "white" or (noise == "auto" and waves is None and _psi_white(oe)):
        note = "compass residuals white: OE kept" if noise == "auto" else ""
        return _timed(_with_message(oe, note), t_start)

    # PEM: the ship starts from the OE estimate, the noise from the OE compass residual's spectrum.
    theta = prob.natural(res.x)
    dyn = list(theta[: prob.n_dyn])
    b = float(theta[prob.n_dyn]) if bias else 0.0
    icl = [list(theta[idx]) for idx in prob.ic_index]
    h = preps[0].h
    w = np.concatenate([p.y["psi"][p.mask["psi"]] - oe.y_fit[i]["psi"][p.mask["psi"]] for i, p in enumerate(preps)])
    sv = noise_sigma(np.concatenate([p.y["psi"][p.mask["psi"]] for p in preps]))
    omega0, lam, ratio = guess_wave_noise(w, 1.0 / h, sv)
    if waves is not None:
        omega0, lam = waves.omega0, waves.lam
        ratio = waves.kw / (math.sqrt(noise_var) if noise_var is not None else max(sv, 1e-12))
    pem_prob = Problem(preps, order, bias, channels, "waves", waves, noise_var, servo)
    noise0 = [dict(zip(NOISE_PARAMS, (omega0, lam, ratio)))[nm] for nm in pem_prob.noise_free]
    servo0 = {nm: float(theta[j]) for nm, j in zip(prob.servo, prob.servo_index)}
    try:
        pem_res = reweighted_solve(pem_prob, start_vector(pem_prob, dyn, b, icl, noise0, servo0), max_nfev,
                                   _collapse_stop(pem_prob))
        pem = finish(pem_prob, pem_res, [pem_res.stopped] if pem_res.stopped else [])
    except (FitError, np.linalg.LinAlgError, FloatingPointError) as exc:
        if noise != "auto":
            raise
        return _timed(_with_message(correlated_residual_errors(prob, res.x, oe),
                                    f"compass residuals coloured but the wave PEM failed ({exc}): OE kept"), t_start)
    if noise == "auto" and not pem.success and oe.success:
        # The refinement failed (a wave parameter out of range, no covariance): the plain fit that
        # worked is kept, and the message says why the noise model was not used.
        why = ", ".join(pem.at_bound) + " out of range" if pem.at_bound else (
            "solver did not converge" if not pem.converged else "covariance not computed")
        return _timed(_with_message(correlated_residual_errors(prob, res.x, oe),
                                    f"compass residuals coloured but the wave PEM failed ({why}): OE kept"), t_start)
    if noise == "auto" and waves is None:
        if pem.bic >= oe.bic:
            return _timed(_with_message(correlated_residual_errors(prob, res.x, oe),
                                        f"compass residuals coloured but the wave PEM does not lower the BIC "
                                        f"({pem.bic:.1f} >= {oe.bic:.1f}): OE kept"), t_start)
        pem = _with_message(pem, f"OE compass residuals coloured; wave PEM chosen (BIC {pem.bic:.1f} < "
                                 f"{oe.bic:.1f})")
    if not _psi_white(pem):
        pem = correlated_residual_errors(pem_prob, pem_res.x, pem)
    return _timed(pem, t_start)


def _initial_states(preps: Sequence, ics: Sequence[Sequence[float]], start: Mapping[str, float], order: int,
                    first: tuple[float, float, float], channels: Sequence[str]) -> list[list[float]]:
    """Start of every record's initial states: the closed-form guess ``ics``, overridden by ``start``.

    The states are named as in the fit (``psi0``, ``r0``, ``rdot0``; ``psi0[i]``... with several
    records). A second-order start whose ``r0`` is given without ``rdot0`` gets the first-order
    model's initial yaw acceleration ``(K (delta_0 - b) - r0) / T`` from the start's ``K``, ``T``
    and ``b``: a second order whose zero cancels a pole (the first start candidate) then reproduces
    the first-order fit whose values were passed, instead of starting thousands of noise variances
    above it (measured: PythonVehicleSimulator's tanker at 20 m, commanded rudder steps, an in-sample
    loss of 2,700-6,000 noise variances at the start with ``rdot0 = 0`` and the guessed heading and
    yaw rate, which :class:`GainFloor` stopped after 25 evaluations on 5 of 6 steps).

    Parameters
    ----------
    preps : sequence of Prepared
        The records (``u[0]`` is the rudder at the first sample: a servo starts at its command).
    ics : sequence of sequence of float
        Guessed ``psi0`` (with a compass channel) and ``r0`` per record.
    start : Mapping[str, float]
        Start values by name.
    order : int
        Model order (``rdot0`` is a state of the second order only).
    first : tuple of float
        The start's first-order K [1/s], T [s] and b [rad].
    channels : sequence of str
        Fitted outputs (``psi0`` is a state only with ``psi``).

    Returns
    -------
    list of list of float
        Initial states per record in the problem's order (``psi0``, ``r0``, ``rdot0``).
    """
    K, T, b = first
    names = (["psi0"] if "psi" in channels else []) + ["r0"]
    out = []
    for i, (prep, ic) in enumerate(zip(preps, ics)):
        tag = (lambda nm: nm) if len(preps) == 1 else (lambda nm, i=i: f"{nm}[{i}]")
        vals = [float(start.get(tag(nm), v)) for nm, v in zip(names, ic)]
        if order != 1:
            r0 = vals[-1]
            given = tag("r0") in start and T > 0 and math.isfinite(K * T)
            rdot0 = start.get(tag("rdot0"), (K * (float(prep.u[0]) - b) - r0) / T if given else 0.0)
            vals.append(float(rdot0))
        out.append(vals)
    return out


#: White-noise OE fits kept for reuse, most recent last: key -> (problem, solver result, fit).
_OE_CACHE: "OrderedDict[tuple, tuple]" = OrderedDict()
#: How many OE fits are kept (a record's preparation repeats one within a few calls).
OE_CACHE_SIZE = 8


def records_digest(records: Sequence[NomotoRecord]) -> bytes:
    """A digest of the records' samples and names: equal digests, equal records (for the OE cache).

    Parameters
    ----------
    records : sequence of NomotoRecord
        The records.
    """
    h = hashlib.blake2b(digest_size=20)
    for rec in records:
        for arr in (rec.t, rec.delta, rec.psi, rec.r):
            if arr is None:
                h.update(b"none;")
                continue
            a = np.ascontiguousarray(arr, dtype=float)
            h.update(repr(a.shape).encode())
            h.update(a.tobytes())
        h.update(repr(rec.name).encode())
    return h.digest()


#: Parameters the second-order model adds (T12, T1T2, T3 for T; the initial yaw acceleration).
ORDER2_ADDED = 3
#: Evaluations after which a second-order solve must show its in-sample gain (:class:`GainFloor`).
GAIN_CHECK_NFEV = 25


class SecondOrderNoGain(FitError):
    """A second-order fit stopped early: its in-sample gain over the first order is below noise."""


@dataclass(frozen=True)
class GainFloor:
    """What a second-order solve must reach to be worth finishing.

    The in-sample gain ``G = sum_ch n_ch (mse1_ch - mse2_ch) / var_ch`` is the drop of the output
    (simulation) error's sum of squares in units of the first order's innovation variance per
    channel (its white-noise variance; with the wave noise model the innovations filter passes
    the slow structural error nearly unchanged, so the drop is read against the innovation, not
    the wave-coloured output error). When the extra pole-zero pair only fits noise, ``G`` is about
    chi-square with ``ORDER2_ADDED`` degrees of freedom (larger under coloured noise, which makes
    the stop rarer, not wrong). A solve whose best point after ``nfev`` evaluations has ``G`` below
    ``ORDER2_ADDED``, the gain noise alone gives on average, is stopped: its held-out gain (which
    the in-sample one bounds in expectation) is then below noise, and on first-order data the
    second order otherwise drifts along its cancelled pole-zero pair to the evaluation limit of
    every start. The floor is this lenient, not the shared rule's quantile, because the structure
    is chosen on the held-out errors of all segments together (:mod:`pipeline.fit.nomoto_structure`),
    where gains too small for one segment add up.

    Attributes
    ----------
    mse : Mapping[str, float]
        First-order output-error mean square per channel.
    var : Mapping[str, float]
        First-order innovation (white-noise) variance per channel, the gain's unit.
    threshold : float
        Smallest gain [-] that goes on.
    nfev : int
        Evaluations before the check.
    """

    mse: Mapping[str, float]
    var: Mapping[str, float]
    threshold: float
    nfev: int = GAIN_CHECK_NFEV

    @classmethod
    def from_first_order(cls, first: NomotoFit, records: NomotoRecord | Sequence[NomotoRecord]) -> "GainFloor":
        """The floor against a first-order fit.

        The first order's mean squares are its output (simulation) errors, as the second order's
        first solve is an output-error one, whatever noise model the first-order fit chose.

        Parameters
        ----------
        first : NomotoFit
            First-order fit of ``records``.
        records : NomotoRecord or sequence of NomotoRecord
            The records it was fitted to.
        """
        recs = [records] if isinstance(records, NomotoRecord) else list(records)
        mse = {}
        for ch in first.channels:
            errs = []
            for rec, sim in zip(recs, first.y_fit):
                y = unwrap_heading(rec.psi) if ch == "psi" else np.asarray(rec.r, float)
                errs.append(y - sim[ch])
            e = np.concatenate(errs)
            e = e[np.isfinite(e)]
            mse[ch] = float(np.mean(e**2)) if e.size else math.nan
        var = {ch: float(first.innovation_var.get(ch, math.nan)) for ch in mse}
        return cls(mse, var, float(ORDER2_ADDED))


def in_sample_gain(prob: Problem, z: np.ndarray, floor: GainFloor) -> float:
    """``sum_ch n_ch (mse1_ch - mse2_ch) / var_ch`` of the problem at ``z`` against the floor's first order [-].

    Parameters
    ----------
    prob : Problem
        The second-order problem.
    z : numpy.ndarray
        Solver vector.
    floor : GainFloor
        The first order's residual mean squares.
    """
    per = prob.channel_residuals(z)
    gain = 0.0
    for ch in prob.channels:
        e = np.concatenate([q[ch] for q in per])
        m1, v1 = floor.mse.get(ch, math.nan), floor.var.get(ch, math.nan)
        if e.size and math.isfinite(m1) and math.isfinite(v1) and v1 > 0:
            gain += e.size * (m1 - float(np.mean(e**2))) / v1
    return gain


def watch_gain(prob: Problem, floor: GainFloor) -> None:
    """Make ``prob.residual`` stop the solve (:class:`SecondOrderNoGain`) when the best point after
    ``floor.nfev`` evaluations has an in-sample gain below ``floor.threshold``.

    Parameters
    ----------
    prob : Problem
        The second-order output-error problem; its ``residual`` is wrapped in place.
    floor : GainFloor
        Evaluation count at which to check, and the in-sample gain [noise variances] below which the
        second order is not worth finishing (the first-order fit it is compared with).
    """
    plain = prob.residual
    best = {"cost": math.inf, "z": None, "n": 0}

    def residual(z: np.ndarray) -> np.ndarray:
        r = plain(z)
        cost = float(r @ r)
        if cost < best["cost"]:
            best["cost"], best["z"] = cost, np.array(z, float)
        best["n"] += 1
        if best["n"] == floor.nfev and best["z"] is not None:
            gain = in_sample_gain(prob, best["z"], floor)
            if gain < floor.threshold:
                raise SecondOrderNoGain(
                    f"second order stopped after {floor.nfev} evaluations: its in-sample gain over the first "
                    f"order, {gain:.3g} noise variances, is below what noise alone gives "
                    f"({floor.threshold:.3g}: the mean of chi-square with {ORDER2_ADDED} added parameters)")
        return r

    prob.residual = residual


def _collapse_stop(prob: Problem):
    """``stop`` for :func:`reweighted_solve`: a second-order solve that ended unconverged with a mode
    its zero cancels (:func:`cancelled_mode` below ``COLLAPSE_WEIGHT``) is the first-order model
    drifting along the cancelled pair; re-solving it with new channel weights drifts on (each solve
    to ``max_nfev``) and cannot make it a candidate, so it is not re-solved (the fit's message says so)."""
    if prob.order == 1:
        return None

    def stop(res: optimize.OptimizeResult) -> str:
        if res.status > 0:
            return ""
        weight = cancelled_mode(prob.order, prob.natural(res.x)[: prob.n_dyn])
        if not weight < COLLAPSE_WEIGHT:
            return ""
        return (f"second order collapsing onto the first (its zero cancels a pole: mode weight {weight:.2g} < "
                f"{COLLAPSE_WEIGHT:g}) without converging in {res.nfev} evaluations: not re-solved with "
                f"re-estimated channel weights")
    return stop


def _plausible(prob: Problem, res: optimize.OptimizeResult) -> bool:
    lo, hi = plausible_ranges(prob)
    theta = prob.natural(res.x)
    return bool(res.status > 0 and np.all((theta > lo) & (theta < hi)))


def _psi_white(fit: NomotoFit) -> bool:
    tests = [t for t in fit.residual_tests if t.name.endswith(" psi")]
    return all(t.white for t in tests)


def correlated_residual_errors(prob: Problem, x: np.ndarray, fit: NomotoFit) -> NomotoFit:
    """``fit`` with Newey-West (Bartlett kernel) standard errors where they are larger (``robust_stderr``).

    An output-error fit kept although its residuals are coloured (the wave noise model could not be
    fitted, or did not lower the BIC), or a wave PEM whose innovations are still not white, has a
    covariance ``s^2 (J'J)^-1`` that assumes white residuals; correlated residuals carry less
    information than their count says, so those errors are too small (measured:
    PythonVehicleSimulator's frigate, slow sinusoid with the measured rudder's sensor noise, T off by
    4 of its standard errors, 30 % coverage over 20 seeds). The heteroscedasticity-and-
    autocorrelation-consistent covariance ``(J'J)^-1 Omega (J'J)^-1`` with ``Omega = sum_l
    (1 - |l|/(L+1)) sum_t g_t g_{t-l}'``, ``g_t = J_t e_t`` (Newey & West 1987), uses the residual's
    own correlation; the bandwidth ``L`` is the last lag up to ``n/4`` at which the residual's
    autocorrelation lies outside the white-noise band ``2 / sqrt(n)`` (:func:`correlation_length`; a
    white sensor noise on top of a slow coloured part, such as the heading's response to a measured
    rudder's sensor noise, makes a lag-1 plug-in bandwidth, or the first crossing of the band, far
    too short).
    Each standard error is only ever raised (the correlation structure of the covariance is kept),
    and the message says by how much. They are kept beside the white-noise ones (``robust_stderr``,
    ``robust_covariance``), which the trial's structure stage pools segments with; the segment fit
    (:mod:`pipeline.fit.nomoto_segment`) reports them.

    Parameters
    ----------
    prob : Problem
        The problem of ``fit`` (its residual is the OE error or the PEM innovation).
    x : numpy.ndarray
        Its solver vector at the solution.
    fit : NomotoFit
        The fit (not modified).
    """
    if not np.all(np.isfinite(fit.stderr)):
        return fit
    e = prob.residual(x)
    jac = prob.jacobian(x)
    n, p = jac.shape
    if n <= 4 * p:
        return fit
    lags = correlation_length(e, n // 4)
    try:
        robust = hac_covariance(jac, e, np.zeros(n, int), bandwidth=lags)
    except np.linalg.LinAlgError:
        return fit
    d = np.where(prob.log_mask, fit.values, 1.0)
    hac = robust.covariance * np.outer(d, d)
    ratio = np.sqrt(np.clip(np.diag(hac), 0.0, None)) / np.where(fit.stderr > 0, fit.stderr, np.inf)
    f = np.where(np.isfinite(ratio), np.maximum(ratio, 1.0), 1.0)
    if not np.any(f > 1.0):
        return fit
    i_k = fit.names.index("K") if "K" in fit.names else 0
    note = (f"standard errors from the residuals' own correlation (Newey-West, {lags} lags; K x {f[i_k]:.2g}): "
            f"coloured residuals carry less information than white ones")
    return replace(fit, robust_stderr=fit.stderr * f, robust_covariance=fit.covariance * np.outer(f, f),
                   message="; ".join(m for m in (fit.message, note) if m))


def correlation_length(e: np.ndarray, most: int) -> int:
    """The last lag (at most ``most``) at which the autocorrelation of ``e`` lies outside ``+-2/sqrt(n)``.

    Parameters
    ----------
    e : numpy.ndarray
        Residuals (NaN-free).
    most : int
        Largest lag returned.
    """
    e = np.asarray(e, float) - float(np.mean(e))
    n = e.size
    if n < 4 or not e @ e > 0:
        return 0
    m = 1 << int(math.ceil(math.log2(2 * n)))
    f = np.fft.rfft(e, m)
    acf = np.fft.irfft(f * np.conj(f), m)[: most + 1] / (e @ e)
    outside = np.nonzero(np.abs(acf[1:]) >= 2.0 / math.sqrt(n))[0]
    return int(outside[-1]) + 1 if outside.size else 0


def _with_message(fit: NomotoFit, note: str) -> NomotoFit:
    if not note:
        return fit
    return replace(fit, message="; ".join(m for m in (fit.message, note) if m))


def _timed(fit: NomotoFit, t_start: float) -> NomotoFit:
    return replace(fit, timings={"total_s": time.perf_counter() - t_start})


def fit_nomoto_oe(records: NomotoRecord | Sequence[NomotoRecord], order: int = 1, bias: bool = True,
                  channels: Sequence[str] | None = None) -> NomotoFit:
    """Output-error fit (white measurement noise); see :func:`fit_nomoto`.

    Parameters
    ----------
    records : NomotoRecord or sequence of NomotoRecord
        Records of one ship.
    order : int
        1 or 2.
    bias : bool
        Estimate the rudder bias.
    channels : sequence of str, optional
        ``"psi"`` and/or ``"r"``.
    """
    return fit_nomoto(records, order=order, noise="white", bias=bias, channels=channels)


def fit_nomoto_pem(records: NomotoRecord | Sequence[NomotoRecord], order: int = 1, bias: bool = True,
                   waves: WaveParams | None = None, noise_var: float | None = None,
                   channels: Sequence[str] | None = None) -> NomotoFit:
    """Prediction-error fit with the wave noise model (Kalman innovations); see :func:`fit_nomoto`.

    Parameters
    ----------
    records : NomotoRecord or sequence of NomotoRecord
        Records of one ship.
    order : int
        1 or 2.
    bias : bool
        Estimate the rudder bias.
    waves : WaveParams, optional
        Fixed wave shape (and K_w with ``noise_var``), e.g. from a PSD fit; estimated when omitted.
    noise_var : float, optional
        Fixed compass noise variance [rad^2] (with ``waves``).
    channels : sequence of str, optional
        ``"psi"`` and/or ``"r"``.
    """
    return fit_nomoto(records, order=order, noise="waves", waves=waves, noise_var=noise_var, bias=bias,
                      channels=channels)
