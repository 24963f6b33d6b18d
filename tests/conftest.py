"""Shared fixtures: the AAUSHIP vessel and the simulated sea trials several test modules read.

Simulating the standard AAUSHIP sea-trial day takes seconds; every module that needs it takes it
from here, so it is simulated once per configuration for the whole session. The results are
frozen records: tests read them and never modify them (a test that needs a variant copies it).

Under pytest-xdist each worker is its own process, so an in-process cache alone simulates every
configuration once per worker (the segment tests' six sea trials were simulated twice each, about
35 s of CPU in ``make test``). The workers of one run therefore share each simulated day through a
pickle in the run's common temporary folder, written by whichever worker gets there first while the
other waits on a file lock (:func:`shared_between_workers`).
"""

from __future__ import annotations

import fcntl
import os
import pickle
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


#: The folder the xdist workers of this run share (set by :func:`_shared_folder`); None outside xdist.
_SHARED: dict[str, Path | None] = {"folder": None}


@pytest.fixture(scope="session", autouse=True)
def _shared_folder(tmp_path_factory):
    """Point :func:`shared_between_workers` at the run's common temporary folder.

    An xdist worker's base temp is ``.../pytest-N/popen-gwK``; its parent belongs to this run only
    (pytest removes old runs' folders). Without xdist nothing is shared: one process, one cache.
    """
    if os.environ.get("PYTEST_XDIST_WORKER"):
        folder = tmp_path_factory.getbasetemp().parent / "shared-between-workers"
        folder.mkdir(exist_ok=True)
        _SHARED["folder"] = folder
    yield
    _SHARED["folder"] = None


def shared_between_workers(key: str, compute):
    """``compute()``, computed once per test run and shared by every xdist worker through a pickle.

    Parameters
    ----------
    key : str
        File-name-safe identity of the value (the same key must mean the same value).
    compute : callable
        Produces the value; called by the first worker that asks, the others load its pickle.
    """
    folder = _SHARED["folder"]
    if folder is None:
        return compute()
    path = folder / f"{key}.pkl"
    with open(folder / f"{key}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if path.exists():
            with open(path, "rb") as f:
                return pickle.load(f)
        value = compute()
        part = path.with_suffix(".part")
        with open(part, "wb") as f:
            pickle.dump(value, f, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(part, path)
        return value


@lru_cache(maxsize=None)
def simulated_sea_trial(level: str = "nominal", seed: int = 21):
    """The AAUSHIP sea-trial day (:func:`pipeline.sim.sea_trial`) with the default sensors at
    ``level`` noise, simulated once per ``(level, seed)`` for the whole run, shared by the xdist
    workers (for module-level helpers; tests take the ``sea_trial_sim`` fixture)."""

    def compute():
        vessel = _aauship()
        return simulate(vessel, sea_trial(vessel), sensors=default_sensors(level), seed=seed)

    return shared_between_workers(f"aauship-sea-trial-{level}-{seed}", compute)


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
