"""Joint output-error fit of one DOF with linear or linear + quadratic damping over all its segments.

One DOF of Fossen's model (2021, sec. 6.4), ``M_ii nu_dot + D_ii nu + D2_i |nu| nu + G_ii eta = tau_i``
(:func:`pipeline.model.vessel5dof.dof_rhs`), is simulated from each segment's start over every
segment of that DOF at once -- coast-downs, steps and steady runs in surge, sway and yaw; free
decays in roll and pitch -- and its parameters are fitted to all of them together by bounded
nonlinear least squares (scipy ``least_squares``, trust-region reflective) on noise-weighted
residuals. Shared parameters: ``a = D_ii/M_ii`` [1/s], ``b = D2_i/M_ii`` [1/m or 1/rad] (quadratic
structure only), ``c = G_ii/M_ii`` [1/s^2] (roll, pitch) and one input gain per input channel that is
not the DOF's generalised force (a thrust command, say). Per segment: the initial state (and, for a
measured angle, its equilibrium offset). A force input is divided by ``M_ii`` of the vessel config,
as in the single-DOF fits (``X_u = -M_ii / T``); without a config mass its gain is fitted too.

Steady-state points (thrust against steady speed from bollard tables or speed runs) enter the
same least squares as rows ``(tau_k/M_ii - a u_k - b |u_k| u_k) / sd_k``, so the drag curve and
the transients are one model (:class:`SteadyPoint`).

Long trials: a residual row depends on the shared parameters and its own segment's locals only, so
the Jacobian is sparse (rows x (shared + locals per segment) numbers) and, above
``DENSE_MAX_PARAMETERS`` parameters, the trust-region steps are LSMR solves on it and the
covariance's shared block comes from the Schur complement (:func:`shared_hac_covariance`); the
cost grows linearly with the number of segments instead of with its cube (a dense SVD step).

The covariance is the Newey-West (HAC) sandwich of the weighted residuals
(:mod:`pipeline.fit.robust_covariance`): the Gauss-Newton ``(J^T J)^-1 s^2`` (Seber & Wild 2003)
assumes white residuals and comes out too small when a logged channel's errors are coloured
(filtered or interpolated speed); the sandwich sums the scores' autocovariance within each record.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
from scipy import optimize, sparse

from ..errors import FitError
from ..model.vessel5dof import simulate_dof
from ..records import DOF_ANGLE, DOF_CHANNELS, DampingFit, Segment, Trial
from .data import noise_sigma, segment_label
from .first_order import guess_decay, guess_step
from .robust_covariance import andrews_bandwidth, hac_covariance, pooled_lag1
from .second_order import guess_damped_oscillation

#: DOF -> (linear derivative, quadratic derivative) names after Fossen.
TERM_NAMES = {"surge": ("X_u", "X_|u|u"), "sway": ("Y_v", "Y_|v|v"), "roll": ("K_p", "K_|p|p"),
              "pitch": ("M_q", "M_|q|q"), "yaw": ("N_r", "N_|r|r")}
#: DOF -> (linear unit, quadratic unit) of the derivatives.
TERM_UNITS = {"surge": ("kg/s", "kg/m"), "sway": ("kg/s", "kg/m"), "roll": ("kg m^2/s", "kg m^2"),
              "pitch": ("kg m^2/s", "kg m^2"), "yaw": ("kg m^2/s", "kg m^2")}
#: DOFs with restoring (second-order model).
SECOND_ORDER = ("roll", "pitch")
#: Segment kinds fitted per DOF family.
KINDS_FIRST = ("coast_down", "step")
KINDS_SECOND = ("free_decay",)
#: Fewest finite samples a segment needs to enter the joint fit.
MIN_RECORD_SAMPLES = 10
#: Residual given to samples of a diverged simulation.
_DIVERGED = 1e6
#: Largest number of fitted parameters (shared + per-segment locals) solved with the dense exact
#: trust-region step (an SVD of the Jacobian, cost rows x parameters^2, so cubic in the segment
#: count); larger problems use the sparse Jacobian with LSMR steps (cost linear in the data). On a
#: 30-minute trial (32 surge segments) the sparse path took the structure selection from 26.6 to
#: 5.1 s CPU with every value within 3e-6 of its standard error; tiny problems keep the exact step
#: (scipy's LSMR path also fails on a single unbounded variable).
DENSE_MAX_PARAMETERS = 10
#: LSMR tolerances of the sparse trust-region steps (scipy's 1e-6 default leaves steps inexact
#: enough to need extra iterations on these stiff, well-determined problems).
LSMR_OPTIONS = {"atol": 1e-10, "btol": 1e-10}


@dataclass(frozen=True)
class DofRecord:
    """One segment prepared for the joint fit, on its uniform sample grid.

    Attributes
    ----------
    label, kind : str
        Segment label and kind.
    y : numpy.ndarray
        Measured output (NaN where missing) [SI].
    inputs : Mapping[str, numpy.ndarray]
        Input channel -> samples held over each interval [SI of the channel].
    sigma : float
        Noise standard deviation of ``y`` [SI].
    output : str
        ``rate`` (velocity channel) or ``angle`` (roll or pitch angle).
    channel : str
        Channel name of ``y``.
    offset : int
        Trial samples dropped at the segment start (decimation onto the logged samples).
    """

    label: str
    kind: str
    y: np.ndarray
    inputs: dict
    sigma: float
    output: str
    channel: str
    offset: int = 0


@dataclass(frozen=True)
class SteadyPoint:
    """A steady-state operating point: generalised force balanced by damping at a steady speed.

    Attributes
    ----------
    speed : float
        Steady velocity of the DOF [m/s or rad/s].
    force : float
        Generalised force (thrust) at that speed [N or N m].
    speed_se, force_se : float
        Standard errors [same units].
    source : str
        Where the point came from (bollard table, speed run).
    """

    speed: float
    force: float
    speed_se: float
    force_se: float
    source: str = ""


# --------------------------------------------------------------------------- data
def _held(x: np.ndarray) -> np.ndarray:
    """Forward-fill (zero-order hold) the NaNs of an input; leading NaNs become the first value."""
    x = np.asarray(x, float).copy()
    ok = np.isfinite(x)
    if not ok.any():
        return np.zeros_like(x)
    idx = np.where(ok, np.arange(x.size), 0)
    np.maximum.accumulate(idx, out=idx)
    x = x[idx]
    x[: int(np.argmax(ok))] = x[int(np.argmax(ok))]
    return x


def dof_records(trial: Trial, segments: Sequence[Segment], dof: str) -> list[DofRecord]:
    """The segments of ``dof`` that the joint fit uses, read from the trial.

    Surge, sway and yaw take coast-downs and steps (output: the velocity channel, ``sog`` for surge
    when there is no ``u``); roll and pitch take free decays (output: the angle when logged, else
    the rate). The input is the segment's input channel when the trial has it, else the levels the
    segment states (held from the segment start).

    Parameters
    ----------
    trial : Trial
        The trial (uniform clock).
    segments : Sequence[Segment]
        Any segments; those of other DOFs or kinds are skipped.
    dof : str
        ``surge``, ``sway``, ``roll``, ``pitch`` or ``yaw``.

    Returns
    -------
    list[DofRecord]
        One record per usable segment (at least ``MIN_RECORD_SAMPLES`` finite samples).
    """
    second = dof in SECOND_ORDER
    kinds = KINDS_SECOND if second else KINDS_FIRST
    rate = DOF_CHANNELS[dof][0]
    if second:
        outputs = [(DOF_ANGLE[dof], "angle"), (rate, "rate")]
    else:
        outputs = [(rate, "rate")] + ([("sog", "rate")] if dof == "surge" else [])
    out = []
    for seg in segments:
        if seg.dof != dof or seg.kind not in kinds:
            continue
        channel, kind = next(((c, k) for c, k in outputs if trial.has(c)), (None, None))
        if channel is None:
            continue
        rows = trial.window(seg.t_start, seg.t_end)
        y = rows[channel].to_numpy(dtype=float)
        if np.isfinite(y).sum() < MIN_RECORD_SAMPLES:
            continue
        inputs = {}
        if seg.input_channel:
            if seg.input_channel in rows.columns and np.isfinite(rows[seg.input_channel].to_numpy(float)).any():
                inputs[seg.input_channel] = _held(rows[seg.input_channel].to_numpy(float))
            else:
                inputs[seg.input_channel] = np.full(y.size, float(seg.input_after))
        elif second and DOF_CHANNELS[dof][1] in rows.columns:
            inputs[DOF_CHANNELS[dof][1]] = _held(rows[DOF_CHANNELS[dof][1]].to_numpy(float))
        sigma = noise_sigma(y[np.isfinite(y)])
        if not (math.isfinite(sigma) and sigma > 0):
            sigma = max(1e-3 * float(np.nanmax(np.abs(y))), 1e-12)
        out.append(DofRecord(segment_label(seg), seg.kind, y, inputs, sigma, kind, channel))
    return out


#: Samples per record the joint fit aims at after decimation (the simulation loop is per sample).
TARGET_SAMPLES = 300
#: Fewest samples per time constant (or per oscillation period / 2 pi) kept by decimation.
MIN_SAMPLES_PER_TIME_SCALE = 5


def _time_scale(record: DofRecord, dt: float, second: bool) -> float:
    """Shortest dynamic time scale of a record from its closed-form guess [s]: T, or 1/wn."""
    ok = np.isfinite(record.y)
    t = (np.arange(record.y.size) * dt)[ok]
    y = record.y[ok]
    try:
        if second:
            g = guess_damped_oscillation(t, y)
            return 1.0 / g["wn"] if g["wn"] > 0 else math.inf
        g = guess_step(t, y) if record.kind == "step" else guess_decay(t, y)
        return g["T"] if g["T"] > 0 else math.inf
    except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError):
        return math.inf


def decimate_records(records: Sequence[DofRecord], dt: float, dof: str) -> tuple[list[DofRecord], float, int]:
    """Keep every k-th sample so that records hold about ``TARGET_SAMPLES`` samples, but never fewer
    than ``MIN_SAMPLES_PER_TIME_SCALE`` per time constant (or per 1/wn).

    The output is decimated plainly (no averaging, so white noise stays white and its level is
    kept; the level is re-read at the fitted rate on the logged samples, :func:`logged_phase`); each input is
    the mean over its kept interval (:func:`interval_mean`), so an input change between kept
    samples keeps its impulse.

    Parameters
    ----------
    records : Sequence[DofRecord]
        Records on the trial grid.
    dt : float
        Trial sample interval [s].
    dof : str
        DOF name (second order for roll and pitch).

    Returns
    -------
    tuple
        Decimated records, their sample interval [s] and the factor ``k``.
    """
    if not records:
        return list(records), dt, 1
    scale = min(_time_scale(r, dt, dof in SECOND_ORDER) for r in records)
    n_max = max(r.y.size for r in records)
    k = max(1, n_max // TARGET_SAMPLES)
    if math.isfinite(scale):
        k = min(k, max(1, int(scale / (MIN_SAMPLES_PER_TIME_SCALE * dt))))
    if k == 1:
        return list(records), dt, 1
    out = []
    for r in records:
        j, sigma = logged_phase(r.y, k, r.sigma)
        out.append(replace(r, y=r.y[j::k], inputs={c: interval_mean(u[j:], k) for c, u in r.inputs.items()},
                           sigma=sigma, offset=r.offset + j))
    return out, dt * k, k


def interval_mean(u: np.ndarray, k: int) -> np.ndarray:
    """A held input decimated by ``k``: the mean over each kept interval ``[i k, (i + 1) k)`` [unit of u].

    The fit holds each decimated input over one decimated interval. Taking the sample at the
    interval's start instead would move an input change that falls inside the interval to its
    start: a thrust cut one trial sample after a coast-down record starts would act for a whole
    decimated interval, and the record's first sample would then be off by ``tau / M_ii`` times
    that extra time (4-5 noise standard deviations in the damping benchmark's catamaran, enough to
    bias the surge terms). The mean keeps the impulse of every interval.

    Parameters
    ----------
    u : numpy.ndarray
        Input on the trial grid, held between samples [unit of u].
    k : int
        Decimation factor.
    """
    u = np.asarray(u, float)
    if k <= 1 or u.size == 0:
        return u.copy()
    n = -(-u.size // k)
    pad = np.concatenate([u, np.full(n * k - u.size, u[-1])])
    return pad.reshape(n, k).mean(axis=1)


def logged_phase(y: np.ndarray, k: int, fallback: float, ratio: float = 1.2) -> tuple[int, float]:
    """Which of the ``k`` decimation offsets keeps a channel's own logged samples, and their noise level.

    An interpolated channel (navigation-filter speed at 50 Hz on a 100 Hz grid) alternates logged
    samples (noise sigma) with interpolated ones (sigma / sqrt 2, correlated). Decimated from
    wherever a record happens to start, one record keeps logged samples and the next interpolated
    ones, and their noise levels read by second differences (so their weights) differ up to 2.5x.
    The offset whose samples look noisiest (by more than ``ratio`` over the quietest) is the logged
    one; without such a contrast (a channel logged at the trial rate) the record keeps offset 0.

    Parameters
    ----------
    y : numpy.ndarray
        Record on the trial grid [unit of y].
    k : int
        Decimation factor.
    fallback : float
        Noise level returned when no offset gives a finite positive estimate [unit of y].
    ratio : float
        Contrast between the noisiest and quietest offset that marks an interpolated channel [-].

    Returns
    -------
    tuple[int, float]
        Offset (samples dropped at the record start) and the noise standard deviation at the
        fitted rate [unit of y].
    """
    ests = []
    for j in range(max(int(k), 1)):
        yy = y[j::k]
        s = noise_sigma(yy[np.isfinite(yy)])
        ests.append(s if math.isfinite(s) and s > 0 else math.nan)
    ests = np.array(ests)
    if not np.isfinite(ests).any():
        return 0, fallback
    j = int(np.nanargmax(ests)) if np.nanmax(ests) > ratio * np.nanmin(ests) else 0
    return j, float(ests[j]) if math.isfinite(ests[j]) else float(np.nanmax(ests))


def _pad(arrays: Sequence[np.ndarray], n: int, fill: float = np.nan) -> np.ndarray:
    out = np.full((len(arrays), n), fill)
    for i, a in enumerate(arrays):
        out[i, : a.size] = a
    return out


# --------------------------------------------------------------------------- problem
class JointProblem:
    """The stacked joint problem of one DOF (built by :func:`problem`): shared parameters,
    per-record initial states, noise-weighted residuals.

    Parameters
    ----------
    records : Sequence[DofRecord]
        The DOF's records.
    dof : str
        DOF name.
    dt : float
        Sample interval [s].
    mass : float
        ``M_ii`` [kg or kg m^2] (NaN: force gains fitted).
    quadratic : bool
        Include ``b``.
    steady : Sequence[SteadyPoint]
        Steady force-speed points.
    drift : bool
        First-order DOFs: a constant offset per record between the measured and the modelled
        velocity (speed over ground = speed through the water + current along the track) [SI].
    """

    def __init__(self, records: Sequence[DofRecord], dof: str, dt: float, mass: float, quadratic: bool,
                 steady: Sequence[SteadyPoint] = (), drift: bool = False) -> None:
        self.records = list(records)
        self.dof = dof
        self.dt = dt
        self.second = dof in SECOND_ORDER
        self.quadratic = quadratic
        self.mass = mass
        self.steady = list(steady)
        force_ch = DOF_CHANNELS[dof][1]
        chans = sorted({c for r in self.records for c in r.inputs if np.any(r.inputs[c] != 0)})
        if self.steady:
            chans = sorted(set(chans) | {force_ch})
        self.fixed_gain = {c: 1.0 / mass for c in chans if c == force_ch and math.isfinite(mass) and mass > 0}
        self.free_gains = [c for c in chans if c not in self.fixed_gain]
        self.names = ("a",) + (("b",) if quadratic else ()) + (("c",) if self.second else ()) + tuple(
            f"g_{c}" for c in self.free_gains)
        self.n_len = max(r.y.size for r in self.records)
        self.Y = _pad([r.y for r in self.records], self.n_len)
        self.W = 1.0 / np.array([r.sigma for r in self.records])[:, None]
        self.angle = np.array([r.output == "angle" for r in self.records])
        self.U = {c: _pad([r.inputs.get(c, np.zeros(r.y.size)) for r in self.records], self.n_len, 0.0) for c in chans}
        # Local parameters per record: nu0 (all); eta0 (second order); offset (measured angle).
        self.drift = bool(drift) and not self.second
        self.n_loc = 1 + (2 if self.second else 0) + (1 if self.drift else 0)
        self.mask = np.isfinite(self.Y)

    def split(self, theta: np.ndarray) -> tuple[dict, np.ndarray]:
        """Shared parameters by name and the per-record locals (records x locals).

        Parameters
        ----------
        theta : numpy.ndarray
            Shared then per-record parameters.
        """
        g = dict(zip(self.names, theta[: len(self.names)]))
        loc = theta[len(self.names):].reshape(len(self.records), self.n_loc)
        return g, loc

    def force(self, g: dict) -> np.ndarray:
        """Force over inertia per record and sample [m/s^2 or rad/s^2].

        Parameters
        ----------
        g : dict
            Shared parameters by name (the free input gains).
        """
        f = np.zeros((len(self.records), self.n_len))
        for c, u in self.U.items():
            f += (self.fixed_gain[c] if c in self.fixed_gain else g[f"g_{c}"]) * u
        return f

    def simulate(self, theta: np.ndarray) -> np.ndarray:
        """Model output per record and sample (padding included) [SI of the output].

        Parameters
        ----------
        theta : numpy.ndarray
            Shared then per-record parameters.
        """
        g, loc = self.split(theta)
        a, b, c = g["a"], g.get("b", 0.0), g.get("c", 0.0)
        f = self.force(g)
        if not self.second:
            x = simulate_dof(loc[:, 0], f, self.dt, a, b, substeps=self.substeps(a, c))
            return x + loc[:, 1][:, None] if self.drift else x
        # Offset of a measured angle's equilibrium: a constant external moment c * offset.
        f = f + c * np.where(self.angle, loc[:, 2], 0.0)[:, None]
        x = simulate_dof(np.column_stack([loc[:, 0], loc[:, 1]]), f, self.dt, a, b, c, self.substeps(a, c))
        return np.where(self.angle[:, None], x[:, :, 1], x[:, :, 0])

    def substeps(self, a: float, c: float) -> int:
        """RK4 steps per sample: ``h`` times the fastest rate (a, sqrt(c)) at most 0.2 (error < 1e-6).

        Parameters
        ----------
        a : float
            Linear damping over inertia [1/s].
        c : float
            Restoring over inertia [1/s^2].
        """
        rate = max(abs(a), math.sqrt(abs(c)), 1e-12)
        return int(min(max(math.ceil(self.dt * rate / 0.2), 1), 50))

    def steady_rows(self, theta: np.ndarray) -> np.ndarray:
        """Weighted residuals of the steady-state points (empty without them) [-].

        Parameters
        ----------
        theta : numpy.ndarray
            Shared then per-record parameters.
        """
        if not self.steady:
            return np.zeros(0)
        g, _ = self.split(theta)
        a, b = g["a"], g.get("b", 0.0)
        ch = DOF_CHANNELS[self.dof][1]
        gain = self.fixed_gain.get(ch, g.get(f"g_{ch}", math.nan))
        u = np.array([p.speed for p in self.steady])
        tau = np.array([p.force for p in self.steady])
        sd = np.hypot(gain * np.array([p.force_se for p in self.steady]),
                      (a + 2 * b * np.abs(u)) * np.array([p.speed_se for p in self.steady]))
        return (gain * tau - a * u - b * np.abs(u) * u) / np.maximum(sd, 1e-12)

    def residual_matrix(self, theta: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Noise-weighted residuals (records x samples), zero outside ``mask`` [-].

        Parameters
        ----------
        theta : numpy.ndarray
            Shared then per-record parameters.
        mask : numpy.ndarray
            Samples that count.
        """
        yhat = self.simulate(theta)
        r = (self.Y - yhat) * self.W
        r = np.where(np.isfinite(r), r, _DIVERGED)
        return np.where(mask, r, 0.0)

    def residuals(self, theta: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """The least-squares residual vector: masked samples, then steady-state rows [-].

        Parameters
        ----------
        theta : numpy.ndarray
            Shared then per-record parameters.
        mask : numpy.ndarray
            Samples that count.
        """
        return np.concatenate([self.residual_matrix(theta, mask)[mask], self.steady_rows(theta)])

    def jacobian(self, theta: np.ndarray, mask: np.ndarray, free_locals: np.ndarray,
                 r0: np.ndarray | None = None) -> sparse.csr_matrix:
        """Forward differences: one simulation per shared parameter, one per local-parameter type
        (every record's local perturbed at once: a record's output depends only on its own).

        Sparse: a residual row has a column per shared parameter and one per local of its own
        record, so the matrix holds ``rows x (shared + locals per record)`` numbers, linear in the
        data (a dense one grows with the square of the segment count).

        Parameters
        ----------
        theta : numpy.ndarray
            Shared then per-record parameters.
        mask : numpy.ndarray
            Samples that count.
        free_locals : numpy.ndarray
            Records x locals: which locals get a column (others stay zero).
        r0 : numpy.ndarray, optional
            ``residual_matrix(theta, mask)`` when the caller has it already (the solver evaluated the
            residuals at ``theta`` just before asking for the Jacobian there): one simulation fewer.

        Returns
        -------
        scipy.sparse.csr_matrix
            Rows: masked samples, then steady-state rows; columns: ``theta``.
        """
        if r0 is None:
            r0 = self.residual_matrix(theta, mask)
        s0 = self.steady_rows(theta)
        ng, k = len(self.names), len(self.records)
        n_mask = int(mask.sum())
        n_rows = n_mask + s0.size
        rows, cols, vals = [], [], []
        for j in range(ng):
            h = 1e-6 * max(abs(theta[j]), 1e-3)
            th = theta.copy()
            th[j] += h
            col = np.concatenate([((self.residual_matrix(th, mask) - r0) / h)[mask], (self.steady_rows(th) - s0) / h])
            rows.append(np.arange(n_rows))
            cols.append(np.full(n_rows, j))
            vals.append(col)
        rec_of_row = np.broadcast_to(np.arange(k)[:, None], mask.shape)[mask]
        for l in range(self.n_loc):
            idx = ng + np.arange(k) * self.n_loc + l
            h = 1e-6 * np.maximum(np.abs(theta[idx]), 1e-3)
            th = theta.copy()
            th[idx] += h
            d = ((self.residual_matrix(th, mask) - r0) / h[:, None])[mask]
            keep = free_locals[rec_of_row, l]
            rows.append(np.flatnonzero(keep))
            cols.append(ng + rec_of_row[keep] * self.n_loc + l)
            vals.append(d[keep])
        return sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                 shape=(n_rows, theta.size))


