"""Effects the simulator can switch on, each a small documented function or field.

Effects on the *input* (what the actuator really delivers, against what was commanded and logged):
:func:`apply_delay`, :func:`apply_rate_limit`, :func:`apply_thrust_asymmetry`.
Effects in the *dynamics*: |x|x damping and a constant water current (fields of the model
parameters, see :func:`pipeline.model.vessel5dof_rhs`), and a rudder bias for a Nomoto ship.
Effects on the *measurement*: waves (second-order wave model added to the compass heading,
:mod:`pipeline.model.waves`) and sensor noise/bias (:mod:`pipeline.sim.sensors`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from ..errors import SimError
from ..model.waves import WaveParams
from ..records import INPUT_UNITS

#: Effect names, as the diagnosis uses them.
EFFECT_NAMES = ("nonlinear_damping", "current", "actuator_delay", "actuator_rate_limit",
                "thrust_asymmetry", "waves", "coupling")


@dataclass(frozen=True)
class Effects:
    """Which unmodelled effects a simulation includes (all off by default).

    Attributes
    ----------
    quadratic_damping : numpy.ndarray or None
        |x|x damping per DOF u, v, p, q, r [SI]; for a Nomoto ship only element 4 (yaw) is used,
        as ``d2`` [s/rad] of :class:`pipeline.model.NomotoParams`.
    current : tuple[float, float]
        Constant water current over ground, north and east [m/s].
    rudder_bias : float
        Constant rudder bias b [rad] of a Nomoto ship (a current's or wind's yaw moment).
    actuator_delay : float
        Pure delay between command and actuator [s].
    actuator_rate_limit : Mapping[str, float]
        Maximum rate per input channel [SI unit/s], e.g. ``{"delta": 0.1}``.
    thrust_reverse_gain : float
        Ratio of reverse to forward thrust for the same command magnitude (1 = symmetric).
    waves : WaveParams or None
        Wave model whose psi_w adds to the measured heading.
    coupling : numpy.ndarray or None
        Extra off-diagonal damping added to D (5x5) [SI]: the "missing coupling" effect.
    """

    quadratic_damping: np.ndarray | None = None
    current: tuple[float, float] = (0.0, 0.0)
    rudder_bias: float = 0.0
    actuator_delay: float = 0.0
    actuator_rate_limit: Mapping[str, float] = field(default_factory=dict)
    thrust_reverse_gain: float = 1.0
    waves: WaveParams | None = None
    coupling: np.ndarray | None = None

    def active(self) -> tuple[str, ...]:
        """Names (``EFFECT_NAMES``) of the effects switched on."""
        on = []
        if self.quadratic_damping is not None and np.any(np.asarray(self.quadratic_damping) != 0):
            on.append("nonlinear_damping")
        if any(c != 0 for c in self.current) or self.rudder_bias != 0:
            on.append("current")
        if self.actuator_delay > 0:
            on.append("actuator_delay")
        if self.actuator_rate_limit:
            on.append("actuator_rate_limit")
        if self.thrust_reverse_gain != 1.0:
            on.append("thrust_asymmetry")
        if self.waves is not None:
            on.append("waves")
        if self.coupling is not None and np.any(np.asarray(self.coupling) != 0):
            on.append("coupling")
        return tuple(on)


def apply_delay(u_history: np.ndarray, k: int, delay_steps: int) -> np.ndarray:
    """Input the actuator applies at step ``k``: the command ``delay_steps`` steps earlier.

    Before the first command the actuator holds the first command (the vessel starts at rest).

    Parameters
    ----------
    u_history : numpy.ndarray, shape (N, m)
        Commands so far (rows up to ``k`` are filled).
    k : int or numpy.ndarray of int
        Current step, or several steps (one applied row each).
    delay_steps : int
        Delay in integration steps (delay [s] / dt [s], rounded).
    """
    return u_history[np.maximum(np.asarray(k) - delay_steps, 0)]


def apply_rate_limit(previous: np.ndarray, target: np.ndarray, max_step: np.ndarray) -> np.ndarray:
    """Move from ``previous`` toward ``target`` by at most ``max_step`` per channel [SI].

    ``max_step`` is rate [SI/s] times dt [s]; ``inf`` leaves a channel unlimited.

    Parameters
    ----------
    previous : numpy.ndarray
        Actuator positions at the previous step, one per input channel [SI].
    target : numpy.ndarray
        Commanded positions at this step [SI].
    max_step : numpy.ndarray
        Largest change per step and channel [SI]; ``inf`` for unlimited channels.
    """
    return previous + np.clip(target - previous, -max_step, max_step)


def apply_thrust_asymmetry(u: np.ndarray, index: int, reverse_gain: float) -> np.ndarray:
    """Scale a negative (reverse) thrust command by ``reverse_gain`` (propellers push less astern).

    Parameters
    ----------
    u : numpy.ndarray
        Input vector [SI]; returned unchanged (not copied) when nothing is scaled.
    index : int
        Position of the thrust channel (``tau_x``) in ``u``.
    reverse_gain : float
        Ratio of reverse to forward thrust [-]; 1 leaves ``u`` as it is.
    """
    if reverse_gain == 1.0 or u[index] >= 0:
        return u
    out = np.array(u, float)
    out[index] *= reverse_gain
    return out


def check_effects(effects: Effects) -> None:
    """Reject physically meaningless effect settings with a message naming the value found.

    Parameters
    ----------
    effects : Effects
        The settings to check.

    Raises
    ------
    SimError
        A setting outside its physical range or of the wrong shape.
    """
    if effects.actuator_delay < 0:
        raise SimError(f"actuator_delay: expected >= 0 s, found {effects.actuator_delay}")
    if effects.thrust_reverse_gain <= 0:
        raise SimError(f"thrust_reverse_gain: expected > 0, found {effects.thrust_reverse_gain}")
    for ch, rate in effects.actuator_rate_limit.items():
        if ch not in INPUT_UNITS:
            # A misspelt channel would otherwise switch the limit off without a word.
            raise SimError(f"actuator_rate_limit: expected input channels {sorted(INPUT_UNITS)}, found {ch!r}")
        if not rate > 0:
            raise SimError(f"actuator_rate_limit[{ch!r}]: expected a positive rate, found {rate}")
    if effects.quadratic_damping is not None and np.shape(effects.quadratic_damping) != (5,):
        raise SimError(f"quadratic_damping: expected 5 values (u v p q r), found shape "
                       f"{np.shape(effects.quadratic_damping)}")
    if effects.coupling is not None and np.shape(effects.coupling) != (5, 5):
        raise SimError(f"coupling: expected a 5x5 matrix, found shape {np.shape(effects.coupling)}")
