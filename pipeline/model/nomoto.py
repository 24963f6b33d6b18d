"""First-order Nomoto ship model (Nomoto et al. 1957; Fossen 2021, sec. 7.2).

    psi_dot = r
    r_dot   = (-r + K (delta - b)) / T

so that psi/delta = K / (s (T s + 1)) with positive rudder giving positive yaw rate. ``b`` is a
rudder bias [rad]: the rudder angle that cancels a constant yaw disturbance (current, wind,
thrust asymmetry), as in the ship-autopilot seed's Kalman model. An optional ``|r| r`` term gives
the nonlinear (Norrbin-type) yaw damping the simulator can switch on.
"""

from __future__ import annotations

from dataclasses import dataclass

from ._backend import ops

NOMOTO_STATES = ("psi", "r")
NOMOTO_INPUTS = ("delta",)


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
    """

    K: float
    T: float
    b: float = 0.0
    d2: float = 0.0


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
        K [1/s], T [s], b [rad].

    Returns
    -------
    array_like, shape (2,)
        ``[psi_dot, r_dot]`` [rad/s, rad/s^2].
    """
    o = ops(x)
    r = x[1]
    return o.stack([r, (-r - params.d2 * o.fabs(r) * r + params.K * (u[0] - params.b)) / params.T])
