"""Sensors of a simulated boat: which channels, at what rate, with what noise and bias.

A sensor samples the true state on its own clock, adds a constant bias and white Gaussian noise
per channel, and names its channels canonically (a second sensor of the same quantity adds a
``@sensor`` suffix, as the readers do).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Mapping

from ..errors import SimError


@dataclass(frozen=True)
class SensorSpec:
    """One sensor.

    Attributes
    ----------
    name : str
        Sensor name (``imu``, ``attitude``, ``nav``, ``gps``, ``actuators``).
    channels : tuple[str, ...]
        Canonical channels it measures.
    rate : float
        Sample rate [Hz].
    noise : Mapping[str, float]
        White-noise standard deviation per channel [SI unit of the channel].
    bias : Mapping[str, float]
        Constant bias per channel [SI unit].
    suffix : str
        Appended to channel names (``@gps`` for a second position/velocity source).
    """

    name: str
    channels: tuple[str, ...]
    rate: float
    noise: Mapping[str, float] = field(default_factory=dict)
    bias: Mapping[str, float] = field(default_factory=dict)
    suffix: str = ""

    def __post_init__(self) -> None:
        if not self.rate > 0:
            raise SimError(f"sensor {self.name}: expected a positive rate [Hz], found {self.rate}")
        for ch in list(self.noise) + list(self.bias):
            if ch not in self.channels:
                raise SimError(f"sensor {self.name}: noise/bias for {ch!r}, which it does not measure "
                               f"(channels {self.channels})")


#: Multipliers of the nominal noise for the three regression noise levels.
NOISE_LEVELS: Mapping[str, float] = {"low": 0.3, "nominal": 1.0, "high": 3.0}


def default_sensors(level: str = "nominal", fast_attitude: bool = True) -> tuple[SensorSpec, ...]:
    """A small-boat sensor set: IMU, attitude/compass, navigation filter, GPS, actuator log.

    Nominal noise is that of a MEMS IMU with an AHRS and a GNSS-aided navigation filter:
    gyro 0.002 rad/s, accelerometer 0.05 m/s^2, attitude 0.002 rad (0.11 deg), speed over ground
    0.005 m/s (filter) and 0.02 m/s (raw GPS), course 0.01 rad, position 0.3 m (raw GPS).

    Parameters
    ----------
    level : str
        ``low``, ``nominal`` or ``high`` (``NOISE_LEVELS``).
    fast_attitude : bool
        Attitude at 100 Hz (needed for a 1 m boat whose roll period is 0.6 s) instead of 50 Hz.
    """
    if level not in NOISE_LEVELS:
        raise SimError(f"noise level: expected one of {sorted(NOISE_LEVELS)}, found {level!r}")
    k = NOISE_LEVELS[level]
    return (
        SensorSpec("imu", ("p", "q", "r", "ax", "ay", "az"), 100.0,
                   noise={"p": 0.002 * k, "q": 0.002 * k, "r": 0.002 * k,
                          "ax": 0.05 * k, "ay": 0.05 * k, "az": 0.05 * k}),
        SensorSpec("attitude", ("phi", "theta", "psi"), 100.0 if fast_attitude else 50.0,
                   noise={"phi": 0.002 * k, "theta": 0.002 * k, "psi": 0.002 * k}),
        SensorSpec("nav", ("lat", "lon", "sog", "cog"), 50.0,
                   noise={"sog": 0.005 * k, "cog": 0.0 * k}),
        SensorSpec("gps", ("lat", "lon", "sog", "cog"), 10.0,
                   noise={"lat": 0.3 * k, "lon": 0.3 * k, "sog": 0.02 * k, "cog": 0.01 * k},
                   suffix="@gps"),
    )


def scaled(sensors: tuple[SensorSpec, ...], factor: float) -> tuple[SensorSpec, ...]:
    """The same sensors with every noise standard deviation multiplied by ``factor``.

    Parameters
    ----------
    sensors : tuple[SensorSpec, ...]
        Sensor set, for example :func:`default_sensors`; not modified.
    factor : float
        Multiplier of every noise standard deviation [-].
    """
    return tuple(replace(s, noise={c: v * factor for c, v in s.noise.items()}) for s in sensors)
