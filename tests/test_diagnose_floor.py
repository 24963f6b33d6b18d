"""The held-out floor: the gap a correct model leaves once its parameters carry training noise.

A clean Nomoto ship (T = 22 s) logged at 10 Hz has a held-out heading gap of about 7 compass-noise
units at every noise level: the heading integrates the fold fits' gain error over one-minute
windows. Before the floor, a clean trial at high noise reported that heading as "unexplained".
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from diagnose_synthetic import simulated_trial
from pipeline.diagnose import diagnose
from pipeline.diagnose.candidates import Candidate
from pipeline.diagnose.crossval import cross_validate
from pipeline.diagnose.floor import heldout_floor, heldout_floors
from pipeline.diagnose.gridfit import grid_data
from pipeline.diagnose.problem import build_problems
from pipeline.diagnose.segments import diagnose_segments
from pipeline.diagnose import significance as sig
from pipeline.sim import Effects, sea_trial
from pipeline.vessel import parse_vessel


@pytest.fixture(scope="module")
def clean_slow_ship(tmp_path_factory):
    v = parse_vessel({"name": "ship", "nomoto": {"K": 0.1, "T": 22.0}})
    trial, _ = simulated_trial(v, sea_trial(v), Effects(), tmp_path_factory.mktemp("floor"), "ship", noise="high",
                               seed=3, dt=0.1, rate=10.0)
    return v, trial


def _yaw_baseline(v, trial, segments):
    """The yaw problem, its data and its baseline's outputs on every window."""
    p = next(q for q in build_problems(trial, segments, v, time_constants={"yaw": 22.0}) if q.dof == "yaw")
    d = grid_data(p)
    base = cross_validate(p, d, [Candidate(p, d)])[0]
    return p, d, base, base.candidate.simulate(base.full, np.arange(len(p.windows)))


def test_floor_predicts_the_clean_heldout_gap(clean_slow_ship):
    v, trial = clean_slow_ship
    p, d, base, full = _yaw_baseline(v, trial, diagnose_segments(trial))
    gaps = {c.channel: c.gap_before for c in sig.score(d, base.heldout, base.heldout, 1, {"y": "r", "angle": "psi"}).channels}
    floor = heldout_floor(p, d, full)
    assert gaps["psi"] > 3.0          # far above the compass noise, with no model error at all
    assert floor["psi"] == pytest.approx(gaps["psi"], rel=0.35)
    assert floor["r"] == pytest.approx(gaps["r"], rel=0.25)


def test_floors_of_several_dofs_in_one_call_are_each_dofs_own_floor(clean_slow_ship):
    # heldout_floors runs every DOF's replicates in one ordered_map (the diagnosis's noise floors),
    # the largest first; each DOF's floor must be the one heldout_floor finds for it alone.
    v, trial = clean_slow_ship
    segs = diagnose_segments(trial)
    small = _yaw_baseline(v, trial, replace(segs, items=segs.items[: len(segs.items) // 2]))
    large = _yaw_baseline(v, trial, segs)
    assert small[1].y.size < large[1].y.size          # the call reorders its units
    alone = [heldout_floor(p, d, full, replicates=2) for p, d, _, full in (small, large)]
    together = heldout_floors([(small[0], small[1], small[3]), (large[0], large[1], None),
                               (large[0], large[1], large[3])], replicates=2)
    assert set(alone[0]) == set(alone[1]) == {"r", "psi"}
    assert alone[0] != alone[1]
    assert together == [alone[0], {}, alone[1]]


@pytest.mark.slow
def test_clean_slow_ship_has_nothing_unexplained(clean_slow_ship):
    # Slow (a whole diagnosis, about 20 s); the floor itself is guarded by the test above.
    v, trial = clean_slow_ship
    rep = diagnose(trial, v)
    assert rep.effect is None
    assert not rep.unexplained
    yaw = next(dd for dd in rep.dofs if dd.dof == "yaw")
    assert yaw.heldout_floor["psi"] > 3.0
