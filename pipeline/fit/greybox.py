"""Grey-box fit of the coupled sway-roll-yaw damping: Y_r, N_v, K_v, K_r, Y_p, N_p and the diagonal.

The model is the project's own 5-DOF right-hand side :func:`pipeline.model.vessel5dof_rhs`
(``M nu_dot + D nu + G eta = tau``, Fossen 2021, ch. 6-7) with the state
``x = [v, p, q, r, phi, theta]``: surge is held at rest (with ``y_g = z_g = 0`` the rigid-body mass
matrix does not couple it to the others, and the linear model has no Coriolis terms); pitch is
carried with its damping and restoring held, because the Euler-angle kinematics
(``theta_dot = q cos phi - r sin phi``) pitch a heeled, turning hull and feed back into roll --
leaving it out biases ``K_p`` by several standard errors in a zig-zag. The unknown lateral
entries of ``D`` are casadi symbols; :func:`vessel5dof_rhs` keeps its numeric
``Vessel5DofParams`` and the unknown part enters through the generalised force,
``tau - D_theta nu``, so the equations fitted are exactly those simulated.

Estimation (Ljung 1999, ch. 7; Bock & Plitt 1984):

- fixed-step RK4 (zero-order-hold inputs, ``substeps`` per sample) as a casadi ``Function``,
  rolled out over the input sequence with ``Function.mapaccum`` (no ``cvodes``: casadi 3.8's
  integrator crashes when asked for output-grid derivatives);
- multiple shooting: a free state every ``shooting_interval`` seconds, continuity as a penalty
  residual that is tightened in a second solve, so long records and poor start values do not
  blow the simulation up;
- output error on ``v, p, q, r, phi, theta`` (those the trial has), each weighted by ``1/sigma``;
  sigma is first the second-difference noise level, then the residual RMS of a first solve;
- ``scipy.optimize.least_squares`` (trust-region reflective, LSMR) with casadi's exact sparse
  Jacobian, compiled to C by casadi's JIT when a compiler works; a weak prior about the start
  values (``PRIOR_SCALES`` scales wide) keeps the solver out of the flat valleys of a trial that
  does not excite some coupling, and is left out of the covariance;
- covariance and Fisher information from the single-shooting sensitivity at the estimate: the
  continuity Jacobian carries every node's sensitivity back to the record's initial state, and the
  initial states are eliminated as nuisance parameters (Schur complement). Coloured residuals
  (an interpolated GNSS velocity, say) inflate each channel's variance by its long-run variance
  ratio (Newey & West 1987).

Inputs: ``tau_y`` [N], ``tau_k``, ``tau_m``, ``tau_n`` [N m] as logged, plus the rudder ``delta``
[rad] through ``vessel.rudder['yaw_moment']`` [N m/rad] and ``['sway_force']`` [N/rad].
Which coefficients the fit determines is decided from its Fisher information by
:mod:`pipeline.fit.identifiability`; :func:`pipeline.fit.extend.extend_fits` runs both.

References
----------
Fossen, T. I. (2021). *Handbook of Marine Craft Hydrodynamics and Motion Control*, 2nd ed. Wiley.
Ljung, L. (1999). *System Identification: Theory for the User*, 2nd ed. Prentice Hall.
Bock, H. G. & Plitt, K. J. (1984). A multiple shooting algorithm for direct solution of optimal
control problems. *IFAC Proceedings* 17(2), 1603-1608.
Newey, W. K. & West, K. D. (1987). A simple, positive semi-definite, heteroskedasticity and
autocorrelation consistent covariance matrix. *Econometrica* 55(3), 703-708.
"""

from __future__ import annotations

import atexit
import math
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Mapping, Sequence

import numpy as np
from scipy import optimize, sparse

from ..errors import FitError
from ..model.vessel5dof import Vessel5DofParams, vessel5dof_rhs
from ..records import DOFS, Segment, Segments, Trial
from ..vessel import Vessel
from .data import noise_sigma, segment_label
from .residual_tests import ResidualTest, residual_test

#: Fossen name -> (row, column) of D in DOF order u v p q r; the derivative is ``-D[row, column]``.
COEFFICIENTS: Mapping[str, tuple[int, int]] = {
    "Y_v": (1, 1), "K_p": (2, 2), "N_r": (4, 4),
    "Y_r": (1, 4), "N_v": (4, 1), "K_v": (2, 1), "K_r": (2, 4), "Y_p": (1, 2), "N_p": (4, 2),
}
DIAGONAL = ("Y_v", "K_p", "N_r")
COUPLED = ("Y_r", "N_v", "K_v", "K_r", "Y_p", "N_p")
#: SI unit of each derivative: force or moment per velocity or angular rate.
UNITS: Mapping[str, str] = {
    "Y_v": "kg/s", "K_p": "kg m^2/s", "N_r": "kg m^2/s",
    "Y_r": "kg m/s", "N_v": "kg m/s", "K_v": "kg m/s", "K_r": "kg m^2/s", "Y_p": "kg m/s", "N_p": "kg m^2/s",
}
#: State of the grey-box model and the index of each in the 10-state 5-DOF vector. Pitch is carried
#: (its damping and restoring held) because the Euler-angle kinematics couple it to roll and yaw:
#: theta_dot = q cos(phi) - r sin(phi) grows in a heeled turn and feeds back into phi_dot.
STATES = ("v", "p", "q", "r", "phi", "theta")
_STATE_INDEX = (1, 2, 3, 4, 7, 8)
NX = len(STATES)
#: Segment kinds and DOFs whose records carry sway, roll or yaw motion under known inputs.
LATERAL_KINDS: Mapping[str, tuple[str, ...]] = {
    "zigzag": ("sway", "roll", "yaw"), "rudder_step": ("sway", "roll", "yaw"), "sinusoid": ("sway", "roll", "yaw"),
    "step": ("sway", "yaw"), "coast_down": ("sway", "yaw"), "free_decay": ("roll",),
}
#: Roll coefficients, fixed when the trial logs neither ``p`` nor ``phi``.
_ROLL = ("K_p", "K_v", "K_r", "Y_p", "N_p")
#: Continuity penalty weights of the two solves (a defect of one noise standard deviation of a state
#: costs as much as PENALTY^2 output samples one standard deviation off).
PENALTIES = (3.0, 300.0)
#: Standard deviation of the weak prior about the start values, in units of each coefficient's scale.
PRIOR_SCALES = 10.0
#: Largest RK4 step times the fastest eigenvalue magnitude (RK4 is accurate to ~1e-5 below 0.3).
MAX_H_LAMBDA = 0.3


