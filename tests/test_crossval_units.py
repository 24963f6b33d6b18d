"""The cross-validation's folds as independent units (pipeline.parallel workers): the same runs as one loop."""

from __future__ import annotations

import numpy as np
import pytest

from diagnose_synthetic import simulated_trial
from pipeline.diagnose.candidates import candidates_for
from pipeline.diagnose.crossval import assign_folds, cross_validate, cross_validate_all, supported
from pipeline.diagnose.gridfit import grid_data
from pipeline.diagnose.problem import build_problems
from pipeline.diagnose.segments import diagnose_segments
from pipeline.sim import Effects, sea_trial
from pipeline.vessel import parse_vessel


@pytest.fixture(scope="module")
def yaw_problem(tmp_path_factory):
    v = parse_vessel({"name": "ship", "nomoto": {"K": 0.1, "T": 8.0}})
    trial, _ = simulated_trial(v, sea_trial(v), Effects(actuator_delay=0.4), tmp_path_factory.mktemp("cvu"), "ship",
                               seed=4, dt=0.1, rate=10.0)
    p = next(q for q in build_problems(trial, diagnose_segments(trial), v, time_constants={"yaw": 8.0})
             if q.dof == "yaw")
    d = grid_data(p)
    return p, d, candidates_for(p, d)[:3]


def _key(runs):
    return [(r.label, tuple(sorted(r.full.params.items())), [tuple(sorted(f.items())) for f in r.fold_params],
             {k: v.tobytes() for k, v in r.heldout.items()}, r.fold_of.tobytes()) for r in runs]


def test_folds_in_workers_equal_one_loop(yaw_problem):
    p, d, cs = yaw_problem
    ticks = []
    serial = cross_validate(p, d, cs, jobs=1)
    spread = cross_validate_all([p], [d], [cs], tick=lambda: ticks.append(1), jobs=2)[0]
    assert len(serial) == len(cs) >= 2
    assert _key(serial) == _key(spread)          # bit for bit
    folds = assign_folds(p)
    assert len(ticks) == int(folds.max()) + 2    # one per fold and one for the fits on every window


def test_a_fold_unit_is_the_baseline_fitted_without_its_windows(yaw_problem):
    p, d, cs = yaw_problem
    base = cross_validate(p, d, cs[:1], jobs=2)[0]
    folds = assign_folds(p)
    train, test = np.flatnonzero(folds != 0), np.flatnonzero(folds == 0)
    test = test[supported(p, train, test)]
    fitted = cs[0].fit(train)
    assert base.fold_params[0] == dict(fitted.params)
    np.testing.assert_array_equal(base.heldout["y"][test], cs[0].simulate(fitted, test)["y"])
    everything = cs[0].fit(np.arange(len(p.windows)))
    assert dict(base.full.params) == dict(everything.params)
