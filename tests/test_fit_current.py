"""A damping fit on speed over ground says when a current, not the damping structure, is the misfit."""

from __future__ import annotations

from pathlib import Path

from pipeline.align.align import align
from pipeline.fit.structure import select_structures
from pipeline.sim import Effects, chain, simulate, step_and_coast
from pipeline.vessel import load_vessel

VESSEL = Path(__file__).resolve().parents[1] / "vessel_configs" / "aauship.toml"


def surge_choice(current):
    v = load_vessel(VESSEL)
    sched = chain(step_and_coast("surge", 4.0, 8.0, 8.0), step_and_coast("surge", 8.0, 8.0, 8.0), rest_s=3.0)
    res = simulate(v, sched, Effects(current=current), seed=3)
    trial = align([res.log], vessel=v)
    segs = [s for s in res.segments.items if s.dof == "surge"]
    return select_structures(trial, segs, v)["surge"]


def test_current_along_the_track_is_named():
    msg = surge_choice((0.3, 0.0)).message
    assert "unsure: the surge speed is over ground, and a constant current along the track" in msg, msg


def test_no_current_no_note():
    msg = surge_choice((0.0, 0.0)).message
    assert "current along the track" not in msg, msg
    # The simulated record is what the model describes: no misfit at the segment starts either.
    assert "of the surge segments holds" not in msg, msg
