"""Shared fixtures: the AAUSHIP vessel and the simulated sea trials several test modules read.

Simulating the standard AAUSHIP sea-trial day takes seconds; every module that needs it takes it
from here, so it is simulated once per configuration for the whole session. The results are
frozen records: tests read them and never modify them (a test that needs a variant copies it).
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import pytest

from pipeline.sim import sea_trial, simulate
from pipeline.sim.sensors import default_sensors
from pipeline.vessel import Vessel, load_vessel

ROOT = Path(__file__).resolve().parents[1]
#: The sample vessel's config (the simulator's truth for the regression tests).
AAUSHIP_TOML = ROOT / "vessel_configs" / "aauship.toml"


@lru_cache(maxsize=None)
def _aauship() -> Vessel:
    return load_vessel(AAUSHIP_TOML)


#: The AAUSHIP vessel, for modules that need it at import time (parametrisation, constants):
#: ``from conftest import AAUSHIP``. Tests take the ``aauship`` fixture.
AAUSHIP = _aauship()


@lru_cache(maxsize=None)
def simulated_sea_trial(level: str = "nominal", seed: int = 21):
    """The AAUSHIP sea-trial day (:func:`pipeline.sim.sea_trial`) with the default sensors at
    ``level`` noise, simulated once per ``(level, seed)`` for the session (for module-level
    helpers; tests take the ``sea_trial_sim`` fixture)."""
    vessel = _aauship()
    return simulate(vessel, sea_trial(vessel), sensors=default_sensors(level), seed=seed)


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The repository's root folder."""
    return ROOT


@pytest.fixture(scope="session")
def aauship_toml() -> Path:
    """Path of ``vessel_configs/aauship.toml``."""
    return AAUSHIP_TOML


@pytest.fixture(scope="session")
def aauship() -> Vessel:
    """The AAUSHIP vessel (``vessel_configs/aauship.toml``), loaded once."""
    return _aauship()


@pytest.fixture(scope="session")
def sea_trial_sim():
    """Factory ``sea_trial_sim(level="nominal", seed=21)``: the AAUSHIP sea-trial day
    (:func:`pipeline.sim.sea_trial`) simulated with the default sensors at that noise level, once
    per ``(level, seed)`` for the whole session."""

    def get(level: str = "nominal", seed: int = 21):
        return simulated_sea_trial(level, seed)

    return get


@pytest.fixture(scope="session")
def sea_trial_day(sea_trial_sim):
    """The AAUSHIP sea-trial day at nominal noise, seed 21 (a :class:`pipeline.sim.SimResult`)."""
    return sea_trial_sim("nominal", 21)
