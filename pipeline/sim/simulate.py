"""Simulate a trial: dynamics with effects, manoeuvre schedule, sensors; returns a RawLog and truth.

The dynamics are the shared right-hand sides of :mod:`pipeline.model` (5-DOF vessel or Nomoto
ship) integrated with RK4 at ``dt`` with zero-order-hold inputs. Commands are logged as the
autopilot sent them; the actuator applies them through the input effects (delay, rate limit,
thrust asymmetry), so an identified model that ignores an effect sees the gap a real boat shows.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Mapping

import numpy as np
import pandas as pd

from ..errors import SimError
from ..geo import ned_to_latlon, wrap_pi
from ..model.integrate import rk4_chunk_integrator
from ..model.nomoto import NomotoParams, nomoto_ship_rhs
from ..model.vessel5dof import INPUTS_5DOF, STATES_5DOF, params_from_vessel, vessel5dof_rhs
from ..model.waves import simulate_waves
from ..records import Channel, IngestSummary, RawLog, Segment, Segments
from ..vessel import Vessel
from .effects import Effects, apply_delay, apply_rate_limit, apply_thrust_asymmetry, check_effects
from .manoeuvres import Schedule
from .sensors import SensorSpec, default_sensors

GRAVITY = 9.81  # [m/s^2]
NOMOTO_SHIP_STATES = ("psi", "r", "x_n", "y_e")
#: Integration steps per compiled call of the plant (:func:`pipeline.model.integrate.rk4_chunk_integrator`).
CHUNK_STEPS = 256


@dataclass(frozen=True)
class SimResult:
    """A simulated trial.

    Attributes
    ----------
    log : RawLog
        Sensor and actuator channels as a boat would log them (``format='sim'``).
    truth : pandas.DataFrame
        True states, commanded inputs (``cmd_<channel>``) and applied generalised forces on the
        integration grid, column ``t`` [s].
    segments : Segments
        The segments the schedule produced (ground truth for the detector).
    vessel : Vessel
        The vessel simulated.
    effects : Effects
        Effects switched on.
    seed : int
        Random seed of the sensor noise and waves.
    """

    log: RawLog
    truth: pd.DataFrame
    segments: Segments
    vessel: Vessel
    effects: Effects
    seed: int


def _plant(vessel: Vessel, effects: Effects, speed: float):
    """(rhs, params, state names, mapping of commanded channels to the model input)."""
    if vessel.has_rigid_body and vessel.damping is not None:
        params = params_from_vessel(vessel)
        d = params.D if effects.coupling is None else params.D + np.asarray(effects.coupling, float)
        d2 = params.D2 if effects.quadratic_damping is None else np.asarray(effects.quadratic_damping, float)
        params = replace(params, D=d, D2=d2, current=np.asarray(effects.current, float))
        return vessel5dof_rhs, params, STATES_5DOF, "5dof"
    if vessel.nomoto:
        d2 = 0.0 if effects.quadratic_damping is None else float(effects.quadratic_damping[4])
        nomoto = NomotoParams(K=vessel.nomoto["K"], T=vessel.nomoto["T"], b=effects.rudder_bias, d2=d2)
        return nomoto_ship_rhs, (nomoto, speed, np.asarray(effects.current, float)), NOMOTO_SHIP_STATES, "nomoto"
    raise SimError(f"{vessel.name}: expected rigid_body + [damping] (5-DOF) or [nomoto] (rudder ship) to "
                   f"simulate; found neither")


def _input_map(kind: str, vessel: Vessel, channels: tuple[str, ...], n_inputs: int):
    """``to_model(applied)``: the model's input rows from the actuators' applied values, shape (steps, channels).

    The 5-DOF model takes generalised forces (a rudder adds its yaw moment and sway force per
    radian); the Nomoto ship takes the rudder angle.
    """
    gain = np.zeros((len(channels), n_inputs))
    for j, ch in enumerate(channels):
        if kind == "nomoto":
            gain[j, 0] = 1.0 if ch == "delta" else 0.0
        elif ch in INPUTS_5DOF:
            gain[j, INPUTS_5DOF.index(ch)] = 1.0
        elif ch == "delta":
            gain[j, 4] = vessel.rudder.get("yaw_moment", 0.0)
            gain[j, 1] = vessel.rudder.get("sway_force", 0.0)

    def to_model(applied: np.ndarray) -> np.ndarray:
        return np.asarray(applied, float) @ gain  # rows of (steps, channels), also with no channel

    return to_model


def simulate(vessel: Vessel, schedule: Schedule, effects: Effects = Effects(),
             sensors: tuple[SensorSpec, ...] | None = None, seed: int = 0, dt: float = 0.01,
             speed: float = 5.0, origin: tuple[float, float] = (57.05, 9.92),
             actuator_rate: float = 50.0) -> SimResult:
    """Simulate ``schedule`` on ``vessel`` with ``effects`` and sample it with ``sensors``.

    Parameters
    ----------
    vessel : Vessel
        Vessel with rigid body + [damping] (5-DOF model) or [nomoto] (rudder ship).
    schedule : Schedule
        Manoeuvres, e.g. :func:`pipeline.sim.manoeuvres.sea_trial`.
    effects : Effects
        Unmodelled effects switched on.
    sensors : tuple[SensorSpec, ...], optional
        Sensor set; default :func:`pipeline.sim.sensors.default_sensors` at nominal noise.
    seed : int
        Seed for noise and waves (deterministic).
    dt : float
        Integration step [s].
    speed : float
        Speed through the water of a Nomoto ship [m/s].
    origin : tuple[float, float]
        Latitude and longitude of the trial origin [deg].
    actuator_rate : float
        Rate at which commands are logged [Hz].

    Returns
    -------
    SimResult
    """
    check_effects(effects)
    if not dt > 0:
        raise SimError(f"dt: expected a positive step [s], found {dt}")
    default = sensors is None
    sensors = default_sensors() if default else sensors
    rng = np.random.default_rng(seed)
    rhs, params, states, kind = _plant(vessel, effects, speed)
    channels = schedule.inputs
    if kind == "nomoto" and any(c != "delta" for c in channels):
        raise SimError(f"{vessel.name} is a Nomoto ship: expected only rudder (delta) commands, found {channels}")

    tick = int(round(1.0 / (actuator_rate * dt)))
    if tick < 1 or abs(tick * dt * actuator_rate - 1.0) > 1e-9:
        raise SimError(f"actuator_rate: expected a rate whose period is a multiple of dt = {dt} s, "
                       f"found {actuator_rate} Hz")
    n = int(round(schedule.duration / dt)) + 1
    t = np.arange(n) * dt
    # Manoeuvres start on an autopilot tick (see the command loop below).
    period = 1.0 / actuator_rate
    starts = np.round(schedule.starts / period) * period
    which = np.searchsorted(starts, t + 1e-9, side="right") - 1
    x = np.zeros((n, len(states)))
    xdot = np.zeros((n, len(states)))
    cmd = np.zeros((n, len(channels)))
    tau = np.zeros((n, 5 if kind == "5dof" else 1))
    delay_steps = int(round(effects.actuator_delay / dt))
    max_step = np.array([effects.actuator_rate_limit.get(c, np.inf) * dt for c in channels])
    tau_x_index = channels.index("tau_x") if "tau_x" in channels else None
    quantize = _pwm_quantizer(vessel, channels)
    to_model = _input_map(kind, vessel, channels, tau.shape[1])
    integrate = rk4_chunk_integrator(rhs, params, len(states), tau.shape[1], dt, CHUNK_STEPS)
    # Manoeuvre boundaries in integration steps (starts lie on autopilot ticks).
    bounds = np.searchsorted(which, np.arange(len(schedule.manoeuvres) + 1), side="left")
    xk = np.zeros(len(states))
    limited = np.zeros(len(channels))
    unlimited = bool(np.all(np.isinf(max_step)))
    for m_idx, man in enumerate(schedule.manoeuvres):
        k = int(bounds[m_idx])
        if k == bounds[m_idx + 1]:
            continue  # shorter than one step: no sample of it, and its initial state is never applied
        for name, value in man.initial.items():
            if name in states:
                xk[states.index(name)] = value
        while k < bounds[m_idx + 1]:
            # A stretch whose commands are known before it is integrated: up to the next tick when
            # the manoeuvre reads the state (a zig-zag watches the heading), else a whole chunk.
            step_to = k + tick if man.uses_state else k + CHUNK_STEPS
            k_end = int(min(step_to, bounds[m_idx + 1]))
            state = dict(zip(states, xk))
            for j in range(k, k_end):
                if j % tick == 0:
                    # A digital autopilot issues commands on its own tick and logs them there; between
                    # ticks the command is held, so the logged steps are exactly the applied ones.
                    c = man.command(float(t[j] - starts[m_idx]), state)
                    cmd[j] = quantize([c.get(ch, 0.0) for ch in channels])
                else:
                    cmd[j] = cmd[j - 1]
            rows = np.arange(k, k_end)
            target = apply_delay(cmd, rows, delay_steps)
            # The rate limiter tracks the actuator's own position; the reverse-thrust loss acts on
            # what the propeller makes of it and must not feed back into the limiter's state.
            if unlimited:
                applied = target.copy()
            else:
                applied = np.empty_like(target)
                for i, j in enumerate(rows):
                    limited = (apply_rate_limit(limited, target[i], max_step) if j
                               else np.where(np.isinf(max_step), target[i], 0.0))
                    applied[i] = limited
            if tau_x_index is not None:
                applied = np.array([apply_thrust_asymmetry(a, tau_x_index, effects.thrust_reverse_gain)
                                    for a in applied])
            tau[k:k_end] = to_model(applied)
            x[k:k_end], xdot[k:k_end], xk = integrate(xk, tau[k:k_end])
            k = k_end
    # Casadi's arithmetic leaves signed zeros (-0.0) at rest where numpy gave +0.0; adding zero clears
    # them, so a course over ground at rest, atan2(0, 0), reads 0 and not pi (as before the compiled plant).
    x += 0.0
    xdot += 0.0

    truth = pd.DataFrame(x, columns=list(states))
    truth.insert(0, "t", t)
    for j, ch in enumerate(channels):
        truth[f"cmd_{ch}"] = cmd[:, j]
    if kind == "5dof":
        for j, ch in enumerate(INPUTS_5DOF):
            truth[f"applied_{ch}"] = tau[:, j]
        vn, ve = xdot[:, 5], xdot[:, 6]
        # Specific force in the body frame: kinematic acceleration minus gravity (z down).
        u_, v_, r_ = x[:, 0], x[:, 1], x[:, 4]
        phi, theta = x[:, 7], x[:, 8]
        truth["ax"] = xdot[:, 0] - r_ * v_ + GRAVITY * np.sin(theta)
        truth["ay"] = xdot[:, 1] + r_ * u_ - GRAVITY * np.cos(theta) * np.sin(phi)
        truth["az"] = -GRAVITY * np.cos(theta) * np.cos(phi)
    else:
        truth["applied_delta"] = tau[:, 0]
        vn, ve = xdot[:, 2], xdot[:, 3]
    truth["vn"], truth["ve"] = vn, ve
    truth["psi_w"] = (simulate_waves(t, effects.waves, rng) if effects.waves is not None else np.zeros(n))

    if default:
        sensors = _simulated_only(sensors, set(truth.columns))
    log = _sample_sensors(truth, sensors, channels, rng, origin, actuator_rate, vessel, effects, seed)

    def level(ch: str | None, value: float) -> float:
        # The truth level is what the actuator applied: the command after PWM rounding.
        if ch not in channels:
            return value
        vec = np.zeros(len(channels))
        vec[channels.index(ch)] = value
        return float(quantize(vec)[channels.index(ch)])

    segs = tuple(Segment(kind=s.kind, dof=s.dof, t_start=float(starts[i] + s.t_start),
                         t_end=float(starts[i] + s.t_end), input_channel=s.input_channel,
                         input_before=level(s.input_channel, s.input_before),
                         input_after=level(s.input_channel, s.input_after), origin="truth", label=m.name)
                 for i, m in enumerate(schedule.manoeuvres) for s in m.segments)
    return SimResult(log=log, truth=truth, segments=Segments(f"sim-{vessel.name}-{seed}", segs),
                     vessel=vessel, effects=effects, seed=seed)


def _simulated_only(sensors: tuple[SensorSpec, ...], columns: set[str]) -> tuple[SensorSpec, ...]:
    """The default sensor set cut to what the plant simulates (a Nomoto ship has no roll, pitch or
    accelerations); sensors a caller names explicitly are left alone and fail loudly instead."""
    source = {"lat": "x_n", "lon": "y_e", "sog": "vn", "cog": "vn"}
    out = []
    for s in sensors:
        keep = tuple(c for c in s.channels if source.get(c, c) in columns)
        if keep:
            out.append(replace(s, channels=keep, noise={c: v for c, v in s.noise.items() if c in keep},
                               bias={c: v for c, v in s.bias.items() if c in keep}))
    return tuple(out)


def _pwm_quantizer(vessel: Vessel, channels: tuple[str, ...]):
    """Round commands to whole PWM microseconds for inputs the vessel drives through one PWM map.

    A servo or ESC receives an integer pulse width, so that is what the actuator applies and the
    autopilot logs; without this a PWM log would disagree with the simulated truth by up to half
    a microsecond of the map (0.08 deg of a 35 deg rudder).
    """
    maps = {}
    for ch in channels:
        hits = [a for a in vessel.actuators if a.target == ch]
        if len(hits) == 1:
            maps[channels.index(ch)] = hits[0]

    # A command is held for many ticks: each distinct value is converted once (the two numpy
    # conversions cost about 60 us per tick, a third of the simulator's time on a thruster boat).
    seen: dict[tuple[float, ...], np.ndarray] = {}

    def quantize(values):
        key = tuple(float(v) for v in values)
        if key not in seen:
            out = np.asarray(key, float)
            for j, amap in maps.items():
                out[j] = float(amap.to_input(np.round(amap.to_pwm(out[j]))))
            if len(seen) > 100_000:
                seen.clear()
            seen[key] = out
        return seen[key].copy()

    return quantize


def _sample_sensors(truth: pd.DataFrame, sensors: tuple[SensorSpec, ...], inputs: tuple[str, ...],
                    rng: np.random.Generator, origin: tuple[float, float], actuator_rate: float,
                    vessel: Vessel, effects: Effects, seed: int) -> RawLog:
    t = truth["t"].to_numpy()
    t_end = t[-1]

    def at(ts: np.ndarray, col: str) -> np.ndarray:
        return np.interp(ts, t, truth[col].to_numpy()) if col in truth else np.full(len(ts), np.nan)

    chans: dict[str, Channel] = {}
    counts: dict[str, int] = {}
    for s in sensors:
        ts = np.arange(0.0, t_end + 1e-9, 1.0 / s.rate)
        noise = {c: s.noise.get(c, 0.0) for c in s.channels}
        bias = {c: s.bias.get(c, 0.0) for c in s.channels}
        if "lat" in s.channels or "lon" in s.channels:
            # Position noise and bias are given in metres north/east and converted to degrees.
            xn = at(ts, "x_n") + bias.get("lat", 0.0) + noise.get("lat", 0.0) * rng.standard_normal(len(ts))
            ye = at(ts, "y_e") + bias.get("lon", 0.0) + noise.get("lon", 0.0) * rng.standard_normal(len(ts))
            lat, lon = ned_to_latlon(xn, ye, *origin)
            values = {"lat": lat, "lon": lon}
        else:
            values = {}
        if "sog" in s.channels or "cog" in s.channels:
            # Speed noise acts on each NED velocity component, so course noise grows as speed
            # falls, as it does in a GNSS receiver; extra course noise adds on top.
            vn = at(ts, "vn") + noise.get("sog", 0.0) * rng.standard_normal(len(ts))
            ve = at(ts, "ve") + noise.get("sog", 0.0) * rng.standard_normal(len(ts))
            values["sog"] = np.hypot(vn, ve) + bias.get("sog", 0.0)
            values["cog"] = wrap_pi(np.arctan2(ve, vn) + bias.get("cog", 0.0)
                                    + noise.get("cog", 0.0) * rng.standard_normal(len(ts)))
        for c in s.channels:
            if c in values:
                continue
            if c == "psi":
                base = np.interp(ts, t, np.unwrap(truth["psi"].to_numpy())) + at(ts, "psi_w")
            elif c in truth:
                base = at(ts, c)
            else:
                raise SimError(f"sensor {s.name}: channel {c!r} is not simulated for {vessel.name}; "
                               f"simulated: {sorted(truth.columns)}")
            val = base + bias[c] + noise[c] * rng.standard_normal(len(ts))
            values[c] = wrap_pi(val) if c in ("phi", "theta", "psi", "cog") else val
        for c in s.channels:
            name = c + s.suffix
            chans[name] = Channel(name, ts, np.asarray(values[c], float), source=s.name)
        counts[s.name] = len(ts)
    if inputs:
        ts = np.arange(0.0, t_end + 1e-9, 1.0 / actuator_rate)
        # Commands are logged exactly as sent, held between integration steps.
        idx = np.minimum(np.searchsorted(t, ts + 1e-9, side="right") - 1, len(t) - 1)
        for ch in inputs:
            chans[ch] = Channel(ch, ts, truth[f"cmd_{ch}"].to_numpy()[idx], source="actuators")
        counts["actuators"] = len(ts)
    summary = IngestSummary(path=f"sim:{vessel.name}:seed{seed}", format="sim", read=counts,
                            warnings=tuple(f"effect on: {e}" for e in effects.active()))
    return RawLog(source=summary.path, format="sim", channels=chans, summary=summary, time_reference="trial")


def resample(result: SimResult, seed: int, origin: tuple[float, float] = (57.05, 9.92),
             actuator_rate: float = 50.0) -> SimResult:
    """The same simulated truth sampled again with the sensor noise of another seed.

    Without waves the truth does not depend on the seed, so this equals :func:`simulate` with
    ``seed`` (same default sensors, ``origin`` and ``actuator_rate``) without integrating the
    plant again: Monte Carlo runs over sensor noise then cost one simulation.

    Parameters
    ----------
    result : SimResult
        A simulation with the default sensors and no waves.
    seed : int
        Seed of the sensor noise.
    origin : tuple[float, float]
        Latitude and longitude of the trial origin [deg], as given to :func:`simulate`.
    actuator_rate : float
        Rate at which commands are logged [Hz], as given to :func:`simulate`.

    Returns
    -------
    SimResult

    Raises
    ------
    SimError
        The simulation had waves (their realisation depends on the seed).
    """
    if result.effects.waves is not None:
        raise SimError("resample: expected a simulation without waves (the waves depend on the seed); "
                       "found waves: simulate again with the new seed")
    truth = result.truth
    channels = tuple(c[4:] for c in truth.columns if c.startswith("cmd_"))
    sensors = _simulated_only(default_sensors(), set(truth.columns))
    log = _sample_sensors(truth, sensors, channels, np.random.default_rng(seed), origin, actuator_rate,
                          result.vessel, result.effects, seed)
    return replace(result, log=log, seed=seed)
