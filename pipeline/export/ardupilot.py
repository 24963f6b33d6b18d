"""ArduPilot Rover / boat parameters from the identified model, within their documented ranges.

Steering (first-order Nomoto, ``r/delta = K/(T s + 1)``, steering output +-1 = +-``max_rudder``):
``ATC_STR_RAT_MAX = K max_rudder`` [deg/s] (the fastest turn the rudder can hold),
``ATC_STR_ACC_MAX = ATC_STR_RAT_MAX / T`` [deg/s/s] (the initial turn acceleration at full rudder)
and ``ATC_STR_RAT_FF = 1 / (K max_rudder)`` [output per rad/s] (the steady-state output for a turn
rate). Ranges from the ArduPilot Rover parameter list (ardupilot.org/rover/docs/parameters.html);
a value outside its range is clamped and the file says so.
"""

from __future__ import annotations

import math

from .errors import ExportError
from .model import ExportModel

#: Documented ranges (ArduPilot Rover parameter list).
RANGES = {"ATC_STR_RAT_FF": (0.0, 3.0), "ATC_STR_RAT_MAX": (0.0, 1000.0), "ATC_STR_ACC_MAX": (0.0, 1000.0)}


def ardupilot_params(model: ExportModel) -> tuple[dict[str, float], list[str]]:
    """Parameter values and notes (clamping, what could not be derived).

    Parameters
    ----------
    model : ExportModel
        Needs Nomoto K and T and the rudder limit (vessel config ``[rudder] max_angle``).

    Returns
    -------
    tuple
        ``{name: value}`` within ``RANGES``, and notes.

    Raises
    ------
    ExportError
        K, T or the rudder limit missing.
    """
    k, t = model.nomoto.get("K", math.nan), model.nomoto.get("T", math.nan)
    if not (math.isfinite(k) and math.isfinite(t) and k > 0 and t > 0):
        raise ExportError(f"ardupilot: expected identified Nomoto K > 0 and T > 0 in the coefficients, found "
                          f"K = {k}, T = {t}")
    if not (math.isfinite(model.max_rudder) and model.max_rudder > 0):
        raise ExportError("ardupilot: expected the rudder limit ([rudder] max_angle in --vessel V.toml), found none")
    rate_max = math.degrees(k * model.max_rudder)
    raw = {"ATC_STR_RAT_MAX": rate_max, "ATC_STR_ACC_MAX": rate_max / t, "ATC_STR_RAT_FF": 1.0 / (k * model.max_rudder)}
    out, notes = {}, []
    for name, v in raw.items():
        lo, hi = RANGES[name]
        c = min(max(v, lo), hi)
        if c != v:
            notes.append(f"{name} = {v:.6g} is outside its documented range [{lo:g}, {hi:g}]: clamped to {c:g}")
        out[name] = c
    notes.append("speed controller (CRUISE_SPEED, CRUISE_THROTTLE, ATC_ACCEL_MAX) not written: they need the "
                 "thrust at a throttle setting, which the coefficients do not hold")
    return out, notes


def ardupilot_text(model: ExportModel) -> str:
    """A Mission Planner / MAVProxy ``.param`` file (``NAME,VALUE`` lines, ``#`` comments).

    Parameters
    ----------
    model : ExportModel
        The identified model.
    """
    params, notes = ardupilot_params(model)
    lines = [f"# ArduPilot Rover steering parameters for {model.name} from vesselid (Nomoto K = "
             f"{model.nomoto['K']:.6g} 1/s, T = {model.nomoto['T']:.6g} s, max rudder = "
             f"{math.degrees(model.max_rudder):.4g} deg)"]
    lines += [f"# {n}" for n in notes]
    lines += [f"{name},{value:.6g}" for name, value in params.items()]
    return "\n".join(lines) + "\n"
