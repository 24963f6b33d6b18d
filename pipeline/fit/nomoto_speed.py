"""Nomoto K and T as functions of speed, from runs at several speeds.

Each speed's records are fitted with the project's Nomoto fit (:func:`pipeline.fit.nomoto_oe.fit_nomoto`,
first order). Across speeds ``U`` the laws are::

    K(U) = k0 + k1 U        T(U) = t0 + t1 / U

which contain both the speed-independent model (``k1 = t1 = 0``) and Nomoto's scaling with ship
length ``L`` (``K = K' U / L``, ``T = T' L / U``: ``k0 = t0 = 0``; Fossen 2021, sec. 7.2). Each law
is a weighted least-squares line through the per-speed estimates (weights ``1 / stderr^2``); the
slope is kept only when the chi-square of the constant fit exceeds its 99 % point (``ALPHA``) and
at least two speeds were identified, else the inverse-variance mean is the law. With a length the
dimensionless ``K'`` and ``T'`` per speed are given too. Uncertainty at any speed comes from the
law's covariance, scaled up by the reduced chi-square when the points scatter more than their
errors say (Birge ratio).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
from scipy import stats

from ..errors import FitError
from .nomoto_oe import fit_nomoto
from .nomoto_records import NomotoRecord

#: Significance level of a speed dependence (chi-square of the constant law).
ALPHA = 0.01


@dataclass(frozen=True)
class SpeedPoint:
    """K and T identified at one speed.

    Attributes
    ----------
    speed : float
        Mean speed of the runs [m/s].
    K, K_stderr : float
        Nomoto gain [1/s].
    T, T_stderr : float
        Time constant [s].
    n_records : int
        Records fitted together.
    success : bool
        The Nomoto fit's verdict.
    message : str
        The fit's notes.
    """

    speed: float
    K: float
    K_stderr: float
    T: float
    T_stderr: float
    n_records: int
    success: bool
    message: str = ""


@dataclass(frozen=True)
class SpeedLaw:
    """One parameter against speed: ``value = c0 + c1 x(U)``, ``x = U`` for K, ``1/U`` for T.

    Attributes
    ----------
    name : str
        ``K`` or ``T``.
    regressor : str
        ``U`` or ``1/U``.
    coefficients : numpy.ndarray
        ``(c0, c1)``; ``c1 = 0`` for a constant law.
    covariance : numpy.ndarray
        Their covariance (2 x 2).
    speed_dependent : bool
        The slope is kept.
    chi2_constant, p_constant : float
        Chi-square of the constant law and its p-value.
    birge : float
        Scale applied to the covariance (``sqrt(reduced chi-square)`` when above 1).
    """

    name: str
    regressor: str
    coefficients: np.ndarray
    covariance: np.ndarray
    speed_dependent: bool
    chi2_constant: float
    p_constant: float
    birge: float

    def at(self, speed: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Value and standard error at ``speed`` [SI of the parameter].

        Parameters
        ----------
        speed : float or numpy.ndarray
            Speed through the water [m/s], positive.
        """
        u = np.asarray(speed, float)
        x = u if self.regressor == "U" else 1.0 / u
        basis = np.stack([np.ones_like(x), x], axis=-1)
        val = basis @ self.coefficients
        var = np.einsum("...i,ij,...j->...", basis, self.covariance, basis)
        return val, np.sqrt(np.clip(var, 0, None))


@dataclass(frozen=True)
class NomotoSpeedMap:
    """K(U) and T(U) with the per-speed estimates they come from.

    Attributes
    ----------
    points : tuple[SpeedPoint, ...]
        Per speed, ascending.
    K, T : SpeedLaw
        The laws.
    length : float
        Ship length [m] for the dimensionless values (NaN when not given).
    message : str
        What was chosen and why.
    """

    points: tuple[SpeedPoint, ...]
    K: SpeedLaw
    T: SpeedLaw
    length: float
    message: str

    @property
    def speed_dependent(self) -> bool:
        """K or T varies with speed."""
        return self.K.speed_dependent or self.T.speed_dependent

    def at(self, speed: float) -> dict:
        """K, T and their standard errors at one speed [1/s, s].

        Parameters
        ----------
        speed : float
            Speed [m/s].
        """
        k, ks = self.K.at(speed)
        t, ts = self.T.at(speed)
        return {"speed": float(speed), "K": float(k), "K_stderr": float(ks), "T": float(t), "T_stderr": float(ts)}

    def dimensionless(self) -> list[dict]:
        """Per speed ``K' = K L / U`` and ``T' = T U / L`` with standard errors (empty without a length)."""
        if not (math.isfinite(self.length) and self.length > 0):
            return []
        L = self.length
        return [{"speed": p.speed, "K_prime": p.K * L / p.speed, "K_prime_stderr": p.K_stderr * L / p.speed,
                 "T_prime": p.T * p.speed / L, "T_prime_stderr": p.T_stderr * p.speed / L} for p in self.points]


