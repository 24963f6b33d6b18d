"""The held-out floor's replicates start where the model starts and carry the log's timing of the
commands (pipeline.diagnose.floor.replicate_model).

The replicates are the baseline's own outputs plus noise, cross-validated like the trial. Their
measured start values were drawn around each window's first block mean; at a slow log rate a window
that opens with a transient has a first block mean far from its start, and the replicates' fits were
pulled off the model they were made from (randomised seed 42 r013, AAUSHIP's yaw at 2.1 Hz: a floor
of 8.8 noise units in r, 1.1 once started at the model's initial states). What that bias stood in for
by chance is the log's own timing: a command sampled by the log switched anywhere within the interval
before the sample that records it, and a correct model on a clean trial leaves that misfit (seed 28
r005, a clean AAUSHIP at 1.75 Hz: yaw gaps of 11.7 and 28.1 noise units).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest

from pipeline.diagnose import significance as sig
from pipeline.diagnose.candidates import Candidate
from pipeline.diagnose.crossval import cross_validate
from pipeline.diagnose.floor import heldout_floor, jittered, replicate_model
from pipeline.diagnose.gridfit import grid_data, initial_states
from pipeline.diagnose.problem import build_problems
from pipeline.diagnose.segments import diagnose_segments
from pipeline.diagnose.timing import advance_input, input_timing
from pipeline.diagnose.verdict import _refine_time_constants
from pipeline.flow import load_trial
from test_diagnose_benchmark_signature import _bench


def random_problem(seed: int, n: int, kinds: tuple[str, ...], index: int, dof: str = "yaw"):
    """A randomised benchmark trial's ``dof`` problem as the diagnosis builds it (before its log
    timing), with the trial's truth."""
    b = _bench()
    case = b.random_cases(n, seed, kinds)[index]
    with tempfile.TemporaryDirectory() as tmp:
        files, vessel, truth = b.make_random_trial(case, Path(tmp))
        vessel = b.stated_noise(case, truth, vessel)
        trial = load_trial(files, vessel)
    segs = diagnose_segments(trial)
    return truth, next(q for q in build_problems(trial, segs, vessel,
                                                 time_constants=_refine_time_constants(trial, segs, vessel))
                       if q.dof == dof)


def _yaw(seed: int, n: int, kinds: tuple[str, ...], index: int):
    """A randomised trial's yaw problem as the diagnosis builds it: the problem with its log timing, the
    inputs as logged, the advance [samples], the data and the baseline's run and outputs."""
    truth, p0 = random_problem(seed, n, kinds, index)
    p, adv = input_timing(p0)
    d = grid_data(p)
    base = cross_validate(p, d, [Candidate(p, d)])[0]
    full = base.candidate.simulate(base.full, np.arange(len(p.windows)))
    return truth, p, {c: p0.raw[c] for c in p0.inputs}, adv * p.fs, d, base, full


def test_a_jittered_switch_lands_within_half_a_sample_of_the_advanced_one():
    u = np.r_[np.zeros(10), np.ones(10), 3 * np.ones(10)]
    rng = np.random.default_rng(0)
    for _ in range(50):
        j = jittered(u, 0.3, rng)
        # Each switch keeps its height and moves as a whole: the area under the input changes by the
        # shift times the height, at most (0.3 + 0.5) samples each.
        shift = (j.sum() - u.sum())
        assert 1 * (0.3 - 0.5) + 2 * (0.3 - 0.5) - 1e-9 <= shift <= 1 * 0.8 + 2 * 0.8 + 1e-9
        assert j[0] == 0 and j[-1] == 3 and np.all(np.diff(j) >= 0)
    # Without jitter it is the log-timing advance itself.
    class OnTime:
        def uniform(self, lo, hi, n):
            return np.zeros(n)

    assert np.allclose(jittered(u, 0.3, OnTime()), advance_input(u, 0.3))
    assert np.allclose(jittered(u, 1.0, OnTime()), advance_input(u, 1.0))


@pytest.fixture(scope="module")
def coupled_slow_yaw():
    return _yaw(42, 16, ("pair",), 13)


@pytest.mark.slow
def test_the_replicates_start_at_the_models_initial_states(coupled_slow_yaw):
    truth, p, logged, adv, d, base, full = coupled_slow_yaw
    assert truth["vessel"] == "aauship" and truth["log_rate_hz"] < 2.5 and truth["noise_stated"]
    spec, theta = base.full.state
    model = replicate_model(base)
    assert model is not None and model.logged is None
    assert np.allclose(model.x0, initial_states(d, spec, base.full.params["T"], theta))
    # The first block means are not the start: at 2.1 Hz one analysis step is a log sample, a ninth of
    # the time constant, and several windows open with a rudder or thrust switch.
    first = full["y"][np.arange(len(model.x0)), np.argmax(d.mask, axis=1)]
    assert np.max(np.abs(first - model.x0)) / d.sigma_y > 20
    # Started there, replicates of the model on time leave about the noise; started at the first block
    # means (before), several times that.
    assert heldout_floor(p, d, full, replicates=2, model=model)["r"] < 2.0
    assert heldout_floor(p, d, full, replicates=2)["r"] > 5.0


@pytest.mark.slow
def test_a_clean_slow_log_is_at_its_floor_with_the_logs_timing():
    # Slow (10-15 s each, under load): a randomised trial built as the diagnosis builds it.
    truth, p, logged, adv, d, base, full = _yaw(28, 18, ("clean",), 5)
    assert truth["effects"] == [] and truth["log_rate_hz"] < 2.0 and adv > 0
    gaps = {c.channel: c.gap_before for c in sig.score(d, base.heldout, base.heldout, 1, {"y": "r", "angle": "psi"}).channels}
    on_time = heldout_floor(p, d, full, replicates=2, model=replicate_model(base))
    sampled = heldout_floor(p, d, full, replicates=2, model=replicate_model(base, logged, adv))
    assert gaps["r"] > 8 and gaps["psi"] > 20          # a clean trial, far above the sensor noise
    assert on_time["r"] < 2.0 and on_time["psi"] < 3.0    # the dynamics alone leave about the noise
    for ch in ("r", "psi"):                              # the log's timing leaves the rest
        assert gaps[ch] < 1.5 * sampled[ch]
        assert sampled[ch] == pytest.approx(gaps[ch], rel=0.35)
