"""Dynamic models with one right-hand-side signature ``f(t, x, u, params) -> x_dot``.

The same functions serve simulation (``pipeline.sim``), fitting (``pipeline.fit``), the Kalman
process model (``pipeline.autopilot``) and the diagnosis (``pipeline.diagnose``), so the model a user
fits is the model that is simulated. Each right-hand side accepts numpy arrays or casadi symbols.
"""

from .integrate import integrate_rk4
from .nomoto import NOMOTO_INPUTS, NOMOTO_STATES, NomotoParams, nomoto_rhs
from .vessel5dof import INPUTS_5DOF, STATES_5DOF, Vessel5DofParams, params_from_vessel, vessel5dof_rhs

__all__ = [
    "integrate_rk4",
    "NomotoParams", "nomoto_rhs", "NOMOTO_STATES", "NOMOTO_INPUTS",
    "Vessel5DofParams", "vessel5dof_rhs", "params_from_vessel", "STATES_5DOF", "INPUTS_5DOF",
]