# --------------------------------------------------------------------------- starts
def _start(p: JointProblem) -> np.ndarray:
    """Closed-form starts: per-segment exponential or damped-cosine guesses, their median shared."""
    a_s, c_s, locs, gains = [], [], [], {c: [] for c in p.free_gains}
    t = np.arange(p.n_len) * p.dt
    for r in p.records:
        ok = np.isfinite(r.y)
        tt, yy = t[: r.y.size][ok], r.y[ok]
        if not p.second:
            try:
                gs = guess_step(tt, yy) if r.kind == "step" else {**guess_decay(tt, yy), "y_ss": 0.0}
                T = gs["T"] if math.isfinite(gs["T"]) and gs["T"] > 0 else tt[-1]
            except (ValueError, np.linalg.LinAlgError):
                gs, T = {"y_ss": 0.0}, max(float(tt[-1]), p.dt)
            a_s.append(1.0 / T)
            locs.append([float(np.mean(yy[:3]))] + ([0.0] if p.drift else []))
            for c in p.free_gains:
                u = r.inputs.get(c)
                if u is not None and r.kind == "step" and abs(u[-1]) > 0:
                    gains[c].append(gs["y_ss"] / (T * u[-1]))
        else:
            try:
                gd = guess_damped_oscillation(tt, yy)
                wn, zeta, A, ph, off = gd["wn"], gd["zeta"], gd["A"], gd["phase"], gd["offset"]
            except (FitError, ValueError, np.linalg.LinAlgError):
                wn, zeta, A, ph, off = 2 * math.pi / max(float(tt[-1]), p.dt), 0.1, float(yy[0]), 0.0, 0.0
            wd = wn * math.sqrt(max(1 - zeta**2, 1e-6))
            v0 = A * math.cos(ph)
            vdot0 = A * (-zeta * wn * math.cos(ph) - wd * math.sin(ph))
            a_s.append(2 * zeta * wn)
            c_s.append(wn**2)
            if r.output == "angle":
                locs.append([vdot0, v0, off])
            else:
                locs.append([v0 + off, -(vdot0 + 2 * zeta * wn * v0) / wn**2, 0.0])
    g = {"a": float(np.median(a_s)), "b": 0.0, "c": float(np.median(c_s)) if c_s else 0.0}
    for c in p.free_gains:
        g[f"g_{c}"] = float(np.median(gains[c])) if gains[c] else g["a"]
    return np.concatenate([[g[n] for n in p.names], np.ravel(locs)])


