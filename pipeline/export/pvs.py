"""A Python module whose vessel class runs in Fossen's PythonVehicleSimulator (PVS) main loop.

PVS's ``lib.mainLoop.simulate(N, sampleTime, vehicle)`` takes any object with the attributes
``nu`` (6), ``u_actual``, ``dimU``, ``controlMode``, ``name``, ``L``, ``controlDescription`` and the
methods ``dynamics(eta, nu, u_actual, u_control, sampleTime) -> (nu, u_actual)`` and
``stepInput(t)``. The generated module defines such a class for the identified model, in PVS's
6-DOF order (u, v, w, p, q, r) with the generalised forces as its controls, integrated by forward
Euler as PVS's own vessels are; it needs only numpy, so it loads with or without PVS installed.
"""

from __future__ import annotations

import json
import math

import numpy as np

from .model import ExportModel

_TEMPLATE = '''"""Vessel model identified by vesselid, as a PythonVehicleSimulator vehicle.

Use: ``from python_vehicle_simulator.lib.mainLoop import simulate``;
``simTime, simData = simulate(N, sampleTime, IdentifiedVessel(tau_step=[...], t_off=...))``.
Equations (Fossen 2021, DOF order u v w p q r, SI): M nu_dot + D nu + D2 |nu| nu + G eta = tau.
"""

import numpy as np

PARAMS = json.loads(r"""{params}""")


class IdentifiedVessel:
    """{name}: generalised forces as controls, held ``tau_step`` until ``t_off`` [s], then zero."""

    def __init__(self, tau_step=(0, 0, 0, 0, 0, 0), t_off=float("inf"), nu0=(0, 0, 0, 0, 0, 0)):
        self.name = PARAMS["name"] + " (identified by vesselid)"
        self.L = PARAMS["length"]
        self.controlMode = "stepInput"
        self.controlDescription = "Step in the generalised forces tau (N, N m)"
        self.controls = ["tau_X (N)", "tau_Y (N)", "tau_Z (N)", "tau_K (N m)", "tau_M (N m)", "tau_N (N m)"]
        self.dimU = 6
        self.nu = np.array(nu0, float)
        self.u_actual = np.zeros(6)
        self.tau_step = np.array(tau_step, float)
        self.t_off = float(t_off)
        self.M = np.array(PARAMS["M"], float)
        self.Minv = np.linalg.inv(self.M)
        self.D = np.array(PARAMS["D"], float)
        self.D2 = np.array(PARAMS["D2"], float)
        self.G = np.array(PARAMS["G"], float)

    def stepInput(self, t):
        return self.tau_step.copy() if t < self.t_off else np.zeros(6)

    def dynamics(self, eta, nu, u_actual, u_control, sampleTime):
        tau = np.asarray(u_control, float)
        nu_dot = self.Minv @ (tau - self.D @ nu - self.D2 * np.abs(nu) * nu - self.G @ np.asarray(eta, float))
        return nu + sampleTime * nu_dot, tau.copy()
'''


def pvs_parameters(model: ExportModel) -> dict:
    """PVS 6-DOF matrices (u v w p q r) of the identified model; heave is left undamped and unforced.

    Parameters
    ----------
    model : ExportModel
        Needs the inertia and damping of every DOF it exports (NaN DOFs get zero damping and unit
        inertia, listed in ``missing``).
    """
    idx = (0, 1, 3, 4, 5)  # u v p q r in the 6-DOF order
    M = np.eye(6)
    D = np.zeros((6, 6))
    D2 = np.zeros(6)
    G = np.zeros((6, 6))
    missing = []
    for i, j in enumerate(idx):
        if math.isfinite(model.inertia[i]) and math.isfinite(model.damping[i]):
            M[j, j] = model.inertia[i]
            D[j, j] = model.damping[i]
            D2[j] = model.quadratic[i]
        else:
            missing.append("uvpqr"[i])
    G[3, 3] = model.restoring.get("roll", 0.0)
    G[4, 4] = model.restoring.get("pitch", 0.0)
    return {"name": model.name, "length": 1.0, "M": M.tolist(), "D": D.tolist(), "D2": D2.tolist(), "G": G.tolist(),
            "missing": missing, "notes": list(model.notes)}


def pvs_module(model: ExportModel) -> str:
    """Text of the generated Python module.

    Parameters
    ----------
    model : ExportModel
        The identified model.
    """
    params = json.dumps(pvs_parameters(model), indent=1)
    body = _TEMPLATE.replace("{params}", params).replace("{name}", model.name)
    return body.replace("import numpy as np\n\nPARAMS", "import json\n\nimport numpy as np\n\nPARAMS", 1)
