"""A trial diagnosed on another trial's frame (:mod:`pipeline.diagnose.frame`): the windows, analysis step,
input timing and noise units of each DOF are those of the other trial, so that two trials of one schedule
and log differ in their diagnoses by what differs in their data, not by how each was cut."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.diagnose import diagnose
from pipeline.diagnose.frame import diagnosis_frame, on_frame
from pipeline.diagnose.gridfit import grid_data
from pipeline.diagnose.problem import build_problems
from pipeline.diagnose.segments import diagnose_segments
from pipeline.diagnose.timing import advance_input

from test_diagnose_timing import _surge_log


def _surge(trial):
    return next(p for p in build_problems(trial, diagnose_segments(trial)) if p.dof == "surge")


def test_a_problem_on_another_trials_frame_takes_its_windows_step_timing_and_noise(tmp_path):
    # One schedule and noise draw (seed 5) logged at 2 Hz, without and with a 0.6 s thrust delay.
    a = _surge_log(tmp_path, 5, 2.0, False)
    b = _surge_log(tmp_path, 5, 2.0, False, delay=0.6)
    f = diagnosis_frame(a)["surge"]
    own = _surge(b)
    pb = on_frame(own, f)
    assert pb.windows == f.windows and pb.m == f.m and pb.t_guess == f.t_guess
    assert pb.dt == pytest.approx(f.m / pb.fs)
    # The sampled command is advanced by the frame's timing (a 2 Hz log: about half a sample).
    assert f.advance > 0
    assert np.allclose(pb.raw["tau_x"], advance_input(own.raw["tau_x"], f.advance * own.fs))
    # The noise unit is the frame's, not the one measured on the trial's own data.
    assert grid_data(pb).sigma_y == f.noise_unit["u"]
    assert grid_data(own).sigma_y != f.noise_unit["u"]
    # Without a frame the problem measures its noise as before.
    assert own.noise_unit == {}


def test_a_frame_of_a_longer_log_is_refused_with_a_clear_message(tmp_path):
    a = _surge_log(tmp_path, 5, 2.0, False)
    f = diagnosis_frame(a)["surge"]
    p = _surge(a)
    short = {k: v[:len(v) // 2] for k, v in p.raw.items()}
    from dataclasses import replace
    with pytest.raises(ValueError, match="expected a frame of a trial of"):
        on_frame(replace(p, raw=short), f)


@pytest.mark.slow
def test_a_trial_diagnosed_on_its_own_frame_is_diagnosed_as_without_it(tmp_path):
    # Slow: four surge diagnoses (85 s under load).
    # The frame is what the diagnosis uses, so passing the trial's own frame changes nothing; another
    # trial's frame gives the frame's windows and noise unit.
    a = _surge_log(tmp_path, 7, 2.0, False)
    b = _surge_log(tmp_path, 7, 2.0, False, delay=0.6)
    plain = diagnose(a)
    fa = diagnosis_frame(a)
    same = diagnose(a, frame=fa)
    assert [d.gap for d in same.dofs] == pytest.approx([d.gap for d in plain.dofs], rel=1e-9)
    assert [e.label for e in same.effects] == [e.label for e in plain.effects]
    fb = diagnosis_frame(b)
    on_b = diagnose(a, frame=fb)
    s = next(d for d in on_b.dofs if d.dof == "surge")
    assert s.n_windows == len(fb["surge"].windows)
    assert s.noise_floor == fb["surge"].noise_unit["u"]
