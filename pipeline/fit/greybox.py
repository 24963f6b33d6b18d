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

- fixed-step RK4 (zero-order-hold inputs, ``substeps`` per sample): one sub-step is a casadi
  ``Function`` (and its sensitivity-augmented twin), compiled to C within bounded time and memory
  (:mod:`pipeline.fit.casadi_jit`; the generated code depends on the model, not on the data), mapped
  over the shooting intervals of a chunk and stepped through the samples (no ``cvodes``: casadi 3.8's
  integrator crashes when asked for output-grid derivatives);
- multiple shooting: a free state every ``shooting_interval`` seconds, continuity as a penalty
  residual that is tightened in a second solve, so long records and poor start values do not
  blow the simulation up;
- output error on ``v, p, q, r, phi, theta`` (those the trial has), each weighted by ``1/sigma``;
  sigma is first the second-difference noise level, then the residual RMS of a first solve;
- Levenberg-Marquardt on the normal equations (:mod:`pipeline.fit.levenberg_marquardt`): ``J^T J``
  (block tridiagonal in the shooting nodes with a dense border for the coefficients) and ``J^T r``
  are summed chunk by chunk from the exact sensitivities, so memory grows linearly with the
  records and no matrix is sized by the square of the sample count; it starts from the single-DOF
  fits and stops when a step gains less than the noise. A weak prior about the start values
  (``PRIOR_SCALES`` scales wide) keeps the solver out of the flat valleys of a trial that does not
  excite some coupling, and is left out of the covariance;
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

import math
import time
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np
from scipy import sparse

from ..errors import FitError
from ..parallel import ordered_map
from ..model.vessel5dof import Vessel5DofParams, vessel5dof_rhs
from ..records import DOFS, Segment, Segments, Trial
from ..vessel import Vessel
from .casadi_jit import compile_function
from .data import noise_sigma, segment_label
from .levenberg_marquardt import levenberg_marquardt
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
    return ca.Function("rk4_step", [x, tau, theta], [ca.densify(xk)], ["x", "tau", "theta"], ["x_next"])


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
    return ca.Function("rk4_sensitivity", [x, s, tau, theta], [ca.densify(x_next), ca.densify(s_next)],
                       ["x", "S", "tau", "theta"], ["x_next", "S_next"])


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


#: Shooting intervals simulated together in one pass. Bounds the working memory of a pass to about
#: CHUNK_NODES x (samples per interval) x NX x (NX + k) doubles (~30 MB at 50 Hz, 5 s, k = 9),
#: whatever the trial length.
CHUNK_NODES = 128


