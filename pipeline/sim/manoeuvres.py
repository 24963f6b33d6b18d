"""Sea-trial manoeuvres: input programmes and the segments they produce (the ground truth).

A :class:`Manoeuvre` commands inputs as a function of local time and (for zig-zags) the measured
state, may set an initial condition (a roll or pitch free decay starts from a pushed-down hull),
and lists the segments a perfect detector should find. :func:`sea_trial` chains manoeuvres with
rests in between into one trial, as a test day at sea would.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from ..errors import SimError
from ..records import DOF_CHANNELS

#: command(t_local [s], state dict) -> {input channel: value [SI]}
Command = Callable[[float, Mapping[str, float]], Mapping[str, float]]


@dataclass(frozen=True)
class TruthSegment:
    """A segment the manoeuvre produces, in manoeuvre-local time [s]."""

    kind: str
    dof: str
    t_start: float
    t_end: float
    input_channel: str | None = None
    input_before: float = 0.0
    input_after: float = 0.0


@dataclass(frozen=True)
class Manoeuvre:
    """One manoeuvre.

    Attributes
    ----------
    name : str
        Descriptive name.
    duration : float
        Length [s].
    inputs : tuple[str, ...]
        Input channels it commands.
    command : Command
        Input programme.
    initial : Mapping[str, float]
        State values forced at the manoeuvre start (``phi``, ``theta``, ``p``, ...) [SI].
    segments : tuple[TruthSegment, ...]
        What it should segment into.
    uses_state : bool
        Whether ``command`` reads the state (a zig-zag does). The simulator then evaluates it with the
        state of each autopilot tick; an open-loop programme (False) is evaluated a stretch ahead
        and integrated in one go. True unless a manoeuvre says otherwise.
    """

    name: str
    duration: float
    inputs: tuple[str, ...]
    command: Command
    initial: Mapping[str, float] = field(default_factory=dict)
    segments: tuple[TruthSegment, ...] = ()
    uses_state: bool = True


def _force_channel(dof: str) -> str:
    if dof not in DOF_CHANNELS:
        raise SimError(f"manoeuvre DOF: expected one of {sorted(DOF_CHANNELS)}, found {dof!r}")
    return DOF_CHANNELS[dof][1]


def step_and_coast(dof: str, force: float, t_on: float, t_off: float, channel: str | None = None) -> Manoeuvre:
    """Step from rest to ``force`` held ``t_on`` s (reach steady state), then cut it for ``t_off`` s.

    Gives a ``step`` segment and a ``coast_down`` segment (AAUSHIP seed, "method one").

    Parameters
    ----------
    dof : str
        surge, sway or yaw.
    force : float
        Generalised force during the step [N or N m] (or rudder [rad] when ``channel='delta'``).
    t_on, t_off : float
        Step and coast durations [s]; use at least 5 time constants each.
    channel : str, optional
        Input channel; default the DOF's generalised force.
    """
    ch = channel or _force_channel(dof)
    if t_on <= 0 or t_off <= 0:
        raise SimError(f"step_and_coast: expected positive durations, found t_on={t_on}, t_off={t_off}")

    def command(t: float, _x: Mapping[str, float]) -> Mapping[str, float]:
        return {ch: force if t < t_on else 0.0}

    return Manoeuvre(f"{dof} step {force:g} and coast-down", t_on + t_off, (ch,), command,
                     segments=(TruthSegment("step", dof, 0.0, t_on, ch, 0.0, force),
                               TruthSegment("coast_down", dof, t_on, t_on + t_off, ch, force, 0.0)),
                     uses_state=False)


def free_decay(dof: str, angle0: float, duration: float) -> Manoeuvre:
    """Release the hull from ``angle0`` [rad] in roll or pitch and let it oscillate out.

    Parameters
    ----------
    dof : str
        ``roll`` or ``pitch``.
    angle0 : float
        Initial roll or pitch angle [rad], released with zero angular rate.
    duration : float
        Length [s]; no input is commanded.

    Raises
    ------
    SimError
        ``dof`` is neither roll nor pitch.
    """
    angle = {"roll": "phi", "pitch": "theta"}.get(dof)
    if angle is None:
        raise SimError(f"free_decay: expected dof roll or pitch, found {dof!r}")
    vel = DOF_CHANNELS[dof][0]
    return Manoeuvre(f"{dof} free decay from {np.degrees(angle0):.1f} deg", duration, (),
                     lambda t, x: {}, initial={angle: angle0, vel: 0.0},
                     segments=(TruthSegment("free_decay", dof, 0.0, duration),), uses_state=False)


def rudder_step(delta: float, t_on: float, t_off: float, thrust: Mapping[str, float] | None = None) -> Manoeuvre:
    """Rudder step ``delta`` [rad] held ``t_on`` s, then amidships for ``t_off`` s (Nomoto test).

    Parameters
    ----------
    delta : float
        Rudder angle [rad]; positive gives positive yaw rate.
    t_on, t_off : float
        Durations [s].
    thrust : Mapping[str, float], optional
        Inputs held constant throughout (for example ``{"tau_x": 4.0}`` to keep way on).
    """
    held = dict(thrust or {})

    def command(t: float, _x: Mapping[str, float]) -> Mapping[str, float]:
        return {**held, "delta": delta if t < t_on else 0.0}

    return Manoeuvre(f"rudder step {np.degrees(delta):.0f} deg", t_on + t_off, ("delta", *held), command,
                     segments=(TruthSegment("rudder_step", "yaw", 0.0, t_on, "delta", 0.0, delta),
                               TruthSegment("rudder_step", "yaw", t_on, t_on + t_off, "delta", delta, 0.0)),
                     uses_state=False)


def zigzag(delta: float, psi_switch: float, duration: float,
           thrust: Mapping[str, float] | None = None) -> Manoeuvre:
    """Zig-zag (Kempf): rudder to +delta, reverse each time heading passes +-psi_switch from the start.

    A 10/10 zig-zag is ``zigzag(radians(10), radians(10), ...)``. Heading feedback uses the true
    heading, as a helmsman watching the compass would.

    Parameters
    ----------
    delta, psi_switch : float
        Rudder amplitude and heading-change trigger [rad].
    duration : float
        Length [s].
    thrust : Mapping[str, float], optional
        Inputs held constant throughout.
    """
    held = dict(thrust or {})
    memo: dict[str, float] = {}

    def command(t: float, x: Mapping[str, float]) -> Mapping[str, float]:
        if t == 0.0 or "psi0" not in memo:
            memo.clear()
            memo.update(psi0=x["psi"], sign=1.0)
        dpsi = x["psi"] - memo["psi0"]
        if memo["sign"] > 0 and dpsi >= psi_switch:
            memo["sign"] = -1.0
        elif memo["sign"] < 0 and dpsi <= -psi_switch:
            memo["sign"] = 1.0
        return {**held, "delta": memo["sign"] * delta}

    return Manoeuvre(f"zig-zag {np.degrees(delta):.0f}/{np.degrees(psi_switch):.0f}", duration,
                     ("delta", *held), command,
                     segments=(TruthSegment("zigzag", "yaw", 0.0, duration, "delta", 0.0, delta),))


def sinusoid(amplitude: float, omega: float, periods: float, channel: str = "delta", dof: str = "yaw") -> Manoeuvre:
    """Sinusoidal input ``amplitude sin(omega t)`` for a number of periods (the seeds' test).

    The ship-autopilot seed uses omega = 0.005 and 0.05 rad/s on the rudder.

    Parameters
    ----------
    amplitude : float
        Input amplitude [SI unit of ``channel``: rad for ``delta``, N for ``tau_x``, ...].
    omega : float
        Input frequency [rad/s], positive.
    periods : float
        Number of periods, positive; the length is ``periods * 2 pi / omega`` [s].
    channel : str
        Input channel commanded.
    dof : str
        DOF of the truth segment it produces.

    Raises
    ------
    SimError
        ``omega`` or ``periods`` not positive.
    """
    if omega <= 0 or periods <= 0:
        raise SimError(f"sinusoid: expected positive omega and periods, found {omega}, {periods}")
    duration = periods * 2 * np.pi / omega
    return Manoeuvre(f"sinusoid {amplitude:g} at {omega:g} rad/s", duration, (channel,),
                     lambda t, x: {channel: amplitude * np.sin(omega * t)},
                     segments=(TruthSegment("sinusoid", dof, 0.0, duration, channel, 0.0, amplitude),),
                     uses_state=False)


def rest(duration: float) -> Manoeuvre:
    """All inputs zero for ``duration`` [s] (lets motions die out between manoeuvres).

    Parameters
    ----------
    duration : float
        Length [s].
    """
    return Manoeuvre("rest", duration, (), lambda t, x: {}, uses_state=False)


@dataclass(frozen=True)
class Schedule:
    """Manoeuvres in order; ``starts`` are their start times in the trial [s]."""

    manoeuvres: tuple[Manoeuvre, ...]

    @property
    def starts(self) -> np.ndarray:
        """Start time of each manoeuvre [s]."""
        return np.concatenate([[0.0], np.cumsum([m.duration for m in self.manoeuvres])[:-1]])

    @property
    def duration(self) -> float:
        """Total length [s]."""
        return float(sum(m.duration for m in self.manoeuvres))

    @property
    def inputs(self) -> tuple[str, ...]:
        """Every input channel any manoeuvre commands, in first-use order."""
        seen: list[str] = []
        for m in self.manoeuvres:
            seen += [c for c in m.inputs if c not in seen]
        return tuple(seen)


def chain(*manoeuvres: Manoeuvre, rest_s: float = 5.0) -> Schedule:
    """Chain manoeuvres with ``rest_s`` seconds of rest before each and after the last.

    Parameters
    ----------
    *manoeuvres : Manoeuvre
        The manoeuvres, in trial order.
    rest_s : float
        Length of each rest [s].
    """
    items: list[Manoeuvre] = []
    for m in manoeuvres:
        items += [rest(rest_s), m]
    items.append(rest(rest_s))
    return Schedule(tuple(items))


def sea_trial(vessel, zigzag_deg: float = 10.0) -> Schedule:
    """The standard identification day for a vessel, sized from its own time constants.

    For a vessel with rigid-body data and damping: surge, sway and yaw step + coast-down, roll and
    pitch free decays (twice each), rudder steps of +-10 deg when the config maps a rudder, and a
    zig-zag. For a Nomoto-only ship: rudder steps and a zig-zag.

    Parameters
    ----------
    vessel : pipeline.vessel.Vessel
        The vessel (its [damping], [restoring], [nomoto] and [rudder] sections size the tests).
    zigzag_deg : float
        Zig-zag rudder angle and heading trigger [deg].
    """
    items: list[Manoeuvre] = []
    z = np.radians(zigzag_deg)
    has_rudder = bool(vessel.rudder.get("yaw_moment")) or not vessel.has_rigid_body
    if vessel.has_rigid_body and vessel.damping is not None:
        d = np.diag(vessel.damping)
        m = np.diag(vessel.mass_matrix())
        tc = m / d  # time constants of the diagonal DOFs [s]
        speeds = {"surge": 1.5, "sway": 0.3, "yaw": 0.5}  # m/s, m/s, rad/s at steady state
        for dof, i in (("surge", 0), ("sway", 1), ("yaw", 4)):
            hold = max(6 * tc[i], 3.0)
            items.append(step_and_coast(dof, float(d[i] * speeds[dof]), hold, hold))
        for dof, i, angle in (("roll", 2, np.radians(20)), ("pitch", 3, np.radians(6))):
            g = vessel.restoring.get(dof, 0.0)
            if g > 0:
                wn = np.sqrt(g / m[i])
                zeta = d[i] / (2 * np.sqrt(g * m[i]))
                length = min(max(4.0 / max(zeta * wn, 1e-3), 2.0), 60.0)
                items += [free_decay(dof, angle, length), free_decay(dof, -angle, length)]
        if has_rudder:
            # 8 T: the yaw rate is within 0.03% of steady before the rudder returns, so the
            # return-to-amidships step also identifies K.
            t_yaw = max(8 * tc[4], 5.0)
            thrust = {"tau_x": float(d[0] * 1.0)}
            items += [rudder_step(np.radians(10), t_yaw, t_yaw, thrust),
                      rudder_step(np.radians(-10), t_yaw, t_yaw, thrust),
                      zigzag(z, z, 12 * tc[4] + 10, thrust)]
    elif vessel.nomoto:
        t_n = float(vessel.nomoto["T"])
        hold = 5 * t_n
        items += [rudder_step(np.radians(10), hold, hold), rudder_step(np.radians(-10), hold, hold),
                  zigzag(z, z, 12 * t_n)]
    else:
        raise SimError(f"{vessel.name}: expected [damping] with rigid_body, or [nomoto], to plan a trial; found neither")
    rest_s = 5.0
    if vessel.has_rigid_body and vessel.damping is not None:
        rest_s = float(max(5.0, 3 * np.max(np.diag(vessel.mass_matrix()) / np.diag(vessel.damping))))
    elif vessel.nomoto:
        rest_s = 3 * float(vessel.nomoto["T"])
    return chain(*items, rest_s=rest_s)
