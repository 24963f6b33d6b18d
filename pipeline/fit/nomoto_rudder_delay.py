"""A lone zig-zag's rudder-to-heading delay, fitted with its first-order K and T (profile likelihood).

A zig-zag never settles: its rudder reverses before the turn is steady, so K and T are read from the
transients together, along a ridge (K / T, the initial turning rate, is sharp; K and T each are not), and
a small delay between the logged rudder and the ship's response moves both along that ridge. Measured on
PythonVehicleSimulator's frigate (first-order Nomoto with Norrbin's cubic yaw-rate term, 1 s servo, 10/10
zig-zag, the noise-free record fitted by output error from its own servo angle): the rudder delayed by
0.025 s moves K by -0.21 % and T by -0.33 % (-8.6 and -13 % per second), against -0.01 and -0.11 % per
0.025 s on its rudder steps, whose steady turns fix K. The simulator's forward Euler step (0.05 s) is such a
delay: it drives the yaw rate from the rudder at the start of each step, half a step late, so its noise-free
zig-zag gives K and T +0.18 % each (+0.01 and -0.02 % with a 0.005 s step), and with the benchmark's noise
K +0.09 to +0.29 % with standard errors of 0.075 %: intervals missing on half the seeds. Norrbin's cubic is
not the cause there: its yaw rate reaches 1.2 deg/s, where ``n3 r^2`` is 2e-4 of the linear damping (K and T
-0.015 %).

A real log has such delays too (a rudder-angle sensor's or a logger's latency, channels stamped apart), and
the log does not state them. The delay is therefore estimated with K and T (:func:`fit_rudder_delay`): the
rudder record is shifted by ``d`` (linear interpolation of the angle that drives the model) and the zig-zag
refitted; ``-2 log L`` of the refits is minimised over ``d`` (bounded Brent, within ``DELAY_REACH`` sample
intervals), its curvature there gives the delay's standard error, and K and T are read at the fitted delay,
their errors those of the joint fit: the conditional error at the delay plus the delay's error carried
through the slope of K (T) on ``d`` (the profile's Schur complement), the latter a stated model term
(``RUDDER_DELAY_TERM``, added in quadrature by :func:`pipeline.fit.nomoto_quality.judge_nomoto`). Where the
record does not fix the delay (the minimum at the bound or a flat profile), K and T stay at zero delay and the
term is the slope times the reach.

Only a lone zig-zag fitted first order with a measured rudder angle gets it: a logged command's servo lag
is fitted already (:mod:`pipeline.fit.nomoto_problem`), a step's steady turn fixes K, and a re-timed
second-order zig-zag (:mod:`pipeline.fit.nomoto_zigzag`) states its own terms.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import minimize_scalar

from ..errors import FitError
from ..records import SegmentFit
from .nomoto_oe import fit_nomoto
from .nomoto_quality import RUDDER_DELAY_TERM
from .nomoto_records import NomotoFit, NomotoRecord

#: Largest delay searched, either way, in sample intervals [-].
DELAY_REACH = 2.0
#: Step of the curvature and slope differences, in sample intervals [-].
DELAY_STEP = 0.25


def fractional_delay(x: np.ndarray, shift: float) -> np.ndarray:
    """``x`` delayed by ``shift`` samples with an all-pass filter (a phase ramp on the record mirrored at its end).

    A linear interpolation between samples would average neighbouring samples at a fractional shift and so
    lower the rudder's sensor noise there: the likelihood would then prefer half-sample delays for the noise's
    sake. A phase shift keeps every frequency's amplitude (the noise's variance) and moves the signal only. The
    record is mirrored at its end first, so its periodic extension has no jump (the rudder's ends differ).

    Parameters
    ----------
    x : numpy.ndarray
        Uniformly sampled signal.
    shift : float
        Delay [samples]; negative: earlier.
    """
    x = np.asarray(x, float)
    n = x.size
    if n < 2 or shift == 0.0:
        return x.copy()
    ext = np.concatenate([x, x[::-1]])
    spec = np.fft.rfft(ext)
    spec *= np.exp(-2j * np.pi * np.fft.rfftfreq(ext.size) * shift)
    return np.fft.irfft(spec, ext.size)[:n]


def delayed_record(rec: NomotoRecord, delay: float) -> NomotoRecord:
    """``rec`` with its rudder acting ``delay`` seconds later (:func:`fractional_delay`).

    Parameters
    ----------
    rec : NomotoRecord
        The record (rudder as it drives the model), uniformly sampled.
    delay : float
        Delay of the rudder [s]; negative: it acts earlier.
    """
    if not math.isfinite(delay):
        raise ValueError(f"rudder delay: expected a finite number of seconds, found {delay!r}")
    t = np.asarray(rec.t, float)
    if t.size < 2:
        return rec
    h = float(np.median(np.diff(t)))
    return replace(rec, delta=fractional_delay(np.asarray(rec.delta, float), delay / h))


@dataclass(frozen=True)
class RudderDelay:
    """The rudder delay fitted with K and T (:func:`fit_rudder_delay`).

    Attributes
    ----------
    delay, se_delay : float
        The delay [s] and its standard error [s] (``se_delay`` NaN where the record does not fix it).
    fixed : bool
        The profile has its minimum inside the reach with a positive curvature.
    fit : NomotoFit
        The fit at ``delay`` (at zero delay when not ``fixed``).
    slope_k, slope_t : float
        Slopes of K [1/s^2] and T [-] on the delay at ``delay``.
    term_k, term_t : float
        The delay's error carried into K [1/s] and T [s].
    k0, t0 : float
        K [1/s] and T [s] at zero delay.
    reach : float
        The largest delay searched [s].
    """

    delay: float
    se_delay: float
    fixed: bool
    fit: NomotoFit
    slope_k: float
    slope_t: float
    term_k: float
    term_t: float
    k0: float
    t0: float
    reach: float


def fit_rudder_delay(rec: NomotoRecord, channels: tuple[str, ...], noise: str) -> RudderDelay | None:
    """The rudder-to-heading delay of a first-order record, fitted with K and T (module docstring).

    Parameters
    ----------
    rec : NomotoRecord
        The record, rudder logged as a measured angle.
    channels : tuple of str
        Outputs fitted (``psi``, ``r``).
    noise : str
        ``white`` (output error, Newey-West errors where the residuals are coloured) or ``waves``.

    Returns
    -------
    RudderDelay or None
        None where a first-order fit fails (not converged, a parameter out of range).
    """
    t = np.asarray(rec.t, float)
    if t.size < 3:
        return None
    h = float(np.median(np.diff(t)))
    reach, step = DELAY_REACH * h, DELAY_STEP * h
    cache: dict[float, NomotoFit | None] = {}

    def fit_at(d: float) -> NomotoFit | None:
        key = round(d, 9)
        if key not in cache:
            try:
                f = fit_nomoto(delayed_record(rec, d), order=1, noise=noise, channels=channels,
                               robust=(noise == "white"))
            except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError):
                f = None
            cache[key] = f if f is not None and f.success else None
        return cache[key]

    def cost(d: float) -> float:
        f = fit_at(d)
        return f.neg2loglik if f is not None else math.inf

    zero = fit_at(0.0)
    if zero is None:
        return None
    res = minimize_scalar(cost, bounds=(-reach, reach), method="bounded", options={"xatol": 0.02 * h})
    d = float(res.x)
    if cost(d) > zero.neg2loglik:
        d = 0.0
    fixed = abs(d) < reach - step
    lo, mid, hi = cost(d - step), cost(d), cost(d + step)
    curv = (lo + hi - 2.0 * mid) / step**2
    fixed = fixed and math.isfinite(curv) and curv > 0
    centre = d if fixed else 0.0
    f_lo, f_mid, f_hi = fit_at(centre - step), fit_at(centre), fit_at(centre + step)
    if f_lo is None or f_mid is None or f_hi is None:
        return None
    slope_k = (f_hi.K - f_lo.K) / (2.0 * step)
    slope_t = (f_hi.T - f_lo.T) / (2.0 * step)
    if fixed:
        se_d = math.sqrt(2.0 / curv)
        # Coloured residuals carry less information than the likelihood's curvature says (Newey-West).
        white = f_mid.error("K")
        ratio = f_mid.reported_error("K") / white if white > 0 else 1.0
        se_d *= max(ratio, 1.0)
        spread = se_d
    else:
        se_d = math.nan
        spread = reach
    return RudderDelay(delay=centre, se_delay=se_d, fixed=fixed, fit=f_mid, slope_k=slope_k, slope_t=slope_t,
                       term_k=abs(slope_k) * spread, term_t=abs(slope_t) * spread, k0=zero.K, t0=zero.T,
                       reach=reach)


def with_rudder_delay(sf: SegmentFit, rec: NomotoRecord, channels: tuple[str, ...]) -> SegmentFit:
    """A lone first-order zig-zag's segment fit with K and T read at the rudder delay fitted with them, and the
    delay's error as the ``RUDDER_DELAY_TERM`` notes of K and T (``sf`` unchanged where it does not apply or
    the refits fail).

    Parameters
    ----------
    sf : SegmentFit
        The zig-zag's segment fit (first order: no ``T3``; the rudder a measured angle: no ``t_servo``).
    rec : NomotoRecord
        Its record (the rudder as it drives the model).
    channels : tuple of str
        Outputs fitted.
    """
    if not (sf.success and sf.segment.kind == "zigzag" and "T3" not in sf.params and "t_servo" not in sf.params
            and "K" in sf.params and "T" in sf.params):
        return sf
    noise = "waves" if sf.model == "nomoto_pem" else "white"
    try:
        rd = fit_rudder_delay(rec, channels, noise)
    except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError):
        return sf
    if rd is None:
        return sf
    f = rd.fit
    params, stderr = dict(sf.params), dict(sf.stderr)
    for name in ("K", "T", "b"):
        if name in f.names and name in params:
            params[name] = f.value(name)
            stderr[name] = f.reported_error(name)
    slopes = (f"K {rd.slope_k / rd.k0:+.3g} and T {rd.slope_t / rd.t0:+.3g} of their values per second of delay: a "
              f"zig-zag never settles, so K and T are read together from its transients and a delay moves both")
    if rd.fixed:
        how = (f"a rudder-to-heading delay d = {rd.delay:+.3g} +- {rd.se_delay:.2g} s fitted with K and T (the "
               f"zig-zag refitted with its rudder shifted, -2 log L minimised over d within +-{rd.reach:.2g} s, its "
               f"curvature the delay's error), K and T read at it (K {rd.k0:.5g} -> {f.K:.5g} 1/s, T {rd.t0:.4g} -> "
               f"{f.T:.4g} s from zero delay), {slopes}")
    else:
        how = (f"the record does not fix a rudder-to-heading delay within +-{rd.reach:.2g} s (its -2 log L has no "
               f"minimum inside): K and T at zero delay, the term the slope times that reach, {slopes}")
    notes = [f"{RUDDER_DELAY_TERM} K: +-{rd.term_k:.6g} 1/s added in quadrature to its standard error: {how}",
             f"{RUDDER_DELAY_TERM} T: +-{rd.term_t:.6g} s added in quadrature to its standard error: {how}"]
    return replace(sf, params=params, stderr=stderr, message="; ".join([sf.message] + notes) if sf.message
                   else "; ".join(notes))