class _Problem:
    """Multiple-shooting output-error problem in scaled variables ``z = [theta/theta_scale, s/x_scale]``.

    The compiled unit is one RK4 sub-step (and its sensitivity-augmented twin), mapped over the
    shooting intervals of a chunk; Python steps it through the samples. Each pass over the chunks
    returns the weighted output errors, the continuity defects and, when asked, the per-interval
    Gram blocks ``B^T B`` and ``B^T e`` of the sensitivities ``B``; the normal equations
    ``J^T J`` (block tridiagonal in the nodes with a dense ``theta`` border) and ``J^T r`` are
    assembled from them, so memory grows with the number of nodes, never with the square of the
    sample count, and a chunk's sensitivities are dropped as soon as they are summed.

    Output residual rows are ordered by interval, sample and state (the node's own sample first,
    the next node's sample belongs to the next interval, the last interval of a record includes
    its last sample); the defects ``x_end(s_j, theta)/x_scale - z_(j+1)`` follow, NX per interval
    that is not the last of its record.
    """

    def __init__(self, records: Sequence[GreyBoxRecord], estimated: Sequence[str], params: Vessel5DofParams,
                 theta_scale: np.ndarray, x_scale: np.ndarray, h: float, substeps: int, shoot: int,
                 jit: bool = True, chunk: int = CHUNK_NODES) -> None:
        self.records = tuple(records)
        self.k = k = len(estimated)
        self.theta_scale = np.asarray(theta_scale, float)
        self.x_scale = np.asarray(x_scale, float)
        self.substeps = int(substeps)
        # One RK4 sub-step is all that is compiled: code size set by the model, not the data.
        self.substep = step_function(params, estimated, h / self.substeps, 1)
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
        self.chunk = max(1, int(chunk))
        self.steps = np.array([iv.steps for iv in intervals])
        # Inputs of every interval, padded with zeros to a common length (the padding is discarded).
        self.u = np.zeros((node, shoot, 5))
        for iv in intervals:
            rec = self.records[iv.record]
            self.u[iv.node, : iv.steps] = rec.tau[iv.start: iv.start + iv.steps]
        path = compile_function(self.substep, jit)
        sens = compile_function(sensitivity_step(self.substep), jit)
        self.f_path, self.f_sens = path.function, sens.function
        self.compiled = path.compiled and sens.compiled
        self.compile_note = path.note or sens.note
        self._maps: dict[tuple[str, int], _Buffered] = {}
        # Output rows: for interval j, samples 0..m_j-1 of its window (m_j = steps, or steps + 1 for
        # the last interval of a record), NX states per sample; padded layout (node, sample, state).
        self.m = np.array([iv.steps + 1 if iv.last else iv.steps for iv in intervals])
        self.n_sim = int(NX * self.m.sum())
        self._not_last = np.array([not iv.last for iv in intervals])
        self.n_def = NX * int(self._not_last.sum())
        y_pad = np.full((node, shoot + 1, NX), np.nan)
        for iv, m in zip(intervals, self.m):
            y_pad[iv.node, :m] = self.records[iv.record].y[iv.start: iv.start + m]
        valid = np.arange(shoot + 1)[None, :] < self.m[:, None]
        self._pad_index = np.flatnonzero(np.broadcast_to(valid[:, :, None], y_pad.shape).reshape(-1))
        self.y = y_pad.reshape(-1)[self._pad_index]
        self.state_of_row = np.tile(np.arange(NX), self.n_sim // NX)
        self.measured = np.isfinite(self.y)
        self._y0_pad = np.where(np.isfinite(y_pad), y_pad, 0.0)
        self._measured_pad = np.isfinite(y_pad)
        # Where each interval's local variables [node_j, theta, node_(j+1)] sit in z (the last
        # node's "next" points at itself; its defect rows are zero).
        nxt = np.minimum(np.arange(node) + 1, max(node - 1, 0))
        self._local_index = np.concatenate([k + NX * np.arange(node)[:, None] + np.arange(NX),
                                            np.broadcast_to(np.arange(k), (node, k)),
                                            k + NX * nxt[:, None] + np.arange(NX)], axis=1)

    # ---------------------------------------------------------------- roll-outs
    def _mapped(self, which: str, lanes: int) -> _Buffered:
        key = (which, lanes)
        if key not in self._maps:
            self._maps[key] = _Buffered((self.f_sens if which == "sens" else self.f_path).map(lanes))
        return self._maps[key]

    def rollout(self, x0: np.ndarray, tau: np.ndarray, theta: np.ndarray, sensitivities: bool = False):
        """Simulate lanes side by side from their initial states.

        Parameters
        ----------
        x0 : numpy.ndarray, shape (L, NX)
            Initial states [SI].
        tau : numpy.ndarray, shape (L, steps, 5)
            Generalised force held over each sample interval [N, N m].
        theta : numpy.ndarray, shape (k,)
            Estimated ``D`` entries (positive convention) [SI].
        sensitivities : bool
            Also return ``dx/d[x0, theta]``.

        Returns
        -------
        states : numpy.ndarray, shape (L, steps + 1, NX)
        sens : numpy.ndarray, shape (L, steps + 1, NX, NX + k), or None
        """
        lanes, steps = tau.shape[:2]
        k = self.k
        th = np.tile(np.asarray(theta, float), lanes)
        x = np.asarray(x0, float).reshape(-1).copy()
        states = np.empty((lanes, steps + 1, NX))
        states[:, 0] = x.reshape(lanes, NX)
        sens = None
        if sensitivities:
            f = self._mapped("sens", lanes)
            first = np.hstack([np.eye(NX), np.zeros((NX, k))])
            s = np.tile(first.T.reshape(-1), lanes)
            sens = np.empty((lanes, steps + 1, NX, NX + k))
            sens[:, 0] = first
        else:
            f = self._mapped("path", lanes)
        for j in range(steps):
            u = tau[:, j].reshape(-1)
            for _ in range(self.substeps):
                if sensitivities:
                    x, s = f(x, s, u, th)
                else:
                    (x,) = f(x, u, th)
            states[:, j + 1] = x.reshape(lanes, NX)
            if sensitivities:
                sens[:, j + 1] = s.reshape(lanes, NX + k, NX).transpose(0, 2, 1)
        return states, sens

    def _theta(self, z: np.ndarray) -> np.ndarray:
        return z[: self.k] * self.theta_scale

    def _nodes(self, z: np.ndarray) -> np.ndarray:
        return z[self.k:].reshape(self.n_nodes, NX) * self.x_scale

    def _pad_weights(self, w: np.ndarray) -> np.ndarray:
        out = np.zeros((self.n_nodes, self.shoot + 1, NX))
        out.reshape(-1)[self._pad_index] = w
        return out

    def _rho_nodes(self, rho) -> np.ndarray:
        """Defect weights per (node, state); zero for the last interval of each record."""
        out = np.zeros((self.n_nodes, NX))
        r = np.asarray(rho, float)
        if r.ndim == 1 and r.size == NX and self.n_def != NX:
            out[self._not_last] = r
        else:
            out[self._not_last] = np.broadcast_to(r, (self.n_def,)).reshape(-1, NX)
        return out

    def evaluate(self, z: np.ndarray, w_pad: np.ndarray, gram: bool = False):
        """One pass over the chunks.

        Parameters
        ----------
        z : numpy.ndarray
            Scaled decision vector.
        w_pad : numpy.ndarray, shape (n_nodes, shoot + 1, NX)
            Output weights in the padded layout (0 where unmeasured or padding).
        gram : bool
            Also return the Gram blocks.

        Returns
        -------
        e : numpy.ndarray, shape (n_nodes, shoot + 1, NX)
            Weighted output errors (0 at padding).
        dfc : numpy.ndarray, shape (n_nodes, NX)
            Unweighted continuity defects (0 for the last interval of a record).
        blocks : tuple or None
            ``(G, b, E)``: output Gram ``B^T B`` (n_nodes, NX + k, NX + k) and ``B^T e``
            (n_nodes, NX + k) in the local columns ``[node, theta]``, and the defect Jacobian
            ``E = d(x_end/x_scale)/d[node, theta]`` (n_nodes, NX, NX + k).
        """
        k = self.k
        theta = self._theta(z)
        nodes = self._nodes(z)
        col_scale = np.concatenate([self.x_scale, self.theta_scale])
        e = np.zeros((self.n_nodes, self.shoot + 1, NX))
        ends = np.zeros((self.n_nodes, NX))
        if gram:
            g_blk = np.zeros((self.n_nodes, NX + k, NX + k))
            b_blk = np.zeros((self.n_nodes, NX + k))
            e_blk = np.zeros((self.n_nodes, NX, NX + k))
        for lo in range(0, self.n_nodes, self.chunk):
            sl = slice(lo, min(lo + self.chunk, self.n_nodes))
            states, sens = self.rollout(nodes[sl], self.u[sl], theta, sensitivities=gram)
            e[sl] = w_pad[sl] * (states - self._y0_pad[sl])
            idx = np.arange(sl.start, sl.stop)
            ends[sl] = states[idx - lo, self.steps[sl]]
            if gram:
                b = sens * col_scale * w_pad[sl][:, :, :, None]
                g_blk[sl] = np.einsum("csnk,csnl->ckl", b, b, optimize=True)
                b_blk[sl] = np.einsum("csnk,csn->ck", b, e[sl], optimize=True)
                e_blk[sl] = sens[idx - lo, self.steps[sl]] * col_scale / self.x_scale[:, None]
                del b, sens
        nxt = np.zeros((self.n_nodes, NX))
        nxt[:-1] = z[self.k:].reshape(self.n_nodes, NX)[1:]
        dfc = np.where(self._not_last[:, None], ends / self.x_scale - nxt, 0.0)
        return e, dfc, ((g_blk, b_blk, e_blk) if gram else None)

    def weights(self, sigma: np.ndarray) -> np.ndarray:
        """Row weights of the output residuals: ``1/sigma`` of the row's state, 0 where unmeasured."""
        return np.where(self.measured, 1.0 / np.asarray(sigma, float)[self.state_of_row], 0.0)

    def residual(self, z: np.ndarray, w: np.ndarray, rho) -> np.ndarray:
        """Weighted output errors followed by ``rho`` (scalar or per defect row) times the continuity defects."""
        e, dfc, _ = self.evaluate(z, self._pad_weights(w))
        return np.concatenate([e.reshape(-1)[self._pad_index], (self._rho_nodes(rho) * dfc)[self._not_last].reshape(-1)])

    def cost(self, z: np.ndarray, w_pad: np.ndarray, rho_nodes: np.ndarray) -> float:
        """``0.5 |r|^2`` of the weighted output errors and weighted defects."""
        e, dfc, _ = self.evaluate(z, w_pad)
        return 0.5 * (float(np.sum(e * e)) + float(np.sum((rho_nodes * dfc) ** 2)))

    def normal_equations(self, z: np.ndarray, w_pad: np.ndarray, rho_nodes: np.ndarray
                         ) -> tuple[float, np.ndarray, sparse.csc_matrix]:
        """``(0.5 |r|^2, J^T r, J^T J)`` assembled from the per-interval blocks (``J`` never formed)."""
        k = self.k
        e, dfc, (g_blk, b_blk, e_blk) = self.evaluate(z, w_pad, gram=True)
        nl = 2 * NX + k
        # Local Jacobian of interval j's defect rows in [node_j, theta, node_(j+1)]: rho [E, -I].
        jd = np.zeros((self.n_nodes, NX, nl))
        jd[:, :, : NX + k] = e_blk
        jd[:, :, NX + k:] = -np.eye(NX)
        jd *= rho_nodes[:, :, None]
        rd = rho_nodes * dfc
        local = np.einsum("cnk,cnl->ckl", jd, jd)
        local[:, : NX + k, : NX + k] += g_blk
        grad_l = np.einsum("cnk,cn->ck", jd, rd)
        grad_l[:, : NX + k] += b_blk
        rows = np.broadcast_to(self._local_index[:, :, None], local.shape).reshape(-1)
        cols = np.broadcast_to(self._local_index[:, None, :], local.shape).reshape(-1)
        h = sparse.coo_matrix((local.reshape(-1), (rows, cols)), shape=(self.n_z, self.n_z)).tocsc()
        g = np.bincount(self._local_index.reshape(-1), grad_l.reshape(-1), minlength=self.n_z)
        cost = 0.5 * (float(np.sum(e * e)) + float(np.sum(rd * rd)))
        return cost, g, h

    def simulate(self, z: np.ndarray, sensitivities: bool = False):
        """States ``(n_nodes, shoot + 1, NX)`` from each node, and (``sensitivities``) their
        derivatives with respect to ``[node state, theta]``, ``(n_nodes, shoot + 1, NX, NX + k)``
        (every node at once: for checks on small problems)."""
        return self.rollout(self._nodes(z), self.u, self._theta(z), sensitivities)

    def jacobian(self, z: np.ndarray, w: np.ndarray, rho) -> sparse.csr_matrix:
        """Sparse Jacobian of :meth:`residual`, formed whole (for checks on small problems; the
        solver uses :meth:`normal_equations`)."""
        k = self.k
        _, sens = self.simulate(z, sensitivities=True)
        col_scale = np.concatenate([self.x_scale, self.theta_scale])
        w_pad = self._pad_weights(w)
        blocks = (sens * col_scale * w_pad[:, :, :, None]).reshape(-1, NX + k)[self._pad_index]
        node_of_row = np.repeat(np.arange(self.n_nodes), (self.shoot + 1) * NX)[self._pad_index]
        rows = np.repeat(np.arange(self.n_sim), NX + k)
        cols = np.concatenate([k + NX * node_of_row[:, None] + np.arange(NX),
                               np.broadcast_to(np.arange(k), (self.n_sim, k))], axis=1).reshape(-1)
        data = [blocks.reshape(-1)]
        ri, ci = [rows], [cols]
        if self.n_def:
            rho_n = self._rho_nodes(rho)
            idx = np.flatnonzero(self._not_last)
            end = sens[idx, self.steps[idx]] * col_scale / self.x_scale[:, None] * rho_n[idx][:, :, None]
            r0 = self.n_sim + NX * np.arange(idx.size)
            drows = r0[:, None] + np.arange(NX)
            data += [end.reshape(-1), -rho_n[idx].reshape(-1)]
            ri += [np.repeat(drows.reshape(-1), NX + k), drows.reshape(-1)]
            ci += [np.broadcast_to(self._local_index[idx][:, None, : NX + k], end.shape).reshape(-1),
                   self._local_index[idx][:, NX + k:].reshape(-1)]
        return sparse.csr_matrix((np.concatenate(data), (np.concatenate(ri), np.concatenate(ci))),
                                 shape=(self.n_sim + self.n_def, self.n_z))

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

    def effective_fisher(self, g_blk: np.ndarray, e_blk: np.ndarray) -> tuple[np.ndarray, int]:
        """Fisher information of the scaled ``theta`` on the continuity manifold, initial states eliminated.

        Along each record the nodes follow ``dz_(j+1) = A_j dz_j + B_j dtheta`` (``[A_j, B_j] = E_j``),
        so every node is a linear map ``T_j`` of ``w = [theta, x0 of the record]``; the record's
        information in ``w`` is ``sum_j P_j^T G_j P_j`` with ``P_j = [T_j; I 0]``, and its initial state
        is eliminated by a Schur complement (records do not share initial states).

        Parameters
        ----------
        g_blk : numpy.ndarray, shape (n_nodes, NX + k, NX + k)
            Output Gram blocks from :meth:`evaluate`.
        e_blk : numpy.ndarray, shape (n_nodes, NX, NX + k)
            Defect Jacobians from :meth:`evaluate`.

        Returns
        -------
        fisher : numpy.ndarray, shape (k, k)
        n_w : int
            Free variables on the manifold (``k + NX`` per record), for the residual degrees of freedom.
        """
        k = self.k
        f_eff = np.zeros((k, k))
        theta_rows = np.hstack([np.eye(k), np.zeros((k, NX))])
        by_record: dict[int, list[_Interval]] = {}
        for iv in self.intervals:
            by_record.setdefault(iv.record, []).append(iv)
        for ivs in by_record.values():
            t = np.hstack([np.zeros((NX, k)), np.eye(NX)])
            fr = np.zeros((k + NX, k + NX))
            for iv in ivs:
                p = np.vstack([t, theta_rows])
                fr += p.T @ g_blk[iv.node] @ p
                if not iv.last:
                    t = e_blk[iv.node] @ p
            f_eff += fr[:k, :k] - fr[:k, k:] @ np.linalg.pinv(fr[k:, k:], rcond=1e-12, hermitian=True) @ fr[k:, :k]
        return 0.5 * (f_eff + f_eff.T), k + NX * len(by_record)

    def continuous(self, z: np.ndarray) -> list[np.ndarray]:
        """Each record simulated whole from its first node (records of similar length side by side)."""
        nodes = self._nodes(z)
        theta = self._theta(z)
        first = {}
        for iv in self.intervals:
            first.setdefault(iv.record, iv.node)
        order = sorted(range(len(self.records)), key=lambda r: self.records[r].t.size)
        out: list[np.ndarray | None] = [None] * len(self.records)
        for lo in range(0, len(order), 32):
            group = order[lo: lo + 32]
            length = max(self.records[r].t.size for r in group)
            tau = np.zeros((len(group), length - 1, 5))
            for i, r in enumerate(group):
                tau[i, : self.records[r].t.size - 1] = self.records[r].tau[:-1]
            states, _ = self.rollout(nodes[[first[r] for r in group]], tau, theta)
            for i, r in enumerate(group):
                out[r] = states[i, : self.records[r].t.size].copy()
        return out


# --------------------------------------------------------------------------- fit
def start_damping(d_start: np.ndarray | None, vessel: Vessel) -> tuple[np.ndarray, list[str]]:
    """Start D: the given matrix, NaN filled from the config's [damping], then M_ii / 1 s, off-diagonals 0.

    Parameters
    ----------
    d_start : numpy.ndarray or None
        5x5 start damping [SI] (u v p q r), e.g. the single-DOF ``Fits.damping_matrix``; NaN where unknown.
    vessel : Vessel
        Mass matrix and optional ``[damping]``.

    Returns
    -------
    d0 : numpy.ndarray, shape (5, 5)
        Start matrix with every entry finite and a positive diagonal.
    notes : list[str]
        Which diagonal entries were filled in, and from where.
    """
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


#: Groups of records whose residual tests are one unit of :func:`pipeline.parallel.ordered_map`.
RESIDUAL_TEST_GROUPS = 8


def _record_residual_tests(inputs: tuple, indices: tuple[int, ...]) -> list[tuple[list[ResidualTest], list]]:
    """Residual tests of the grey-box records ``indices`` (``inputs``: records, their continuous
    simulations, the measured output channels): per record its tests, one per output channel, and
    ``(state index, residual count, long-run variance ratio)`` of each channel long enough for it."""
    records, y_fit, outputs = inputs
    out = []
    for i in indices:
        rec, yf = records[i], y_fit[i]
        inputs_ = {ch: rec.tau[:, j] for j, ch in ((1, "tau_y"), (2, "tau_k"), (3, "tau_m"), (4, "tau_n"))
                   if np.ptp(rec.tau[:, j]) > 0}
        tests, ratios = [], []
        for c in outputs:
            kk = STATES.index(c)
            e = rec.y[:, kk] - yf[:, kk]
            tests.append(residual_test(e, inputs_, f"grey-box {c} [{rec.t[0]:.1f}-{rec.t[-1]:.1f} s]"))
            e = e[np.isfinite(e)]
            if e.size > 4 * KAPPA_LAGS:
                ratios.append((kk, e.size, long_run_variance_ratio(e, KAPPA_LAGS)))
        out.append((tests, ratios))
    return out


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
    d0, notes = start_damping(d_start, vessel)
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
        return prob._rho_nodes(rho * x_scale / sd)

    # A weak prior (standard deviation PRIOR_SCALES times each coefficient's scale) about the start
    # bowls out the flat valleys of a trial that does not excite some coupling, so the solver stops
    # instead of crawling along them; it is far weaker than the data on anything they determine and
    # is left out of the Fisher information and the covariance.
    k = len(estimated)
    z_prior = z[:k].copy()

    def cost(zz, w_pad, rho_n):
        return prob.cost(zz, w_pad, rho_n) + 0.5 * float(np.sum(((zz[:k] - z_prior) / PRIOR_SCALES) ** 2))

    def normal(zz, w_pad, rho_n):
        f, g, hm = prob.normal_equations(zz, w_pad, rho_n)
        g = g.copy()
        g[:k] += (zz[:k] - z_prior) / PRIOR_SCALES ** 2
        prior = sparse.diags(np.concatenate([np.full(k, PRIOR_SCALES ** -2.0), np.zeros(prob.n_z - k)]))
        return f + 0.5 * float(np.sum(((zz[:k] - z_prior) / PRIOR_SCALES) ** 2)), g, (hm + prior).tocsc()

    for stage, rho in enumerate(PENALTIES if solve else ()):
        w_pad = prob._pad_weights(prob.weights(sigma))
        rho_n = defect_weight(sigma, rho)
        res = levenberg_marquardt(lambda zz: cost(zz, w_pad, rho_n), lambda zz: normal(zz, w_pad, rho_n), z,
                                  lower=lower, max_njev=max_nfev)
        z = res.x
        if not res.converged:
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
    theta = z[:k] * theta_scale
    damping = d0.copy()
    for i, n in enumerate(estimated):
        damping[COEFFICIENTS[n]] = theta[i]

    # The continuous simulation of each record from its fitted initial state, and its residual tests.
    y_fit = list(prob.continuous(z)) if solve else []
    tests = []
    kappa_num = np.zeros(NX)
    kappa_den = np.zeros(NX)
    # The records' residual tests are independent: groups of records in worker processes when the
    # cores allow; summed here in record order, as one loop would.
    groups = [g for g in np.array_split(np.arange(len(y_fit)), max(min(len(y_fit), RESIDUAL_TEST_GROUPS), 1))
              if g.size]
    for group in ordered_map(_record_residual_tests, [tuple(int(i) for i in g) for g in groups],
                             context=(records, y_fit, outputs)):
        for rec_tests, ratios in group:
            tests.extend(rec_tests)
            for kk, size, ratio in ratios:
                kappa_num[kk] += size * ratio
                kappa_den[kk] += size
    kappa = np.where(kappa_den > 0, np.maximum(kappa_num / np.maximum(kappa_den, 1), 1.0), 1.0)
    coloured = [f"{c} x{math.sqrt(kappa[STATES.index(c)]):.2g}" for c in outputs if kappa[STATES.index(c)] > 1.5]
    if coloured:
        messages.append("residuals are coloured (interpolated or filtered channels, unmodelled dynamics): "
                        "standard errors inflated by the long-run variance ratio, " + ", ".join(coloured))

    # Fisher information on the continuity manifold with each channel's noise variance inflated by
    # its long-run variance ratio kappa (the effective number of independent samples is N/kappa),
    # accumulated record by record from the per-interval blocks (no matrix sized by the samples).
    w_eff = prob._pad_weights(prob.weights(sigma * np.sqrt(kappa)))
    _, _, (g_blk, _, e_blk) = prob.evaluate(z, w_eff, gram=True)
    f_z, n_w = prob.effective_fisher(g_blk, e_blk)
    e_out, defects, _ = prob.evaluate(z, prob._pad_weights(prob.weights(sigma)))
    n_meas = int(prob.measured.sum())
    s2 = float(np.sum(e_out * e_out)) / max(n_meas - n_w, 1)
    # The Fisher matrix is J^T J / sigma^2 (known noise); the covariance takes the residual variance.
    cov_z, se_z = covariance_from_fisher(f_z, s2)
    fisher = f_z / np.outer(theta_scale, theta_scale)
    cov = cov_z * np.outer(theta_scale, theta_scale)
    stderr = se_z * theta_scale
    sd_def = np.where(measured_state, sigma, 0.01 * x_scale)
    max_defect = float(np.max(np.abs(defects * x_scale / sd_def))) if prob.n_def else 0.0
    if max_defect > 0.1:
        messages.append(f"continuity defects up to {max_defect:.2g} noise standard deviations remain")
    if not prob.compiled:
        notes.append("rollout evaluated in casadi's virtual machine"
                     + (f" ({prob.compile_note})" if prob.compile_note else " (JIT not requested)"))

    names = estimated
    values = -theta  # Fossen: the derivative is -D[i, j]
    method = (f"grey-box output-error fit of the linear 5-DOF model (pipeline.model.vessel5dof_rhs; states "
              f"v p q r phi theta, surge at rest, pitch damping held; M = M_RB + M_A and restoring from the "
              f"config) to {len(records)} record(s) "
              f"of zig-zags/rudder steps/sway-yaw steps/roll decays ({', '.join(outputs)} measured); RK4 "
              f"h = {h:.3g} s x {substeps}, multiple shooting every {shoot * h:.3g} s; Levenberg-Marquardt on the "
              f"sparse normal equations of the casadi sensitivities (stops when the gain is below the noise); "
              f"covariance s^2 (J^T J)^-1 with initial states eliminated")
    return GreyBoxFit(names=names, values=values, stderr=stderr, covariance=cov, fisher=fisher, fixed=fixed,
                      damping=damping, outputs=outputs, sigma={c: float(sigma[STATES.index(c)]) for c in outputs},
                      records=records, y_fit=tuple(y_fit), residual_tests=tuple(tests), s2=s2, n=n_meas,
                      converged=converged, max_defect=max_defect, message="; ".join(messages), method=method,
                      kappa={c: float(kappa[STATES.index(c)]) for c in outputs},
                      elapsed=time.perf_counter() - t_start, notes=tuple(notes))
