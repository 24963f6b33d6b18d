"""Gazebo / VRX ``usv_gazebo_dynamics_plugin`` SDF block.

The plugin (osrf/vrx, ``usv_gazebo_plugins/src/usv_gazebo_dynamics_plugin.cc``) reads positive
damping magnitudes and forms ``D = diag(xU + xUU |u|, yV + yVV |v|, zW + zWW |w|, kP + kPP |p|,
mQ + mQQ |q|, nR + nRR |r|)`` with force ``-D nu``, and positive added masses ``xDotU ...`` with
force ``-M_A nu_dot``. Gazebo's body frame is x forward, y left, z up; diagonal damping and added
mass are unchanged by that change of frame (each term flips sign in both force and velocity).
The rigid-body mass and inertia belong to the SDF link's ``<inertial>`` block, not to the plugin.
"""

from __future__ import annotations

import math
from xml.sax.saxutils import escape

from .model import ExportModel

#: Parameters the plugin reads (its Load(); osrf/vrx commit a4b16805), in its order.
PLUGIN_PARAMETERS = ("bodyName", "waterLevel", "waterDensity", "xDotU", "yDotV", "zDotW", "kDotP", "mDotQ",
                     "nDotR", "xU", "xUU", "yV", "yVV", "zW", "zWW", "kP", "kPP", "mQ", "mQQ", "nR", "nRR",
                     "hullRadius", "boatWidth", "boatLength", "length_n", "wave_model")
PLUGIN_FILENAME = "libusv_gazebo_dynamics_plugin.so"
#: DOF index (u v p q r) -> (linear, quadratic, added-mass) element names.
_ELEMENTS = {0: ("xU", "xUU", "xDotU"), 1: ("yV", "yVV", "yDotV"), 2: ("kP", "kPP", "kDotP"),
             3: ("mQ", "mQQ", "mDotQ"), 4: ("nR", "nRR", "nDotR")}


def vrx_sdf(model: ExportModel, body_name: str = "base_link") -> str:
    """The ``<plugin>`` element for the identified model.

    DOFs that were not identified are left out (the plugin then uses its defaults, stated in a
    comment); heave (``zW``) is not identified by vesselid and is left to the plugin's default.

    Parameters
    ----------
    model : ExportModel
        The identified model.
    body_name : str
        The link the plugin acts on.

    Returns
    -------
    str
        XML text of one ``<plugin>`` element.
    """
    lines = [f'<plugin name="{escape(model.name)}_dynamics_plugin" filename="{PLUGIN_FILENAME}">',
             f"  <!-- identified by vesselid from sea-trial logs; SI units; {escape('; '.join(model.notes))} -->",
             f"  <bodyName>{escape(body_name)}</bodyName>"]
    missing = []
    for i, (lin, quad, dot) in _ELEMENTS.items():
        if math.isfinite(model.damping[i]):
            lines.append(f"  <{lin}>{model.damping[i]:.6g}</{lin}>")
            lines.append(f"  <{quad}>{model.quadratic[i]:.6g}</{quad}>")
        else:
            missing += [lin, quad]
        lines.append(f"  <{dot}>{model.added_mass[i]:.6g}</{dot}>")
    if missing:
        lines.insert(2, f"  <!-- not identified, plugin defaults apply: {', '.join(missing)} -->")
    lines.append("</plugin>")
    return "\n".join(lines) + "\n"
