"""Linear 5-DOF vessel model (u, v, p, q, r) with kinematics, after Fossen (2021, ch. 6-7).

    M nu_dot + D nu + D2 |nu| nu + G eta = tau          nu  = [u, v, p, q, r]
    x_n_dot = u cos psi - v sin psi + V_c,n             eta = [x_n, y_e, phi, theta, psi]
    y_e_dot = u sin psi + v cos psi + V_c,e
    phi_dot, theta_dot, psi_dot from the Euler-angle rates of p, q, r

``nu`` is the velocity relative to the water; a constant current (V_c,n, V_c,e) [m/s] only moves
the vessel over ground. ``D2`` holds optional |x|x damping per DOF (zero for the linear model).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..vessel import Vessel
from ._backend import is_symbolic, ops

STATES_5DOF = ("u", "v", "p", "q", "r", "x_n", "y_e", "phi", "theta", "psi")
INPUTS_5DOF = ("tau_x", "tau_y", "tau_k", "tau_m", "tau_n")


@dataclass(frozen=True)
class Vessel5DofParams:
    """Parameters of :func:`vessel5dof_rhs`.

    Attributes
    ----------
    M : numpy.ndarray, shape (5, 5)
        Mass matrix M_RB + M_A [SI].
    D : numpy.ndarray, shape (5, 5)
        Linear damping, positive definite [SI].
    G : numpy.ndarray, shape (5, 5)
        Restoring on (phi, theta) in DOF order (only [2,2] and [3,3] non-zero) [N m/rad].
    D2 : numpy.ndarray, shape (5,)
        |x|x damping per DOF [SI]; zero for the linear model.
    current : numpy.ndarray, shape (2,)
        Water current over ground, north and east [m/s].
    """

    M: np.ndarray
    D: np.ndarray
    G: np.ndarray
    D2: np.ndarray = field(default_factory=lambda: np.zeros(5))
    current: np.ndarray = field(default_factory=lambda: np.zeros(2))

    Minv: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        # M^-1 is needed at every right-hand-side call; computed once here.
        object.__setattr__(self, "Minv", np.linalg.inv(np.asarray(self.M, float)))


def params_from_vessel(vessel: Vessel, D: np.ndarray | None = None) -> Vessel5DofParams:
    """Model parameters from a vessel config (its [damping] section unless ``D`` is given).

    Parameters
    ----------
    vessel : Vessel
        Config with rigid-body data.
    D : numpy.ndarray, optional
        Damping to use instead of the config's [SI].
    """
    from ..errors import ConfigError

    damping = vessel.damping if D is None else np.asarray(D, float)
    if damping is None:
        raise ConfigError(f"{vessel.name}: expected a [damping] matrix or diagonal to simulate, found none")
    d2 = vessel.quadratic_damping if vessel.quadratic_damping is not None else np.zeros(5)
    return Vessel5DofParams(M=vessel.mass_matrix(), D=damping, G=vessel.restoring_matrix(), D2=d2)


def vessel5dof_rhs(t, x, u, params: Vessel5DofParams):
    """Right-hand side of the 5-DOF model.

    Parameters
    ----------
    t : float
        Time [s] (unused; time-invariant).
    x : array_like, shape (10,)
        ``[u, v, p, q, r, x_n, y_e, phi, theta, psi]`` [m/s, rad/s, m, rad].
    u : array_like, shape (5,)
        ``[tau_x, tau_y, tau_k, tau_m, tau_n]`` [N, N m].
    params : Vessel5DofParams
        Model matrices.

    Returns
    -------
    array_like, shape (10,)
        State derivative.
    """
    if not is_symbolic(x):
        return _rhs_numeric(x, u, params)
    o = ops(x)
    nu = [x[i] for i in range(5)]
    phi, theta, psi = x[7], x[8], x[9]
    eta_rest = [0.0, 0.0, phi, theta, 0.0]
    minv = params.Minv
    force = []
    for i in range(5):
        f_i = u[i] - params.D2[i] * o.fabs(nu[i]) * nu[i]
        for j in range(5):
            if params.D[i, j] != 0.0:
                f_i = f_i - params.D[i, j] * nu[j]
            if params.G[i, j] != 0.0:
                f_i = f_i - params.G[i, j] * eta_rest[j]
        force.append(f_i)
    nu_dot = []
    for i in range(5):
        acc = 0.0
        for j in range(5):
            if minv[i, j] != 0.0:
                acc = acc + minv[i, j] * force[j]
        nu_dot.append(acc)
    uu, vv, p, q, r = nu
    cpsi, spsi = o.cos(psi), o.sin(psi)
    cphi, sphi = o.cos(phi), o.sin(phi)
    ctheta = o.cos(theta)
    x_n_dot = uu * cpsi - vv * spsi + params.current[0]
    y_e_dot = uu * spsi + vv * cpsi + params.current[1]
    phi_dot = p + (q * sphi + r * cphi) * o.tan(theta)
    theta_dot = q * cphi - r * sphi
    psi_dot = (q * sphi + r * cphi) / ctheta
    return o.stack(nu_dot + [x_n_dot, y_e_dot, phi_dot, theta_dot, psi_dot])


def _rhs_numeric(x, u, params: Vessel5DofParams) -> np.ndarray:
    """Vectorised numpy form of :func:`vessel5dof_rhs` (same equations)."""
    x = np.asarray(x, float)
    nu = x[:5]
    phi, theta, psi = x[7], x[8], x[9]
    eta_rest = np.array([0.0, 0.0, phi, theta, 0.0])
    force = np.asarray(u, float) - params.D @ nu - params.D2 * np.abs(nu) * nu - params.G @ eta_rest
    out = np.empty(10)
    out[:5] = params.Minv @ force
    uu, vv, p, q, r = nu
    cpsi, spsi = np.cos(psi), np.sin(psi)
    cphi, sphi = np.cos(phi), np.sin(phi)
    out[5] = uu * cpsi - vv * spsi + params.current[0]
    out[6] = uu * spsi + vv * cpsi + params.current[1]
    out[7] = p + (q * sphi + r * cphi) * np.tan(theta)
    out[8] = q * cphi - r * sphi
    out[9] = (q * sphi + r * cphi) / np.cos(theta)
    return out