@dataclass(frozen=True)
class GreyBoxRecord:
    """One time window of lateral motion (overlapping segments merged).

    Attributes
    ----------
    t : numpy.ndarray, shape (n,)
        Trial time [s] on the trial's uniform grid.
    y : numpy.ndarray, shape (n, len(outputs))
        Measured outputs [SI]; NaN where missing.
    tau : numpy.ndarray, shape (n, 5)
        Generalised force ``[tau_x, tau_y, tau_k, tau_m, tau_n]`` [N, N m] (surge zero), held over
        each sample interval.
    labels : tuple[str, ...]
        Segments merged into the window.
    """

    t: np.ndarray
    y: np.ndarray
    tau: np.ndarray
    labels: tuple[str, ...]


@dataclass(frozen=True)
class GreyBoxFit:
    """Result of :func:`fit_coupled_damping`.

    Attributes
    ----------
    names : tuple[str, ...]
        Coefficients estimated (Fossen names, ``COEFFICIENTS``).
    values, stderr : numpy.ndarray
        Estimates with Fossen's signs (``Y_r = -D[1, 4]``) and standard errors [``UNITS``]; stderr is
        ``inf`` along directions the data do not determine.
    covariance : numpy.ndarray
        ``s^2 F^-1`` of the values (pseudo-inverse on the determined subspace, ``inf`` diagonal where
        not determined).
    fisher : numpy.ndarray
        Fisher information ``J^T J / sigma^2`` of the values at the estimate, with the records'
        initial states eliminated (1/unit_i/unit_j).
    fixed : Mapping[str, str]
        Coefficients held fixed, with the reason.
    damping : numpy.ndarray, shape (5, 5)
        ``D`` with the lateral entries from the fit and the rest from the start matrix [SI].
    outputs : tuple[str, ...]
        Channels fitted.
    sigma : Mapping[str, float]
        Output noise standard deviation used as weight (residual RMS of the first solve) [SI].
    records : tuple[GreyBoxRecord, ...]
        Data windows.
    y_fit : tuple[numpy.ndarray, ...]
        Model outputs per record (the continuous simulation from each record's initial state).
    residual_tests : tuple[ResidualTest, ...]
        Whiteness and input cross-correlation per record and channel.
    s2 : float
        Weighted RSS over residual degrees of freedom (1 when the weights are the true noise).
    n : int
        Output samples used.
    converged : bool
        Both solves converged.
    max_defect : float
        Largest continuity defect at the estimate, in output-noise standard deviations.
    message : str
        Solver and data notes.
    method : str
        Model and solver description for the Estimate.
    elapsed : float
        Wall time [s].
    notes : tuple[str, ...]
        Start values filled in and other remarks.
    kappa : Mapping[str, float]
        Long-run variance ratio ``1 + 2 sum_k w_k rho_e(k)`` of each channel's residuals (1 for white
        residuals); the covariance uses ``sigma^2 kappa``.
    """

    names: tuple[str, ...]
    values: np.ndarray
    stderr: np.ndarray
    covariance: np.ndarray
    fisher: np.ndarray
    fixed: Mapping[str, str]
    damping: np.ndarray
    outputs: tuple[str, ...]
    sigma: Mapping[str, float]
    records: tuple[GreyBoxRecord, ...]
    y_fit: tuple[np.ndarray, ...]
    residual_tests: tuple[ResidualTest, ...]
    s2: float
    n: int
    converged: bool
    max_defect: float
    message: str
    method: str
    elapsed: float = math.nan
    notes: tuple[str, ...] = field(default_factory=tuple)
    kappa: Mapping[str, float] = field(default_factory=dict)

    def value(self, name: str) -> float:
        """Estimate of one coefficient (Fossen sign) [``UNITS[name]``].

        Parameters
        ----------
        name : str
            Coefficient name, one of ``names``.
        """
        return float(self.values[self.names.index(name)])


# --------------------------------------------------------------------------- data
def lateral_segments(segments: Segments, vessel: Vessel | None = None) -> tuple[Segment, ...]:
    """Segments with sway, roll or yaw motion under known inputs (``LATERAL_KINDS``).

    Parameters
    ----------
    segments : Segments
        All segments of a trial.
    vessel : Vessel, optional
        When given, segments driven by the rudder (``input_channel='delta'``) are left out unless
        the config maps the rudder to a force (``[rudder] yaw_moment`` or ``sway_force``): without
        the map the input is not known, and a zero force would be a wrong one.
    """
    mapped = vessel is None or bool(vessel.rudder.get("yaw_moment") or vessel.rudder.get("sway_force"))
    return tuple(s for s in segments.items if s.dof in LATERAL_KINDS.get(s.kind, ()) and s.t_end > s.t_start
                 and (mapped or s.input_channel != "delta"))


