"""Trees of short simulated trials, for the batch tests and the batch benchmark.

Each trial is a real DataFlash log (``.bin``, with a GPS clock, so the catalogue gets its date and
place from the log) written by :mod:`pipeline.sim` from a vessel whose surge damping can be scaled
per trial (hull fouling), plus a trial manifest. The schedule is short on purpose (a surge step +
coast-down and a rudder step, sensors at ``rate`` Hz) so dozens of trials process in minutes.
"""

from __future__ import annotations

import copy
import tomllib
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np

#: Reference vessel the variants are made from.
BASE_VESSEL = Path(__file__).resolve().parents[2] / "vessel_configs" / "aauship.toml"


@dataclass(frozen=True)
class VesselVariant:
    """A vessel of a simulated fleet.

    Attributes
    ----------
    name : str
        Vessel name (config ``name``).
    mass_scale, damping_scale : float
        Multipliers of the base vessel's mass and inertia, and of its damping diagonal [-].
    fouling_per_trial : float
        Relative growth of the surge damping D[0,0] per trial (0.01 = 1 %/trial, compounded).
    origin : tuple[float, float]
        Trial area, latitude and longitude [deg].
    """

    name: str
    mass_scale: float = 1.0
    damping_scale: float = 1.0
    fouling_per_trial: float = 0.0
    origin: tuple[float, float] = (57.05, 9.92)


#: Four vessels, the second one fouling at 1 %/trial.
FLEET = (
    VesselVariant("skiff", 1.0, 1.0, 0.0, (57.05, 9.92)),
    VesselVariant("fouler", 1.2, 1.1, 0.01, (56.15, 10.21)),
    VesselVariant("tender", 0.8, 0.9, 0.0, (55.40, 10.38)),
    VesselVariant("barge", 1.5, 1.4, 0.0, (54.32, 10.13)),
)


def vessel_doc(variant: VesselVariant, surge_factor: float = 1.0) -> dict:
    """The vessel config (as a TOML dict) of a variant, optionally with its surge damping scaled.

    Parameters
    ----------
    variant : VesselVariant
        The vessel.
    surge_factor : float
        Extra multiplier of D[0,0] (the fouling of one trial) [-].
    """
    doc = copy.deepcopy(tomllib.loads(BASE_VESSEL.read_text()))
    doc["name"] = variant.name
    rb = doc["rigid_body"]
    rb["mass"] = rb["mass"] * variant.mass_scale
    rb["inertia"] = [x * variant.mass_scale for x in rb["inertia"]]
    d = [x * variant.damping_scale for x in doc["damping"]["diagonal"]]
    d[0] *= surge_factor
    doc["damping"]["diagonal"] = d
    return doc


def write_trial(folder: str | Path, name: str, vessel_config: str | Path, truth_doc: dict, seed: int,
                start: datetime, origin: tuple[float, float], rate: float = 10.0, rudder: bool = True) -> Path:
    """Simulate one short trial, write its DataFlash log and its manifest.

    Parameters
    ----------
    folder : str or Path
        Trial folder (created).
    name : str
        Trial name.
    vessel_config : str or Path
        The vessel config the manifest names (what the lab knows about the boat).
    truth_doc : dict
        Vessel config the simulator uses (the boat as it really is, e.g. fouled).
    seed : int
        Noise seed.
    start : datetime
        UTC time of the trial start (timezone-aware), written as the log's GPS clock.
    origin : tuple[float, float]
        Latitude and longitude of the trial area [deg].
    rate : float
        Highest sensor rate [Hz].
    rudder : bool
        Add a rudder step after the surge step and coast-down (Nomoto K and T); False halves
        the trial (surge only).

    Returns
    -------
    Path
        The manifest.
    """
    from dataclasses import replace

    import tomli_w

    from ..sim import simulate
    from ..sim.manoeuvres import chain, rudder_step, step_and_coast
    from ..sim.sensors import default_sensors
    from ..sim.writers import write_log
    from ..vessel import parse_vessel

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    truth = parse_vessel(truth_doc, f"{name} truth")
    d = np.diag(truth.damping)
    tc = np.diag(truth.mass_matrix()) / d
    items = [step_and_coast("surge", float(d[0] * 1.5), 6 * tc[0], 6 * tc[0])]
    if rudder:
        items.append(rudder_step(np.radians(10), 8 * tc[4], 8 * tc[4], {"tau_x": float(d[0])}))
    schedule = chain(*items, rest_s=float(3 * tc[0]))
    sensors = tuple(replace(s, rate=min(s.rate, rate)) for s in default_sensors("nominal"))
    result = simulate(truth, schedule, sensors=sensors, seed=seed, dt=0.02, origin=origin)
    write_log(result.log, folder / f"{name}.bin", vessel=truth, gps_start=start)
    manifest = folder / "trial.toml"
    rel = Path(vessel_config).resolve()
    manifest.write_text(tomli_w.dumps({"name": name, "vessel": str(rel), "logs": [f"{name}.bin"]}))
    return manifest


def write_fleet(root: str | Path, trials_per_vessel: int = 10, fleet: tuple[VesselVariant, ...] = FLEET,
                rate: float = 10.0, first: datetime = datetime(2025, 4, 1, 9, 0, tzinfo=timezone.utc),
                spacing: timedelta = timedelta(days=7), rudder: bool = True) -> list[Path]:
    """Write ``trials_per_vessel`` trials of every vessel under ``root`` (``<vessel>/<trial>/``).

    Trial ``k`` of a vessel is recorded ``k * spacing`` after ``first`` with seed ``1000 * i + k``
    and its surge damping multiplied by ``(1 + fouling_per_trial) ** k``. Vessel configs go to
    ``root/vessels/<name>.toml`` (the unfouled boat, as the lab knows it).

    Parameters
    ----------
    root : str or Path
        Output folder.
    trials_per_vessel : int
        Trials per vessel.
    fleet : tuple[VesselVariant, ...]
        The vessels.
    rate : float
        Highest sensor rate [Hz].
    first : datetime
        Date of the first trial (UTC, timezone-aware).
    spacing : timedelta
        Time between a vessel's trials.
    rudder : bool
        Include the rudder step (see :func:`write_trial`).

    Returns
    -------
    list[Path]
        The manifests written.
    """
    import tomli_w

    root = Path(root)
    (root / "vessels").mkdir(parents=True, exist_ok=True)
    out = []
    for i, var in enumerate(fleet):
        cfg = root / "vessels" / f"{var.name}.toml"
        cfg.write_text(tomli_w.dumps(vessel_doc(var)))
        for k in range(trials_per_vessel):
            name = f"{var.name}-{k + 1:02d}"
            truth = vessel_doc(var, (1 + var.fouling_per_trial) ** k)
            out.append(write_trial(root / var.name / name, name, cfg, truth, 1000 * i + k,
                                   first + k * spacing, var.origin, rate, rudder))
    return out
