"""Nomoto ship models, written once (Nomoto et al. 1957; Norrbin 1963; Fossen 2021, sec. 7.2).

First order (and Norrbin's nonlinear form)::

    psi_dot = r
    r_dot   = (-r - n3 r^3 - d2 |r| r + K (delta - b)) / T

so that psi/delta = K / (s (T s + 1)) with positive rudder giving positive yaw rate. ``b`` is a
rudder bias [rad]: the rudder angle that cancels a constant yaw disturbance (current, wind,
thrust asymmetry), as in the ship-autopilot seed's Kalman model. ``n3`` [s^2/rad^2] is Norrbin's
cubic term (``T r_dot + r + n3 r^3 = K delta``); ``d2`` the ``|r| r`` damping the simulator can
switch on.

Second order: ``r / (delta - b) = K (1 + T3 s) / ((1 + T1 s)(1 + T2 s))`` (:func:`nomoto2_rhs`),
whose first-order equivalent has ``T = T1 + T2 - T3``.

The heading model the Kalman filter and the prediction-error fit share (the ship-autopilot seed's
eq. 1: wave states, Nomoto, rudder bias as a random walk) is :func:`heading_model_matrices`; the
rudder servo (first-order lag with a rate limit) is :func:`servo_response`.

Speed-scaled Nomoto (Nomoto's scaling ``K = K' u / L``, ``T = T' L / u``, Fossen 2021, sec. 7.2, applied
on a speed ``u(t)`` that changes during the record)::

    T0 (U0 / u) r_dot + r = K0 (u / U0) (delta - b)

is the constant-coefficient model at the reference speed ``U0`` in the distance-sailed time
``tau = integral of u / U0 dt`` (:func:`distance_time`), for the rate per distance ``r U0 / u``:
``dpsi/dtau = r U0 / u`` and ``T0 d(r U0/u)/dtau + r U0/u = K0 (delta - b)`` up to the term
``T0 (r U0 / u) (du/dtau) / u`` of a speed that changes within the time constant. A linear
manoeuvring model whose damping scales with the speed and whose rudder force with its square
(Clarke et al. 1983, as in PythonVehicleSimulator's Clarke83 ship) is, in ``tau``, the model at
``U0`` for any order, so each time constant scales with ``U0 / u`` and the gain with ``u / U0``.

References
----------
Nomoto, K., Taguchi, T., Honda, K., Hirano, S. (1957). On the steering qualities of ships.
International Shipbuilding Progress 4, 354-370.
Norrbin, N. H. (1963). On the design and analysis of the zig-zag test on base of quasi-linear
frequency response. SSPA Report B104-3.
Fossen, T. I. (2021). Handbook of Marine Craft Hydrodynamics and Motion Control, 2nd ed., Wiley.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.signal

from ._backend import ops
from .waves import WaveParams, wave_matrices

NOMOTO_STATES = ("psi", "r")
NOMOTO_INPUTS = ("delta",)
#: States of the second-order model (:func:`nomoto2_rhs`).
NOMOTO2_STATES = ("psi", "r", "x2")
#: States of the augmented heading model (:func:`heading_model_matrices`).
HEADING_MODEL_STATES = ("xi_w", "psi_w", "psi", "r", "b")
#: Dynamic parameter names per model order.
#: Order 3 is the second-order model written with ``T12 = T1 + T2`` [s] and ``T1T2 = T1 T2`` [s^2]
#: (both positive for a stable ship), which also holds complex pole pairs (Clarke83-type ships).
NOMOTO_ORDER_PARAMS = {1: ("K", "T"), 2: ("K", "T1", "T2", "T3"), 3: ("K", "T12", "T1T2", "T3")}
#: The order key of the sum/product form of the second-order model.
ORDER2_SUM_PRODUCT = 3


@dataclass(frozen=True)
class NomotoParams:
    """Parameters of :func:`nomoto_rhs`.

    Attributes
    ----------
    K : float
        Gain [1/s]: steady yaw rate per rudder angle.
    T : float
        Time constant [s].
    b : float
        Rudder bias [rad].
    d2 : float
        Quadratic yaw damping [s/rad]: adds ``-d2 |r| r`` to the numerator (zero for the
        linear Nomoto model; used by the simulator's nonlinear-damping effect).
    n3 : float
        Norrbin's cubic yaw damping [s^2/rad^2]: adds ``-n3 r^3`` to the numerator.
    """

    K: float
    T: float
    b: float = 0.0
    d2: float = 0.0
    n3: float = 0.0


def nomoto_rhs(t, x, u, params: NomotoParams):
    """Right-hand side of the first-order Nomoto model.

    Parameters
    ----------
    t : float
        Time [s] (unused; the model is time-invariant).
    x : array_like, shape (2,)
        State ``[psi, r]`` [rad, rad/s].
    u : array_like, shape (1,)
        Input ``[delta]`` [rad].
    params : NomotoParams
        K [1/s], T [s], b [rad], d2 [s/rad], n3 [s^2/rad^2].

    Returns
    -------
    array_like, shape (2,)
        ``[psi_dot, r_dot]`` [rad/s, rad/s^2].
    """
    o = ops(x)
    r = x[1]
    damping = r + params.d2 * o.fabs(r) * r + params.n3 * r * r * r
    return o.stack([r, (-damping + params.K * (u[0] - params.b)) / params.T])


def nomoto_ship_rhs(t, x, u, params):
    """First-order Nomoto yaw dynamics plus the track of a ship at constant speed through the water.

    Parameters
    ----------
    t : float
        Time [s] (unused; time-invariant).
    x : array_like, shape (4,)
        ``[psi, r, x_n, y_e]`` [rad, rad/s, m, m].
    u : array_like, shape (1,)
        ``[delta]`` [rad].
    params : tuple
        ``(NomotoParams, speed [m/s], current [m/s] north and east)``.

    Returns
    -------
    array_like, shape (4,)
        State derivative.
    """
    nomoto, speed, current = params
    o = ops(x)
    psi_r = nomoto_rhs(t, x[:2], u, nomoto)
    return o.stack([psi_r[0], psi_r[1], speed * o.cos(x[0]) + current[0], speed * o.sin(x[0]) + current[1]])


@dataclass(frozen=True)
class Nomoto2Params:
    """Parameters of :func:`nomoto2_rhs` (second-order Nomoto model).

    Attributes
    ----------
    K : float
        Gain [1/s].
    T1, T2 : float
        Time constants of the poles [s] (``T1 >= T2`` by convention).
    T3 : float
        Time constant of the zero [s].
    b : float
        Rudder bias [rad].
    """

    K: float
    T1: float
    T2: float
    T3: float
    b: float = 0.0

    @property
    def T_equivalent(self) -> float:
        """First-order equivalent time constant ``T1 + T2 - T3`` [s] (Fossen 2021, eq. 7.41)."""
        return self.T1 + self.T2 - self.T3


def nomoto2_coefficients(K: float, T1: float, T2: float, T3: float) -> tuple[float, float, float, float]:
    """``(a1, a0, b1, b0)`` of ``r (s^2 + a1 s + a0) = (b1 s + b0)(delta - b)``.

    Parameters
    ----------
    K : float
        Gain [1/s].
    T1, T2, T3 : float
        Pole and zero time constants [s].

    Returns
    -------
    tuple of float
        ``a1 = (T1 + T2)/(T1 T2)`` [1/s], ``a0 = 1/(T1 T2)`` [1/s^2], ``b1 = K T3/(T1 T2)`` [1/s],
        ``b0 = K/(T1 T2)`` [1/s^2].
    """
    a1 = (T1 + T2) / (T1 * T2)
    a0 = 1.0 / (T1 * T2)
    return a1, a0, K * T3 / (T1 * T2), K / (T1 * T2)


def nomoto2_rhs(t, x, u, params: Nomoto2Params):
    """Right-hand side ``f(t, x, u, params)`` of the second-order Nomoto model.

    Observable canonical form of ``r/(delta - b) = K (1 + T3 s) / ((1 + T1 s)(1 + T2 s))``::

        psi_dot = r
        r_dot   = -a1 r + x2 + b1 (delta - b)
        x2_dot  = -a0 r + b0 (delta - b)

    with the coefficients of :func:`nomoto2_coefficients`.

    Parameters
    ----------
    t : float
        Time [s] (unused; time-invariant).
    x : array_like, shape (3,)
        ``[psi, r, x2]`` [rad, rad/s, rad/s^2]; ``x2 = r_dot + a1 r - b1 (delta - b)``.
    u : array_like, shape (1,)
        ``[delta]`` [rad].
    params : Nomoto2Params
        K [1/s], T1, T2, T3 [s], b [rad].

    Returns
    -------
    array_like, shape (3,)
        ``[psi_dot, r_dot, x2_dot]``.
    """
    o = ops(x)
    a1, a0, b1, b0 = nomoto2_coefficients(params.K, params.T1, params.T2, params.T3)
    v = u[0] - params.b
    return o.stack([x[1], -a1 * x[1] + x[2] + b1 * v, -a0 * x[1] + b0 * v])


def nomoto2_sum_product(K: float, T12: float, T1T2: float, T3: float) -> tuple[float, float, float, float]:
    """``(a1, a0, b1, b0)`` of the second-order model from ``T12 = T1 + T2`` and ``T1T2 = T1 T2``.

    Parameters
    ----------
    K : float
        Gain [1/s].
    T12 : float
        Sum of the pole time constants [s].
    T1T2 : float
        Their product [s^2] (complex poles when ``T12^2 < 4 T1T2``).
    T3 : float
        Zero time constant [s].

    Returns
    -------
    tuple of float
        As :func:`nomoto2_coefficients`.
    """
    return T12 / T1T2, 1.0 / T1T2, K * T3 / T1T2, K / T1T2


def pole_time_constants(T12: float, T1T2: float) -> tuple[float, float] | None:
    """``(T1, T2)`` with ``T1 >= T2`` from their sum and product; None for a complex pair.

    Parameters
    ----------
    T12 : float
        ``T1 + T2`` [s].
    T1T2 : float
        ``T1 T2`` [s^2].
    """
    disc = T12 * T12 - 4.0 * T1T2
    if disc < 0:
        return None
    root = math.sqrt(disc)
    return 0.5 * (T12 + root), 0.5 * (T12 - root)


def nomoto_matrices(order: int, dyn: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Continuous ``(A, B)`` of the linear Nomoto model for the input ``delta - b``; state 0 is psi.

    The same system as :func:`nomoto_rhs` (``n3 = d2 = 0``) or :func:`nomoto2_rhs`.

    Parameters
    ----------
    order : int
        1 (``dyn = (K, T)``, states ``[psi, r]``), 2 (``dyn = (K, T1, T2, T3)``, states
        ``NOMOTO2_STATES``) or 3 (``dyn = (K, T12, T1T2, T3)``, the same states).
    dyn : sequence of float
        Dynamic parameters [1/s, s, ...].

    Returns
    -------
    a, b : numpy.ndarray
        ``(n, n)`` and ``(n, 1)``.
    """
    if order == 1:
        K, T = dyn
        return np.array([[0.0, 1.0], [0.0, -1.0 / T]]), np.array([[0.0], [K / T]])
    if order in (2, ORDER2_SUM_PRODUCT):
        a1, a0, b1, b0 = nomoto2_coefficients(*dyn) if order == 2 else nomoto2_sum_product(*dyn)
        a = np.array([[0.0, 1.0, 0.0], [0.0, -a1, 1.0], [0.0, -a0, 0.0]])
        return a, np.array([[0.0], [b1], [b0]])
    raise ValueError(f"Nomoto model order: expected 1, 2 or 3, found {order!r}")


def distance_time(t: np.ndarray, u: np.ndarray, u_ref: float) -> np.ndarray:
    """Distance-sailed time ``tau = t0 + integral of u / u_ref dt`` (trapezoid) of the speed-scaled Nomoto model.

    Parameters
    ----------
    t : numpy.ndarray, shape (N,)
        Sample times [s], increasing.
    u : numpy.ndarray, shape (N,)
        Speed through the water at the samples [m/s], positive and finite.
    u_ref : float
        Reference speed ``U0`` [m/s] (the straight-run speed of the model's K0 and T0).

    Returns
    -------
    numpy.ndarray, shape (N,)
        ``tau`` [s], ``tau[0] = t[0]``; equal to ``t`` where ``u = u_ref`` throughout.

    Raises
    ------
    ValueError
        Shapes differ, times not increasing, a speed not positive and finite, or ``u_ref`` not positive.
    """
    t = np.asarray(t, float)
    u = np.asarray(u, float)
    if t.shape != u.shape or t.ndim != 1:
        raise ValueError(f"error: distance time: expected t and u of one shape, found {t.shape} and {u.shape}")
    if not (math.isfinite(u_ref) and u_ref > 0):
        raise ValueError(f"error: distance time: expected a positive reference speed [m/s], found {u_ref!r}")
    if not np.all(np.isfinite(u) & (u > 0)):
        raise ValueError("error: distance time: expected positive finite speeds [m/s], found "
                         f"{int((~(np.isfinite(u) & (u > 0))).sum())} others")
    if t.size > 1 and not np.all(np.diff(t) > 0):
        raise ValueError("error: distance time: expected increasing sample times")
    s = u / u_ref
    tau = np.empty_like(t)
    if t.size:
        tau[0] = t[0]
        tau[1:] = t[0] + np.cumsum(0.5 * (s[1:] + s[:-1]) * np.diff(t))
    return tau


def rudder_secant_factor(delta_before, delta_after, a: float):
    """Gain of a rudder step relative to ``K0`` under the rudder-amplitude model ``K(delta) = K0 (1 + a delta^2)``.

    The rudder's effect on the steady turn rate is written as a general odd expansion (a Taylor series,
    not any one ship's law)::

        r_ss = K0 f(delta),    f(delta) = delta (1 + a delta^2) + O(delta^5)

    so the steady gain at a held angle is ``K0 (1 + a delta^2)`` and ``K0`` is the linearisation
    (``delta -> 0``). A step from ``delta_before`` to ``delta_after`` changes the steady turn rate by
    ``K0 (f(d2) - f(d1))``, its secant gain ``K0 (1 + a (d1^2 + d1 d2 + d2^2))``: a step into a turn, the
    step back out of it and a reversal ``d -> -d`` all read ``1 + a d^2``. A rudder force that goes with
    ``sin 2 delta`` (PythonVehicleSimulator's Clarke83 ship) has ``a = -2/3``; a speed that settles at
    a level set by the rudder angle (a ship slowing in its turns) adds its own even term.

    Parameters
    ----------
    delta_before, delta_after : float or numpy.ndarray
        Rudder angles held before and after the step [rad].
    a : float
        Curvature of the gain [1/rad^2].

    Returns
    -------
    float or numpy.ndarray
        ``1 + a (d1^2 + d1 d2 + d2^2)`` [-].
    """
    return 1.0 + a * step_amplitude_sq(delta_before, delta_after)


def step_amplitude_sq(delta_before, delta_after):
    """The squared amplitude ``d1^2 + d1 d2 + d2^2`` [rad^2] a rudder step's secant gain is linear in
    (:func:`rudder_secant_factor`).

    Parameters
    ----------
    delta_before, delta_after : float or numpy.ndarray
        Rudder angles held before and after the step [rad].
    """
    d1 = np.asarray(delta_before, float)
    d2 = np.asarray(delta_after, float)
    out = d1 * d1 + d1 * d2 + d2 * d2
    return float(out) if out.ndim == 0 else out


def heading_model_matrices(K: float, T: float, waves: WaveParams
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(A, B, E, C)`` of the augmented heading model, states ``HEADING_MODEL_STATES``.

    The ship-autopilot seed's model (Fossen 2021, sec. 13.3)::

        xi_w_dot  = psi_w
        psi_w_dot = -omega_0^2 xi_w - 2 lambda omega_0 psi_w + K_w w_w
        psi_dot   = r
        r_dot     = (-r + K (delta - b)) / T
        b_dot     = w_b
        y         = psi + psi_w + v

    shared by the Kalman filter (:mod:`pipeline.autopilot.kalman`) and the prediction-error fit.

    Parameters
    ----------
    K : float
        Nomoto gain [1/s].
    T : float
        Nomoto time constant [s].
    waves : WaveParams
        Wave model (omega_0 [rad/s], lambda [-], K_w [rad s^-1/2]).

    Returns
    -------
    A : numpy.ndarray, shape (5, 5)
    B : numpy.ndarray, shape (5, 1)
        Rudder input [rad].
    E : numpy.ndarray, shape (5, 2)
        Noise inputs ``(w_w, w_b)``.
    C : numpy.ndarray, shape (1, 5)
        Compass ``y = psi + psi_w``.
    """
    aw, ew, _ = wave_matrices(waves)
    a = np.zeros((5, 5))
    a[:2, :2] = aw
    a[2, 3] = 1.0
    a[3, 3], a[3, 4] = -1.0 / T, -K / T
    b = np.zeros((5, 1))
    b[3, 0] = K / T
    e = np.zeros((5, 2))
    e[:2, 0] = ew[:, 0]
    e[4, 1] = 1.0
    c = np.array([[0.0, 1.0, 1.0, 0.0, 0.0]])
    return a, b, e, c


def servo_response(delta_c: np.ndarray, h: float, t_servo: float, rate_max: float = math.inf,
                   delta0: float | None = None, substeps: int = 40) -> np.ndarray:
    """Rudder angle of a servo following a held command: first-order lag with a rate limit.

    ``delta_dot = clip((delta_c - delta) / T_s, -rate_max, rate_max)`` (Fossen 2021, sec. 9.5;
    PythonVehicleSimulator's ships use this form), integrated with ``substeps`` Euler steps per
    sample. The value returned for interval ``k`` is the mean rudder angle over
    ``[t_k, t_k+1)``, so that a zero-order-hold simulation driven by it keeps the heading's
    increment right to second order.

    Parameters
    ----------
    delta_c : numpy.ndarray, shape (N,)
        Commanded rudder angle, held over each sample interval [rad].
    h : float
        Sample time [s].
    t_servo : float
        Servo time constant [s] (0 gives a pure rate limiter).
    rate_max : float
        Rate limit [rad/s] (``inf``: none).
    delta0 : float, optional
        Rudder angle at the first sample [rad]; the first command by default.
    substeps : int
        Integration steps per sample.

    Returns
    -------
    numpy.ndarray, shape (N,)
        Mean servo angle over each sample interval [rad].
    """
    u = np.asarray(delta_c, float)
    d = float(u[0] if delta0 is None else delta0)
    lim = rate_max if rate_max > 0 else math.inf
    if t_servo > 0:
        # Without the rate limit the lag is linear: exact per sample, d[k+1] = a d[k] + (1 - a) u[k].
        a = math.exp(-h / t_servo)
        start = np.empty(u.size)
        start[0] = d
        if u.size > 1:
            zi = np.array([a * d])
            start[1:] = scipy.signal.lfilter([1.0 - a], [1.0, -a], u[:-1], zi=zi)[0]
        if not np.isfinite(lim) or float(np.max(np.abs(u - start))) <= lim * t_servo:
            return u + (start - u) * (t_servo / h) * (1.0 - a)
    dt = h / substeps
    # A lag shorter than the Euler step would overshoot: below 2 dt the rate limit alone acts.
    lag = t_servo if t_servo > 2 * dt else 0.0
    # The rate limit makes the recursion nonlinear, so it cannot be a linear filter; it runs as a
    # casadi ``mapaccum`` of one sample's ``substeps`` Euler steps (compiled graph, chunks of
    # ``_SERVO_CHUNK`` samples) with the same operations in the same order as the scalar loop
    # ``err = u_k - d; rate = err / lag`` (or ``err / dt`` inside the limit, else
    # ``copysign(lim, err)``); ``rate = min(max(rate, -lim), lim); d += dt rate``; the interval mean is
    # the trapezoid sum over the sub-steps divided by ``substeps`` -- bit-identical to that loop
    # (tests/test_servo_response.py) and about 60 times faster.
    step = _servo_accumulator(int(substeps))
    out = np.empty(u.size)
    n = _SERVO_CHUNK
    for k0 in range(0, u.size, n):
        uk = u[k0: k0 + n]
        par = np.empty((4, n))
        par[0, : uk.size] = uk
        par[0, uk.size:] = uk[-1]
        par[1], par[2], par[3] = lag, lim, dt
        ds, means = step(d, par)
        out[k0: k0 + uk.size] = np.asarray(means).ravel()[: uk.size]
        d = float(np.asarray(ds).ravel()[uk.size - 1])
    return out


#: Samples per call of the compiled servo recursion (:func:`servo_response`).
_SERVO_CHUNK = 4096


@functools.lru_cache(maxsize=8)
def _servo_accumulator(substeps: int):
    """casadi function: (rudder angle [rad], 4 x chunk of (command, lag, rate limit, Euler step)) ->
    (rudder angle after each sample, mean rudder angle over each sample) [rad]."""
    import casadi as ca

    d0, uk, lag, lim, dt = (ca.SX.sym(n) for n in ("d", "u", "lag", "lim", "dt"))
    d, acc = d0, 0.0
    for _ in range(substeps):
        err = uk - d
        limited = ca.if_else(ca.fabs(err) < lim * dt, err / dt, ca.copysign(lim, err))
        rate = ca.if_else(lag != 0, err / lag, limited)
        rate = ca.fmin(ca.fmax(rate, -lim), lim)
        d_new = d + dt * rate
        acc = acc + 0.5 * (d + d_new)
        d = d_new
    one = ca.Function("servo_sample", [d0, ca.vertcat(uk, lag, lim, dt)], [d, acc / substeps])
    return one.mapaccum("servo_chunk", _SERVO_CHUNK)
