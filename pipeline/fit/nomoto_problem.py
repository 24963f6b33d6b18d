"""The whole-record Nomoto criterion: records prepared on their grid, output-error and
prediction-error residuals, the solver, and the covariance (see :mod:`pipeline.fit.nomoto_oe`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
import scipy.signal
from scipy import optimize

from ..errors import FitError
from ..model.nomoto import (NOMOTO_ORDER_PARAMS, nomoto2_coefficients, nomoto2_sum_product, nomoto_matrices,
                            pole_time_constants,
                            servo_response)
from ..model.waves import WaveParams
from .nomoto_pem import initial_state_response, innovation_filter, InnovationFilter, noise_from_ratio, whiten_profiled
from .nomoto_records import NomotoFit, NomotoRecord
from .nomoto_sensitivity import complex_step, propagate_outputs, zoh_derivatives
from .nomoto_zoh import simulate_zoh, zoh_discretise
from .residual_tests import residual_test

#: Dynamic parameter names per model order.
DYNAMIC_PARAMS: Mapping[int, tuple[str, ...]] = NOMOTO_ORDER_PARAMS
#: Wave/noise parameters of the PEM (estimated on a log scale).
NOISE_PARAMS = ("omega0", "lambda", "kw_ratio")
#: Rudder-servo parameters (estimated on a log scale when only the command is logged).
SERVO_PARAMS = ("t_servo", "rate_servo")
NOISE_MODELS = ("auto", "white", "waves")
#: Fewest samples a record must have.
MIN_SAMPLES = 50
#: Factor beyond the plausible range at which a log-parameter is held (see :class:`Problem`).
NUMERIC_MARGIN = 100.0
#: Relative jitter of the sample spacing accepted as uniform.
UNIFORM_TOLERANCE = 1e-3
# The residual is linear in these (initial states, and the bias through the input delta - b).
_LINEAR_KINDS = frozenset({"b", "psi0", "r0", "rdot0"})
# Parameters whose Jacobian columns are exact (sensitivity equations); the rest by finite differences.
_EXACT_KINDS = frozenset({"K", "T", "T1", "T2", "T3", "T12", "T1T2"}) | _LINEAR_KINDS
# Floors of the finite-difference steps per parameter kind (step = 1e-6 max(|x|, floor)).
# Key of the full state trajectory (N, n) in the dict :meth:`Problem.simulate` returns.
STATES_KEY = "states"
_FD_FLOOR = {"K": 1e-3, "T": 1.0, "T12": 1.0, "T1T2": 1.0, "T1": 1.0, "T2": 1.0, "T3": 1.0, "b": 1e-2, "psi0": 1e-2, "r0": 1e-3,
             "rdot0": 1e-4, "log": 10.0}


# --------------------------------------------------------------------------- preparation
@dataclass(frozen=True)
class Prepared:
    h: float
    u: np.ndarray
    y: Mapping[str, np.ndarray]
    mask: Mapping[str, np.ndarray]
    duration: float
    name: str


def unwrap_heading(psi: np.ndarray) -> np.ndarray:
    """Heading unwrapped over its finite samples (NaN kept) [rad].

    Parameters
    ----------
    psi : numpy.ndarray
        Heading [rad], wrapped or not; NaN marks a missing sample.
    """
    out = np.array(psi, float)
    ok = np.isfinite(out)
    out[ok] = np.unwrap(out[ok])
    return out


def prepare(rec: NomotoRecord, i: int, channels: Sequence[str]) -> Prepared:
    """Check one record and put it on its uniform grid (heading unwrapped, masks of finite samples).

    Parameters
    ----------
    rec : NomotoRecord
        The record.
    i : int
        Its index, for messages when it has no name.
    channels : sequence of str
        Outputs to fit (``psi``, ``r``).

    Returns
    -------
    Prepared

    Raises
    ------
    FitError
        Too few samples, non-uniform time, non-finite rudder, missing channel.
    """
    name = rec.name or f"record {i}"
    t = np.asarray(rec.t, float)
    u = np.asarray(rec.delta, float)
    if t.ndim != 1 or t.size < MIN_SAMPLES:
        raise FitError(f"{name}: expected at least {MIN_SAMPLES} samples, found {t.size}")
    if u.shape != t.shape:
        raise FitError(f"{name}: expected delta with {t.size} samples like t, found shape {u.shape}")
    if not np.all(np.isfinite(u)):
        raise FitError(f"{name}: expected a finite rudder angle on every sample (the model is driven by it), "
                       f"found {int((~np.isfinite(u)).sum())} non-finite samples")
    dt = np.diff(t)
    h = float(np.median(dt))
    if not (h > 0 and np.all(np.abs(dt - h) <= UNIFORM_TOLERANCE * h)):
        raise FitError(f"{name}: expected uniform, increasing sample times, found spacings "
                       f"{float(dt.min()):.4g}..{float(dt.max()):.4g} s")
    ys, masks = {}, {}
    for ch in channels:
        raw = rec.psi if ch == "psi" else rec.r
        if raw is None:
            raise FitError(f"{name}: channel {ch!r} requested but not given")
        y = np.asarray(raw, float)
        if y.shape != t.shape:
            raise FitError(f"{name}: expected {ch} with {t.size} samples like t, found shape {y.shape}")
        y = unwrap_heading(y) if ch == "psi" else y
        m = np.isfinite(y)
        if m.sum() < MIN_SAMPLES:
            raise FitError(f"{name}: expected at least {MIN_SAMPLES} finite {ch} samples, found {int(m.sum())}")
        ys[ch], masks[ch] = np.where(m, y, 0.0), m
    return Prepared(h=h, u=u, y=ys, mask=masks, duration=float(t[-1] - t[0]), name=name)


# --------------------------------------------------------------------------- the problem
class Problem:
    """Residuals of the OE/PEM criterion over several records and their Jacobian (exact sensitivities;
    finite differences for the noise parameters and, through the sensitivities, the servo's; with caches)."""

    def __init__(self, recs: Sequence[Prepared], order: int, bias: bool, channels: tuple[str, ...],
                 noise: str, fixed_waves: WaveParams | None, fixed_noise_var: float | None,
                 servo: Sequence[str] = ()):
        self.recs = recs
        self.servo = tuple(servo)
        self.order = order
        self.bias = bias
        self.channels = channels
        self.noise = noise
        self.fixed_waves = fixed_waves
        self.fixed_noise_var = fixed_noise_var
        dyn = list(DYNAMIC_PARAMS[order])
        self.names: list[str] = dyn + (["b"] if bias else [])
        self.kinds: list[str] = list(self.names)
        self.ic_names = (["psi0"] if "psi" in channels else []) + ["r0"] + (["rdot0"] if order != 1 else [])
        self.ic_index: list[list[int]] = []
        for i in range(len(recs)):
            idx = []
            for nm in self.ic_names:
                idx.append(len(self.names))
                self.names.append(nm if len(recs) == 1 else f"{nm}[{i}]")
                self.kinds.append(nm)
            self.ic_index.append(idx)
        self.noise_index: list[int] = []
        self.noise_free: tuple[str, ...] = ()
        if noise == "waves":
            self.noise_free = NOISE_PARAMS if fixed_waves is None else (
                ("kw_ratio",) if fixed_noise_var is None else ())
            for nm in self.noise_free:
                self.noise_index.append(len(self.names))
                self.names.append(nm)
                self.kinds.append("log")
        # The rudder servo driven by a logged command: lag t_servo [s], rate limit rate_servo [rad/s].
        self.servo_index: list[int] = []
        for nm in self.servo:
            if nm not in SERVO_PARAMS:
                raise FitError(f"servo parameters: expected names among {SERVO_PARAMS}, found {nm!r}")
            self.servo_index.append(len(self.names))
            self.names.append(nm)
            self.kinds.append("log")
        self.n_dyn = len(dyn)
        # Time constants and noise parameters are positive: the solver works on their logarithms.
        self.log_mask = np.array([k in ("T", "T1", "T2", "T3", "T12", "T1T2", "log") for k in self.kinds])
        self.weights = {ch: 1.0 for ch in channels}
        # The solver is unbounded, but a log-parameter far outside its plausible range means a pole
        # pair at 1e13 rad/s or a wave model decaying in a picosecond: discretising those overflows
        # (the scaled-and-squared exponential of a stiff, lightly damped pair). Such values are held
        # at NUMERIC_MARGIN times beyond the plausible range (still reported as out of range).
        lo, hi = plausible_ranges(self)
        pos_lo = np.where(np.isfinite(lo) & (lo > 0), lo, math.exp(-60.0))
        pos_hi = np.where(np.isfinite(hi) & (hi > 0), hi, math.exp(60.0))
        squared = np.array([k == "T1T2" for k in self.kinds])
        margin = np.where(squared, NUMERIC_MARGIN**2, NUMERIC_MARGIN)
        self._z_lo = np.where(self.log_mask, np.log(pos_lo / margin), -np.inf)
        self._z_hi = np.where(self.log_mask, np.log(pos_hi * margin), np.inf)
        self._sim_cache: dict = {}
        self._filt_cache: dict = {}
        self._phi_cache: dict = {}
        self._servo_cache: dict = {}
        # The exact discretisation per dynamic parameters and sample time: a finite-difference step
        # in a servo or noise parameter, or a new initial state, needs no new matrix exponential.
        self._zoh_cache: dict = {}

    def clear_caches(self) -> None:
        """Drop the cached simulations, filters and discretisations (e.g. before keeping the problem)."""
        for cache in (self._sim_cache, self._filt_cache, self._phi_cache, self._servo_cache, self._zoh_cache):
            cache.clear()

    def discretised(self, dyn: tuple[float, ...], h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Continuous ``A`` and the exact zero-order-hold ``(A_d, B_d)`` of the dynamic parameters ``dyn`` (cached).

        Parameters
        ----------
        dyn : tuple of float
            K, T (or the second-order parameters) [SI].
        h : float
            Sample time [s].
        """
        key = (dyn, h)
        out = self._zoh_cache.get(key)
        if out is None:
            a, bm = nomoto_matrices(self.order, dyn)
            ad, bd = zoh_discretise(a, bm, h)
            out = (a, ad, bd)
            if len(self._zoh_cache) > 64:
                self._zoh_cache.clear()
            self._zoh_cache[key] = out
        return out

    def rudder(self, z: np.ndarray, i: int) -> np.ndarray:
        """Rudder angle driving record ``i``: the logged one, or the servo's response to the logged
        command (:func:`pipeline.model.nomoto.servo_response`) when servo parameters are estimated.

        Parameters
        ----------
        z : numpy.ndarray
            Solver vector.
        i : int
            Record index.
        """
        rec = self.recs[i]
        if not self.servo:
            return rec.u
        x = self.natural(z)
        vals = dict(zip(self.servo, (float(x[j]) for j in self.servo_index)))
        key = (i, tuple(vals.values()))
        out = self._servo_cache.get(key)
        if out is None:
            if len(self._servo_cache) > 64:
                self._servo_cache.clear()
            out = servo_response(rec.u, rec.h, vals.get("t_servo", 0.0), vals.get("rate_servo", math.inf))
            self._servo_cache[key] = out
        return out

    # -- pieces
    def natural(self, z: np.ndarray) -> np.ndarray:
        """SI parameter values from the solver's vector (logarithms of the positive ones).

        Parameters
        ----------
        z : numpy.ndarray
            Solver vector.
        """
        z = np.asarray(z, float)
        out = z.copy()
        m = self.log_mask
        out[m] = np.exp(np.clip(z[m], self._z_lo[m], self._z_hi[m]))   # exp only where it is the map
        return out

    def solver_vector(self, theta: np.ndarray) -> np.ndarray:
        """The solver's vector from SI values.

        Parameters
        ----------
        theta : numpy.ndarray
            Parameter values in SI units.
        """
        theta = np.asarray(theta, float)
        return np.where(self.log_mask, np.log(np.where(self.log_mask, theta, 1.0)), theta)

    def _noise_params(self, z: np.ndarray) -> tuple[float, float, float]:
        vals = dict(zip(self.noise_free, self.natural(z)[self.noise_index]))
        fw = self.fixed_waves
        omega0 = vals.get("omega0", fw.omega0 if fw else math.nan)
        lam = vals.get("lambda", fw.lam if fw else math.nan)
        if "kw_ratio" in vals:
            ratio = vals["kw_ratio"]
        else:
            ratio = fw.kw / math.sqrt(self.fixed_noise_var)
        return omega0, lam, ratio

    def _filter(self, x: np.ndarray, h: float) -> InnovationFilter | None:
        if self.noise != "waves":
            return None
        omega0, lam, ratio = self._noise_params(x)
        key = (omega0, lam, ratio, h)
        f = self._filt_cache.get(key)
        if f is None:
            if len(self._filt_cache) > 64:
                self._filt_cache.clear()
            f = innovation_filter(WaveParams(omega0, lam, ratio), 1.0, h)
            self._filt_cache[key] = f
        return f

    def _phi(self, filt: InnovationFilter, h: float, n: int) -> np.ndarray:
        key = (filt.num.tobytes(), filt.gain.tobytes(), h, n)
        phi = self._phi_cache.get(key)
        if phi is None:
            if len(self._phi_cache) > 64:
                self._phi_cache.clear()
            phi = initial_state_response(filt, n)
            self._phi_cache[key] = phi
        return phi

    def simulate(self, z: np.ndarray, i: int) -> dict[str, np.ndarray]:
        """Noise-free outputs of record ``i`` at the solver vector ``z``.

        Parameters
        ----------
        z : numpy.ndarray
            Solver vector.
        i : int
            Record index.
        """
        rec = self.recs[i]
        x = self.natural(z)
        dyn = tuple(float(v) for v in x[: self.n_dyn])
        b = float(x[self.n_dyn]) if self.bias else 0.0
        icd = {nm: float(x[j]) for nm, j in zip(self.ic_names, self.ic_index[i])}
        psi0 = icd.pop("psi0", 0.0)
        servo = tuple(float(x[j]) for j in self.servo_index)
        # The initial heading only shifts psi: it is added after the cached simulation, so a
        # finite-difference step in psi0 costs no new simulation.
        key = (i, dyn, b, tuple(icd.values()), servo)
        out = self._sim_cache.get(key)
        if out is None:
            u = self.rudder(z, i)
            a, ad, bd = self.discretised(dyn, rec.h)
            x0 = np.zeros(a.shape[0])
            x0[1] = icd["r0"]
            if self.order != 1:
                a1, _, b1, _ = nomoto2_coefficients(*dyn) if self.order == 2 else nomoto2_sum_product(*dyn)
                # x2 from the initial yaw acceleration: x2 = r_dot + a1 r - b1 (delta - b).
                x0[2] = icd["rdot0"] + a1 * icd["r0"] - b1 * (u[0] - b)
            states = simulate_zoh(ad, bd, x0, u - b)
            out = {"psi": states[:, 0], "r": states[:, 1], STATES_KEY: states}
            if len(self._sim_cache) > 256:
                self._sim_cache.clear()
            self._sim_cache[key] = out
        return {"psi": out["psi"] + psi0, "r": out["r"], STATES_KEY: out[STATES_KEY]} if psi0 else out

    def channel_residuals(self, x: np.ndarray) -> list[dict[str, np.ndarray]]:
        """Unweighted residuals per record and channel (masked samples removed).

        Parameters
        ----------
        x : numpy.ndarray
            Solver vector.
        """
        res = []
        for i, rec in enumerate(self.recs):
            sim = self.simulate(x, i)
            filt = self._filter(x, rec.h)
            per = {}
            for ch in self.channels:
                w = rec.y[ch] - sim[ch]
                m = rec.mask[ch]
                if ch == "psi" and filt is not None:
                    if m.all():
                        e = whiten_profiled(filt, w, self._phi(filt, rec.h, w.size))
                    else:
                        e = whiten_with_gaps(filt, w, m)
                    per[ch] = e[m]
                else:
                    per[ch] = w[m]
            res.append(per)
        return res

    def residual(self, x: np.ndarray) -> np.ndarray:
        """Weighted residual vector of every record and channel (the solver's criterion).

        Parameters
        ----------
        x : numpy.ndarray
            Solver vector.
        """
        parts = []
        for per in self.channel_residuals(x):
            for ch in self.channels:
                parts.append(per[ch] * self.weights[ch])
        return np.concatenate(parts)

    def fd_steps(self, x: np.ndarray) -> np.ndarray:
        """Finite-difference steps per parameter: ``1e-6 max(|x|, floor)``.

        Parameters
        ----------
        x : numpy.ndarray
            Solver vector.
        """
        floor = np.array([1.0 if lg else _FD_FLOOR.get(k, 1e-3) for k, lg in zip(self.kinds, self.log_mask)])
        return 1e-6 * np.maximum(np.abs(x), floor)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Jacobian of :meth:`residual`: exact for K, T (T12, T1T2, T3), the bias and the initial
        states (discrete sensitivity equations, :mod:`pipeline.fit.nomoto_sensitivity`); for the servo
        parameters the central difference of the servo's rudder angle run through the same equations;
        central differences of the residual for the noise parameters.

        Parameters
        ----------
        x : numpy.ndarray
            Solver vector.
        """
        x = np.asarray(x, float)
        jac = np.empty((self._n_residuals(), len(self.names)))
        exact = [j for j, k in enumerate(self.kinds) if k in _EXACT_KINDS] + list(self.servo_index)
        jac[:, exact] = self._sensitivity_columns(x, exact)
        fd = [j for j in range(len(self.names)) if j not in set(exact)]
        if fd:
            jac[:, fd] = self.fd_jacobian(x, fd)
        return jac

    def _n_residuals(self) -> int:
        return sum(int(rec.mask[ch].sum()) for rec in self.recs for ch in self.channels)

    def fd_jacobian(self, x: np.ndarray, cols: Sequence[int] | None = None) -> np.ndarray:
        """Finite-difference Jacobian columns: central for K, T and the noise and servo parameters;
        one-sided for the parameters the residual is linear in (initial states, bias), where a
        forward difference is exact (up to rounding).

        Parameters
        ----------
        x : numpy.ndarray
            Solver vector.
        cols : sequence of int, optional
            Columns to compute (all by default).
        """
        steps = self.fd_steps(x)
        cols = range(len(steps)) if cols is None else cols
        base = None
        out = []
        for j in cols:
            s = steps[j]
            xp = np.array(x, float)
            if self.kinds[j] in _LINEAR_KINDS:
                if base is None:
                    base = self.residual(x)
                s = 1e3 * s   # exact for a linear map: a larger step only lowers the rounding error
                xp[j] += s
                out.append((self.residual(xp) - base) / s)
                continue
            xm = np.array(x, float)
            xp[j] += s
            xm[j] -= s
            out.append((self.residual(xp) - self.residual(xm)) / (2 * s))
        return np.column_stack(out)

    def _sensitivity_columns(self, z: np.ndarray, cols: Sequence[int]) -> np.ndarray:
        """Jacobian columns ``cols`` of the residual: exact for the dynamic parameters, the bias and the
        initial states; for the servo parameters the central difference of the servo's rudder angle,
        run through the ship's sensitivity equations (the ship is linear in the rudder, so this is the
        central difference of the residual itself, without two further simulations)."""
        x = self.natural(z)
        dyn = [float(v) for v in x[: self.n_dyn]]
        b = float(x[self.n_dyn]) if self.bias else 0.0
        a, bm = nomoto_matrices(self.order, dyn)
        dmats = complex_step(lambda d: np.hstack(nomoto_matrices(self.order, d)), dyn)
        n = a.shape[0]
        da = [m[:, :n] for m in dmats]
        db = [m[:, n:] for m in dmats]
        if self.order != 1:
            coef = nomoto2_coefficients if self.order == 2 else nomoto2_sum_product
            a1, _, b1, _ = coef(*dyn)
            dcoef = complex_step(lambda d: np.array(coef(*d)), dyn)
        # d natural / d solver: theta for the log parameters (0 where natural() holds them at the margin).
        held = self.log_mask & ((z <= self._z_lo) | (z >= self._z_hi))
        chain = np.where(self.log_mask, np.where(held, 0.0, x), 1.0)
        cols = list(cols)
        dyn_c = [c for c, j in enumerate(cols) if j < self.n_dyn]
        dyn_j = [cols[c] for c in dyn_c]
        b_c = [c for c, j in enumerate(cols) if self.kinds[j] == "b"]
        servo_c = [c for c, j in enumerate(cols) if j in self.servo_index]
        steps = self.fd_steps(z)
        # The servo columns are derivatives in the solver's coordinates already (no chain factor).
        chain = chain.copy()
        chain[[cols[c] for c in servo_c]] = 1.0
        out = np.zeros((self._n_residuals(), len(cols)))
        row = 0
        for i, rec in enumerate(self.recs):
            sim = self.simulate(z, i)
            states = sim[STATES_KEY]
            u = self.rudder(z, i) - b
            nsamp = u.size
            ad, bd, dad, dbd = zoh_derivatives(a, bm, da, db, rec.h)
            own = set(self.ic_index[i])
            # Columns this record depends on: the shared ones and its own initial states.
            use = [c for c, j in enumerate(cols)
                   if j < self.n_dyn or self.kinds[j] == "b" or j in own or j in self.servo_index]
            at = {c: k for k, c in enumerate(use)}
            # Driving terms (column, state, sample): each column's rows contiguous for the filters.
            v = np.zeros((len(use), n, nsamp))
            s0 = np.zeros((n, len(use)))
            if dyn_c:
                # dA_d x[k] + dB_d (u[k] - b) for every dynamic parameter at once (one matrix product).
                dad_s = np.stack([dad[j] for j in dyn_j])                       # (p_dyn, n, n)
                dbd_s = np.stack([dbd[j][:, 0] for j in dyn_j])                 # (p_dyn, n)
                drive = (dad_s.reshape(-1, n) @ states.T).reshape(len(dyn_j), n, nsamp)
                drive += dbd_s[:, :, None] * u[None, None, :]
                v[[at[c] for c in dyn_c]] = drive
                if self.order != 1:
                    r0 = float(x[self.ic_index[i][self.ic_names.index("r0")]])
                    for c, j in zip(dyn_c, dyn_j):
                        s0[2, at[c]] = dcoef[j][0] * r0 - dcoef[j][2] * u[0]
            for c in b_c:
                v[at[c]] = -bd[:, 0][:, None]
                if self.order != 1:
                    s0[2, at[c]] = b1
            for c in servo_c:
                j = cols[c]
                zp, zm = np.array(z, float), np.array(z, float)
                zp[j] += steps[j]
                zm[j] -= steps[j]
                du = (self.rudder(zp, i) - self.rudder(zm, i)) / (2 * steps[j])
                v[at[c]] = bd[:, 0][:, None] * du[None, :]
                if self.order != 1:
                    s0[2, at[c]] = -b1 * du[0]
            for c in use:
                kind = self.kinds[cols[c]]
                if kind == "psi0":
                    s0[0, at[c]] = 1.0
                elif kind == "r0":
                    s0[1, at[c]] = 1.0
                    if self.order != 1:
                        s0[2, at[c]] = a1
                elif kind == "rdot0":
                    s0[2, at[c]] = 1.0
            sens = propagate_outputs(ad, v, s0, [0 if ch == "psi" else 1 for ch in self.channels])
            scale = chain[[cols[c] for c in use]][:, None]
            filt = self._filter(z, rec.h)
            for ch in self.channels:
                m = rec.mask[ch]
                d = sens[0 if ch == "psi" else 1] * scale                       # (columns, samples)
                if ch == "psi" and filt is not None:
                    if m.all():
                        d = whiten_profiled_rows(filt, d, self._phi(filt, rec.h, nsamp))
                    else:
                        d = np.vstack([whiten_with_gaps(filt, d[c], m) for c in range(len(use))])
                k = int(m.sum())
                out[row:row + k, use] = (d if k == nsamp else d[:, m]).T * (-self.weights[ch])
                row += k
        return out


def whiten_profiled_rows(filt: InnovationFilter, w: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """:func:`pipeline.fit.nomoto_pem.whiten_profiled` of every row of ``w`` (it is linear in ``w``): the
    Jacobian's heading columns whitened in one pass, the samples along the last axis.

    Parameters
    ----------
    filt : InnovationFilter
        The innovations filter.
    w : numpy.ndarray, shape (p, N)
        Output errors (or their derivatives) per row.
    phi : numpy.ndarray, shape (N, 2)
        :func:`pipeline.fit.nomoto_pem.initial_state_response` for ``N`` samples.
    """
    e0 = scipy.signal.lfilter(filt.num, filt.den, w, axis=-1)
    g = phi.T @ phi
    det = g[0, 0] * g[1, 1] - g[0, 1] * g[1, 0]
    if not det > 1e-300:
        return e0
    rhs = e0 @ phi                                                              # (p, 2)
    x0 = np.column_stack([g[1, 1] * rhs[:, 0] - g[0, 1] * rhs[:, 1], g[0, 0] * rhs[:, 1] - g[1, 0] * rhs[:, 0]]) / det
    return e0 - x0 @ phi.T


def whiten_with_gaps(filt: InnovationFilter, w: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Innovations of the steady-state wave filter over a record with missing compass samples.

    Parameters
    ----------
    filt : InnovationFilter
        From :func:`pipeline.fit.nomoto_pem.innovation_filter`.
    w : numpy.ndarray
        Output error ``y - y_sim`` [rad] (any value where ``mask`` is False).
    mask : numpy.ndarray of bool
        True where the compass was logged.
    """
    # A missing compass sample is a Kalman step without update: predict only. Rare (segments do
    # not span gaps), so the plain loop is good enough.
    a, l, c = filt.ad, filt.gain.ravel(), filt.c.ravel()
    xh = np.zeros(2)
    e = np.zeros(w.size)
    for k in range(w.size):
        if mask[k]:
            e[k] = w[k] - c @ xh
            xh = a @ xh + l * e[k]
        else:
            xh = a @ xh
    return e


# --------------------------------------------------------------------------- the fit
def plausible_ranges(prob: Problem) -> tuple[np.ndarray, np.ndarray]:
    """Plausible SI ranges; an estimate outside is reported (the solver itself is unbounded).

    Parameters
    ----------
    prob : Problem
        The problem.
    """
    h = min(r.h for r in prob.recs)
    dur = max(r.duration for r in prob.recs)
    lo = np.full(len(prob.names), -np.inf)
    hi = np.full(len(prob.names), np.inf)
    for j, k in enumerate(prob.kinds):
        if k in ("T", "T1", "T2", "T3", "T12"):
            lo[j], hi[j] = 0.1 * h, 100.0 * dur
        elif k == "T1T2":
            lo[j], hi[j] = (0.1 * h) ** 2, (100.0 * dur) ** 2
        elif k == "b":
            lo[j], hi[j] = -math.pi / 2, math.pi / 2
    for nm, j in zip(prob.servo, prob.servo_index):
        # A servo faster than a tenth of a sample is not seen; slower than the record is not a servo.
        lo[j], hi[j] = (0.1 * h, dur) if nm == "t_servo" else (math.radians(0.1), math.radians(1000.0))
    for nm, j in zip(prob.noise_free, prob.noise_index):
        if nm == "omega0":
            lo[j], hi[j] = 2 * math.pi / dur, math.pi / h
        elif nm == "lambda":
            lo[j], hi[j] = 1e-3, 5.0
        else:
            lo[j], hi[j] = 1e-8, 1e8
    return lo, hi


def solve(prob: Problem, z0: np.ndarray, max_nfev: int) -> optimize.OptimizeResult:
    """Levenberg-Marquardt on the problem's weighted residuals.

    Parameters
    ----------
    prob : Problem
        The problem.
    z0 : numpy.ndarray
        Start (solver vector).
    max_nfev : int
        Maximum function evaluations.
    """
    # MINPACK's Levenberg-Marquardt: positivity comes from the log parameters, and its QR is its
    # own code, so a tall Jacobian costs no threaded LAPACK call per iteration.
    return optimize.least_squares(prob.residual, z0, jac=prob.jacobian, method="lm", x_scale="jac",
                                  max_nfev=max_nfev, xtol=1e-10, ftol=1e-10, gtol=1e-10)


#: Weight of a second-order mode below which its zero counts as cancelling its pole [-]: the model
#: is then the first-order one (see :func:`cancelled_mode`).
COLLAPSE_WEIGHT = 0.02


def cancelled_mode(order: int, dyn: Sequence[float]) -> float:
    """Smallest weight of the two modes of a second-order Nomoto model's yaw-rate response [-].

    ``K (1 + T3 s) / ((1 + T1 s)(1 + T2 s)) = K (A1 / (1 + T1 s) + A2 / (1 + T2 s))`` with
    ``A1 = (T1 - T3) / (T1 - T2)`` and ``A2 = (T3 - T2) / (T1 - T2)`` (``A1 + A2 = 1``). A weight near
    zero means the zero cancels that pole: the model is the first-order one with the other time
    constant, whatever the cancelled pair's values (the solver then drifts along the pair without
    converging).

    Parameters
    ----------
    order : int
        Model order (2 or 3; NaN for the first order).
    dyn : sequence of float
        Dynamic parameters (``K, T1, T2, T3`` or ``K, T12, T1T2, T3``).

    Returns
    -------
    float
        ``min(|A1|, |A2|)``; NaN for the first order, complex or equal poles.
    """
    if order == 1:
        return math.nan
    if order == 2:
        _, t1, t2, t3 = dyn
    else:
        poles = pole_time_constants(dyn[1], dyn[2])
        if poles is None:
            return math.nan
        (t1, t2), t3 = poles, dyn[3]
    if not t1 != t2:
        return math.nan
    return float(min(abs((t1 - t3) / (t1 - t2)), abs((t3 - t2) / (t1 - t2))))


def reweighted_solve(prob: Problem, x0: np.ndarray, max_nfev: int, stop=None) -> optimize.OptimizeResult:
    """Solve, re-estimating the per-channel variances (maximum likelihood for unknown variances).

    Parameters
    ----------
    prob : Problem
        The problem (its channel weights are updated in place: it is local to one fit).
    x0 : numpy.ndarray
        Start (solver vector).
    max_nfev : int
        Maximum function evaluations per solver call.
    stop : callable, optional
        ``stop(result) -> str``: a non-empty reason ends the re-weighting after a solve (the result
        then carries it as ``result.stopped``).
    """
    def update_weights(x: np.ndarray) -> None:
        per = prob.channel_residuals(x)
        for ch in prob.channels:
            e = np.concatenate([p[ch] for p in per])
            ms = float(np.mean(e**2))
            prob.weights[ch] = 1.0 / math.sqrt(ms) if ms > 0 else 1.0

    update_weights(x0)
    res = solve(prob, x0, max_nfev)
    res.stopped = ""
    # One channel: the weight is only a scale, the solution does not depend on it.
    for _ in range(4 if len(prob.channels) > 1 else 0):
        why = stop(res) if stop is not None else ""
        if why:
            res.stopped = why
            break
        old = dict(prob.weights)
        update_weights(res.x)
        if all(abs(prob.weights[c] / old[c] - 1.0) < 1e-3 for c in prob.channels):
            break
        res = solve(prob, res.x, max_nfev)
        res.stopped = ""
    update_weights(res.x)
    return res


def concentrated_nll(prob: Problem, x: np.ndarray) -> float:
    """``sum_ch n_ch log(mse_ch)`` of the unweighted residuals at ``x`` [-].

    The Gaussian negative log-likelihood with every channel's variance concentrated out (up to a
    constant and a factor 2). Unlike the solver's weighted cost, it does not depend on the channel
    weights, which :func:`reweighted_solve` re-estimates from each start's own residuals (and, for a
    single channel, sets once from the start): costs of solves from different starts are not
    comparable, this criterion is.

    Parameters
    ----------
    prob : Problem
        The problem.
    x : numpy.ndarray
        Solver vector.
    """
    per = prob.channel_residuals(x)
    total = 0.0
    for ch in prob.channels:
        e = np.concatenate([q[ch] for q in per])
        if not e.size:
            continue
        ms = float(np.mean(e**2))
        if not (ms > 0 and math.isfinite(ms)):
            return math.inf if not ms == 0 else -math.inf
        total += e.size * math.log(ms)
    return total


def start_vector(prob: Problem, dyn: Sequence[float], b: float, ics: Sequence[Sequence[float]],
                  noise0: Sequence[float], servo0: Mapping[str, float] | None = None) -> np.ndarray:
    """Solver vector from SI start values.

    Parameters
    ----------
    prob : Problem
        The problem.
    dyn : sequence of float
        K, T (or K, T1, T2, T3) [SI].
    b : float
        Rudder bias [rad].
    ics : sequence of sequence of float
        Initial states per record, in ``prob.ic_names`` order.
    noise0 : sequence of float
        Start of the free noise parameters.
    servo0 : Mapping[str, float], optional
        Start of the servo parameters (default ``t_servo`` = 2 samples, ``rate_servo`` = 10 deg/s).
    """
    x = np.ones(len(prob.names))
    x[: prob.n_dyn] = dyn
    if prob.bias:
        x[prob.n_dyn] = b
    for idx, ic in zip(prob.ic_index, ics):
        x[idx] = ic
    if prob.noise_index:
        x[prob.noise_index] = np.asarray(noise0, float)
    defaults = {"t_servo": 2 * min(r.h for r in prob.recs), "rate_servo": math.radians(10.0)}
    defaults.update(servo0 or {})
    for nm, j in zip(prob.servo, prob.servo_index):
        x[j] = defaults[nm]
    return prob.solver_vector(x)


def normal_covariance(jac: np.ndarray, s2: float) -> tuple[np.ndarray, str]:
    """``(J^T J)^-1 s^2`` through the column-scaled normal matrix (p x p eigen-decomposition).

    Same result as the SVD of :func:`pipeline.fit.least_squares.fit_least_squares` for the
    well-conditioned problems here, without a threaded LAPACK call on the tall Jacobian.

    Parameters
    ----------
    jac : numpy.ndarray
        Jacobian of the weighted residuals, shape (n, p).
    s2 : float
        Residual variance ``RSS/(n - p)``.
    """
    p = jac.shape[1]
    scale = np.linalg.norm(jac, axis=0)
    if not np.all(np.isfinite(jac)) or np.any(scale == 0):
        return np.full((p, p), np.nan), "Jacobian has a zero or non-finite column: a parameter does not affect the fit"
    js = jac / scale
    w, v = np.linalg.eigh(js.T @ js)
    # cond(J)^2 above 1e12 is where the normal equations lose the digits the errors need.
    if w[0] <= w[-1] * 1e-12:
        return np.full((p, p), np.nan), (f"Jacobian is near-singular (condition number "
                                         f"{math.sqrt(w[-1] / max(w[0], 1e-300)):.1e}): parameters not separable")
    inv = (v / w) @ v.T
    return inv / np.outer(scale, scale) * s2, ""


def finish(prob: Problem, res: optimize.OptimizeResult, messages: list[str]) -> NomotoFit:
    """The :class:`NomotoFit` at the solution: covariance, criteria, residual tests, messages.

    Parameters
    ----------
    prob : Problem
        The problem.
    res : scipy.optimize.OptimizeResult
        Solver result.
    messages : list of str
        Notes so far (extended).
    """
    x = res.x
    names = tuple(prob.names)
    p = x.size
    resid = prob.residual(x)
    n = resid.size
    rss = float(resid @ resid)
    jac = prob.jacobian(x)
    cov, why = (normal_covariance(jac, rss / (n - p)) if n > p
                else (np.full((p, p), np.nan), "no degrees of freedom"))
    if why:
        messages.append(why)
    # Solver space -> SI: d theta / d z = theta for the log parameters (delta method).
    values = prob.natural(x)
    d = np.where(prob.log_mask, values, 1.0)
    cov = cov * np.outer(d, d)
    stderr = np.sqrt(np.clip(np.diag(cov), 0.0, None)) if not why else np.full(p, np.nan)
    lo, hi = plausible_ranges(prob)
    at_bound = tuple(nm for nm, v, a, b in zip(names, values, lo, hi) if not a < v < b)
    if at_bound:
        messages.append(f"parameter(s) {', '.join(at_bound)} outside the plausible range "
                        f"({', '.join(f'{a:.3g}..{b:.3g}' for nm, a, b in zip(names, lo, hi) if nm in at_bound)})")
    if res.status <= 0:
        messages.append(f"solver did not converge: {res.message}")
    per = prob.channel_residuals(x)
    inn_var, neg2 = {}, 0.0
    for ch in prob.channels:
        e = np.concatenate([q[ch] for q in per])
        inn_var[ch] = float(np.mean(e**2))
        neg2 += e.size * (math.log(2 * math.pi * inn_var[ch]) + 1.0) if inn_var[ch] > 0 else -math.inf
    waves, noise_var = None, {}
    h0 = prob.recs[0].h
    if prob.noise == "waves":
        omega0, lam, ratio = prob._noise_params(x)
        if prob.fixed_noise_var is not None and prob.fixed_waves is not None:
            waves, r = prob.fixed_waves, prob.fixed_noise_var
        else:
            waves, r = noise_from_ratio(omega0, lam, ratio, inn_var["psi"], h0)
        noise_var["psi"] = r
    elif "psi" in prob.channels:
        noise_var["psi"] = inn_var["psi"]
    if "r" in prob.channels:
        noise_var["r"] = inn_var["r"]
    y_fit, residuals, tests = [], [], []
    for i, rec in enumerate(prob.recs):
        sim = prob.simulate(x, i)
        y_fit.append({ch: sim[ch] for ch in prob.channels})
        full = {}
        for ch in prob.channels:
            e = np.full(rec.u.size, np.nan)
            e[rec.mask[ch]] = per[i][ch]
            full[ch] = e
            tests.append(residual_test(e, {"delta": rec.u}, f"{rec.name} {ch}"))
        residuals.append(full)
    messages += [tst.message for tst in tests if tst.message]
    model = "OE" if prob.noise == "white" else "PEM (wave noise model)"
    messages.insert(0, f"{model}, order {prob.order}, {len(prob.recs)} record(s), channels {'+'.join(prob.channels)}")
    return NomotoFit(order=prob.order, noise_model=prob.noise, names=names, values=values, stderr=stderr,
                     covariance=cov, waves=waves, noise_var=noise_var, innovation_var=inn_var,
                     y_fit=tuple(y_fit), residuals=tuple(residuals), n=n, neg2loglik=neg2,
                     aic=neg2 + 2 * p, bic=neg2 + p * math.log(n), converged=res.status > 0,
                     at_bound=at_bound, residual_tests=tuple(tests), message="; ".join(messages),
                     channels=prob.channels)
