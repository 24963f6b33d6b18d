"""5-DOF vessel model (u, v, p, q, r) with linear and optional |x|x damping and kinematics (Fossen 2021, ch. 6-7).

    M nu_dot + D nu + D2 |nu| nu + G eta = tau          nu  = [u, v, p, q, r]
    x_n_dot = u cos psi - v sin psi + V_c,n             eta = [x_n, y_e, phi, theta, psi]
    y_e_dot = u sin psi + v cos psi + V_c,e
    phi_dot, theta_dot, psi_dot from the Euler-angle rates of p, q, r

``nu`` is the velocity relative to the water; a constant current (V_c,n, V_c,e) [m/s] only moves
the vessel over ground. ``D2`` holds optional |x|x damping per DOF (zero for the linear model).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

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


def params_from_vessel(vessel: Vessel, D: np.ndarray | None = None, D2: np.ndarray | None = None) -> Vessel5DofParams:
    """Model parameters from a vessel config (its [damping] section unless ``D`` / ``D2`` are given).

    An identified model runs in the simulator by passing the fit's damping matrix and quadratic
    damping (``coefficients.json`` ``damping_matrix`` and ``quadratic_damping``) here.

    Parameters
    ----------
    vessel : Vessel
        Config with rigid-body data.
    D : numpy.ndarray, optional
        Damping to use instead of the config's [SI].
    D2 : numpy.ndarray, optional
        |x|x damping per DOF (u v p q r) to use instead of the config's [SI].
    """
    from ..errors import ConfigError

    damping = vessel.damping if D is None else np.asarray(D, float)
    if damping is None:
        raise ConfigError(f"{vessel.name}: expected a [damping] matrix or diagonal to simulate, found none")
    d2 = vessel.quadratic_damping if vessel.quadratic_damping is not None else np.zeros(5)
    if D2 is not None:
        d2 = np.nan_to_num(np.asarray(D2, float))
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


def dof_rhs(nu, eta, force, a, b, c=0.0):
    """One DOF of :func:`vessel5dof_rhs` divided by its inertia (numpy arrays or casadi symbols).

    ``M_ii nu_dot + D_ii nu + D2_i |nu| nu + G_ii eta = tau_i`` divided by ``M_ii``::

        nu_dot  = -a nu - b |nu| nu - c eta + f      a = D_ii/M_ii, b = D2_i/M_ii, c = G_ii/M_ii, f = tau_i/M_ii
        eta_dot = nu                                  (roll and pitch, small angles)

    Parameters
    ----------
    nu : array_like or casadi.SX
        Velocity [m/s or rad/s] (any shape, elementwise).
    eta : array_like or casadi.SX or None
        Angle about the restoring equilibrium [rad]; None for a first-order DOF (surge, sway, yaw).
    force : array_like or casadi.SX
        Generalised force over inertia ``f`` [m/s^2 or rad/s^2].
    a : float
        Linear damping over inertia [1/s].
    b : float
        Quadratic damping over inertia [1/m or 1/rad].
    c : float
        Restoring over inertia [1/s^2].

    Returns
    -------
    tuple
        ``(nu_dot, eta_dot)``; ``eta_dot`` is None for a first-order DOF.
    """
    o = ops(nu)
    nu_dot = force - (a + b * o.fabs(nu)) * nu
    if eta is None:
        return nu_dot, None
    return nu_dot - c * eta, nu


@lru_cache(maxsize=32)
def _dof_stepper(k: int, second: bool, substeps: int, n_steps: int):
    """Casadi function ``(x0, F, P) -> X``: ``n_steps`` samples of RK4 on :func:`dof_rhs` for ``k`` records.

    Compiled once per shape: the per-sample loop runs in casadi's virtual machine instead of the
    Python interpreter (two orders of magnitude faster for the fits that simulate it hundreds of times).
    The accumulated map is not expanded into one SX graph: that graph grows with the sample count
    (2.7 M nodes, 1.7 s and about 240 MB for 8 records x 3000 samples, kept per shape by the cache),
    while the mapped one-step function evaluates at the same speed in constant memory.
    """
    import casadi as ca

    nu = ca.SX.sym("nu", k)
    eta = ca.SX.sym("eta", k) if second else None
    f = ca.SX.sym("f", k)
    prm = ca.SX.sym("p", 4)  # a, b, c, h
    a, b, c, h = prm[0], prm[1], prm[2], prm[3]
    x, e = nu, eta
    for _ in range(substeps):
        k1, l1 = dof_rhs(x, e, f, a, b, c)
        k2, l2 = dof_rhs(x + 0.5 * h * k1, None if e is None else e + 0.5 * h * l1, f, a, b, c)
        k3, l3 = dof_rhs(x + 0.5 * h * k2, None if e is None else e + 0.5 * h * l2, f, a, b, c)
        k4, l4 = dof_rhs(x + h * k3, None if e is None else e + h * l3, f, a, b, c)
        if e is not None:
            e = e + (h / 6.0) * (l1 + 2 * l2 + 2 * l3 + l4)
        x = x + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
    state = nu if eta is None else ca.vertcat(nu, eta)
    nxt = x if eta is None else ca.vertcat(x, e)
    step = ca.Function("dof_step", [state, f, prm], [nxt])
    return step.mapaccum("dof_sim", n_steps)


def simulate_dof(x0: np.ndarray, force: np.ndarray, dt: float, a: float, b: float, c: float = 0.0,
                 substeps: int = 2) -> np.ndarray:
    """Integrate :func:`dof_rhs` for ``k`` records on a common uniform grid (RK4, force held per sample).

    Parameters
    ----------
    x0 : numpy.ndarray, shape (k,) or (k, 2)
        Initial ``nu`` (and, second column, ``eta``).
    force : numpy.ndarray, shape (k, n)
        Force over inertia per sample, held until the next sample (zero-order hold) [m/s^2 or rad/s^2].
    dt : float
        Sample interval [s].
    a, b, c : float
        See :func:`dof_rhs`.
    substeps : int
        RK4 steps per sample.

    Returns
    -------
    numpy.ndarray, shape (k, n) or (k, n, 2)
        States at the sample times (the first is ``x0``); non-finite once a record diverges.
    """
    x0 = np.asarray(x0, float)
    k, n = force.shape
    second = x0.ndim == 2
    out = np.empty((k, n) + ((2,) if second else ()))
    state0 = x0.T.ravel() if second else x0
    if second:
        out[:, 0, 0], out[:, 0, 1] = x0[:, 0], x0[:, 1]
    else:
        out[:, 0] = x0
    if n < 2:
        return out
    sim = _dof_stepper(k, second, int(substeps), n - 1)
    prm = np.tile(np.array([[a], [b], [c], [dt / substeps]]), (1, n - 1))
    xs = np.asarray(sim(state0, np.asarray(force[:, : n - 1], float), prm))
    if second:
        out[:, 1:, 0] = xs[:k]
        out[:, 1:, 1] = xs[k:]
    else:
        out[:, 1:] = xs
    return out
