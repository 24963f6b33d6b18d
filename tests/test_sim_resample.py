"""sim.resample: the same truth with another seed's sensor noise equals a fresh simulation."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.sim import chain, simulate, step_and_coast
from pipeline.sim.simulate import resample
from pipeline.vessel import load_vessel

VESSEL = Path(__file__).resolve().parents[1] / "vessel_configs" / "aauship.toml"


def test_resample_equals_fresh_simulation():
    v = load_vessel(VESSEL)
    sched = chain(step_and_coast("surge", 5.0, 4.0, 4.0), rest_s=2.0)
    a = simulate(v, sched, seed=0)
    b = simulate(v, sched, seed=7)
    c = resample(a, 7)
    assert c.seed == 7 and set(c.log.channels) == set(b.log.channels)
    for name, ch in b.log.channels.items():
        assert np.array_equal(ch.values, c.log.channels[name].values, equal_nan=True), name
    assert not np.array_equal(a.log.channels["sog"].values, c.log.channels["sog"].values)
