"""Steady-state maps: thrust (or command) against steady speed as a drag curve with uncertainty.

A bollard table or a set of speed runs gives points ``(u_k, tau_k)`` where thrust balances drag,
``tau = D u + D2 |u| u`` (Fossen 2021, sec. 6.4; ``X_u = -D``, ``X_|u|u = -D2``). The vessel
config's ``[steady_state]`` section lists them per DOF::

    [steady_state.surge]
    speed = [0.81, 1.05, 1.37]        # steady speed [m/s] (rad/s for yaw)
    force = [5.0, 10.1, 21.0]         # thrust at that speed [N] (N m for yaw)
    speed_se = 0.02                   # one value or one per point
    force_se = [0.5, 0.5, 1.0]
    source = "bollard table"

:func:`steady_points` turns it into :class:`pipeline.fit.quadratic.SteadyPoint` rows, which the joint
damping fit (:func:`pipeline.fit.structure.apply_structures`) fits together with the transients, so
the drag curve and the coast-downs are one model. :func:`fit_drag_curve` fits the curve on its own:
weighted least squares with the effective variance ``force_se^2 + (D + 2 D2 |u|)^2 speed_se^2``
(errors in both variables, two passes), the covariance scaled by the Birge ratio when the points
scatter beyond their errors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from ..config_schema import STEADY_DOFS, STEADY_KEYS
from ..errors import ConfigError, FitError
from .quadratic import TERM_NAMES, TERM_UNITS, SteadyPoint

#: Keys of one DOF's table; they and the DOFs a steady-state map can describe (those driven by
#: thrust against damping, ``STEADY_DOFS``) are declared once, in the config schema.
KEYS = set(STEADY_KEYS)


@dataclass(frozen=True)
class DragCurve:
    """``tau = D u + D2 |u| u`` fitted to steady points.

    Attributes
    ----------
    dof : str
        DOF name.
    names : tuple[str, ...]
        Fossen derivatives (``X_u``, ``X_|u|u``), values ``-D``, ``-D2``.
    values, stderr : numpy.ndarray
        Derivatives and standard errors [kg/s, kg/m or rotational units].
    covariance : numpy.ndarray
        Their covariance.
    units : tuple[str, ...]
        Units of the derivatives.
    chi2, birge : float
        Chi-square of the fit and the scale applied to the covariance.
    n : int
        Points used.
    """

    dof: str
    names: tuple[str, ...]
    values: np.ndarray
    stderr: np.ndarray
    covariance: np.ndarray
    units: tuple[str, ...]
    chi2: float
    birge: float
    n: int

    def drag(self, speed: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Drag force at ``speed`` and its standard error [N or N m].

        Parameters
        ----------
        speed : float or numpy.ndarray
            Steady velocity [m/s or rad/s].
        """
        u = np.asarray(speed, float)
        basis = np.stack([u, np.abs(u) * u], axis=-1)[..., : self.values.size]
        val = -(basis @ self.values)
        var = np.einsum("...i,ij,...j->...", basis, self.covariance, basis)
        return val, np.sqrt(np.clip(var, 0, None))


def _column(where: str, table: Mapping[str, Any], key: str, n: int, default: float | None = None,
            broadcast: bool = False) -> np.ndarray:
    raw = table.get(key, default)
    if raw is None:
        raise ConfigError(f"{where}: expected '{key}' (a number or a list of {n} numbers), found nothing")
    try:
        arr = np.atleast_1d(np.asarray(raw, float))
    except (TypeError, ValueError):
        raise ConfigError(f"{where}.{key}: expected numbers, found {raw!r}") from None
    if broadcast and arr.size == 1 and n > 1:
        arr = np.full(n, float(arr[0]))
    if arr.size != n or not np.all(np.isfinite(arr)):
        raise ConfigError(f"{where}.{key}: expected {n} finite number(s), found {raw!r}")
    return arr