def generalised_force(trial: Trial, vessel: Vessel, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
    """Generalised force ``[0, tau_y, tau_k, tau_m, tau_n]`` [N, N m] from the trial's inputs.

    Logged ``tau_y``, ``tau_k``, ``tau_m``, ``tau_n`` are used as they are; the rudder ``delta`` [rad] adds
    ``yaw_moment * delta`` to ``tau_n`` and ``sway_force * delta`` to ``tau_y`` (vessel config
    ``[rudder]``). Missing samples are held from the previous one (zero before the first).

    Parameters
    ----------
    trial : Trial
        The trial.
    vessel : Vessel
        Rudder effectiveness.
    rows : slice or numpy.ndarray
        Rows of ``trial.data`` to use.

    Returns
    -------
    numpy.ndarray, shape (n, 5)
    """
    data = trial.data.iloc[rows] if isinstance(rows, slice) else trial.data.iloc[np.asarray(rows)]
    n = len(data)
    tau = np.zeros((n, 5))

    def held(ch: str) -> np.ndarray:
        if ch not in data.columns:
            return np.zeros(n)
        x = data[ch].to_numpy(dtype=float)
        ok = np.isfinite(x)
        if not ok.any():
            return np.zeros(n)
        idx = np.where(ok, np.arange(n), -1)
        idx = np.maximum.accumulate(idx)
        return np.where(idx >= 0, x[np.maximum(idx, 0)], 0.0)

    tau[:, 1] = held("tau_y")
    tau[:, 2] = held("tau_k")
    tau[:, 3] = held("tau_m")
    tau[:, 4] = held("tau_n")
    if "delta" in data.columns:
        delta = held("delta")
        tau[:, 4] += float(vessel.rudder.get("yaw_moment", 0.0)) * delta
        tau[:, 1] += float(vessel.rudder.get("sway_force", 0.0)) * delta
    return tau


def build_records(trial: Trial, segments: Sequence[Segment], vessel: Vessel,
                  merge_gap: float = 1.0) -> tuple[GreyBoxRecord, ...]:
    """Merge overlapping (or nearly touching) segment windows into records of trial samples.

    Parameters
    ----------
    trial : Trial
        The trial.
    segments : sequence of Segment
        Lateral segments (:func:`lateral_segments`).
    vessel : Vessel
        For the rudder map.
    merge_gap : float
        Windows closer than this are merged [s] (a step and the coast-down after it keep one
        continuous state); a free decay always starts a record of its own.

    Returns
    -------
    tuple[GreyBoxRecord, ...]
        In time order, split at the trial's gaps; pieces shorter than 10 samples are dropped.
        ``y`` has one column per ``STATES`` entry, NaN where the trial lacks the channel.
    """
    spans = sorted((s.t_start, s.t_end, segment_label(s), s.kind == "free_decay") for s in segments)
    merged: list[list] = []
    for a, b, label, release in spans:
        if merged and release and a <= merged[-1][1]:
            # A free decay starts from a hull pushed over by hand: an unknown input, so the state
            # jumps. The record before it ends there and the decay gets its own initial state.
            merged[-1][1] = min(merged[-1][1], a - 1e-9)
        if merged and not release and a <= merged[-1][1] + merge_gap:
            merged[-1][1] = max(merged[-1][1], b)
            merged[-1][2].append(label)
        else:
            merged.append([a, b, [label]])
    t_all = trial.t
    columns = [trial.data[c].to_numpy(dtype=float) if trial.has(c) else np.full(t_all.size, np.nan)
               for c in STATES]
    out = []
    for a, b, labels in merged:
        keep = (t_all >= a) & (t_all <= b)
        # A gap splits the record: the fixed-step rollout needs a uniform grid.
        for gap in trial.gaps:
            keep &= ~((t_all > gap.t_start) & (t_all < gap.t_end))
        rows = np.flatnonzero(keep)
        for piece in np.split(rows, np.flatnonzero(np.diff(rows) > 1) + 1):
            if piece.size < 10:
                continue
            y = np.column_stack([c[piece] for c in columns])
            out.append(GreyBoxRecord(t=t_all[piece], y=y, tau=generalised_force(trial, vessel, piece),
                                     labels=tuple(labels)))
    return tuple(out)


# --------------------------------------------------------------------------- model
def _assemble_full(xl, ca):
    """10-state 5-DOF vector from the lateral state (surge, pitch and positions at rest)."""
    zero = ca.SX(1, 1)
    full = [zero] * 10
    for k, i in enumerate(_STATE_INDEX):
        full[i] = xl[k]
    return ca.vertcat(*full)


def step_function(params: Vessel5DofParams, estimated: Sequence[str], h: float, substeps: int):
    """casadi ``Function`` ``(x[NX], tau[5], theta[k]) -> x_next[NX]``: RK4 over one sample interval.

    ``theta`` holds the positive-convention ``D`` entries of ``estimated`` (``D[i, j] = -derivative``);
    ``params.D`` must be zero at those entries.

    Parameters
    ----------
    params : Vessel5DofParams
        Known M, G and the fixed part of D.
    estimated : sequence of str
        Coefficient names in ``theta`` order.
    h : float
        Sample interval [s].
    substeps : int
        RK4 steps per interval.
    """
    import casadi as ca

    x = ca.SX.sym("x", len(STATES))
    tau = ca.SX.sym("tau", 5)
    theta = ca.SX.sym("theta", len(estimated))

    def f(xl):
        full = _assemble_full(xl, ca)
        nu = full[:5]
        d_theta = ca.SX(5, 5)
        for k, name in enumerate(estimated):
            i, j = COEFFICIENTS[name]
            d_theta[i, j] = theta[k]
        dx = vessel5dof_rhs(0.0, full, tau - ca.mtimes(d_theta, nu), params)
        return ca.vertcat(*[dx[i] for i in _STATE_INDEX])

    dt = h / substeps
    xk = x
    for _ in range(substeps):
        k1 = f(xk)
        k2 = f(xk + dt / 2 * k1)
        k3 = f(xk + dt / 2 * k2)
        k4 = f(xk + dt * k3)
        xk = xk + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ca.Function("rk4_step", [x, tau, theta], [xk], ["x", "tau", "theta"], ["x_next"])


def _substeps(params: Vessel5DofParams, d_start: np.ndarray, h: float) -> int:
    """RK4 steps per sample so that ``h |lambda_max| <= MAX_H_LAMBDA`` for the linearised model."""
    vel = [1, 2, 3, 4]
    a = np.zeros((6, 6))
    minv = np.linalg.inv(params.M)[np.ix_(vel, vel)]
    a[:4, :4] = -minv @ np.abs(d_start)[np.ix_(vel, vel)]
    a[:4, 4:] = -minv @ params.G[np.ix_(vel, [2, 3])]
    a[4, 1] = a[5, 2] = 1.0
    lam = float(np.max(np.abs(np.linalg.eigvals(a))))
    return int(max(1, math.ceil(h * lam / MAX_H_LAMBDA)))


# --------------------------------------------------------------------------- problem
@dataclass(frozen=True)
class _Interval:
    record: int
    start: int      # sample index in the record of the shooting node
    steps: int      # samples integrated
    last: bool      # last interval of its record
    node: int       # index of its node state in the decision vector


def sensitivity_step(step) -> object:
    """casadi ``Function`` ``(x, S, tau, theta) -> (x_next, S_next)`` propagating the sensitivity
    ``S = dx/d[x_0, theta]`` (NX x (NX + k)) through one RK4 step by the chain rule:
    ``S_next = Phi_x S + [0, Phi_theta]`` with the exact (algorithmic) Jacobians of the step.

    Parameters
    ----------
    step : casadi.Function
        ``(x, tau, theta) -> x_next`` from :func:`step_function`.
    """
    import casadi as ca

    x = ca.SX.sym("x", step.size1_in(0))
    tau = ca.SX.sym("tau", step.size1_in(1))
    theta = ca.SX.sym("theta", step.size1_in(2))
    k = theta.shape[0]
    s = ca.SX.sym("S", x.shape[0], x.shape[0] + k)
    x_next = step(x, tau, theta)
    phi_x = ca.jacobian(x_next, x)
    s_next = ca.mtimes(phi_x, s)
    if k:
        s_next = s_next + ca.horzcat(ca.SX(x.shape[0], x.shape[0]), ca.jacobian(x_next, theta))
    return ca.Function("rk4_sensitivity", [x, s, tau, theta], [x_next, s_next],
                       ["x", "S", "tau", "theta"], ["x_next", "S_next"])


@lru_cache(maxsize=1)
def _jit_directory() -> str:
    """A private temporary directory for the generated C and the shared objects, removed at exit
    (casadi writes them to the working directory otherwise)."""
    folder = tempfile.mkdtemp(prefix="vesselid-jit-")
    atexit.register(shutil.rmtree, folder, True)
    return folder + os.sep


def _jit_options() -> dict:
    # The directory goes at exit; casadi's own clean-up would race with that and warn.
    return {"jit": True, "compiler": "shell", "jit_cleanup": False, "jit_temp_suffix": True,
            "jit_options": {"flags": ["-O1"], "verbose": False, "cleanup": False, "directory": _jit_directory()}}


@lru_cache(maxsize=16)
def _compiled(serialized: str):
    """JIT-compiled copy of a serialised casadi Function (cached: one compile per model and length)."""
    import casadi as ca

    fn = ca.Function.deserialize(serialized)
    args = fn.mx_in()
    return ca.Function(fn.name() + "_jit", args, fn.call(args), fn.name_in(), fn.name_out(), _jit_options())


def compile_function(fn, jit: bool = True):
    """``fn`` compiled to C by casadi's JIT when a C compiler is available, else ``fn`` itself.

    The rollout runs ~20x faster compiled than in casadi's virtual machine; the result is the same.

    Parameters
    ----------
    fn : casadi.Function
        Function to compile.
    jit : bool
        False returns ``fn`` unchanged.

    Returns
    -------
    tuple[casadi.Function, bool]
        The function to call, and whether it is compiled.
    """
    if not jit:
        return fn, False
    try:
        return _compiled(fn.serialize()), True
    except Exception:  # noqa: BLE001 - no compiler, or the compiler failed: the VM gives the same numbers
        return fn, False


class _Buffered:
    """Evaluate a casadi Function into preallocated numpy arrays (casadi's zero-copy buffer API)."""

    def __init__(self, fn) -> None:
        self.fn = fn
        self.args = [np.zeros(fn.nnz_in(i)) for i in range(fn.n_in())]
        self.res = [np.zeros(fn.nnz_out(i)) for i in range(fn.n_out())]
        self.buf, self.trigger = fn.buffer()
        for i, a in enumerate(self.args):
            self.buf.set_arg(i, memoryview(a))
        for i, r in enumerate(self.res):
            self.buf.set_res(i, memoryview(r))

    def __call__(self, *args: np.ndarray) -> list[np.ndarray]:
        """Outputs (column-major nonzeros, copied) for inputs given as arrays (any shape, column-major)."""
        for dst, src in zip(self.args, args):
            dst[:] = np.asarray(src, float).ravel(order="F")
        self.trigger()
        return [r.copy() for r in self.res]


class _Problem:
    """Multiple-shooting output-error problem in scaled variables ``z = [theta/theta_scale, s/x_scale]``.

    Every shooting interval is rolled out by one casadi call (``mapaccum`` over the steps of the
    sensitivity-augmented RK4 step, ``map`` over the intervals), which returns the states and their
    exact derivatives with respect to the interval's node state and ``theta``. The output residuals
    are the simulated lateral state at every sample (node state, then the rollout) minus the data;
    the defects are the continuity gaps ``x_end(s_j, theta)/x_scale - z_(j+1)`` between consecutive
    intervals of one record.
    """

    def __init__(self, records: Sequence[GreyBoxRecord], estimated: Sequence[str], params: Vessel5DofParams,
                 theta_scale: np.ndarray, x_scale: np.ndarray, h: float, substeps: int, shoot: int,
                 jit: bool = True) -> None:
        self.records = tuple(records)
        self.k = k = len(estimated)
        self.theta_scale = np.asarray(theta_scale, float)
        self.x_scale = np.asarray(x_scale, float)
        self.step = step_function(params, estimated, h, substeps)
        intervals = []
        node = 0
        for r, rec in enumerate(self.records):
            n = rec.t.size
            starts = list(range(0, n - 1, shoot))
            for j, s0 in enumerate(starts):
                last = j == len(starts) - 1
                intervals.append(_Interval(r, s0, (n - 1 - s0) if last else shoot, last, node))
                node += 1
        self.intervals = tuple(intervals)
        self.n_nodes = node
        self.n_z = k + NX * node
        self.shoot = shoot
        # Inputs of every interval, padded with zeros to a common length (the padding is discarded).
        u = np.zeros((5, shoot * node))
        for iv in intervals:
            rec = self.records[iv.record]
            u[:, iv.node * shoot: iv.node * shoot + iv.steps] = rec.tau[iv.start: iv.start + iv.steps].T
        self.u = u
        self.jit = jit
        path, compiled = compile_function(self.step.mapaccum("rollout", shoot), jit)
        sens, compiled_s = compile_function(sensitivity_step(self.step).mapaccum("rollout_sensitivity", shoot, 2), jit)
        self.compiled = compiled and compiled_s
        self.f_path = _Buffered(path.map(node))
        self.f_sens = _Buffered(sens.map(node))
        self.s0 = np.tile(np.hstack([np.eye(NX), np.zeros((NX, k))]), (1, node))
        # Output rows: for interval j, samples 0..m_j-1 of its window (m_j = steps, or steps + 1 for
        # the last interval of a record), NX states per sample.
        self.m = np.array([iv.steps + 1 if iv.last else iv.steps for iv in intervals])
        self.n_sim = int(NX * self.m.sum())
        self.n_def = NX * sum(1 for iv in intervals if not iv.last)
        self.y = np.concatenate([self.records[iv.record].y[iv.start: iv.start + m].reshape(-1)
                                 for iv, m in zip(intervals, self.m)])
        self.state_of_row = np.tile(np.arange(NX), self.n_sim // NX)
        self.measured = np.isfinite(self.y)
        self.y0 = np.where(self.measured, self.y, 0.0)
        # Index bookkeeping: (interval, step) of each sample row block.
        self._iv_of_sample = np.repeat(np.arange(node), self.m)
        self._step_of_sample = np.concatenate([np.arange(m) for m in self.m])
        self._not_last = np.array([not iv.last for iv in intervals])
        self._csr = None

    def _theta(self, z: np.ndarray) -> np.ndarray:
        return np.broadcast_to((z[: self.k] * self.theta_scale)[:, None], (self.k, self.shoot * self.n_nodes))

    def _nodes(self, z: np.ndarray) -> np.ndarray:
        return z[self.k:].reshape(self.n_nodes, NX) * self.x_scale

    def simulate(self, z: np.ndarray, sensitivities: bool = False):
        """States ``(n_nodes, shoot + 1, NX)`` from each node, and (``sensitivities``) their
        derivatives with respect to ``[node state, theta]``, ``(n_nodes, shoot + 1, NX, NX + k)``."""
        nodes = self._nodes(z)
        if sensitivities:
            xp, sp = self.f_sens(nodes.T, self.s0, self.u, self._theta(z))
            sp = sp.reshape(self.n_nodes, self.shoot, NX + self.k, NX).transpose(0, 1, 3, 2)
            s_first = np.broadcast_to(np.hstack([np.eye(NX), np.zeros((NX, self.k))]),
                                      (self.n_nodes, 1, NX, NX + self.k))
            sens = np.concatenate([s_first, sp], axis=1)
        else:
            (xp,) = self.f_path(nodes.T, self.u, self._theta(z))
            sens = None
        xp = xp.reshape(self.n_nodes, self.shoot, NX)
        states = np.concatenate([nodes[:, None, :], xp], axis=1)
        return states, sens

    def _split_states(self, z: np.ndarray, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        sim = states[self._iv_of_sample, self._step_of_sample].reshape(-1)
        steps = np.array([iv.steps for iv in self.intervals])
        ends = states[np.arange(self.n_nodes), steps][self._not_last] / self.x_scale
        nxt = z[self.k:].reshape(self.n_nodes, NX)[1:][self._not_last[:-1]] if self.n_nodes > 1 else np.zeros((0, NX))
        return sim, (ends - nxt).reshape(-1)

    def weights(self, sigma: np.ndarray) -> np.ndarray:
        """Row weights of the output residuals: ``1/sigma`` of the row's state, 0 where unmeasured."""
        return np.where(self.measured, 1.0 / np.asarray(sigma, float)[self.state_of_row], 0.0)

    def residual(self, z: np.ndarray, w: np.ndarray, rho) -> np.ndarray:
        """Weighted output errors followed by ``rho`` (scalar or per defect row) times the continuity defects."""
        states, _ = self.simulate(z)
        sim, dfc = self._split_states(z, states)
        return np.concatenate([w * (sim - self.y0), rho * dfc])

    def jacobian(self, z: np.ndarray, w: np.ndarray, rho) -> sparse.csr_matrix:
        """Exact sparse Jacobian of :meth:`residual` (casadi algorithmic differentiation)."""
        rho = np.broadcast_to(np.asarray(rho, float), (self.n_def,))
        _, sens = self.simulate(z, sensitivities=True)
        k = self.k
        # d state / d z: node columns scale by x_scale, theta columns by theta_scale.
        col_scale = np.concatenate([self.x_scale, self.theta_scale])
        blocks = sens[self._iv_of_sample, self._step_of_sample] * col_scale  # (samples, NX, NX + k)
        blocks = blocks * w.reshape(-1, NX)[:, :, None]
        n_samp = blocks.shape[0]
        rows = np.broadcast_to(np.arange(NX * n_samp).reshape(n_samp, NX, 1), blocks.shape)
        node_cols = k + NX * self._iv_of_sample[:, None, None] + np.arange(NX)[None, None, :]
        cols = np.concatenate([np.broadcast_to(node_cols, (n_samp, NX, NX)),
                               np.broadcast_to(np.arange(k)[None, None, :], (n_samp, NX, k))], axis=2)
        data = [blocks.reshape(-1)]
        ri = [rows.reshape(-1)]
        ci = [cols.reshape(-1)]
        if self.n_def:
            idx = np.flatnonzero(self._not_last)
            steps = np.array([self.intervals[i].steps for i in idx])
            end = sens[idx, steps] * col_scale / self.x_scale[None, :, None]  # (n_d, NX, NX + k)
            n_d = idx.size
            r0 = self.n_sim + NX * np.arange(n_d)
            drows = np.broadcast_to(r0[:, None, None] + np.arange(NX)[None, :, None], end.shape)
            ncols = k + NX * idx[:, None, None] + np.arange(NX)[None, None, :]
            dcols = np.concatenate([np.broadcast_to(ncols, (n_d, NX, NX)),
                                    np.broadcast_to(np.arange(k)[None, None, :], (n_d, NX, k))], axis=2)
            data += [(rho.reshape(n_d, NX, 1) * end).reshape(-1), -rho]
            ri += [drows.reshape(-1), (r0[:, None] + np.arange(NX)).reshape(-1)]
            ci += [dcols.reshape(-1), (k + NX * (idx[:, None] + 1) + np.arange(NX)).reshape(-1)]
        data = np.concatenate(data)
        if self._csr is None:
            # The sparsity pattern never changes: sort it into CSR order once, then only permute data.
            order = sparse.csr_matrix((np.arange(1, data.size + 1, dtype=float),
                                       (np.concatenate(ri), np.concatenate(ci))),
                                      shape=(self.n_sim + self.n_def, self.n_z))
            order.sort_indices()
            self._csr = (order.data.astype(np.int64) - 1, order.indices.copy(), order.indptr.copy())
        perm, indices, indptr = self._csr
        return sparse.csr_matrix((data[perm], indices, indptr), shape=(self.n_sim + self.n_def, self.n_z))

    def split(self, jac: sparse.spmatrix) -> tuple[sparse.csr_matrix, sparse.csr_matrix]:
        """Output rows and defect rows of a Jacobian from :meth:`jacobian`."""
        j = sparse.csr_matrix(jac)
        return j[: self.n_sim], j[self.n_sim:]

    def node_guess(self) -> np.ndarray:
        """Node states from the data (0 where a state is not measured), scaled."""
        out = np.zeros(NX * self.n_nodes)
        for iv in self.intervals:
            rec = self.records[iv.record]
            lo, hi = iv.start, min(iv.start + 3, rec.t.size)
            block = rec.y[lo:hi]
            count = np.isfinite(block).sum(axis=0)
            vals = np.where(count > 0, np.nansum(block, axis=0) / np.maximum(count, 1), np.nan)
            out[NX * iv.node: NX * iv.node + NX] = np.where(np.isfinite(vals), vals, 0.0) / self.x_scale
        return out

    def reduction(self, jac_def: sparse.spmatrix) -> np.ndarray:
        """Matrix ``T`` with ``dz = T dw`` on the continuity manifold, ``w = [theta_z, first node of each record]``.

        From ``defect_j = x_end(z_j, theta)/x_scale - z_(j+1) = 0``:
        ``dz_(j+1) = A_j dz_j + B_j dtheta`` with ``A_j``, ``B_j`` read from the defect Jacobian
        (``jac_def`` computed with ``rho = 1``).
        """
        c = sparse.csr_matrix(jac_def).toarray() if self.n_def else np.zeros((0, self.n_z))
        n_w = self.k + NX * len(self.records)
        t = np.zeros((self.n_z, n_w))
        t[: self.k, : self.k] = np.eye(self.k)
        seen = set()
        row = 0
        for iv in self.intervals:
            zi = slice(self.k + NX * iv.node, self.k + NX * iv.node + NX)
            if iv.record not in seen:
                seen.add(iv.record)
                col = self.k + NX * iv.record
                t[zi, col: col + NX] = np.eye(NX)
            if not iv.last:
                blk = c[row: row + NX]
                nxt = slice(zi.start + NX, zi.stop + NX)
                t[nxt] = blk[:, zi] @ t[zi] + blk[:, : self.k] @ t[: self.k]
                row += NX
        return t


# --------------------------------------------------------------------------- fit
def _start_damping(d_start: np.ndarray | None, vessel: Vessel) -> tuple[np.ndarray, list[str]]:
    """Start D: the given matrix, NaN filled from the config's [damping], then M_ii / 1 s, off-diagonals 0."""
    notes = []
    d0 = np.full((5, 5), np.nan) if d_start is None else np.array(d_start, float)
    if d0.shape != (5, 5):
        raise FitError(f"start damping: expected a 5x5 matrix (u v p q r), found shape {d0.shape}")
    m = vessel.mass_matrix()
    for i in range(5):
        if not (np.isfinite(d0[i, i]) and d0[i, i] > 0):
            prior = vessel.damping[i, i] if vessel.damping is not None else math.nan
            if math.isfinite(prior) and prior > 0:
                d0[i, i] = prior
                notes.append(f"start D[{i},{i}] for {DOFS[i]} from the config's [damping] (no fitted value)")
            else:
                d0[i, i] = m[i, i] / 1.0
                notes.append(f"start D[{i},{i}] for {DOFS[i]} = M[{i},{i}]/(1 s) (no fitted or configured value)")
    return np.where(np.isfinite(d0), d0, 0.0), notes


def _robust_sigma(records: Sequence[GreyBoxRecord], k: int) -> float:
    vals = [noise_sigma(r.y[np.isfinite(r.y[:, k]), k]) for r in records if np.isfinite(r.y[:, k]).sum() >= 5]
    vals = [v for v in vals if math.isfinite(v) and v > 0]
    return float(np.median(vals)) if vals else math.nan


#: Lags of the Bartlett-weighted long-run variance ratio of the residuals.
KAPPA_LAGS = 25


def long_run_variance_ratio(e: np.ndarray, lags: int = KAPPA_LAGS) -> float:
    """``kappa = 1 + 2 sum_{k=1}^{L} (1 - k/(L+1)) rho_e(k)``: variance of a mean of ``e`` over that of
    white noise (Newey & West 1987), at least 1.

    For an output error whose sensitivities vary slowly against the noise correlation time (the
    usual case: an interpolated or low-pass filtered channel), the least-squares covariance of the
    parameters is ``kappa`` times the white-noise one.

    Parameters
    ----------
    e : numpy.ndarray
        Residuals in time order.
    lags : int
        Bandwidth ``L``.
    """
    from .residual_tests import autocorrelation

    rho = autocorrelation(e, lags)
    w = 1.0 - np.arange(1, lags + 1) / (lags + 1)
    return float(max(1.0 + 2.0 * np.sum(w * rho[1:]), 1.0))


def _effective_fisher(f: np.ndarray, k: int) -> np.ndarray:
    """Fisher information of the first ``k`` variables with the others eliminated (Schur complement)."""
    a, b, c = f[:k, :k], f[:k, k:], f[k:, k:]
    if c.size == 0:
        return a
    return a - b @ np.linalg.pinv(c, rcond=1e-12, hermitian=True) @ b.T


def covariance_from_fisher(fisher: np.ndarray, s2: float = 1.0, rcond: float = 1e-10) -> tuple[np.ndarray, np.ndarray]:
    """Covariance ``s^2 F^-1`` and standard errors, with ``inf`` along directions ``F`` does not determine.

    Parameters
    ----------
    fisher : numpy.ndarray
        Symmetric Fisher information (any units; scale it first for a meaningful ``rcond``).
    s2 : float
        Residual variance factor.
    rcond : float
        Eigenvalues below ``rcond`` times the largest count as zero.

    Returns
    -------
    covariance, stderr : numpy.ndarray
        Pseudo-inverse on the determined subspace; the diagonal and the standard error are ``inf``
        for every parameter with a loading above 1e-6 on a null direction.
    """
    lam, vec = np.linalg.eigh(0.5 * (fisher + fisher.T))
    top = float(lam.max(initial=0.0))
    good = lam > rcond * top if top > 0 else np.zeros(lam.size, bool)
    cov = (vec[:, good] / lam[good]) @ vec[:, good].T * s2
    stderr = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    undetermined = np.any(np.abs(vec[:, ~good]) > 1e-6, axis=1) if (~good).any() else np.zeros(lam.size, bool)
    stderr = np.where(undetermined, np.inf, stderr)
    cov = cov.copy()
    cov[undetermined, undetermined] = np.inf
    return cov, stderr


def fit_coupled_damping(trial: Trial, segments: Segments, vessel: Vessel, d_start: np.ndarray | None = None,
                        estimate: Sequence[str] = tuple(COEFFICIENTS), shooting_interval: float = 5.0,
                        max_nfev: int = 40, jit: bool = True, solve: bool = True) -> GreyBoxFit:
    """Fit the lateral (sway, roll, yaw) block of D, coupled terms included, to a trial.

    Parameters
    ----------
    trial : Trial
        Trial with some of ``v`` [m/s], ``p``, ``q``, ``r`` [rad/s], ``phi``, ``theta`` [rad] and the inputs
        ``tau_y`` [N], ``tau_k``, ``tau_n`` [N m], ``delta`` [rad].
    segments : Segments
        Its segments; those in ``LATERAL_KINDS`` (zig-zags, rudder steps, sinusoids, sway and yaw
        steps and coast-downs, roll free decays) are merged into records.
    vessel : Vessel
        Rigid-body data (``M``), roll restoring and the rudder map.
    d_start : numpy.ndarray, optional
        5x5 start D [SI], e.g. ``Fits.damping_matrix`` (NaN entries are filled: diagonal from the
        config's [damping] or ``M_ii/(1 s)``, off-diagonals 0). The surge and pitch entries are kept.
    estimate : sequence of str
        Coefficients to estimate (``COEFFICIENTS``); the rest are held at their start values.
    shooting_interval : float
        Time between multiple-shooting nodes [s].
    max_nfev : int
        Most Jacobian evaluations per solve.
    jit : bool
        Compile the rollout to C with casadi's JIT (falls back to casadi's virtual machine, about 20x
        slower, when no C compiler works).
    solve : bool
        False evaluates the Fisher information at the start values without solving (a screening of
        what the trial can determine before the fit is attempted).

    Returns
    -------
    GreyBoxFit

    Raises
    ------
    FitError
        No rigid-body data, no lateral segment, no lateral channel, or a non-uniform grid.
    """
    import casadi as ca

    t_start = time.perf_counter()
    if not vessel.has_rigid_body:
        raise FitError(f"{vessel.name}: the coupled damping needs rigid_body mass and inertia; found "
                       f"mass={vessel.mass}, inertia={np.asarray(vessel.inertia).tolist()}")
    segs = lateral_segments(segments, vessel)
    if not segs:
        kinds = sorted({f"{s.kind}/{s.dof}" for s in segments.items}) or ["none"]
        unmapped = lateral_segments(segments) and not lateral_segments(segments, vessel)
        raise FitError(f"coupled damping: expected zig-zags, rudder steps, sway or yaw steps/coast-downs or "
                       f"roll free decays, found only {kinds}"
                       + ("; the rudder-driven ones need [rudder] yaw_moment or sway_force in the vessel config "
                          "(the rudder's force is not known)" if unmapped else ""))
    outputs = tuple(c for c in STATES if trial.has(c))
    if not outputs:
        raise FitError(f"coupled damping: expected at least one of {list(STATES)} in the trial, found "
                       f"{sorted(c for c in trial.data.columns if c != 't')}")
    records = build_records(trial, segs, vessel)
    if not records:
        raise FitError("coupled damping: every lateral segment is shorter than 10 samples or split by gaps")
    h = float(np.median(np.diff(records[0].t)))
    for rec in records:
        dt = np.diff(rec.t)
        if np.any(np.abs(dt - h) > 1e-6 * max(h, 1.0)):
            raise FitError(f"coupled damping: expected a uniform sample interval of {h:.6g} s, found "
                           f"{dt.min():.6g} to {dt.max():.6g} s in [{rec.t[0]:.2f}, {rec.t[-1]:.2f}] s")

    fixed: dict[str, str] = {n: "held at its start value (not requested)" for n in COEFFICIENTS if n not in estimate}
    if "p" not in outputs and "phi" not in outputs:
        for n in _ROLL:
            fixed[n] = "the trial logs no roll channel (p or phi): log roll rate or roll angle"
    estimated = tuple(n for n in COEFFICIENTS if n in estimate and n not in fixed)
    d0, notes = _start_damping(d_start, vessel)
    d_fixed = d0.copy()
    for n in estimated:
        d_fixed[COEFFICIENTS[n]] = 0.0
    m = vessel.mass_matrix()
    if np.any(m[np.ix_([1, 2, 3, 4], [0])] != 0):
        notes.append("M couples surge to sway/roll/pitch/yaw (z_g or y_g != 0): that coupling is ignored "
                     "(surge held at rest)")
    params = Vessel5DofParams(M=m, D=d_fixed, G=vessel.restoring_matrix())
    substeps = _substeps(params, d0, h)
    shoot = max(2, int(round(shooting_interval / h)))

    # Scales make the Fisher matrix comparable across coefficients: a diagonal term against its own
    # size, a coupled term against a tenth of the geometric mean of the two diagonal terms it links.
    theta_scale = np.array([abs(d0[COEFFICIENTS[n]]) if COEFFICIENTS[n][0] == COEFFICIENTS[n][1]
                            else 0.1 * math.sqrt(abs(d0[COEFFICIENTS[n][0], COEFFICIENTS[n][0]])
                                                 * abs(d0[COEFFICIENTS[n][1], COEFFICIENTS[n][1]]))
                            for n in estimated])
    theta_scale = np.where(theta_scale > 0, theta_scale, 1.0)
    sigma0 = np.array([_robust_sigma(records, k) for k in range(NX)])
    spread = np.array([np.nanstd(np.concatenate([r.y[:, k] for r in records])) if np.isfinite(
        np.concatenate([r.y[:, k] for r in records])).any() else math.nan for k in range(NX)])
    sigma0 = np.where(np.isfinite(sigma0) & (sigma0 > 0), sigma0,
                      np.where(np.isfinite(spread), 1e-3 * spread + 1e-12, 1.0))
    x_scale = np.where(np.isfinite(spread) & (spread > 0), spread, np.array([0.1, 0.1, 0.05, 0.1, 0.05, 0.02]))

    prob = _Problem(records, estimated, params, theta_scale, x_scale, h, substeps, shoot, jit)
    z = np.concatenate([d0[tuple(np.array([COEFFICIENTS[n] for n in estimated]).T)] / theta_scale
                        if estimated else np.zeros(0), prob.node_guess()])
    lower = np.full(prob.n_z, -np.inf)
    for i, n in enumerate(estimated):
        if n in DIAGONAL:
            lower[i] = 1e-6  # D_ii > 0: a negative diagonal damping is an unstable, unphysical start
    z = np.maximum(z, lower + 1e-9)

    # Unmeasured states (no v channel, say) still need a defect scale: a hundredth of their spread.
    sigma = sigma0
    measured_state = np.array([c in outputs for c in STATES])
    converged = True
    messages = []

    def defect_weight(sig: np.ndarray, rho: float) -> np.ndarray:
        sd = np.where(measured_state, sig, 0.01 * x_scale)
        return rho * np.tile(x_scale / sd, prob.n_def // NX)

    # A weak prior (standard deviation PRIOR_SCALES times each coefficient's scale) about the start
    # bowls out the flat valleys of a trial that does not excite some coupling, so the solver stops
    # instead of crawling along them; it is far weaker than the data on anything they determine and
    # is left out of the Fisher information and the covariance.
    k = len(estimated)
    z_prior = z[:k].copy()
    prior = sparse.hstack([sparse.identity(k) / PRIOR_SCALES, sparse.csr_matrix((k, prob.n_z - k))]).tocsr()

    def fun(zz, w, dw):
        return np.concatenate([prob.residual(zz, w, dw), (zz[:k] - z_prior) / PRIOR_SCALES])

    def jac(zz, w, dw):
        return sparse.vstack([prob.jacobian(zz, w, dw), prior]).tocsr()

    for stage, rho in enumerate(PENALTIES if solve else ()):
        w = prob.weights(sigma)
        dw = defect_weight(sigma, rho)
        res = optimize.least_squares(lambda zz: fun(zz, w, dw), z, jac=lambda zz: jac(zz, w, dw),
                                     bounds=(lower, np.inf), method="trf", tr_solver="lsmr", x_scale="jac",
                                     tr_options={"atol": 1e-10, "btol": 1e-10}, ftol=1e-7, xtol=1e-7,
                                     max_nfev=max_nfev)
        z = res.x
        if res.status <= 0:
            converged = False
            messages.append(f"solve {stage + 1} did not converge: {res.message}")
        if stage == 0:
            # Per-channel residual RMS replaces the second-difference noise level, which a fast roll
            # oscillation inflates; the weights then reflect what the model leaves unexplained.
            r = prob.residual(z, np.ones(prob.n_sim), 0.0)[: prob.n_sim]
            sigma = sigma.copy()
            for kk in range(NX):
                rows = prob.measured & (prob.state_of_row == kk)
                if rows.sum() > 10:
                    rms = float(np.sqrt(np.mean(r[rows] ** 2)))
                    sigma[kk] = rms if rms > 0 else sigma[kk]

    if not solve:
        converged = False
        messages.append("not solved: Fisher information at the start values (screening)")
    k = len(estimated)
    theta = z[:k] * theta_scale
    damping = d0.copy()
    for i, n in enumerate(estimated):
        damping[COEFFICIENTS[n]] = theta[i]

    # The continuous simulation of each record from its fitted initial state, and its residual tests.
    step = prob.step
    y_fit, tests = [], []
    nodes = z[k:].reshape(prob.n_nodes, NX) * x_scale
    first_node = {}
    for iv in prob.intervals:
        first_node.setdefault(iv.record, iv.node)
    kappa_num = np.zeros(NX)
    kappa_den = np.zeros(NX)
    for r_i, rec in enumerate(records if solve else ()):
        x0 = nodes[first_node[r_i]]
        n = rec.t.size
        path = np.asarray(step.mapaccum(n - 1)(x0, ca.DM(rec.tau[:-1].T), ca.repmat(ca.DM(theta), 1, n - 1)))
        yf = np.column_stack([x0, path]).T
        y_fit.append(yf)
        inputs = {ch: rec.tau[:, j] for j, ch in ((1, "tau_y"), (2, "tau_k"), (3, "tau_m"), (4, "tau_n"))
                  if np.ptp(rec.tau[:, j]) > 0}
        for c in outputs:
            kk = STATES.index(c)
            e = rec.y[:, kk] - yf[:, kk]
            tests.append(residual_test(e, inputs, f"grey-box {c} [{rec.t[0]:.1f}-{rec.t[-1]:.1f} s]"))
            e = e[np.isfinite(e)]
            if e.size > 4 * KAPPA_LAGS:
                kappa_num[kk] += e.size * long_run_variance_ratio(e, KAPPA_LAGS)
                kappa_den[kk] += e.size
    kappa = np.where(kappa_den > 0, np.maximum(kappa_num / np.maximum(kappa_den, 1), 1.0), 1.0)
    coloured = [f"{c} x{math.sqrt(kappa[STATES.index(c)]):.2g}" for c in outputs if kappa[STATES.index(c)] > 1.5]
    if coloured:
        messages.append("residuals are coloured (interpolated or filtered channels, unmodelled dynamics): "
                        "standard errors inflated by the long-run variance ratio, " + ", ".join(coloured))

    # Fisher information on the continuity manifold with each channel's noise variance inflated by
    # its long-run variance ratio kappa (the effective number of independent samples is N/kappa).
    w_eff = prob.weights(sigma * np.sqrt(kappa))
    jac = prob.jacobian(z, w_eff, 1.0)
    j_out, j_def = prob.split(jac)
    t_red = prob.reduction(j_def)
    j_w = np.asarray(j_out @ t_red)
    f_w = j_w.T @ j_w
    w = prob.weights(sigma)
    r_out = prob.residual(z, w, 0.0)[: prob.n_sim]
    n_meas = int(prob.measured.sum())
    n_w = t_red.shape[1]
    s2 = float(r_out @ r_out) / max(n_meas - n_w, 1)
    f_z = _effective_fisher(f_w, k)
    # The Fisher matrix is J^T J / sigma^2 (known noise); the covariance takes the residual variance.
    cov_z, se_z = covariance_from_fisher(f_z, s2)
    fisher = f_z / np.outer(theta_scale, theta_scale)
    cov = cov_z * np.outer(theta_scale, theta_scale)
    stderr = se_z * theta_scale
    defects = prob.residual(z, w, 1.0)[prob.n_sim:]
    sd_def = np.where(measured_state, sigma, 0.01 * x_scale)
    max_defect = float(np.max(np.abs(defects * np.tile(x_scale / sd_def, prob.n_def // NX)))) if defects.size else 0.0
    if max_defect > 0.1:
        messages.append(f"continuity defects up to {max_defect:.2g} noise standard deviations remain")
    if not prob.compiled:
        notes.append("rollout evaluated in casadi's virtual machine (no working C compiler for the JIT)")

    names = estimated
    values = -theta  # Fossen: the derivative is -D[i, j]
    method = (f"grey-box output-error fit of the linear 5-DOF model (pipeline.model.vessel5dof_rhs; states "
              f"v p q r phi theta, surge at rest, pitch damping held; M = M_RB + M_A and restoring from the "
              f"config) to {len(records)} record(s) "
              f"of zig-zags/rudder steps/sway-yaw steps/roll decays ({', '.join(outputs)} measured); RK4 "
              f"h = {h:.3g} s x {substeps}, multiple shooting every {shoot * h:.3g} s; scipy least_squares "
              f"(trf) with the casadi Jacobian; covariance s^2 (J^T J)^-1 with initial states eliminated")
    return GreyBoxFit(names=names, values=values, stderr=stderr, covariance=cov, fisher=fisher, fixed=fixed,
                      damping=damping, outputs=outputs, sigma={c: float(sigma[STATES.index(c)]) for c in outputs},
                      records=records, y_fit=tuple(y_fit), residual_tests=tuple(tests), s2=s2, n=n_meas,
                      converged=converged, max_defect=max_defect, message="; ".join(messages), method=method,
                      kappa={c: float(kappa[STATES.index(c)]) for c in outputs},
                      elapsed=time.perf_counter() - t_start, notes=tuple(notes))
