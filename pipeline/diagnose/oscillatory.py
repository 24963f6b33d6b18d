"""Roll and pitch: oscillatory DOFs with a restoring moment, analysed like the others.

The first-order machinery (:mod:`pipeline.diagnose.gridfit`) has no restoring term, so roll and
pitch get their own baseline, the linear mass-damper-spring of Fossen (2021, sec. 4.3)::

    phi_dot = p,     p_dot = -2 zeta omega_n p - omega_n^2 phi + b tau_k

and one candidate, ``nonlinear_damping``: ``- d2 |p| p`` added to ``p_dot`` (amplitude-dependent
decay; Himeno 1981). Windows are the segments of the DOF (free decays, heeling tests); a window
is integrated (RK4, the input held) from its own measured initial state (angle and rate at its
start, about the equilibrium where it settles); it never crosses a gap. The
parameters are fitted by output error on the training folds; the held-out outputs go through the
same significance test (:func:`pipeline.diagnose.significance.score`), so roll and pitch
candidates compete with every other DOF's under one ranking rule.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
import scipy.optimize

from ..records import Segments, Trial
from ..segment import noise_std
from ..segment.replay import gaps_of
from .gridfit import GridData, channel_scale
from .problem import Window, block_noise, halves

#: DOF -> (rate channel, angle channel, moment input).
CHANNELS: Mapping[str, tuple[str, str, str]] = {"roll": ("p", "phi", "tau_k"), "pitch": ("q", "theta", "tau_m")}
#: Analysis steps per natural period.
STEPS_PER_PERIOD = 20
#: RK4 sub-steps per analysis step.
SUBSTEPS = 1
#: Shortest usable window, in natural periods.
MIN_PERIODS = 1.5
#: Fewest logged samples per natural period for the DOF to be analysed: below it the log cannot
#: resolve the oscillation (AAUSHIP's 0.6 s roll at 1-5 Hz), and a replay on such a grid is a
#: model error of the discretisation, not a gap of the boat. The fit stage says "not identified".
MIN_SAMPLES_PER_PERIOD = 5.0


@dataclass(frozen=True)
class OscProblem:
    """One roll or pitch problem on its analysis grid.

    Attributes
    ----------
    dof, rate, angle : str
        DOF, rate channel (None when not logged) and angle channel.
    inputs : tuple[str, ...]
        Moment input when logged and varying, else empty (free decays only).
    dt : float
        Analysis step [s].
    windows : tuple[Window, ...]
        Windows (trial sample ranges).
    omega_guess : float
        Natural frequency from the residual spectrum [rad/s].
    data : GridData
        Block means of the rate (``y``) and angle (``angle``) per window, noise levels and scales.
    u : numpy.ndarray
        Input block means per window (W, n), zero without input.
    channel : str
        Response channel name scored as ``y`` (the rate, or the angle's derivative when no rate).
    m : int
        Trial samples per analysis step.
    raw : Mapping[str, numpy.ndarray]
        Trial-rate inputs (for the residual's correlations).
    """

    dof: str
    rate: str | None
    angle: str
    inputs: tuple[str, ...]
    dt: float
    windows: tuple[Window, ...]
    omega_guess: float
    data: GridData = field(repr=False)
    u: np.ndarray = field(repr=False)
    channel: str = ""
    m: int = 1
    raw: Mapping[str, np.ndarray] = field(default_factory=dict, repr=False)

    @property
    def n(self) -> int:
        """Analysis samples of the longest window."""
        return int(self.data.y.shape[1])

    @property
    def t_guess(self) -> float:
        """``1 / omega_n`` [s]: the time scale that sizes the frequency bands."""
        return 1.0 / self.omega_guess

    @property
    def outputs(self) -> tuple[str, ...]:
        """Channels scored."""
        return tuple(c for c in (self.rate, self.angle) if c)


def _natural_frequency(x: np.ndarray, fs: float) -> float:
    """Natural frequency [rad/s] of a decaying oscillation: the poles of an AR(2) model fitted by
    least squares to the record at a step of about a twentieth of its period (a periodogram of a
    strongly damped one-second decay cannot resolve its frequency).

    Parameters
    ----------
    x : numpy.ndarray
        Angle record at the trial rate [rad].
    fs : float
        Trial rate [Hz].
    """
    x = x[np.isfinite(x)]
    if len(x) < 16:
        return math.nan
    best = math.nan
    for step in (1, 2, 4, 8, 16):
        y = x[::step] - np.mean(x[::step])
        if len(y) < 12:
            break
        a = np.column_stack([y[1:-1], y[:-2]])
        coef, *_ = np.linalg.lstsq(a, y[2:], rcond=None)
        z = np.roots([1.0, -coef[0], -coef[1]])
        if np.all(np.abs(np.imag(z)) < 1e-12):
            continue
        s_pole = np.log(z[0].astype(complex)) * fs / step
        wn = float(abs(s_pole))
        best = wn
        # Stop at the first step that resolves the period with at least ~8 samples.
        if 2 * np.pi / wn * fs / step < 40:
            break
    return best


def build_oscillatory(trial: Trial, segments: Segments, dof: str) -> OscProblem | None:
    """The roll or pitch problem of a trial, or None when the DOF is not measured or not excited.

    Parameters
    ----------
    trial : Trial
        Aligned trial.
    segments : Segments
        Its segments; those of ``dof`` are the windows.
    dof : str
        ``roll`` or ``pitch``.
    """
    rate, angle, force = CHANNELS[dof]
    if not trial.has(angle):
        return None
    fs, t = trial.fs, trial.t
    segs = [s for s in segments.items if s.dof == dof and s.t_end > s.t_start]
    if not segs:
        return None
    ang = trial.data[angle].to_numpy(float)
    spans = [(int(np.searchsorted(t, s.t_start)), int(np.searchsorted(t, s.t_end))) for s in segs]
    oms = [_natural_frequency(ang[a:b], fs) for a, b in spans if b - a >= 16]
    om = float(np.nanmedian(oms)) if any(np.isfinite(oms)) else math.nan
    if not (math.isfinite(om) and om > 0):
        return None
    period = 2 * np.pi / om
    if period * fs < MIN_SAMPLES_PER_PERIOD:
        return None
    m = max(int(round(period / STEPS_PER_PERIOD * fs)), 1)
    dt = m / fs
    wins = []
    gaps = gaps_of(trial, (rate, angle, force))
    for s, (a, b) in zip(segs, spans):
        for ga, gb in _gap_free(trial, a, b, gaps):
            if (gb - ga) / fs >= MIN_PERIODS * period and (gb - ga) // m >= 8:
                wins.append(Window(ga, gb, float(t[ga]), float(t[gb - 1]), (s.kind,), (dof,), s.kind))
    if len(wins) == 1 and (wins[0].i1 - wins[0].i0) / fs >= 2 * MIN_PERIODS * period:
        wins = halves(wins[0], t)
    if len(wins) < 2:
        return None
    n = max((w.i1 - w.i0) // m for w in wins)

    def grid(x: np.ndarray) -> np.ndarray:
        out = np.full((len(wins), n), np.nan)
        for k, w in enumerate(wins):
            nb = (w.i1 - w.i0) // m
            # Point samples at the analysis grid (the RK4 states), not block means: the model is
            # integrated between grid points.
            out[k, :nb] = x[w.i0:w.i0 + nb * m:m]
        return out

    a_g = grid(ang)
    has_rate = trial.has(rate)
    r_raw = trial.data[rate].to_numpy(float) if has_rate else np.gradient(ang, 1.0 / fs)
    r_g = grid(r_raw)
    inputs: tuple[str, ...] = ()
    raw: dict[str, np.ndarray] = {}
    u_g = np.zeros_like(a_g)
    if trial.has(force):
        u_raw = trial.data[force].to_numpy(float)
        if np.nanmax(np.abs(u_raw)) > 0:
            inputs = (force,)
            raw[force] = np.nan_to_num(u_raw)
            u_g = np.nan_to_num(grid(u_raw))
    mask = np.isfinite(a_g) & np.isfinite(r_g)
    # Noise of a point sample (m = 1 blocks), measured on the windows.
    s_a = block_noise(ang, tuple(wins), 1)
    s_r = block_noise(r_raw, tuple(wins), 1) if has_rate else math.nan
    if not math.isfinite(s_a) or s_a <= 0:
        s_a = noise_std(ang)
    peak = np.nanmax(np.abs(a_g - np.nanmean(a_g, axis=1, keepdims=True)))
    if not (peak > 10 * max(s_a, 1e-12)):
        return None
    data = GridData(dt=dt, y=r_g, y0=np.nan_to_num(r_g[:, 0]), angle=a_g, mask=mask, m=1,
                    w_y=1.0 / channel_scale(r_g, mask), w_angle=1.0 / channel_scale(a_g, mask),
                    sigma_y=s_r if has_rate else math.nan, sigma_angle=s_a)
    return OscProblem(dof=dof, rate=rate if has_rate else None, angle=angle, inputs=inputs, dt=dt,
                      windows=tuple(wins), omega_guess=float(om), data=data, u=u_g,
                      channel=rate if has_rate else f"d{angle}/dt", m=m, raw=raw)


def _gap_free(trial: Trial, a: int, b: int, gaps: tuple) -> list[tuple[int, int]]:
    pieces = [(a, b)]
    t = trial.t
    for g in gaps:
        ga, gb = int(np.searchsorted(t, g.t_start)), int(np.searchsorted(t, g.t_end))
        nxt = []
        for x, y in pieces:
            if ga >= y or gb <= x:
                nxt.append((x, y))
                continue
            nxt += [(x, ga)] if ga - x >= 4 else []
            nxt += [(gb, y)] if y - gb >= 4 else []
        pieces = nxt
    return pieces


def simulate(theta: np.ndarray, x0: np.ndarray, u: np.ndarray, dt: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Integrate every window at once (RK4, ``SUBSTEPS`` per step, input held over a step).

    Parameters
    ----------
    theta : numpy.ndarray
        ``(log omega_n, zeta, b, d2)`` [log rad/s, -, rad/s^2 per input unit, 1/rad].
    x0 : numpy.ndarray, shape (W, 2)
        Initial angle [rad] and rate [rad/s] per window.
    u : numpy.ndarray, shape (W, n)
        Held input.
    dt : float
        Step [s].
    n : int
        Steps.

    Returns
    -------
    angle, rate : numpy.ndarray
        (W, n) each, at the grid points.
    """
    wn = math.exp(theta[0])
    c1, c0, b, d2 = 2 * float(theta[1]) * wn, wn * wn, float(theta[2]), float(theta[3])
    w_count = len(x0)
    ang, rate = np.full((w_count, n), np.nan), np.full((w_count, n), np.nan)
    h = dt / SUBSTEPS
    # Plain floats, one window at a time: a few windows of a few hundred steps, where numpy's
    # per-call overhead on arrays of two elements would cost a hundred times the arithmetic.
    for w in range(w_count):
        x, v = float(x0[w, 0]), float(x0[w, 1])
        uu = u[w].tolist()
        aw, rw = ang[w], rate[w]
        for k in range(n):
            aw[k], rw[k] = x, v
            f = b * uu[k]
            for _ in range(SUBSTEPS):
                k1x, k1v = v, f - c1 * v - d2 * abs(v) * v - c0 * x
                vx = v + 0.5 * h * k1v
                k2x, k2v = vx, f - c1 * vx - d2 * abs(vx) * vx - c0 * (x + 0.5 * h * k1x)
                vx = v + 0.5 * h * k2v
                k3x, k3v = vx, f - c1 * vx - d2 * abs(vx) * vx - c0 * (x + 0.5 * h * k2x)
                vx = v + h * k3v
                k4x, k4v = vx, f - c1 * vx - d2 * abs(vx) * vx - c0 * (x + h * k3x)
                x += h / 6 * (k1x + 2 * k2x + 2 * k3x + k4x)
                v += h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
            if not (abs(x) < 1e6 and abs(v) < 1e6):
                break
    return ang, rate


def _resid(p: OscProblem, idx: np.ndarray, theta: np.ndarray, x0: np.ndarray) -> np.ndarray:
    d = p.data
    n = d.y.shape[1]
    # Equilibrium offsets (a heel from a sensor mounting or a steady wind) per window.
    ang, rate = simulate(theta, x0[:, :2], p.u[idx], p.dt, n)
    ang = ang + x0[:, 2:3]
    msk = d.mask[idx]
    out = [np.where(msk, (d.angle[idx] - ang) * d.w_angle, 0.0)]
    if p.rate is not None:
        out.append(np.where(msk, (d.y[idx] - rate) * d.w_y, 0.0))
    r = np.concatenate([o.ravel() for o in out])
    return np.where(np.isfinite(r), r, 1e3)


def _x0_guess(p: OscProblem, idx: np.ndarray) -> np.ndarray:
    """Measured start of each window: angle above its equilibrium, rate, and the equilibrium
    (median of the window's last third, where a decay has settled) [rad, rad/s, rad]."""
    a0 = p.data.angle[idx]
    out = np.zeros((len(idx), 3))
    for k in range(len(idx)):
        row = a0[k][np.isfinite(a0[k])]
        if not len(row):
            continue
        off = float(np.median(row[2 * len(row) // 3:]))
        out[k] = (row[0] - off, np.nan_to_num(p.data.y[idx[k], 0]), off)
    return out


def fit(p: OscProblem, idx: np.ndarray, nonlinear: bool, start: np.ndarray | None = None) -> np.ndarray:
    """Fit the model parameters by output error on windows ``idx``, each window started from its
    measured state (:func:`_x0_guess`).

    Parameters
    ----------
    p : OscProblem
        The problem.
    idx : numpy.ndarray
        Window indices.
    nonlinear : bool
        Fit ``d2`` as well (else it stays 0).
    start : numpy.ndarray, optional
        Parameters to start from.

    Returns
    -------
    numpy.ndarray
        ``(log omega_n, zeta, b, d2)``.
    """
    th0 = np.array([math.log(p.omega_guess), 0.1, 0.0, 0.0]) if start is None else np.asarray(start, float).copy()
    free = [0, 1] + ([2] if p.inputs else []) + ([3] if nonlinear else [])
    x0 = _x0_guess(p, idx)

    def res(z):
        th = th0.copy()
        th[free] = z
        return _resid(p, idx, th, x0)

    lo = np.full(len(free), -np.inf)
    hi = np.full(len(free), np.inf)
    lo[1], hi[1] = 0.0, 2.0
    if nonlinear:
        lo[free.index(3)] = 0.0
    z0 = np.clip(th0[free], lo + 1e-9, hi - 1e-9)
    sol = scipy.optimize.least_squares(res, z0, bounds=(lo, hi), x_scale="jac", max_nfev=100)
    th = th0.copy()
    th[free] = sol.x
    return th


def predict(p: OscProblem, idx: np.ndarray, theta: np.ndarray) -> dict[str, np.ndarray]:
    """Held-out outputs on windows ``idx``, each started from its measured state.

    Parameters
    ----------
    p : OscProblem
        The problem.
    idx : numpy.ndarray
        Window indices.
    theta : numpy.ndarray
        Model parameters.
    """
    xx = _x0_guess(p, idx)
    ang, rate = simulate(theta, xx[:, :2], p.u[idx], p.dt, p.data.y.shape[1])
    msk = p.data.mask[idx]
    return {"y": np.where(msk, rate, np.nan), "angle": np.where(msk, ang + xx[:, 2:3], np.nan)}


def params_of(theta: np.ndarray, nonlinear: bool) -> dict[str, float]:
    """Named parameters: ``omega_n`` [rad/s], ``zeta`` [-], ``b`` and, with the effect, ``d2`` [1/rad].

    Parameters
    ----------
    theta : numpy.ndarray
        Model parameters.
    nonlinear : bool
        Include ``d2``.
    """
    out = {"omega_n": math.exp(theta[0]), "zeta": float(theta[1]), "b": float(theta[2])}
    if nonlinear:
        out["d2"] = float(theta[3])
    return out


@dataclass(frozen=True)
class OscRun:
    """Cross-validated baseline or candidate of an oscillatory DOF (the shape the selection uses).

    Attributes
    ----------
    label : str
        ``baseline`` or ``nonlinear_damping``.
    heldout : Mapping[str, numpy.ndarray]
        Held-out outputs (``"y"`` rate, ``"angle"``), (W, n) each.
    full : Mapping[str, float]
        Parameters fitted on every window.
    fold_params : tuple[Mapping[str, float], ...]
        Parameters fitted in each fold.
    fold_of : numpy.ndarray
        Fold of each window.
    """

    label: str
    heldout: Mapping[str, np.ndarray]
    full: Mapping[str, float]
    fold_params: tuple
    fold_of: np.ndarray = field(repr=False, default=None)


def cross_validate(p: OscProblem, max_folds: int = 5) -> tuple[OscRun, OscRun]:
    """Baseline and ``nonlinear_damping``, each fitted on the other folds and predicted on its own.

    Parameters
    ----------
    p : OscProblem
        The problem.
    max_folds : int
        Most folds (windows are dealt to folds in turn).
    """
    nw = len(p.windows)
    k = min(nw, max_folds)
    fold_of = np.arange(nw) % k
    shape = p.data.y.shape
    held = [{"y": np.full(shape, np.nan), "angle": np.full(shape, np.nan)} for _ in range(2)]
    fps: list[list] = [[], []]
    for f in range(k):
        train, test = np.flatnonzero(fold_of != f), np.flatnonzero(fold_of == f)
        th_b = fit(p, train, False)
        th_n = fit(p, train, True, start=th_b)
        for j, th in enumerate((th_b, th_n)):
            pred = predict(p, test, th)
            for key in ("y", "angle"):
                held[j][key][test] = pred[key]
            fps[j].append(params_of(th, j == 1))
    everything = np.arange(nw)
    th_b = fit(p, everything, False)
    th_n = fit(p, everything, True, start=th_b)
    return (OscRun("baseline", held[0], params_of(th_b, False), tuple(fps[0]), fold_of),
            OscRun("nonlinear_damping", held[1], params_of(th_n, True), tuple(fps[1]), fold_of))


#: Units of the oscillatory parameters.
UNITS: Mapping[str, str] = {"omega_n": "rad/s", "zeta": "-", "b": "(rad/s^2)/(input)", "d2": "1/rad"}
