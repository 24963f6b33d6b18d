"""Dynamic models with one right-hand-side signature ``f(t, x, u, params) -> x_dot``.

The same functions serve simulation (``pipeline.sim``), fitting (``pipeline.fit``), the Kalman
process model (``pipeline.autopilot``) and the diagnosis (``pipeline.diagnose``), so the model a user
fits is the model that is simulated. Each right-hand side accepts numpy arrays or casadi symbols.
"""

from .integrate import integrate_rk4, rk4_chunk_integrator
from .discretise import expm_small, noise_integral, van_loan, zoh
from .nomoto import (HEADING_MODEL_STATES, NOMOTO2_STATES, NOMOTO_INPUTS, NOMOTO_STATES, Nomoto2Params, NomotoParams,
                     heading_model_matrices, nomoto2_rhs, nomoto_matrices, nomoto_rhs, nomoto_ship_rhs,
                     servo_response)
from .vessel5dof import INPUTS_5DOF, STATES_5DOF, Vessel5DofParams, params_from_vessel, vessel5dof_rhs

__all__ = [
    "integrate_rk4", "rk4_chunk_integrator",
    "NomotoParams", "nomoto_rhs", "nomoto_ship_rhs", "NOMOTO_STATES", "NOMOTO_INPUTS",
    "Nomoto2Params", "nomoto2_rhs", "NOMOTO2_STATES", "nomoto_matrices", "heading_model_matrices",
    "HEADING_MODEL_STATES", "servo_response",
    "zoh", "van_loan", "noise_integral", "expm_small",
    "Vessel5DofParams", "vessel5dof_rhs", "params_from_vessel", "STATES_5DOF", "INPUTS_5DOF",
]
