"""ROS 2 parameter file (YAML): ``<node>: {ros__parameters: {...}}``.

ROS 2 parameter values are booleans, integers, doubles, strings or homogeneous arrays of one of
them; nested mappings become dotted names. Coefficients that were not identified are left out
(YAML ``null`` is not a ROS 2 parameter value) and listed in ``not_identified``.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import yaml

from ..records import DOF_NAMES, DOFS
from .model import ExportModel

_LIN = ("X_u", "Y_v", "K_p", "M_q", "N_r")
_QUAD = ("X_uu", "Y_vv", "K_pp", "M_qq", "N_rr")  # ROS parameter names allow no '|'


def ros2_parameters(model: ExportModel, coefficients: Mapping[str, Any], node: str = "vessel_model") -> dict:
    """The parameter file as a mapping (dump with :func:`ros2_yaml`).

    Parameters
    ----------
    model : ExportModel
        The identified model.
    coefficients : Mapping
        The loaded ``coefficients.json`` (every identified coefficient is added with its stderr).
    node : str
        Node name at the top of the file.
    """
    p: dict[str, Any] = {"vessel": model.name,
                         "convention": "M nu_dot + D nu + D2 |nu| nu = tau; Fossen derivatives X_u = -D[0,0]; SI"}
    missing = []
    damping, quadratic = {}, {}
    for i, vel in enumerate(DOFS):
        if math.isfinite(model.damping[i]):
            damping[_LIN[i]] = -float(model.damping[i])
            quadratic[_QUAD[i]] = -float(model.quadratic[i])
        else:
            missing.append(_LIN[i])
        if math.isfinite(model.inertia[i]):
            p.setdefault("inertia", {})[DOF_NAMES[vel]] = float(model.inertia[i])
    p["damping"] = {"linear": damping, "quadratic": quadratic}
    coef = {}
    for name, e in coefficients.get("coefficients", {}).items():
        if e.get("success") and e.get("value") is not None:
            key = name.replace("|", "")
            coef[key] = {"value": float(e["value"]), "unit": str(e.get("unit", ""))}
            # A standard error that was not computed is left out: ROS 2's YAML parameter parser
            # (rcl_yaml_param_parser) reads doubles with strtod, and .nan is not a value it is sure to take.
            if e.get("stderr") is not None and math.isfinite(float(e["stderr"])):
                coef[key]["stderr"] = float(e["stderr"])
        else:
            missing.append(name)
    p["coefficients"] = coef
    if model.nomoto:
        p["nomoto"] = {k: float(v) for k, v in model.nomoto.items()}
    p["not_identified"] = sorted(set(missing)) or [""]
    return {node: {"ros__parameters": p}}


def ros2_yaml(model: ExportModel, coefficients: Mapping[str, Any], node: str = "vessel_model") -> str:
    """YAML text of :func:`ros2_parameters`.

    Parameters
    ----------
    model : ExportModel
        The identified model.
    coefficients : Mapping
        The loaded ``coefficients.json``.
    node : str
        Node name.
    """
    header = "# ROS 2 parameters of the model identified by vesselid (SI units, Fossen signs)\n"
    return header + yaml.safe_dump(ros2_parameters(model, coefficients, node), sort_keys=False)
