"""Norrbin's nonlinear steering model against the linear Nomoto model, chosen by held-out error.

Norrbin (1963): ``T r_dot + r + n3 r^3 = K (delta - b)`` (:func:`pipeline.model.nomoto.nomoto_rhs`
with ``n3``; Fossen 2021, sec. 7.2.3). ``n3`` [s^2/rad^2] makes the steady turning rate saturate
with rudder angle (the ship's spiral curve is not a straight line). The linear model is fitted
first with the project's Nomoto fit (:func:`pipeline.fit.nomoto_oe.fit_nomoto`, white-noise
output error) and starts both structures here: the same output-error criterion (yaw rate and/or
heading, each weighted by its noise level) is minimised over every record at once with ``n3`` held
at 0 (Nomoto) or free (Norrbin). Held-out error decides, with the significance rule of the gap
diagnosis (:func:`pipeline.fit.heldout_test.is_significant`): with three or more records each fold
leaves whole records out (their initial state fitted on their own samples with the ship held);
with fewer, interleaved time blocks of every record. The covariance is the HAC sandwich of
:mod:`pipeline.fit.robust_covariance`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
from scipy import optimize

from ..errors import FitError
from ..model.nomoto import NomotoParams, nomoto_rhs
from .data import noise_sigma
from .heldout_test import heldout_gain, is_significant
from .least_squares import confidence_interval
from .nomoto_oe import fit_nomoto
from .nomoto_records import NomotoFit, NomotoRecord
from .robust_covariance import hac_covariance

#: Shared parameters of the Norrbin structure (the Nomoto structure omits ``n3``).
SHARED = ("K", "T", "n3", "b")
#: Units of the shared parameters.
UNITS = {"K": "1/s", "T": "s", "n3": "s^2/rad^2", "b": "rad"}
#: Samples per record kept for the fit (every k-th sample, noise stays white).
TARGET_SAMPLES = 250
#: Most folds of the leave-records-out split; time blocks per record otherwise.
MAX_FOLDS = 5
TIME_BLOCKS = 4
BLOCKS_PER_FOLD = 4
#: Structures a user may ask for.
MODELS = ("auto", "nomoto", "norrbin")


@dataclass(frozen=True)
class NorrbinFit:
    """One steering structure fitted to every record.

    Attributes
    ----------
    structure : str
        ``nomoto`` (``n3 = 0``) or ``norrbin``.
    names : tuple[str, ...]
        Shared parameters in covariance order.
    values, stderr : numpy.ndarray
        Estimates and HAC standard errors [SI, see ``UNITS``].
    covariance : numpy.ndarray
        Their covariance.
    ci95 : Mapping[str, tuple[float, float]]
        95 % confidence intervals (t quantile).
    rmse : float
        RMS of the noise-weighted residuals [-].
    n, dof_resid : int
        Residuals and residual degrees of freedom.
    lag1 : float
        Lag-1 autocorrelation of the residuals [-].
    y_fit : tuple
        Per record, channel -> simulated output on the fitted grid.
    success : bool
        Converged with a finite covariance and ``T > 0``.
    message : str
        What is doubtful.
    """

    structure: str
    names: tuple[str, ...]
    values: np.ndarray
    stderr: np.ndarray
    covariance: np.ndarray
    ci95: Mapping[str, tuple[float, float]]
    rmse: float
    n: int
    dof_resid: int
    lag1: float
    y_fit: tuple = ()
    success: bool = True
    message: str = ""

    def value(self, name: str) -> float:
        """Estimate of one parameter; ``n3`` is 0 for the Nomoto structure [SI].

        Parameters
        ----------
        name : str
            ``K``, ``T``, ``n3`` or ``b``.
        """
        return float(self.values[self.names.index(name)]) if name in self.names else 0.0

    def error(self, name: str) -> float:
        """Standard error of one parameter (0 for a parameter the structure does not have) [SI].

        Parameters
        ----------
        name : str
            ``K``, ``T``, ``n3`` or ``b``.
        """
        return float(self.stderr[self.names.index(name)]) if name in self.names else 0.0


@dataclass(frozen=True)
class NorrbinChoice:
    """Nomoto against Norrbin on held-out data.

    Attributes
    ----------
    selected : str
        ``nomoto`` or ``norrbin``.
    fits : Mapping[str, NorrbinFit]
        Both structures fitted to all records (only ``nomoto`` when forced).
    nomoto_api : NomotoFit
        The project's linear Nomoto fit that started both.
    heldout_rmse : Mapping[str, float]
        Held-out RMS of the noise-weighted residuals per structure [-].
    p_value, p_robust, shrink, explained : float
        The significance rule's numbers (:func:`pipeline.fit.heldout_test.is_significant`).
    significant : bool
        Norrbin passed the rule.
    folds : str
        How the held-out data were chosen.
    message : str
        Why this structure.
    """

    selected: str
    fits: Mapping[str, NorrbinFit]
    nomoto_api: NomotoFit
    heldout_rmse: Mapping[str, float]
    p_value: float
    p_robust: float
    shrink: float
    explained: float
    significant: bool
    folds: str
    message: str = ""


class _Problem:
    """Stacked records (padded), channels weighted by their noise level."""

    def __init__(self, records: Sequence[NomotoRecord], cubic: bool) -> None:
        self.cubic = cubic
        self.names = SHARED if cubic else ("K", "T", "b")
        self.channels = tuple(ch for ch in ("psi", "r") if all(getattr(r, ch) is not None for r in records))
        if not self.channels:
            raise FitError("Norrbin fit: expected records with heading 'psi' or yaw rate 'r', found neither")
        h = [float(np.median(np.diff(r.t))) for r in records]
        k = max(1, int(max(r.t.size for r in records) // TARGET_SAMPLES))
        self.dt = h[0] * k
        if any(abs(x - h[0]) > 1e-6 * h[0] for x in h):
            raise FitError(f"Norrbin fit: expected one sample interval over all records, found {sorted(set(h))} s")
        self.n_len = max((r.t.size + k - 1) // k for r in records)
        k_rec = len(records)
        self.delta = np.zeros((k_rec, self.n_len))
        self.Y = {ch: np.full((k_rec, self.n_len), np.nan) for ch in self.channels}
        self.W = {}
        for i, rec in enumerate(records):
            # The rudder over each kept interval is the mean of the k held samples it spans (plain
            # subsampling would shift a ramped rudder by up to k samples and bias T).
            raw = np.asarray(rec.delta, float)
            m = -(-raw.size // k)
            d = np.concatenate([raw, np.full(m * k - raw.size, raw[-1])]).reshape(m, k).mean(axis=1)
            self.delta[i, : d.size] = d
            self.delta[i, d.size:] = d[-1]
            for ch in self.channels:
                y = np.asarray(getattr(rec, ch), float)
                if ch == "psi":
                    ok = np.isfinite(y)
                    y = y.copy()
                    y[ok] = np.unwrap(y[ok])
                y = y[::k]
                self.Y[ch][i, : y.size] = y
        for ch in self.channels:
            s = [noise_sigma(row[np.isfinite(row)]) for row in self.Y[ch]]
            s = [x if math.isfinite(x) and x > 0 else 1e-3 * max(float(np.nanmax(np.abs(self.Y[ch]))), 1e-9) for x in s]
            self.W[ch] = 1.0 / np.array(s)[:, None]
        self.mask = {ch: np.isfinite(self.Y[ch]) for ch in self.channels}
        self.k = k_rec
        self.r_scale = float(np.nanmax(np.abs(self.Y["r"]))) if "r" in self.Y else 0.0

    def simulate_many(self, thetas: Sequence[np.ndarray]) -> np.ndarray:
        """States ``(len(thetas), records, samples, [psi, r])`` by RK4 with the rudder held per sample;
        all parameter vectors are integrated together (one model evaluation per RK4 stage)."""
        nb, ng = len(thetas), len(self.names)
        th = np.asarray(thetas, float)
        col = {n: np.repeat(th[:, j], self.k) for j, n in enumerate(self.names)}
        p = NomotoParams(K=col["K"], T=col["T"], b=col["b"], n3=col.get("n3", 0.0))
        x0 = th[:, ng:].reshape(nb * self.k, 2)
        r_max = max(float(np.nanmax(np.abs(x0[:, 1]))), self.r_scale)
        rate = float(np.max((1.0 + 3.0 * np.abs(p.n3) * r_max**2) / np.maximum(np.abs(p.T), 1e-9)))
        m = int(min(max(math.ceil(self.dt * rate / 0.5), 1), 50))
        h = self.dt / m
        out = np.empty((nb * self.k, self.n_len, 2))
        x = x0.T.copy()
        delta = np.tile(self.delta, (nb, 1))
        with np.errstate(over="ignore", invalid="ignore"):
            for j in range(self.n_len):
                out[:, j] = x.T
                u = (delta[:, j],)
                for _ in range(m):
                    k1 = nomoto_rhs(0.0, x, u, p)
                    k2 = nomoto_rhs(0.0, x + 0.5 * h * k1, u, p)
                    k3 = nomoto_rhs(0.0, x + 0.5 * h * k2, u, p)
                    k4 = nomoto_rhs(0.0, x + h * k3, u, p)
                    x = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        return out.reshape(nb, self.k, self.n_len, 2)

    def split(self, theta: np.ndarray) -> tuple[dict, np.ndarray]:
        ng = len(self.names)
        return dict(zip(self.names, theta[:ng])), theta[ng:].reshape(self.k, 2)

    def rows_from_states(self, xs: np.ndarray, masks: Mapping[str, np.ndarray]) -> dict:
        """Channel -> weighted residual matrix of states ``xs`` (records, samples, 2), zero outside ``masks``."""
        out = {}
        for ch in self.channels:
            yhat = xs[:, :, 0] if ch == "psi" else xs[:, :, 1]
            r = (self.Y[ch] - yhat) * self.W[ch]
            r = np.where(np.isfinite(r), r, 1e6)
            out[ch] = np.where(masks[ch], r, 0.0)
        return out

    def vector(self, rows: Mapping[str, np.ndarray], masks: Mapping[str, np.ndarray]) -> np.ndarray:
        return np.concatenate([rows[ch][masks[ch]] for ch in self.channels])

    def residual_rows(self, theta: np.ndarray, masks: Mapping[str, np.ndarray]) -> dict:
        """Channel -> weighted residual matrix, zero outside ``masks``."""
        return self.rows_from_states(self.simulate_many([theta])[0], masks)

    def residuals(self, theta: np.ndarray, masks: Mapping[str, np.ndarray]) -> np.ndarray:
        return self.vector(self.residual_rows(theta, masks), masks)

    def groups(self, masks: Mapping[str, np.ndarray]) -> np.ndarray:
        idx = np.broadcast_to(np.arange(self.k)[:, None], (self.k, self.n_len))
        return np.concatenate([idx[masks[ch]] + c * self.k for c, ch in enumerate(self.channels)])


def _solve(p: _Problem, theta0: np.ndarray, masks: Mapping[str, np.ndarray], free: np.ndarray,
           max_nfev: int = 60) -> np.ndarray:
    lo = np.full(theta0.size, -np.inf)
    hi = np.full(theta0.size, np.inf)
    lo[p.names.index("T")] = 1e-3
    if p.cubic:
        # Total damping 1 + 3 n3 r^2 stays positive over the records' yaw rates.
        r_max = max(float(np.nanmax(np.abs(p.Y["r"]))) if "r" in p.Y else 0.0,
                    float(np.nanmax(np.abs(theta0[len(p.names) + 1:: 2]))), 1e-6)
        lo[p.names.index("n3")] = -0.3 / r_max**2
    x0 = np.clip(theta0, lo + 1e-12, hi)

    def full(x):
        th = theta0.copy()
        th[free] = x
        return th

    def jac(x):
        return _jacobian(p, full(x), masks)[:, free]

    res = optimize.least_squares(lambda x: p.residuals(full(x), masks), x0[free], jac=jac,
                                 bounds=(lo[free], hi[free]), x_scale="jac", method="trf", max_nfev=max_nfev)
    return full(res.x)


def _jacobian(p: _Problem, theta: np.ndarray, masks: Mapping[str, np.ndarray]) -> np.ndarray:
    """Forward differences, every perturbation integrated in one batch: one per shared parameter and
    one per initial-state type (every record's perturbed at once: a record depends only on its own)."""
    ng = len(p.names)
    thetas, steps = [theta], []
    for j in range(ng):
        th = theta.copy()
        steps.append(1e-6 * max(abs(theta[j]), 1e-3))
        th[j] += steps[-1]
        thetas.append(th)
    loc_steps = []
    for l in range(2):
        idx = ng + np.arange(p.k) * 2 + l
        th = theta.copy()
        loc_steps.append(1e-6 * np.maximum(np.abs(theta[idx]), 1e-3))
        th[idx] += loc_steps[-1]
        thetas.append(th)
    xs = p.simulate_many(thetas)
    vec = [p.vector(p.rows_from_states(x, masks), masks) for x in xs]
    r0 = vec[0]
    jac = np.zeros((r0.size, theta.size))
    for j in range(ng):
        jac[:, j] = (vec[1 + j] - r0) / steps[j]
    groups = p.groups(masks) % p.k
    for l in range(2):
        d = (vec[1 + ng + l] - r0) / loc_steps[l][groups]
        for i in range(p.k):
            jac[:, ng + 2 * i + l] = np.where(groups == i, d, 0.0)
    return jac


def _free_all(p: _Problem, masks: Mapping[str, np.ndarray]) -> np.ndarray:
    has = np.zeros(p.k, bool)
    for ch in p.channels:
        has |= masks[ch].any(axis=1)
    return np.concatenate([np.ones(len(p.names), bool), np.repeat(has, 2)])


def _start(p: _Problem, nomoto: NomotoFit, records: Sequence[NomotoRecord]) -> np.ndarray:
    shared = {"K": nomoto.K, "T": nomoto.T, "n3": 0.0, "b": nomoto.b}
    fitted = dict(zip(nomoto.names, np.asarray(nomoto.values, float)))
    x0 = []
    for i in range(len(records)):
        first = {ch: (p.Y[ch][i, np.flatnonzero(p.mask[ch][i])[0]] if ch in p.Y and p.mask[ch][i].any() else 0.0)
                 for ch in ("psi", "r")}
        for ch in ("psi", "r"):
            val = fitted.get(f"{ch}0[{i}]", fitted.get(f"{ch}0") if len(records) == 1 else None)
            x0.append(float(val) if val is not None and math.isfinite(val) else float(first[ch]))
    return np.concatenate([[shared[n] for n in p.names], x0])


def _fit(p: _Problem, theta0: np.ndarray, structure: str) -> tuple[NorrbinFit, np.ndarray]:
    masks = p.mask
    free = _free_all(p, masks)
    theta = _solve(p, theta0, masks, free, max_nfev=100)
    r = p.residuals(theta, masks)
    jac = _jacobian(p, theta, masks)[:, free]
    ng = len(p.names)
    rob = hac_covariance(jac, r, p.groups(masks))
    cov = rob.covariance[:ng, :ng]
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    n, k = r.size, int(free.sum())
    dof_resid = max(n - k, 1)
    vals = theta[:ng].copy()
    ci = {nm: confidence_interval(float(v), float(s), dof_resid) for nm, v, s in zip(p.names, vals, se)}
    g, _ = p.split(theta)
    xs = p.simulate_many([theta])[0]
    y_fit = tuple({ch: (xs[i, :, 0] if ch == "psi" else xs[i, :, 1]) for ch in p.channels} for i in range(p.k))
    ok = bool(np.all(np.isfinite(se)) and g["T"] > 0 and np.all(np.isfinite(xs)))
    msg = []
    if rob.rho > 0.5:
        msg.append(f"residuals coloured (lag-1 autocorrelation {rob.rho:.2f}): standard errors from the HAC "
                   f"sandwich ({rob.bandwidth} lags)")
    return NorrbinFit(structure, p.names, vals, se, cov, ci, float(math.sqrt(float(r @ r) / max(n, 1))), n, dof_resid,
                      rob.rho, y_fit, ok, "; ".join(msg)), theta


def _folds(p: _Problem) -> tuple[list[dict], str]:
    if p.k >= 3:
        nf = min(p.k, MAX_FOLDS)
        out = []
        for f in range(nf):
            out.append({ch: np.where(np.arange(p.k)[:, None] % nf == f, p.mask[ch], False) for ch in p.channels})
        return out, f"{nf}-fold leave-records-out over {p.k} records"
    out = []
    for j in range(TIME_BLOCKS):
        m = {ch: np.zeros_like(p.mask[ch]) for ch in p.channels}
        for ch in p.channels:
            for i in range(p.k):
                idx = np.flatnonzero(p.mask[ch][i])
                for block in np.array_split(idx, BLOCKS_PER_FOLD * TIME_BLOCKS)[j::TIME_BLOCKS]:
                    m[ch][i, block] = True
        out.append(m)
    return out, f"{TIME_BLOCKS} folds of interleaved time blocks over {p.k} record(s)"


def _heldout(p: _Problem, theta_full: np.ndarray, folds: Sequence[dict]) -> dict:
    """Channel -> held-out weighted residual matrix (NaN off the test sets)."""
    out = {ch: np.full(p.mask[ch].shape, np.nan) for ch in p.channels}
    ng = len(p.names)
    for test in folds:
        train = {ch: p.mask[ch] & ~test[ch] for ch in p.channels}
        th = _solve(p, theta_full, train, _free_all(p, train), max_nfev=25)
        has_train = np.zeros(p.k, bool)
        has_test = np.zeros(p.k, bool)
        for ch in p.channels:
            has_train |= train[ch].any(axis=1)
            has_test |= test[ch].any(axis=1)
        lone = ~has_train & has_test
        if lone.any():
            lone_mask = {ch: test[ch] & lone[:, None] for ch in p.channels}
            free = np.concatenate([np.zeros(ng, bool), np.repeat(lone, 2)])
            th = _solve(p, th, lone_mask, free, max_nfev=25)
        rows = p.residual_rows(th, {ch: np.ones_like(p.mask[ch]) for ch in p.channels})
        for ch in p.channels:
            out[ch][test[ch]] = rows[ch][test[ch]]
    return out


def select_norrbin(records: NomotoRecord | Sequence[NomotoRecord], model: str = "auto") -> NorrbinChoice:
    """Fit Nomoto and Norrbin to all records and choose by held-out error.

    Parameters
    ----------
    records : NomotoRecord or sequence of NomotoRecord
        Records of one ship at one speed (rudder and heading and/or yaw rate, one sample interval);
        for K, T over speed see :mod:`pipeline.fit.nomoto_speed`.
    model : str
        ``auto`` (held-out choice), ``nomoto`` (linear only) or ``norrbin`` (forced; both scored).

    Returns
    -------
    NorrbinChoice

    Raises
    ------
    FitError
        Unknown ``model``, no record, or records the Nomoto fit rejects.
    """
    if model not in MODELS:
        raise FitError(f"--model: expected one of {list(MODELS)}, found {model!r}")
    recs = [records] if isinstance(records, NomotoRecord) else list(records)
    if not recs:
        raise FitError("Norrbin fit: expected at least one record, found none")
    api = fit_nomoto(recs, order=1, noise="white")
    p_lin = _Problem(recs, cubic=False)
    lin, th_lin = _fit(p_lin, _start(p_lin, api, recs), "nomoto")
    if model == "nomoto":
        return NorrbinChoice("nomoto", {"nomoto": lin}, api, {"nomoto": math.nan}, math.nan, math.nan, math.nan,
                             math.nan, False, "not scored", "linear Nomoto structure forced")
    p_cub = _Problem(recs, cubic=True)
    th_cub0 = np.concatenate([th_lin[:2], [0.0], th_lin[2:]])
    cub, th_cub = _fit(p_cub, th_cub0, "norrbin")
    folds, how = _folds(p_lin)
    e0 = _heldout(p_lin, th_lin, folds)
    e1 = _heldout(p_cub, th_cub0, folds)
    rows0, rows1, fold_of = [], [], []
    for f, test in enumerate(folds):
        for ch in p_lin.channels:
            for i in range(p_lin.k):
                if test[ch][i].any():
                    rows0.append(np.where(test[ch][i], e0[ch][i], np.nan))
                    rows1.append(np.where(test[ch][i], e1[ch][i], np.nan))
                    fold_of.append(f)
    r0, r1, fold_of = np.array(rows0), np.array(rows1), np.array(fold_of)
    rms = {"nomoto": float(np.sqrt(np.nanmean(r0**2))), "norrbin": float(np.sqrt(np.nanmean(r1**2)))}
    # Residuals are noise-weighted: the white-noise level is 1 in these units.
    cs, shrink, p_rob = heldout_gain("+".join(p_lin.channels), r0, r1, fold_of, len(folds), 1.0)
    pv = cs.p_value if math.isfinite(cs.p_value) else 1.0
    # "explained" on the scale of the weighted output's spread, as the damping selection does.
    scale = max(float(np.nanstd(np.concatenate([(p_lin.Y[ch] * p_lin.W[ch])[p_lin.mask[ch]] for ch in p_lin.channels]))),
                1e-12)
    explained = cs.explained / scale
    sig = bool(is_significant(pv, p_rob, shrink, explained) and cub.success)
    chosen = "norrbin" if (model == "norrbin" or sig) else "nomoto"
    why = (f"held-out weighted RMS Nomoto {rms['nomoto']:.4g}, Norrbin {rms['norrbin']:.4g} ({shrink:+.1f} % gap "
           f"shrink, p = {pv:.2g}, robust p = {p_rob:.2g}, explained {explained:.3g}; {how})")
    why = ("Norrbin forced; " if model == "norrbin" else
           "n3 significant on held-out data: " if sig else "n3 not significant on held-out data: ") + why
    return NorrbinChoice(chosen, {"nomoto": lin, "norrbin": cub}, api, rms, pv, p_rob, float(shrink), float(explained),
                         sig, how, why)