def speed_law(name: str, speeds: np.ndarray, values: np.ndarray, stderr: np.ndarray) -> SpeedLaw:
    """Weighted line or constant through per-speed estimates (module docstring).

    Parameters
    ----------
    name : str
        ``K`` (regressor ``U``) or ``T`` (regressor ``1/U``).
    speeds, values, stderr : numpy.ndarray
        Per-speed speed [m/s], estimate and standard error [SI].

    Returns
    -------
    SpeedLaw

    Raises
    ------
    FitError
        No point with a positive finite standard error.
    """
    u, y, s = (np.asarray(a, float) for a in (speeds, values, stderr))
    ok = np.isfinite(u) & (u > 0) & np.isfinite(y) & np.isfinite(s) & (s > 0)
    if not ok.any():
        raise FitError(f"{name} over speed: expected at least one speed with a finite estimate and error, found none")
    u, y, s = u[ok], y[ok], s[ok]
    reg = "U" if name == "K" else "1/U"
    x = u if reg == "U" else 1.0 / u
    w = 1.0 / s**2
    mean = float(np.sum(w * y) / np.sum(w))
    chi2_c = float(np.sum(w * (y - mean) ** 2))
    n = y.size
    p_c = float(stats.chi2.sf(chi2_c, n - 1)) if n > 1 else 1.0
    dependent = n >= 2 and np.ptp(x) > 0 and p_c < ALPHA
    if dependent:
        basis = np.column_stack([np.ones(n), x])
        cov = np.linalg.inv(basis.T @ (w[:, None] * basis))
        coef = cov @ basis.T @ (w * y)
        chi2 = float(np.sum(w * (y - basis @ coef) ** 2))
        dof = n - 2
    else:
        coef = np.array([mean, 0.0])
        cov = np.array([[1.0 / np.sum(w), 0.0], [0.0, 0.0]])
        chi2, dof = chi2_c, n - 1
    birge = math.sqrt(chi2 / dof) if dof > 0 and chi2 > dof else 1.0
    return SpeedLaw(name, reg, coef, cov * birge**2, bool(dependent), chi2_c, p_c, birge)


def fit_nomoto_speeds(runs: Mapping[float, Sequence[NomotoRecord]] | Sequence[tuple[float, Sequence[NomotoRecord]]],
                      length: float = math.nan, noise: str = "white") -> NomotoSpeedMap:
    """Fit K and T at each speed and the laws K(U), T(U) across speeds.

    Parameters
    ----------
    runs : Mapping or sequence of (speed, records)
        Mean speed [m/s] -> the records logged at that speed (rudder steps, zig-zags).
    length : float
        Ship length [m] for ``K'``, ``T'`` (optional).
    noise : str
        Noise model of each speed's Nomoto fit (``white``, ``waves`` or ``auto``).

    Returns
    -------
    NomotoSpeedMap

    Raises
    ------
    FitError
        No run, a non-positive speed, or no speed identified.
    """
    items = sorted((float(u), list(r)) for u, r in (runs.items() if isinstance(runs, Mapping) else runs))
    if not items:
        raise FitError("K, T over speed: expected runs at one or more speeds, found none")
    for u, recs in items:
        if not (math.isfinite(u) and u > 0):
            raise FitError(f"K, T over speed: expected positive speeds [m/s], found {u!r}")
        if not recs:
            raise FitError(f"K, T over speed: no record at speed {u:g} m/s")
    points = []
    for u, recs in items:
        try:
            f = fit_nomoto(recs, order=1, noise=noise)
            points.append(SpeedPoint(u, f.K, f.error("K"), f.T, f.error("T"), len(recs), f.success, f.message))
        except FitError as exc:
            points.append(SpeedPoint(u, math.nan, math.nan, math.nan, math.nan, len(recs), False, str(exc)))
    good = [p for p in points if p.success]
    if not good:
        raise FitError("K, T over speed: the Nomoto fit failed at every speed ("
                       + "; ".join(f"{p.speed:g} m/s: {p.message}" for p in points) + ")")
    arr = {k: np.array([getattr(p, k) for p in good]) for k in ("speed", "K", "K_stderr", "T", "T_stderr")}
    k_law = speed_law("K", arr["speed"], arr["K"], arr["K_stderr"])
    t_law = speed_law("T", arr["speed"], arr["T"], arr["T_stderr"])
    msg = [f"{len(good)} of {len(points)} speed(s) identified"]
    for law in (k_law, t_law):
        msg.append(f"{law.name} {'varies' if law.speed_dependent else 'constant'} with speed (constant law "
                   f"chi2 = {law.chi2_constant:.3g}, p = {law.p_constant:.2g})")
    return NomotoSpeedMap(tuple(points), k_law, t_law, float(length), "; ".join(msg))
