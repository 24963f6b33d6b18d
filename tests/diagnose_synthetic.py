"""Synthetic trials for the diagnosis' tests: simulate, write a real log, read it back.

Test support, not part of the package (moved out of ``pipeline.diagnose``).

Small helpers the simulator does not have: sensors a Nomoto ship's simulation can feed (it has
no roll, pitch or accelerations, which :func:`pipeline.sim.sensors.default_sensors` asks for),
and a wave model sized by the standard deviation of the heading it adds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.flow import load_trial
from pipeline.model.waves import WaveParams
from pipeline.records import Trial
from pipeline.sim import Effects, simulate
from pipeline.sim.manoeuvres import Schedule
from pipeline.sim.sensors import NOISE_LEVELS, SensorSpec, default_sensors
from pipeline.sim.writers import write_log
from pipeline.vessel import Vessel


def nomoto_sensors(level: str = "nominal", rate: float = 50.0) -> tuple[SensorSpec, ...]:
    """Gyro, compass and GNSS of a Nomoto ship at the noise ``level`` of :data:`NOISE_LEVELS`.

    Parameters
    ----------
    level : str
        ``low``, ``nominal`` or ``high``.
    rate : float
        Gyro and compass rate [Hz]; GNSS at most 10 Hz.
    """
    k = NOISE_LEVELS[level]
    return (SensorSpec("imu", ("r",), rate, noise={"r": 0.002 * k}),
            SensorSpec("attitude", ("psi",), rate, noise={"psi": 0.002 * k}),
            SensorSpec("gps", ("lat", "lon", "sog", "cog"), min(rate, 10.0),
                       noise={"lat": 0.3 * k, "lon": 0.3 * k, "sog": 0.02 * k, "cog": 0.01 * k}))


def waves_with_sigma(omega0: float, lam: float, sigma: float) -> WaveParams:
    """Wave model whose heading has standard deviation ``sigma`` [rad].

    For ``psi_w = K_w s / (s^2 + 2 lam omega0 s + omega0^2) w`` with unit white noise,
    ``var(psi_w) = K_w^2 / (4 lam omega0)``.

    Parameters
    ----------
    omega0 : float
        Peak frequency [rad/s].
    lam : float
        Relative damping [-].
    sigma : float
        Standard deviation of the wave heading [rad].
    """
    return WaveParams(omega0=float(omega0), lam=float(lam), kw=float(sigma * np.sqrt(4 * lam * omega0)))


def simulated_trial(vessel: Vessel, schedule: Schedule, effects: Effects, folder: str | Path, name: str,
                    noise: str = "nominal", seed: int = 0, dt: float | None = None,
                    rate: float | None = None) -> tuple[Trial, Path]:
    """Simulate a trial, write it as canonical CSV and read it back (the user's path).

    Parameters
    ----------
    vessel : Vessel
        5-DOF vessel or Nomoto ship.
    schedule : Schedule
        Manoeuvres.
    effects : Effects
        Unmodelled effects switched on.
    folder : str or Path
        Where the CSV goes.
    name : str
        File stem.
    noise : str
        Sensor noise level.
    seed : int
        Seed.
    dt : float, optional
        Integration step [s]; default 0.01 s, or T/500 (at most 0.1 s) for a Nomoto ship.
    rate : float, optional
        Sensor and command-log rate of a Nomoto ship [Hz] (default 1/dt, at most 50 Hz).

    Returns
    -------
    (Trial, Path)
    """
    if vessel.has_rigid_body and vessel.damping is not None:
        sensors, step, cmd_rate = default_sensors(noise), dt or 0.01, 50.0
    else:
        step = dt or float(min(max(vessel.nomoto["T"] / 500, 0.01), 0.1))
        cmd_rate = rate or float(min(1.0 / step, 50.0))
        sensors = nomoto_sensors(noise, cmd_rate)
    res = simulate(vessel, schedule, effects, sensors=sensors, seed=seed, dt=step, actuator_rate=cmd_rate)
    path = write_log(res.log, Path(folder) / f"{name}.csv", vessel=vessel)
    return load_trial([path], vessel), path
