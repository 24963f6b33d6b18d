"""The identified model read back from ``coefficients.json``: the one object every export writes.

``M nu_dot + D nu + D2 |nu| nu + G eta = tau`` in DOF order u, v, p, q, r (Fossen 2021), with D and
D2 positive, plus Nomoto K and T where identified. The inertia ``M_ii`` comes from the vessel
config when one is given, else from the structure fits recorded in ``coefficients.json`` (each
joint fit states the ``M_ii`` it used). Rigid-body mass and added mass are only separated when the
vessel config gives both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from ..records import DOF_NAMES, DOFS
from ..report.coefficients_json import damping_from_dict
from ..vessel import Vessel
from .errors import ExportError


@dataclass(frozen=True)
class ExportModel:
    """An identified model ready for export (SI units, Fossen's body frame and signs).

    Attributes
    ----------
    name : str
        Vessel name.
    inertia : numpy.ndarray, shape (5,)
        ``M_ii = M_RB + M_A`` per DOF u v p q r [kg, kg m^2]; NaN where unknown.
    added_mass : numpy.ndarray, shape (5,)
        Added mass ``-X_udot ...`` per DOF [kg, kg m^2] (0 where the config gives none).
    damping : numpy.ndarray, shape (5,)
        Linear damping ``D_ii > 0`` [kg/s, kg m^2/s]; NaN where not identified.
    damping_stderr : numpy.ndarray, shape (5,)
        Its standard errors.
    quadratic : numpy.ndarray, shape (5,)
        ``D2_i >= 0`` of ``D2 |nu| nu`` [kg/m, kg m^2]; 0 where the linear structure was kept.
    quadratic_stderr : numpy.ndarray, shape (5,)
        Its standard errors (NaN where not fitted).
    restoring : Mapping[str, float]
        ``roll``, ``pitch`` restoring [N m/rad] where known.
    nomoto : Mapping[str, float]
        ``K`` [1/s] and ``T`` [s] where identified.
    max_rudder : float
        Rudder limit [rad] from the vessel config (NaN when unknown).
    notes : tuple[str, ...]
        Where each part came from and what is missing.
    """

    name: str
    inertia: np.ndarray
    added_mass: np.ndarray
    damping: np.ndarray
    damping_stderr: np.ndarray
    quadratic: np.ndarray
    quadratic_stderr: np.ndarray
    restoring: Mapping[str, float] = field(default_factory=dict)
    nomoto: Mapping[str, float] = field(default_factory=dict)
    max_rudder: float = math.nan
    notes: tuple[str, ...] = ()

    def require(self, what: str, dofs: tuple[int, ...], target: str) -> None:
        """Raise when ``what`` (``damping``, ``inertia``) is not finite for the DOF indices ``dofs``.

        Parameters
        ----------
        what : str
            Attribute name.
        dofs : tuple[int, ...]
            Indices into u v p q r.
        target : str
            Export target, for the message.
        """
        vals = np.asarray(getattr(self, what))
        bad = [DOF_NAMES[DOFS[i]] for i in dofs if not math.isfinite(vals[i])]
        if bad:
            hint = " (pass --vessel V.toml for the mass and inertia)" if what == "inertia" else ""
            raise ExportError(f"{target}: expected identified {what} for {', '.join(bad)}, found none in the "
                              f"coefficients{hint}")


def _num(x) -> float:
    return math.nan if x is None else float(x)


def model_from_coefficients(data: Mapping[str, Any], vessel: Vessel | None = None) -> ExportModel:
    """Build the export model from a loaded ``coefficients.json`` (and optionally the vessel config).

    Parameters
    ----------
    data : Mapping
        From :func:`pipeline.report.coefficients_json.load_coefficients`.
    vessel : Vessel, optional
        Config: rigid-body mass and inertia, added mass, restoring and rudder limit.

    Returns
    -------
    ExportModel
    """
    notes = []
    D, D_se = damping_from_dict(data)
    damping, damping_se = np.diag(D).copy(), np.diag(D_se).copy()
    qd = data.get("quadratic_damping") or {}
    quad = np.array([_num(x) for x in qd.get("values", [None] * 5)])
    quad_se = np.array([_num(x) for x in qd.get("stderr", [None] * 5)])
    if not qd:
        notes.append("coefficients.json has no quadratic_damping (structure selection not run): D2 = 0")
    quad = np.where(np.isfinite(quad), quad, 0.0)
    inertia = np.full(5, np.nan)
    added = np.zeros(5)
    restoring: dict[str, float] = {}
    structure = data.get("model_structure") or {}
    for i, vel in enumerate(DOFS):
        dof = DOF_NAMES[vel]
        ch = structure.get(dof)
        if ch:
            fit = ch["models"][ch["selected"]]
            if fit.get("inertia") is not None:
                inertia[i] = float(fit["inertia"])
            c = (fit.get("parameters") or {}).get("c", {}).get("value")
            if c is not None and math.isfinite(inertia[i]) and dof in ("roll", "pitch"):
                restoring[dof] = float(c) * inertia[i]
    max_rudder = math.nan
    if vessel is not None and vessel.has_rigid_body:
        m = vessel.mass_matrix()
        inertia = np.diag(m).copy()
        added = np.array([vessel.added_mass.get(k, 0.0) for k in ("surge", "sway", "roll", "pitch", "yaw")], float) \
            if isinstance(vessel.added_mass, Mapping) else np.zeros(5)
        notes.append(f"mass, inertia and added mass from vessel config {vessel.name!r}")
    elif np.isfinite(inertia).any():
        notes.append("M_ii from the structure fits in coefficients.json (rigid-body and added mass not separated)")
    if vessel is not None:
        for dof in ("roll", "pitch"):
            if vessel.restoring.get(dof):
                restoring[dof] = float(vessel.restoring[dof])
        max_rudder = float(vessel.rudder.get("max_angle", math.nan)) if vessel.rudder else math.nan
    nomoto = {}
    coefs = data.get("coefficients", {})
    for key, name in (("K", "K_nomoto"), ("T", "T_nomoto")):
        e = coefs.get(name)
        if e and e.get("success") and e.get("value") is not None:
            nomoto[key] = float(e["value"])
    return ExportModel(name=str(data.get("vessel", "vessel")), inertia=inertia, added_mass=added, damping=damping,
                       damping_stderr=damping_se, quadratic=quad, quadratic_stderr=quad_se, restoring=restoring,
                       nomoto=nomoto, max_rudder=max_rudder, notes=tuple(notes))