def _bounds(p: JointProblem, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lo = np.full(theta.size, -np.inf)
    hi = np.full(theta.size, np.inf)
    y_max = max(float(np.nanmax(np.abs(p.Y))), 1e-12)
    if p.second:
        # The quadratic term acts on the rate; a measured angle times wn bounds it.
        wn = math.sqrt(max(float(theta[p.names.index("c")]), 0.0))
        y_max = max(y_max * max(wn, 1.0), float(np.nanmax(np.abs(theta[len(p.names)::p.n_loc]))))
    for j, n in enumerate(p.names):
        if n == "a":
            lo[j] = 1e-9
        elif n == "b":
            # Negative quadratic damping is allowed (a linear truth gives b scattered about 0) as
            # long as the total damping a + b |nu| stays positive over the data.
            lo[j] = -0.9 * theta[0] / y_max
        elif n == "c":
            lo[j] = 1e-9
    return lo, hi


# --------------------------------------------------------------------------- fit
def _solve(p: JointProblem, theta0: np.ndarray, mask: np.ndarray, fixed_shared: bool = False,
           max_nfev: int = 100) -> np.ndarray:
    """Least squares on the residual rows in ``mask``; records with no row keep their start locals.
    ``fixed_shared`` fits only the locals (held-out initial states)."""
    ng = len(p.names)
    has_rows = mask.any(axis=1)
    free = np.ones(theta0.size, bool)
    free[:ng] = not fixed_shared
    loc_free = np.repeat(has_rows[:, None], p.n_loc, axis=1)
    if p.second:
        loc_free[:, 2] &= p.angle
    free[ng:] = loc_free.ravel()
    lo, hi = _bounds(p, theta0)
    x0 = np.clip(theta0, lo, hi)
    at_lo = np.isfinite(lo) & (x0 <= lo)
    x0[at_lo] = lo[at_lo] + 1e-9 * np.maximum(np.abs(lo[at_lo]), 1e-9)

    def full(x):
        th = theta0.copy()
        th[free] = x
        return th

    # The solver asks for the Jacobian where it last evaluated the residuals (the accepted point):
    # that residual matrix is kept and reused as the Jacobian's base point (the same numbers, one
    # simulation fewer per Jacobian).
    last: dict[str, object] = {}

    def fun(x):
        th = full(x)
        rm = p.residual_matrix(th, mask)
        last["x"], last["r"] = x.copy(), rm
        return np.concatenate([rm[mask], p.steady_rows(th)])

    dense = int(free.sum()) <= DENSE_MAX_PARAMETERS

    def jac(x):
        x_last = last.get("x")
        r0 = last["r"] if x_last is not None and x_last.tobytes() == np.asarray(x).tobytes() else None
        j = p.jacobian(full(x), mask, loc_free, r0=r0)[:, free]
        return j.toarray() if dense else j

    res = optimize.least_squares(fun, x0[free], jac=jac, bounds=(lo[free], hi[free]), x_scale="jac",
                                 method="trf", max_nfev=max_nfev, tr_solver="exact" if dense else "lsmr",
                                 tr_options={} if dense else LSMR_OPTIONS)
    return full(res.x)


def _derived_terms(p: JointProblem, values: np.ndarray, cov: np.ndarray) -> tuple[dict, np.ndarray]:
    """Fossen derivatives ``X_u = -M_ii a``, ``X_|u|u = -M_ii b`` and their covariance."""
    if not (math.isfinite(p.mass) and p.mass > 0):
        return {}, np.zeros((0, 0))
    lin, quad = TERM_NAMES[p.dof]
    u1, u2 = TERM_UNITS[p.dof]
    idx = [p.names.index("a")] + ([p.names.index("b")] if p.quadratic else [])
    c = p.mass**2 * cov[np.ix_(idx, idx)]
    vals = -p.mass * values[idx]
    se = np.sqrt(np.clip(np.diag(c), 0, None))
    terms = {lin: (float(vals[0]), float(se[0]), u1)}
    if p.quadratic:
        terms[quad] = (float(vals[1]), float(se[1]), u2)
    return terms, c


def shared_hac_covariance(jac: sparse.spmatrix, resid: np.ndarray, groups: np.ndarray, ng: int
                          ) -> tuple[np.ndarray, float]:
    """The shared parameters' block of :func:`pipeline.fit.robust_covariance.hac_covariance`, from
    the sparse Jacobian without forming a dense matrix of all parameters.

    With ``J = [G L]`` (shared columns ``G``; per-record locals ``L``, block-diagonal by record) the
    shared rows of ``(J^T J)^-1`` are ``S^-1 [I, -C^T]`` with ``C = (L^T L)^-1 L^T G`` and the Schur
    complement ``S = G^T (G - L C)``. The sandwich's shared block is then the Newey-West long-run
    covariance of the projected scores ``z_t = r_t S^-1 (G - L C)_t`` (ng numbers per row), summed
    over Bartlett lags within each record and scaled by ``n / (n - k)`` -- algebraically the dense
    result, at a cost linear in the rows.

    Parameters
    ----------
    jac : scipy.sparse.spmatrix
        Jacobian of the weighted residuals (n x k), the ``ng`` shared columns first.
    resid : numpy.ndarray
        Residuals at the solution (n), time-ordered within each record.
    groups : numpy.ndarray
        Record index per residual (n).
    ng : int
        Number of shared parameters.

    Returns
    -------
    covariance : numpy.ndarray
        ``ng x ng`` sandwich covariance [units of the parameters squared].
    rho : float
        Pooled lag-1 autocorrelation of the residuals [-].

    Raises
    ------
    numpy.linalg.LinAlgError
        Singular ``L^T L`` or Schur complement.
    """
    from scipy.sparse.linalg import splu

    jac = sparse.csc_matrix(jac)
    r = np.asarray(resid, float)
    g = np.asarray(groups)
    n, k = jac.shape
    G = jac[:, :ng].toarray()
    L = jac[:, ng:]
    if L.shape[1]:
        try:
            C = splu(sparse.csc_matrix(L.T @ L)).solve(np.asarray(L.T @ G))
        except RuntimeError as exc:  # exactly singular local block
            raise np.linalg.LinAlgError(str(exc)) from exc
        Gt = G - L @ C
    else:
        Gt = G
    S = G.T @ Gt
    S = 0.5 * (S + S.T)
    z = (Gt * r[:, None]) @ np.linalg.inv(S)
    rho = pooled_lag1(r, g)
    sizes = np.unique(g, return_counts=True)[1]
    lags = andrews_bandwidth(rho, int(np.median(sizes)))
    meat = z.T @ z
    for lag in range(1, lags + 1):
        same = g[lag:] == g[:-lag]
        if not same.any():
            break
        c = z[lag:][same].T @ z[:-lag][same]
        meat += (1.0 - lag / (lags + 1.0)) * (c + c.T)
    cov = meat * (n / max(n - k, 1))
    if not np.all(np.isfinite(cov)):
        raise np.linalg.LinAlgError("non-finite shared covariance")
    return cov, rho


def fit_dof(records: Sequence[DofRecord], dof: str, dt: float, mass: float, structure: str,
            steady: Sequence[SteadyPoint] = (), start: np.ndarray | None = None, drift: bool = False) -> DampingFit:
    """Fit one damping structure jointly to every record of a DOF.

    Parameters
    ----------
    records : Sequence[DofRecord]
        From :func:`dof_records` (at least one).
    dof : str
        DOF name.
    dt : float
        Sample interval [s].
    mass : float
        ``M_ii`` of the vessel config [kg or kg m^2]; NaN when unknown (then a force input's gain is
        fitted and no Fossen derivatives are given).
    structure : str
        ``linear`` or ``quadratic``.
    steady : Sequence[SteadyPoint]
        Steady-state force-speed points fitted together with the transients (surge, sway, yaw).
    start : numpy.ndarray, optional
        Start vector (shared then local parameters of the linear structure), e.g. the linear fit's.
    drift : bool
        Fit a constant velocity offset per record (current along the track; first-order DOFs).

    Returns
    -------
    DampingFit

    Raises
    ------
    FitError
        No records, or an unknown structure.
    """
    if structure not in ("linear", "quadratic"):
        raise FitError(f"{dof}: expected structure 'linear' or 'quadratic', found {structure!r}")
    if not records:
        raise FitError(f"{dof}: no usable segment for a joint damping fit (expected coast-downs, steps "
                       f"or free decays with at least {MIN_RECORD_SAMPLES} samples)")
    p = JointProblem(records, dof, dt, mass, structure == "quadratic", steady, drift)
    theta0 = _start(p) if start is None else _expand(start, p)
    theta = _solve(p, theta0, p.mask)
    return _result(p, theta, structure)


def _expand(linear_theta: np.ndarray, p: JointProblem) -> np.ndarray:
    """A linear structure's parameter vector with ``b = 0`` inserted for the quadratic one."""
    if not p.quadratic:
        return np.asarray(linear_theta, float)
    return np.concatenate([linear_theta[:1], [0.0], linear_theta[1:]])


def _result(p: JointProblem, theta: np.ndarray, structure: str) -> DampingFit:
    mask = p.mask
    ng = len(p.names)
    r = p.residuals(theta, mask)
    loc_free = np.ones((len(p.records), p.n_loc), bool)
    if p.second:
        loc_free[:, 2] = p.angle
    jac = p.jacobian(theta, mask, loc_free)
    keep = np.concatenate([np.ones(ng, bool), loc_free.ravel()])
    jac = jac[:, keep]
    n, k = r.size, int(keep.sum())
    dof_resid = max(n - k, 1)
    msg = []
    # Residual rows in order: each record's samples in time order, then one group per steady point.
    groups = np.concatenate([np.broadcast_to(np.arange(len(p.records))[:, None], mask.shape)[mask],
                             len(p.records) + np.arange(r.size - int(mask.sum()))])
    try:
        if k <= DENSE_MAX_PARAMETERS:
            robust = hac_covariance(jac.toarray(), r, groups)
            cov, lag = robust.covariance[:ng, :ng], robust.rho
        else:
            cov, lag = shared_hac_covariance(jac, r, groups, ng)
    except (np.linalg.LinAlgError, ValueError, RuntimeError):
        cov = np.full((ng, ng), np.nan)
        lag = math.nan
        msg.append("covariance not computed: singular Jacobian")
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    vals = theta[:ng]
    terms, tcov = _derived_terms(p, vals, cov)
    yhat = p.simulate(theta)
    ok = bool(np.all(np.isfinite(se)) and np.all(np.isfinite(yhat[mask])))
    if abs(lag) > 0.5:
        msg.append(f"residuals coloured (lag-1 autocorrelation {lag:.2f}): standard errors from the HAC sandwich")
    return DampingFit(dof=p.dof, structure=structure, names=p.names, values=vals.copy(), stderr=se, covariance=cov,
                    terms=terms, term_covariance=tcov, rmse=float(math.sqrt(float(r @ r) / max(n, 1))), lag1=lag,
                    n=n, dof_resid=dof_resid,
                    y_fit=tuple(yhat[i, : rec.y.size] for i, rec in enumerate(p.records)), success=ok,
                    message="; ".join(msg), initial_states=theta[ng:].copy(), inertia=float(p.mass))


def problem(records: Sequence[DofRecord], dof: str, dt: float, mass: float, structure: str,
            steady: Sequence[SteadyPoint] = (), drift: bool = False) -> JointProblem:
    """The stacked problem of :func:`fit_dof` (for held-out scoring in :mod:`pipeline.fit.structure`).

    Parameters
    ----------
    records, dof, dt, mass, structure, steady, drift
        As for :func:`fit_dof`.
    """
    return JointProblem(records, dof, dt, mass, structure == "quadratic", steady, drift)


def solve(p: JointProblem, theta0: np.ndarray, mask: np.ndarray, fixed_shared: bool = False,
          max_nfev: int = 100) -> np.ndarray:
    """Fit ``p`` on the residual rows in ``mask`` from ``theta0`` (see :func:`fit_dof`).

    Parameters
    ----------
    p : JointProblem
        From :func:`problem`.
    theta0 : numpy.ndarray
        Start (shared then per-record parameters).
    mask : numpy.ndarray
        Samples (records x samples) that enter the fit.
    fixed_shared : bool
        Keep the shared parameters at ``theta0`` and fit only the per-record initial states.
    max_nfev : int
        Most residual evaluations of the solver.
    """
    return _solve(p, theta0, mask, fixed_shared, max_nfev)


def start_vector(p: JointProblem) -> np.ndarray:
    """Closed-form start of :func:`problem` ``p``.

    Parameters
    ----------
    p : JointProblem
        From :func:`problem`.
    """
    return _start(p)


def expand_linear(linear_theta: np.ndarray, p: JointProblem) -> np.ndarray:
    """A linear structure's vector with ``b = 0`` inserted when ``p`` is quadratic.

    Parameters
    ----------
    linear_theta : numpy.ndarray
        Shared then per-record parameters of the linear structure.
    p : JointProblem
        Target problem.
    """
    return _expand(linear_theta, p)
