"""How far the inertia coupling of the vessel config makes a one-DOF damping fit unsure.

The joint damping fit (:mod:`pipeline.fit.quadratic`) treats each DOF alone with the inertia
``M_ii``. When the mass matrix couples DOF ``i`` with another DOF ``c`` (``M_ic != 0``, e.g. sway
and yaw through ``m x_g``), accelerating ``i`` also drives ``c``, and the reaction changes the
inertia the motion of ``i`` feels. For ``c`` free with its own damping ``d_c``, linearised in the
Laplace variable ``s``::

    M_cc s nu_c + d_c nu_c = -M_ci s nu_i     =>   reaction on i:  M_ic M_ci s^2 / (M_cc s + d_c) nu_i

(with restoring ``g_c`` of a coupled roll or pitch, ``M_cc s + d_c + g_c / s``), so the effective
inertia of ``i`` is ``M_ii (1 - delta)`` with

    delta = sum_c  M_ic^2 / (M_ii M_cc)  *  |s| / |s + d_c / M_cc + g_c / (M_cc s)|

evaluated at the fitted DOF's fastest rate: ``s = a + b |nu|_max`` for a decay of a first-order
DOF, ``s = j wn`` for roll or pitch. A coupled DOF that damps out fast (``d_c / M_cc >> |s|``) or
is held by its restoring takes little part; a free, undamped one gives the static Schur
complement ``M_ii - M_ic^2 / M_cc``. ``delta`` is the order of
the bias of the fitted damping terms (``X = -M_ii a``) that no standard error covers. In
PythonVehicleSimulator's Otter (``M_vr = 12.25``) the sway-yaw coupling moved the noise-free
one-DOF yaw fit by 2.7 % (``N_r``) and 4 % (``N_|r|r``), with ``delta`` = 1.9 % (benchmark
``damping_structure.py``).

Not covered: a force on DOF ``i`` from the coupled DOF's *angle* (a restoring coupling ``G_ic``).
A floating hull has none in surge (weight and buoyancy are equal and both vertical, so pitch
gives no surge force), and the vessel config has no such entry. PythonVehicleSimulator's Otter
has one: it turns the payload's weight with the pitch into a surge force ``-m_p g sin(theta)`` that
no buoyancy term balances, so a surge deceleration pitches the boat (``M_uq = -19.75``) and the
pitch pushes back: quasi-static, an extra surge inertia ``m_p g |M_uq| / G_qq`` = 1.77 kg (2.1 %
of ``M_uu``), which is the Otter's 2 % ``X_u`` bias (benchmark: the one-DOF fit moves from -74.8
to -77.5 against -77.55 nominal when the payload weight is not pitched). A coast-down identifies
only ``D_ii / M_ii``, so the data cannot tell that extra inertia from a smaller damping; the
config rule here, which sees only ``M``, ``D`` and diagonal ``G``, gives ``delta`` = 0.12-0.15 % and
rightly does not flag it for a floating hull.
"""

from __future__ import annotations

import math

import numpy as np

from ..records import DOF_NAMES, DOFS, DampingFit
from ..vessel import Vessel
from .quadratic import SECOND_ORDER

#: Effective-inertia change above which a one-DOF fit is reported as unsure [-].
UNSURE_DELTA = 0.01


def fitted_rate(fit: DampingFit, dof: str) -> float:
    """Fastest rate of the fitted DOF: ``a + |b| |nu|_max`` (first order) or ``sqrt(c)`` [1/s].

    Parameters
    ----------
    fit : DampingFit
        A joint damping fit.
    dof : str
        Its DOF name.
    """
    vals = dict(zip(fit.names, fit.values))
    if dof in SECOND_ORDER:
        return math.sqrt(max(float(vals.get("c", 0.0)), 0.0))
    peak = max((float(np.nanmax(np.abs(y))) for y in fit.y_fit if np.size(y)), default=0.0)
    return float(vals["a"]) + abs(float(vals.get("b", 0.0))) * peak


def effective_inertia_change(mass: np.ndarray, damping: np.ndarray | None, dof: str, rate: float,
                             restoring: np.ndarray | None = None) -> tuple[float, list[str]]:
    """``delta`` of the module docstring, and the coupled DOFs that make it.

    Parameters
    ----------
    mass : numpy.ndarray
        Mass matrix M (5x5, DOF order u v p q r) [SI].
    damping : numpy.ndarray or None
        Linear damping D (5x5) [SI]; None: coupled DOFs undamped (the static bound).
    dof : str
        The fitted DOF.
    rate : float
        Its fastest rate [1/s] (a decay rate, or ``wn`` for roll and pitch).
    restoring : numpy.ndarray, optional
        Restoring G (5x5) [SI].

    Returns
    -------
    tuple[float, list[str]]
        ``delta`` [-] and the names of the coupled DOFs.
    """
    i = [DOF_NAMES[v] for v in DOFS].index(dof)
    delta, names = 0.0, []
    for c in range(5):
        if c == i or mass[i, c] == 0.0 or not (mass[c, c] > 0 and mass[i, i] > 0):
            continue
        d_c = float(damping[c, c]) if damping is not None and math.isfinite(damping[c, c]) else 0.0
        g_c = float(restoring[c, c]) if restoring is not None else 0.0
        s = complex(0.0, rate) if dof in SECOND_ORDER else complex(rate, 0.0)
        share = abs(s) / abs(s + max(d_c, 0.0) / mass[c, c] + g_c / (mass[c, c] * s)) if rate > 0 else 1.0
        delta += float(mass[i, c] ** 2 / (mass[i, i] * mass[c, c])) * share
        names.append(DOF_NAMES[DOFS[c]])
    return delta, names


def coupling_note(vessel: Vessel, dof: str, fit: DampingFit) -> str:
    """``unsure: ...`` when the config's inertia coupling moves the effective inertia of ``dof`` by
    more than ``UNSURE_DELTA``; empty otherwise (or without rigid-body data).

    Parameters
    ----------
    vessel : Vessel
        Vessel config.
    dof : str
        The fitted DOF.
    fit : DampingFit
        Its joint fit (the selected structure).
    """
    if not vessel.has_rigid_body:
        return ""
    mass = vessel.mass_matrix()
    rate = fitted_rate(fit, dof)
    delta, names = effective_inertia_change(mass, vessel.damping, dof, rate, vessel.restoring_matrix())
    if delta <= UNSURE_DELTA:
        return ""
    i = [DOF_NAMES[v] for v in DOFS].index(dof)
    terms = ", ".join(f"M[{dof},{n}] = {mass[i, [DOF_NAMES[v] for v in DOFS].index(n)]:.4g}" for n in names)
    return (f"unsure: the vessel config couples {dof} with {' and '.join(names)} by inertia ({terms}): this one-DOF "
            f"fit ignores the {' and '.join(names)} motion that {dof} accelerations drive, which lowers the "
            f"effective inertia by about {delta:.1%} at the fitted rate {rate:.3g} 1/s, so the damping terms "
            f"may be off by that order beyond their standard errors")