def steady_points(section: Mapping[str, Any]) -> dict[str, list[SteadyPoint]]:
    """The ``[steady_state]`` section of a vessel config as steady points per DOF.

    Parameters
    ----------
    section : Mapping
        DOF -> table with ``speed``, ``force`` (lists), ``speed_se``, ``force_se`` (number or
        list; ``speed_se`` defaults to 0) and an optional ``source``.

    Returns
    -------
    dict[str, list[SteadyPoint]]

    Raises
    ------
    ConfigError
        Unknown DOF or key, lists of different length, missing errors, non-positive force errors.
    """
    if not isinstance(section, Mapping):
        raise ConfigError(f"steady_state: expected a table of DOFs {list(STEADY_DOFS)}, found {type(section).__name__}")
    out = {}
    for dof, table in section.items():
        where = f"steady_state.{dof}"
        if dof not in STEADY_DOFS:
            raise ConfigError(f"{where}: expected a DOF among {list(STEADY_DOFS)}, found {dof!r}")
        if not isinstance(table, Mapping):
            raise ConfigError(f"{where}: expected a table with {sorted(KEYS)}, found {type(table).__name__}")
        unknown = sorted(set(table) - KEYS)
        if unknown:
            raise ConfigError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(KEYS)}")
        speed = _column(where, table, "speed", len(np.atleast_1d(table.get("speed", []))))
        n = speed.size
        if n == 0:
            raise ConfigError(f"{where}.speed: expected at least one steady speed, found none")
        force = _column(where, table, "force", n)
        speed_se = _column(where, table, "speed_se", n, 0.0, broadcast=True)
        force_se = _column(where, table, "force_se", n, broadcast=True)
        if np.any(force_se <= 0) or np.any(speed_se < 0):
            raise ConfigError(f"{where}: expected force_se > 0 and speed_se >= 0, found {force_se.tolist()} and "
                              f"{speed_se.tolist()}")
        src = str(table.get("source", "vessel config steady_state"))
        out[dof] = [SteadyPoint(float(u), float(f), float(su), float(sf), src)
                    for u, f, su, sf in zip(speed, force, speed_se, force_se)]
    return out


def fit_drag_curve(points: Sequence[SteadyPoint], dof: str = "surge", quadratic: bool = True) -> DragCurve:
    """Weighted least squares of ``tau = D u (+ D2 |u| u)`` through steady points (module docstring).

    Parameters
    ----------
    points : Sequence[SteadyPoint]
        At least two points (three for the quadratic curve, so that a scatter is left).
    dof : str
        DOF name (for the derivative names).
    quadratic : bool
        Fit ``D2`` too.

    Returns
    -------
    DragCurve

    Raises
    ------
    FitError
        Too few points, or speeds that do not determine the curve.
    """
    k = 2 if quadratic else 1
    if len(points) < k + 1:
        raise FitError(f"{dof} drag curve: expected at least {k + 1} steady points, found {len(points)}")
    u = np.array([p.speed for p in points])
    tau = np.array([p.force for p in points])
    su = np.array([p.speed_se for p in points])
    sf = np.array([p.force_se for p in points])
    basis = np.column_stack([u, np.abs(u) * u])[:, :k]
    if np.linalg.matrix_rank(basis) < k:
        raise FitError(f"{dof} drag curve: the speeds {u.tolist()} do not determine {k} drag coefficient(s)")
    coef = np.linalg.lstsq(basis / sf[:, None], tau / sf, rcond=None)[0]
    for _ in range(2):
        slope = coef[0] + (2 * coef[1] * np.abs(u) if k == 2 else 0.0)
        sd = np.sqrt(sf**2 + (slope * su) ** 2)
        coef = np.linalg.lstsq(basis / sd[:, None], tau / sd, rcond=None)[0]
    w = basis / sd[:, None]
    cov = np.linalg.inv(w.T @ w)
    chi2 = float(np.sum(((tau - basis @ coef) / sd) ** 2))
    dof_resid = u.size - k
    birge = math.sqrt(chi2 / dof_resid) if dof_resid > 0 and chi2 > dof_resid else 1.0
    cov = cov * birge**2
    names = TERM_NAMES[dof][:k]
    return DragCurve(dof, names, -coef, np.sqrt(np.diag(cov)), cov, TERM_UNITS[dof][:k], chi2, birge, int(u.size))
