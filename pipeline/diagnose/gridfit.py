"""Fitting first-order DOF models on the analysis grid: data layout and separable least squares.

The model itself (exact ZOH block means) is :mod:`pipeline.model.first_order_blocks`.

Every DOF's baseline is the linear first-order model the fit stage identifies, written with an
unknown mass (Fossen 2021, sec. 7.2; Nomoto 1957):

    T y_dot = -y + f(t),        f = sum_j theta_j phi_j(t)

where the ``phi_j`` are forcing regressors (inputs, and in the candidates a constant bias,
another DOF's measured velocity, a split input or a measured ``|y| y``) held constant over each
analysis step. With ``a = exp(-dt/T)`` the exact zero-order-hold recursion and the exact mean of
``y`` over step ``k`` (what a block average of the measurements estimates) are

    y_{k+1} = a y_k + (1 - a) f_k,      y_bar_k = c1 y_k + (1 - c1) f_k,      c1 = T (1 - a) / dt.

The output is linear in ``theta``, in each window's initial state and in output offsets (a current
seen in velocity over ground), so for a given ``T`` they follow from one linear least-squares
solve and only ``T`` is searched (variable projection; Golub and Pereyra 1973). The initial states
are estimated with the model, on training and held-out windows alike, as output-error validation
does when the initial condition is unknown (Ljung 1999, sec. 16.5), with the measured start value
as a prior of its own standard error. The heading, when scored,
is the running integral of ``y_bar`` plus a per-window offset that is projected out (a heading
reference is arbitrary, and a wave at the first sample must not bias a whole window).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Mapping

import numpy as np
import scipy.optimize

from ..model.first_order_blocks import (coefficients, effective_forcing, free_response, integrate_blocks,
                                       within_block, zero_state)
from .problem import DofProblem, block_average, block_noise, initial_values, input_moments, len_blocks


#: Longest half-span of the line that estimates a window's start value, in time constants.
START_SPAN_T = 0.05
#: How much wider than its nominal standard error the prior on a window's start value is.
Y0_PRIOR_WIDTH = 2.5


@dataclass(frozen=True)
class GridData:
    """A DOF problem's signals on the analysis grid, one row per window (NaN-padded).

    Attributes
    ----------
    dt : float
        Analysis step [s].
    y : numpy.ndarray, shape (W, n)
        Measured response, block means [SI].
    y0 : numpy.ndarray, shape (W,)
        Measured response at each window start [SI].
    y0_sigma : float
        Standard error of ``y0`` [SI]; the fitted initial states are pulled toward ``y0`` with
        this uncertainty (NaN: no pull).
    angle : numpy.ndarray or None, shape (W, n)
        Measured heading block means (unwrapped) [rad], when scored.
    mask : numpy.ndarray, shape (W, n)
        True on the samples of each window (inside its length).
    forcing : Mapping[str, numpy.ndarray]
        Forcing regressors by name: (W, n) block means of a smooth signal (constant over a step),
        or (3, W, n) moments of a held input (:func:`pipeline.diagnose.problem.input_moments`),
        which the exact ZOH weights turn into the state and block-mean forcing for any T.
    m : int
        Trial samples per analysis step.
    offsets : Mapping[str, numpy.ndarray]
        Output-offset bases by name, block means (W, n).
    w_y, w_angle : float
        1 / scale of the response and of the heading (so channels are comparable) [1/SI].
    sigma_y, sigma_angle : float
        White-noise standard deviation of a block mean of the response and of the heading [SI]:
        the floor no model can get under.
    carried : LinearSpec or None
        Regressors of effects already selected in this DOF (their arrays in ``forcing`` and
        ``offsets``) that every model of these data carries beside its inputs (:func:`carry`); None:
        none.
    derived : Mapping[str, tuple[str, Callable]]
        Carried forcing regressors made from the inputs (a thrust's astern part): name -> (the input
        whose moments it takes, a function of the trial-rate inputs and actuator signals), so that a
        model that transforms the inputs (a delay) makes them again from its own inputs.
    pre : tuple
        Input transforms already selected in this DOF, ``(candidate, value)`` in order: the inputs
        of every model of these data went through them (their regressors in ``forcing`` are the
        transformed inputs'; :func:`pipeline.diagnose.candidates.carry_transform`).
    waves : tuple of str
        Once a wave-band disturbance is selected in this DOF, the output keys (``"angle"``, ``"y"``)
        it acts on: every model of these data has the waves refitted on top of its own training
        residuals and smoothed off its held-out ones (:class:`pipeline.diagnose.candidates.WavesOnTop`);
        empty: none.
    """

    dt: float
    y: np.ndarray
    y0: np.ndarray
    angle: np.ndarray | None
    mask: np.ndarray
    forcing: Mapping[str, np.ndarray] = field(default_factory=dict)
    offsets: Mapping[str, np.ndarray] = field(default_factory=dict)
    m: int = 1
    y0_sigma: float = float("nan")
    w_y: float = 1.0
    w_angle: float = 1.0
    sigma_y: float = float("nan")
    sigma_angle: float = float("nan")
    carried: "LinearSpec | None" = None
    derived: Mapping[str, tuple] = field(default_factory=dict)
    pre: tuple = ()
    waves: tuple = ()

    @cached_property
    def angle_mask(self) -> np.ndarray:
        """Samples where the heading is scored."""
        return self.mask & np.isfinite(self.angle) if self.angle is not None else self.mask

    @cached_property
    def y_weighted(self) -> np.ndarray:
        """Measured response times ``w_y``, zero off-window and where not finite (what every solve
        of these windows compares with)."""
        return np.where(self.mask, np.nan_to_num(self.y), 0.0) * self.w_y

    @cached_property
    def angle_demeaned(self) -> np.ndarray:
        """Measured heading minus its per-window mean (zero off-window)."""
        return _demean(np.nan_to_num(self.angle), self.angle_mask)

    def rows(self, idx: np.ndarray) -> "GridData":
        """The same data restricted to windows ``idx``.

        Parameters
        ----------
        idx : numpy.ndarray
            Window indices.
        """
        idx = np.asarray(idx)
        return GridData(
            dt=self.dt, y=self.y[idx], y0=self.y0[idx],
            angle=None if self.angle is None else self.angle[idx], mask=self.mask[idx],
            forcing={k: (v[:, idx] if v.ndim == 3 else v[idx]) for k, v in self.forcing.items()},
            offsets={k: b[idx] for k, b in self.offsets.items()}, m=self.m, y0_sigma=self.y0_sigma,
            w_y=self.w_y, w_angle=self.w_angle, sigma_y=self.sigma_y, sigma_angle=self.sigma_angle,
            carried=self.carried, derived=self.derived, pre=self.pre, waves=self.waves)

    def with_forcing(self, **arrays: np.ndarray) -> "GridData":
        """A copy with forcing regressors added or replaced.

        Parameters
        ----------
        **arrays : numpy.ndarray
            Regressors by name, (W, n) or (3, W, n).
        """
        return replace(self, forcing={**self.forcing, **arrays})


def grid_data(p: DofProblem, inputs: Mapping[str, np.ndarray] | None = None) -> GridData:
    """Block-average a problem's signals onto its analysis grid.

    Parameters
    ----------
    p : DofProblem
        The DOF problem.
    inputs : Mapping[str, numpy.ndarray], optional
        Trial-rate input signals to use instead of ``p.raw`` (a candidate's delayed or
        rate-limited inputs).

    Returns
    -------
    GridData
        With a forcing regressor per input channel, named after it.
    """
    n = p.n
    w = p.windows
    y = block_average(p.raw[p.channel], w, p.m, n, trapezoid=True)
    mask = np.zeros((len(w), n), bool)
    for k, win in enumerate(w):
        mask[k, :len_blocks(win, p.m)] = True
    mask &= np.isfinite(y)
    # The start value from a line through two blocks' worth of samples ending at the start, spanning
    # at most START_SPAN_T time constants: at a slow log rate (AAUSHIP's yaw at 1 Hz, T = 4 s) five
    # samples span a whole time constant and a rudder switch a sample before the start, and the
    # line's end missed the start value by 17 noise units.
    y0 = initial_values(p.raw[p.channel], w, min(max(p.m, 2), int(START_SPAN_T * p.t_guess * p.fs)))
    angle = block_average(p.raw[p.angle], w, p.m, n, trapezoid=True) if p.angle else None
    src = dict(inputs) if inputs is not None else {c: p.raw[c] for c in p.inputs}
    forcing = {c: input_moments(src[c], w, p.m, n) for c in p.inputs}
    # Scales come from the DOF's own windows: a DOF that is quiet most of the trial would
    # otherwise get a tiny scale and an inflated normalised gap.
    own = np.array([p.dof in win.dofs for win in w])
    smask = mask & own[:, None] if own.any() else mask
    w_angle = 1.0
    if angle is not None:
        w_angle = 1.0 / channel_scale(angle - _first(angle), smask & np.isfinite(angle))
    stated = p.stated_noise
    unit = p.noise_unit
    sigma_y = (unit[p.channel] if p.channel in unit else
               block_noise(p.raw[p.channel], w, p.m, trapezoid=True, stated=stated.get(p.channel)))
    sigma_a = (float("nan") if not p.angle else unit[p.angle] if p.angle in unit else
               block_noise(p.raw[p.angle], w, p.m, trapezoid=True, stated=stated.get(p.angle)))
    # Its standard error: a line's end point through 2m + 1 samples carries about 4 / (2m + 1) of a
    # sample's noise variance, i.e. about twice a block mean's; taken Y0_PRIOR_WIDTH times wider,
    # since the noise between samples is rarely as white as that count assumes, and a prior that
    # is too tight turns a start value's error into a heading drift that candidates then "explain".
    # Only from a noise measured in the DOF's windows or stated: a noise from the whole log
    # (block_noise's fallback for a DOF faster than the log) sets its noise unit and floor, not this
    # prior, whose start values there err by the dynamics within a sample, not by the noise
    # (randomised seed 45 r020's sway: its quadratic damping fitted worse with it; seed 41 r021's lost).
    s0 = block_noise(p.raw[p.channel], w, p.m, trapezoid=True, stated=stated.get(p.channel), whole_log=False)
    y0_sigma = Y0_PRIOR_WIDTH * np.sqrt(2.0) * s0 if np.isfinite(s0) and s0 > 0 else float("nan")
    return GridData(dt=p.dt, y=y, y0=y0, angle=angle, mask=mask, forcing=forcing, m=p.m, y0_sigma=y0_sigma,
                    w_y=1.0 / channel_scale(y, smask), w_angle=w_angle, sigma_y=sigma_y, sigma_angle=sigma_a)


def _first(x: np.ndarray) -> np.ndarray:
    """First finite value of each row, as a column."""
    out = np.zeros((x.shape[0], 1))
    for k in range(x.shape[0]):
        f = x[k][np.isfinite(x[k])]
        out[k, 0] = f[0] if len(f) else 0.0
    return out


def channel_scale(x: np.ndarray, mask: np.ndarray) -> float:
    """Scale of a channel: standard deviation of its samples in the windows (floor 1e-9) [SI].

    Parameters
    ----------
    x : numpy.ndarray
        Block means (W, n).
    mask : numpy.ndarray
        Samples to use.
    """
    vals = x[mask & np.isfinite(x)]
    if len(vals) < 2:
        return 1.0
    return max(float(np.std(vals)), 1e-9)


@dataclass(frozen=True)
class LinearSpec:
    """Which regressors a linear model uses.

    Attributes
    ----------
    forcing : tuple[str, ...]
        Names of forcing regressors in :attr:`GridData.forcing` (theta multiplies each).
    offsets : tuple[str, ...]
        Names of output-offset bases in :attr:`GridData.offsets`.
    sensor_offsets : tuple[str, ...]
        Constant offsets of the response sensor alone (a gyro bias): added to the response
        channel, not integrated into the heading, which another sensor measures.
    """

    forcing: tuple[str, ...]
    offsets: tuple[str, ...] = ()
    sensor_offsets: tuple[str, ...] = ()

    @property
    def names(self) -> tuple[str, ...]:
        """Linear parameter names, in solve order."""
        return self.forcing + self.offsets + self.sensor_offsets


def carry(d: GridData, spec: LinearSpec, forcing: Mapping[str, np.ndarray] | None = None,
          offsets: Mapping[str, np.ndarray] | None = None, derived: Mapping[str, tuple] | None = None) -> GridData:
    """``d`` with the regressors of ``spec`` carried by every model of it (``GridData.carried``).

    Parameters
    ----------
    d : GridData
        Windows.
    spec : LinearSpec
        Regressors to carry (forcing, output offsets, sensor offsets), after those already carried.
    forcing, offsets : Mapping[str, numpy.ndarray], optional
        Their arrays on the analysis grid (forcing (W, n) or (3, W, n), offsets (W, n)).
    derived : Mapping[str, tuple], optional
        Of the forcing, those made from the inputs (``GridData.derived``).
    """
    old = d.carried or LinearSpec(())
    new = LinearSpec(old.forcing + tuple(f for f in spec.forcing if f not in old.forcing),
                     old.offsets + tuple(f for f in spec.offsets if f not in old.offsets),
                     old.sensor_offsets + tuple(f for f in spec.sensor_offsets if f not in old.sensor_offsets))
    return replace(d, forcing={**d.forcing, **(forcing or {})}, offsets={**d.offsets, **(offsets or {})},
                   carried=new, derived={**d.derived, **(derived or {})})


def _columns(d: GridData, spec: LinearSpec, t_const: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Response columns of the linear parameters and of a unit initial state.

    Returns ``(cols, h0, cols_within, h0_within)``: block means (k, W, n) and (n,), and the
    within-step means of their integrals (same shapes) for the heading.
    """
    a, c1 = coefficients(t_const, d.dt)
    n = d.y.shape[1]
    h0 = free_response(n, a, c1)
    h0_state = a ** np.arange(n)
    h0_within = within_block(h0_state, 0.0, t_const, d.dt)
    parts, within = [], []
    if spec.forcing:
        eff = [effective_forcing(d.forcing[name], t_const, d.dt, d.m) for name in spec.forcing]
        f_state = np.stack([e[0] for e in eff])
        f_mean = np.stack([e[1] for e in eff])
        mean, states = zero_state(f_state, f_mean, a, c1)
        parts.append(mean)
        within.append(within_block(states, f_mean, t_const, d.dt))
    if spec.offsets:
        # A current adds V b(t) to what the sensor sees; the water-relative initial state is
        # one of the per-window initial states. (Offsets only occur for surge and sway, which
        # have no heading channel.)
        off = np.stack([np.nan_to_num(d.offsets[name]) for name in spec.offsets])
        parts.append(off)
        within.append(0.5 * d.dt * off)
    if spec.sensor_offsets:
        ones = np.broadcast_to(d.mask.astype(float), (len(spec.sensor_offsets),) + d.y.shape)
        parts.append(np.array(ones))
        within.append(np.zeros_like(ones))
    if parts:
        return np.concatenate(parts), h0, np.concatenate(within), h0_within
    empty = np.zeros((0,) + d.y.shape)
    return empty, h0, empty, h0_within


@dataclass(frozen=True)
class _Normal:
    """Normal equations with the per-window initial states ``y0`` still in them.

    ``g_tt`` (k, k), ``g_yt`` (W, k), ``g_yy`` (W,), ``r_t`` (k,), ``r_y`` (W,), ``bb``: the Gram
    blocks, right-hand sides and target norm of ``|| B - C theta - H y0 ||^2`` summed over the
    scored channels (weighted).
    """

    g_tt: np.ndarray
    g_yt: np.ndarray
    g_yy: np.ndarray
    r_t: np.ndarray
    r_y: np.ndarray
    bb: float


def _normal(d: GridData, spec: LinearSpec, t_const: float, columns: tuple | None = None) -> _Normal:
    """Normal equations of the output-error fit for a given T.

    Each window's initial state multiplies the free response ``H`` on that window only, so its
    block of the Gram matrix is diagonal and every product is a per-window sum (no dense design
    matrix with one column per window). ``columns``: ``_columns(d, spec, t_const)`` when the
    caller has them.
    """
    cols, h0, cols_w, h0_w = _columns(d, spec, t_const) if columns is None else columns
    m = d.mask
    # Each masked array once (the response and the heading channels both use it).
    h0m = np.where(m, h0[None, :], 0.0)
    cm = np.where(m, cols, 0.0)
    hy = h0m * d.w_y
    cy = cm * d.w_y
    chans = [(cy, hy, d.y_weighted)]
    if d.angle is not None:
        am = d.angle_mask
        ca = _demean(integrate_blocks(cm, d.dt, cols_w), am) * d.w_angle
        if spec.sensor_offsets:
            ca[-len(spec.sensor_offsets):] = 0.0  # the response sensor's bias is not in the heading
        ha = _demean(integrate_blocks(h0m, d.dt, h0_w[None, :]), am) * d.w_angle
        chans.append((ca, ha, d.angle_demeaned * d.w_angle))
    k, w = cols.shape[0], d.y.shape[0]
    g_tt, g_yt, g_yy = np.zeros((k, k)), np.zeros((w, k)), np.zeros(w)
    r_t, r_y, bb = np.zeros(k), np.zeros(w), 0.0
    # einsum's own loops, not BLAS: these products are small in k, and a threaded BLAS on a busy
    # machine can spend milliseconds per call waking threads.
    for c, h, b in chans:
        g_tt += np.einsum("iwn,jwn->ij", c, c)
        g_yt += np.einsum("wn,jwn->wj", h, c)
        g_yy += np.einsum("wn,wn->w", h, h)
        r_t += np.einsum("iwn,wn->i", c, b)
        r_y += np.einsum("wn,wn->w", h, b)
        bb += float(np.einsum("wn,wn->", b, b))
    if np.isfinite(d.y0_sigma) and d.y0_sigma > 0:
        # The measured start value as a pseudo-observation of what the sensor saw at the start:
        # the initial state plus any output offset there. Without it a delay at a step from rest
        # is, to first order, the same as a start value off by K delta tau / T, and the step
        # windows would say nothing about delays.
        wgt = (d.w_y / d.y0_sigma) ** 2
        b0 = np.zeros((k, w))
        for j, name in enumerate(spec.offsets):
            b0[len(spec.forcing) + j] = np.nan_to_num(d.offsets[name][:, 0])
        b0[len(spec.forcing) + len(spec.offsets):] = 1.0
        g_yy += wgt
        g_yt += wgt * b0.T
        g_tt += wgt * np.einsum("iw,jw->ij", b0, b0)
        r_t += wgt * np.einsum("iw,w->i", b0, d.y0)
        r_y += wgt * d.y0
        bb += float(wgt * np.sum(d.y0**2))
    return _Normal(g_tt, g_yt, g_yy, r_t, r_y, bb)


def solve_linear(d: GridData, spec: LinearSpec, t_const: float, ridge: float = 1e-9) -> tuple[np.ndarray, float]:
    """Linear parameters and weighted SSE for a given ``T`` [s], initial states profiled out.

    The initial states are eliminated exactly (Schur complement of their diagonal block); the
    reduced system for ``theta`` is solved on scaled columns with a tiny ridge, which keeps
    unexcited directions (a current component along a heading never sailed, an input absent from
    the training windows) at zero instead of at a noise-driven value.

    Parameters
    ----------
    d : GridData
        Windows.
    spec : LinearSpec
        Regressors.
    t_const : float
        Time constant [s].
    ridge : float
        Ridge on the scaled reduced normal matrix.

    Returns
    -------
    theta, sse
        Linear parameters and the weighted sum of squares.
    """
    ne = _normal(d, spec, t_const)
    gy = np.where(ne.g_yy > 0, ne.g_yy, 1.0)
    bb_r = ne.bb - float(np.sum(ne.r_y**2 / gy))
    k = len(ne.r_t)
    if k == 0:
        return np.zeros(0), max(bb_r, 0.0)
    g_r = ne.g_tt - np.einsum("wi,wj,w->ij", ne.g_yt, ne.g_yt, 1.0 / gy)
    r_r = ne.r_t - np.einsum("wi,w->i", ne.g_yt, ne.r_y / gy)
    scale = np.sqrt(np.abs(np.diag(g_r))).copy()
    scale[scale == 0] = 1.0
    gs = g_r / np.outer(scale, scale) + ridge * np.eye(k)
    try:
        sol = np.linalg.solve(gs, r_r / scale)
    except np.linalg.LinAlgError:
        sol = np.linalg.lstsq(gs, r_r / scale, rcond=None)[0]
    theta = sol / scale
    return theta, max(bb_r - float(np.sum(theta * r_r)), 0.0)


def initial_states(d: GridData, spec: LinearSpec, t_const: float, theta: np.ndarray,
                   columns: tuple | None = None) -> np.ndarray:
    """Least-squares initial state of every window given the model (W,) [SI of y].

    On a held-out window this is the only thing fitted to it: the state the boat was in when the
    window began, estimated from the whole window rather than from the few samples at its start
    (a start value off by the gyro's noise would otherwise be integrated into the heading).

    Parameters
    ----------
    d : GridData
        Windows.
    spec : LinearSpec
        Regressors.
    t_const : float
        Time constant [s].
    theta : numpy.ndarray
        Linear parameters.
    columns : tuple, optional
        The response columns of these windows at ``t_const``, when the caller has them.
    """
    ne = _normal(d, spec, t_const, columns)
    gy = np.where(ne.g_yy > 0, ne.g_yy, 1.0)
    th = np.asarray(theta, float)
    return (ne.r_y - (np.einsum("wi,i->w", ne.g_yt, th) if len(th) else 0.0)) / gy


def _demean(x: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Subtract each row's mean over ``mask`` (the per-window heading offset); zero off-mask."""
    xm = np.where(mask, x, 0.0)
    cnt = np.maximum(mask.sum(axis=-1, keepdims=True), 1)
    return np.where(mask, x - xm.sum(axis=-1, keepdims=True) / cnt, 0.0)


def fit_linear(d: GridData, spec: LinearSpec, t_guess: float, t_range: tuple[float, float] | None = None,
               ) -> tuple[float, np.ndarray, float]:
    """Fit ``T`` and the linear parameters by output error (variable projection).

    Parameters
    ----------
    d : GridData
        Training windows.
    spec : LinearSpec
        Regressors.
    t_guess : float
        Starting time constant [s].
    t_range : tuple[float, float], optional
        Search bounds for ``T`` [s]. Default ``t_guess / 20`` to ``t_guess * 20`` searched on a
        grid first; a narrow range given by a caller who already knows ``T`` roughly is searched
        directly.

    Returns
    -------
    T, theta, sse
        Time constant [s], linear parameters (``spec.names`` order), weighted SSE.
    """
    solved: dict[float, tuple[np.ndarray, float]] = {}

    def cost(lt: float) -> float:
        t = float(np.exp(lt))
        solved[t] = solve_linear(d, spec, t)
        return solved[t][1]

    if t_range is None:
        lo, hi = max(t_guess / 20.0, d.dt / 20.0), t_guess * 20.0
        grid = np.exp(np.linspace(np.log(lo), np.log(hi), 13))
        sse = [cost(np.log(t)) for t in grid]
        i = int(np.argmin(sse))
        a_, b_ = np.log(grid[max(i - 1, 0)]), np.log(grid[min(i + 1, len(grid) - 1)])
        best_t, best_c = float(grid[i]), sse[i]
    else:
        a_, b_ = np.log(max(t_range[0], d.dt / 20.0)), np.log(t_range[1])
        best_t, best_c = t_guess, cost(np.log(t_guess))
    res = scipy.optimize.minimize_scalar(cost, bounds=(a_, b_), method="bounded", options={"xatol": 1e-4})
    if res.fun < best_c:
        best_t = float(np.exp(res.x))
    # The search's best point was solved already (the same T, so the same numbers).
    theta, s = solved[best_t] if best_t in solved else solve_linear(d, spec, best_t)
    return best_t, theta, s


def refit_linear(d: GridData, spec: LinearSpec, t_near: float) -> tuple[float, np.ndarray, float]:
    """:func:`fit_linear` in a narrow range (``t_near / 1.6`` to ``t_near * 1.6``) [s].

    Parameters
    ----------
    d : GridData
        Windows.
    spec : LinearSpec
        Regressors.
    t_near : float
        Time constant to search around [s].
    """
    return fit_linear(d, spec, t_near, (t_near / 1.6, t_near * 1.6))


def predict_linear(d: GridData, spec: LinearSpec, t_const: float, theta: np.ndarray,
                   y0: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Model outputs (block means) for every window of ``d``.

    Parameters
    ----------
    d : GridData
        Windows.
    spec : LinearSpec
        Regressors.
    t_const : float
        Time constant [s].
    theta : numpy.ndarray
        Linear parameters.
    y0 : numpy.ndarray, optional
        Initial state per window; default fitted (:func:`initial_states`).

    Returns
    -------
    dict
        ``"y"``: response (W, n); ``"angle"``: integrated heading with the per-window offset
        fitted to the measurement (W, n), when ``d.angle`` is given. NaN outside the windows.
    """
    columns = _columns(d, spec, t_const)
    cols, h0, cols_w, h0_w = columns
    y0 = initial_states(d, spec, t_const, theta, columns) if y0 is None else np.asarray(y0, float)
    yhat = y0[:, None] * h0[None, :]
    within = y0[:, None] * h0_w[None, :]
    bias = 0.0
    if len(cols):
        th = np.asarray(theta, float)
        ns = len(spec.sensor_offsets)
        if ns:
            # The response sensor's own bias: seen on the response, not integrated into the heading.
            bias = np.einsum("k,kwn->wn", th[-ns:], cols[-ns:])
            th, cols, cols_w = th[:-ns], cols[:-ns], cols_w[:-ns]
        yhat = yhat + np.einsum("k,kwn->wn", th, cols)
        within = within + np.einsum("k,kwn->wn", th, cols_w)
    out = outputs_from_response(d, yhat, within)
    out["y"] = out["y"] + bias
    return out


def outputs_from_response(d: GridData, yhat: np.ndarray, within: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Package a predicted response (and its integrated heading) as model outputs.

    Parameters
    ----------
    d : GridData
        Windows.
    yhat : numpy.ndarray
        Predicted block means of the response (W, n).
    within : numpy.ndarray, optional
        Within-step means of its integral (W, n); default the trapezoid.
    """
    m = d.mask
    out = {"y": np.where(m, yhat, np.nan)}
    if d.angle is not None:
        am = m & np.isfinite(d.angle)
        integ = integrate_blocks(np.where(m, yhat, 0.0), d.dt, None if within is None else np.where(m, within, 0.0))
        resid = np.where(am, d.angle - integ, 0.0)
        off = resid.sum(axis=1, keepdims=True) / np.maximum(am.sum(axis=1, keepdims=True), 1)
        out["angle"] = np.where(m, integ + off, np.nan)
    return out


def simulate_quadratic(d: GridData, t_const: float, f: np.ndarray, d2: float,
                       f_mean: np.ndarray | None = None, y0: np.ndarray | None = None,
                       with_within: bool = False):
    """Block-mean response of ``T y_dot = -y - d2 |y| y + f`` from each window's measured start.

    Each step freezes the total damping ``g = 1 + d2 |y|`` at a midpoint estimate (a predictor
    step with ``|y_k|``, then ``|y|`` at the predicted midpoint) and takes the exact exponential
    step of the then-linear equation, which stays stable however stiff ``d2 |y|`` makes it.
    Vectorised over windows.

    Parameters
    ----------
    d : GridData
        Windows (for ``y0``, ``dt``).
    t_const : float
        Time constant [s].
    f : numpy.ndarray, shape (W, n)
        Linear forcing ``sum theta_j phi_j`` for the state update [SI of y].
    d2 : float
        Quadratic damping relative to the linear one [1/(SI of y)].
    f_mean : numpy.ndarray, optional
        Forcing for the step means (differs from ``f`` where an input switches inside a step);
        default ``f``.
    y0 : numpy.ndarray, optional
        Initial state per window; default the measured ``d.y0``.
    with_within : bool
        Also return the within-step means of the integral (for the heading).

    Returns
    -------
    numpy.ndarray, shape (W, n), or a pair of them with ``with_within``
    """
    f_mean = f if f_mean is None else f_mean
    w, n = f.shape
    out = np.empty((w, n))
    inner = np.empty((w, n)) if with_within else None
    y = (d.y0 if y0 is None else np.asarray(y0, float)).astype(float).copy()
    r = d.dt / t_const

    def step(y: np.ndarray, g: np.ndarray, fk: np.ndarray, fm: np.ndarray):
        x = r * g
        a = np.exp(-x)
        c1 = -np.expm1(-x) / x
        yss = fk / g
        ym = fm / g
        return yss + (y - yss) * a, ym + (y - ym) * c1, (ym, c1, g)

    for k in range(n):
        fk, fm = f[:, k], f_mean[:, k]
        g = np.maximum(1.0 + d2 * np.abs(y), 0.05)
        y_pred, _, _ = step(y, g, fk, fm)
        g = np.maximum(1.0 + d2 * 0.5 * np.abs(y + y_pred), 0.05)
        y_next, out[:, k], (ym, c1, g) = step(y, g, fk, fm)
        if inner is not None:
            inner[:, k] = ym * d.dt / 2 + (y - ym) * (t_const / g) * (1 - c1)
        y = y_next
    return (out, inner) if with_within else out


def refine_initial_states(d: GridData, simulate, y0: np.ndarray, iterations: int = 2) -> np.ndarray:
    """Gauss-Newton on each window's initial state of a nonlinear model (windows are independent).

    Parameters
    ----------
    d : GridData
        Windows.
    simulate : callable
        ``simulate(y0) -> yhat`` (W, n) block means.
    y0 : numpy.ndarray
        Starting initial states (W,) (the linear model's estimate).
    iterations : int
        Gauss-Newton steps; the response is nearly linear in ``y0``, two are plenty.

    Returns
    -------
    numpy.ndarray
        Initial states (W,) [SI of y].
    """
    y0 = np.asarray(y0, float).copy()
    step = 1e-3 / max(d.w_y, 1e-12)
    m = d.mask
    am = d.angle_mask

    def parts(yhat: np.ndarray):
        out = outputs_from_response(d, yhat)
        e = [np.where(m, d.y - out["y"], 0.0) * d.w_y]
        if d.angle is not None:
            e.append(np.where(am, d.angle - out["angle"], 0.0) * d.w_angle)
        return e

    prior = (d.w_y / d.y0_sigma) ** 2 if np.isfinite(d.y0_sigma) and d.y0_sigma > 0 else 0.0
    for _ in range(iterations):
        e0 = parts(simulate(y0))
        e1 = parts(simulate(y0 + step))
        num = sum(np.sum((a - b) / step * a, axis=1) for a, b in zip(e0, e1)) + prior * (d.y0 - y0)
        den = sum(np.sum(((a - b) / step) ** 2, axis=1) for a, b in zip(e0, e1)) + prior
        y0 = y0 + np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
    return y0


def weighted_residuals(d: GridData, outputs: Mapping[str, np.ndarray]) -> np.ndarray:
    """Weighted residuals of every channel, stacked (the least-squares objective's vector).

    Parameters
    ----------
    d : GridData
        Windows.
    outputs : Mapping[str, numpy.ndarray]
        Model outputs (``"y"``, ``"angle"``).
    """
    m = d.mask
    parts = [(d.y[m] - outputs["y"][m]) * d.w_y]
    if d.angle is not None and "angle" in outputs:
        am = m & np.isfinite(d.angle)
        parts.append((d.angle[am] - outputs["angle"][am]) * d.w_angle)
    return np.concatenate(parts)
