"""Actuator space: each actuator's own signal, recovered from the logged generalised forces through
the vessel config's allocation, so that delay, rate-limit and asymmetry candidates act on one
actuator rather than on a generalised force.

The ``[[actuators]]`` maps of one source and channel are one actuator driving one or more inputs
(:func:`pipeline.vessel.actuator_allocation`): a twin-thruster boat's port thruster drives ``tau_x``
and ``tau_n``, ``tau = B a``. A late or slow port thruster then reaches surge and yaw together,
through its own column of ``B``, which no delay or rate limit of ``tau_x`` or ``tau_n`` alone
reproduces. The log holds the generalised forces (the readers add the maps of every actuator up), so
the actuators' signals ``a`` are recovered by solving ``tau = B(a)`` sample by sample (``B`` of full
column rank over the logged inputs; the ahead or astern gain per sign of ``a``). A candidate that
changes actuator ``i``'s signal to ``a_i'`` changes every input ``c`` it drives by
``B_ci(a_i') - B_ci(a_i)`` and leaves the others' share alone.

Used only when some actuator drives two or more logged inputs: where each actuator drives one input,
the per-input candidates already act on the actuators, under the input's name as before.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from ..records import Trial
from ..vessel import Actuator, Vessel, actuator_allocation

#: Prefix of an actuator's signal in a :class:`pipeline.diagnose.problem.DofProblem`'s ``raw``.
ACTUATOR_PREFIX = "actuator:"
#: Inputs an actuator drives through the allocation (a rudder's ``delta`` is its own signal, logged).
FORCES = ("tau_x", "tau_y", "tau_n", "tau_k", "tau_m")
#: Largest RMS misfit of the logged forces by the allocation's reconstruction, relative to each
#: force's RMS, for the forces to count as made by the allocation.
CONSISTENT = 1e-3


def actuator_key(name: str) -> str:
    """Key of actuator ``name``'s signal in a DOF problem's ``raw`` signals.

    Parameters
    ----------
    name : str
        Actuator name.
    """
    return ACTUATOR_PREFIX + name


@dataclass(frozen=True)
class ActuatorSpace:
    """The actuators analysed and their signals on the trial grid.

    Attributes
    ----------
    actuators : tuple[Actuator, ...]
        Actuators with their gains on the logged force inputs.
    signals : Mapping[str, numpy.ndarray]
        Actuator name -> normalised signal on the trial grid [-].
    note : str
        What was done (or why actuator space is not used), for the report's notes.
    """

    actuators: tuple[Actuator, ...] = ()
    signals: Mapping[str, np.ndarray] = field(default_factory=dict, repr=False)
    note: str = ""

    @property
    def used(self) -> bool:
        """True when the candidates act on the actuators."""
        return bool(self.actuators)


def held_input(u: np.ndarray) -> np.ndarray:
    """Inputs held between logged samples (zero-order hold), zero before the first one; as every
    DOF problem holds its inputs (:mod:`pipeline.diagnose.problem`).

    Parameters
    ----------
    u : numpy.ndarray
        A logged input on the trial grid, NaN between its samples [SI].
    """
    u = np.asarray(u, float).copy()
    ok = np.isfinite(u)
    if not ok.any():
        return np.zeros_like(u)
    idx = np.where(ok, np.arange(len(u)), 0)
    np.maximum.accumulate(idx, out=idx)
    filled = u[idx]
    filled[: int(np.argmax(ok))] = 0.0
    return filled


def solve_allocation(acts: tuple[Actuator, ...], targets: tuple[str, ...], tau: np.ndarray,
                     rounds: int = 4) -> np.ndarray:
    """Actuator signals ``a`` with ``tau = B(a)``, sample by sample (least squares).

    The gain of an actuator on an input is its ahead gain where its signal is positive, its astern
    gain where negative: solved with the ahead gains, then again per pattern of signs until the
    signs settle.

    Parameters
    ----------
    acts : tuple[Actuator, ...]
        The actuators.
    targets : tuple[str, ...]
        Input channels, the columns of ``tau``.
    tau : numpy.ndarray, shape (N, len(targets))
        Logged inputs [SI].
    rounds : int
        Most sign-pattern rounds.

    Returns
    -------
    numpy.ndarray, shape (N, len(acts))
    """
    def matrix(signs: np.ndarray) -> np.ndarray:
        return np.array([[a.gains.get(c, (0.0, 0.0))[0 if s >= 0 else 1] for a, s in zip(acts, signs)]
                         for c in targets])

    ahead = matrix(np.ones(len(acts)))
    x = np.linalg.lstsq(ahead, tau.T, rcond=None)[0].T
    for _ in range(rounds):
        pattern = x < 0
        if not pattern.any():
            break
        new = x.copy()
        for row in np.unique(pattern, axis=0):
            if not row.any():
                continue
            rows = np.all(pattern == row, axis=1)
            new[rows] = np.linalg.lstsq(matrix(np.where(row, -1.0, 1.0)), tau[rows].T, rcond=None)[0].T
        if np.array_equal(new < 0, pattern):
            x = new
            break
        x = new
    return x


def actuator_space(trial: Trial, vessel: Vessel | None) -> ActuatorSpace:
    """The actuators whose signals the diagnosis can recover from the trial's logged forces.

    Parameters
    ----------
    trial : Trial
        The aligned trial.
    vessel : Vessel or None
        Its config; its ``[[actuators]]`` maps are the allocation.

    Returns
    -------
    ActuatorSpace
        Empty (``used`` False) when no actuator drives two logged force inputs, or the allocation
        cannot be inverted or does not reproduce the logged forces (the note says which).
    """
    if vessel is None or not vessel.actuators:
        return ActuatorSpace()
    acts = []
    for a in actuator_allocation(vessel.actuators, f"{vessel.path or vessel.name} [[actuators]]"):
        gains = {c: g for c, g in a.gains.items() if c in FORCES}
        if gains:
            acts.append(Actuator(a.name, gains))
    if not any(len(a.gains) >= 2 for a in acts):
        return ActuatorSpace()
    names = ", ".join(a.name for a in acts)
    targets = tuple(dict.fromkeys(c for a in acts for c in a.gains))
    missing = [c for c in targets if not trial.has(c) or not np.isfinite(trial.data[c].to_numpy(float)).any()]
    if missing:
        return ActuatorSpace(note=f"actuator space not used: the [[actuators]] allocation of {names} drives "
                                  f"{', '.join(targets)}, and the trial does not log {', '.join(missing)}; delay, "
                                  f"rate limit and asymmetry act on the generalised forces")
    tau = np.column_stack([held_input(trial.data[c].to_numpy(float)) for c in targets])
    ahead = np.array([[a.gains.get(c, (0.0, 0.0))[0] for a in acts] for c in targets])
    if np.linalg.matrix_rank(ahead) < len(acts):
        return ActuatorSpace(note=f"actuator space not used: {len(acts)} actuators ({names}) on {len(targets)} "
                                  f"logged inputs ({', '.join(targets)}) cannot be told apart from the logged sums; "
                                  f"delay, rate limit and asymmetry act on the generalised forces")
    x = solve_allocation(tuple(acts), targets, tau)
    rebuilt = np.column_stack([sum(a.contribution(c, x[:, j]) for j, a in enumerate(acts)) for c in targets])
    scale = np.sqrt(np.mean(tau**2, axis=0))
    misfit = np.sqrt(np.mean((rebuilt - tau) ** 2, axis=0))
    bad = [c for c, m, s in zip(targets, misfit, scale) if m > CONSISTENT * max(s, 1e-12)]
    if bad:
        return ActuatorSpace(note=f"actuator space not used: the logged {', '.join(bad)} are not what the "
                                  f"[[actuators]] allocation of {names} makes of any actuator signals (RMS misfit "
                                  + ", ".join(f"{m / max(s, 1e-12):.2g}" for c, m, s in zip(targets, misfit, scale)
                                              if c in bad)
                                  + " of the force); delay, rate limit and asymmetry act on the generalised forces")
    return ActuatorSpace(
        actuators=tuple(acts), signals={a.name: x[:, j] for j, a in enumerate(acts)},
        note=(f"actuator space: the signals of {names} recovered from {', '.join(targets)} through the "
              f"[[actuators]] allocation; delay, rate-limit and asymmetry candidates act on each actuator "
              f"(labelled effect[actuator]) instead of on these inputs"))


def with_actuator(raw: Mapping[str, np.ndarray], act: Actuator, new: np.ndarray) -> dict[str, np.ndarray]:
    """``raw`` with actuator ``act``'s signal replaced by ``new``: every input it drives changes by
    its contribution's change; its own signal entry becomes ``new``.

    Parameters
    ----------
    raw : Mapping[str, numpy.ndarray]
        Trial-rate inputs and actuator signals (keys :func:`actuator_key`).
    act : Actuator
        The actuator.
    new : numpy.ndarray
        Its new signal [-].
    """
    key = actuator_key(act.name)
    old = raw[key]
    out = dict(raw)
    for c in act.gains:
        if c in out:
            out[c] = out[c] - act.contribution(c, old) + act.contribution(c, new)
    out[key] = new
    return out
