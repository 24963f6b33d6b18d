"""The diagnosis's segments: the segment stage's detection (passed in by the flow, or run here) plus
the replay segments the detector cannot see."""

from __future__ import annotations

from dataclasses import replace

from diagnose_synthetic import simulated_trial
from pipeline.diagnose.segments import diagnose_segments
from pipeline.segment import segment_trial
from pipeline.sim import Effects, sea_trial
from pipeline.vessel import parse_vessel


def test_passed_detection_is_used_and_equals_detecting_again(tmp_path):
    v = parse_vessel({"name": "ship", "nomoto": {"K": 0.1, "T": 8.0}})
    trial, _ = simulated_trial(v, sea_trial(v), Effects(), tmp_path, "ship", seed=1, dt=0.1, rate=10.0)
    detected = segment_trial(trial)
    assert detected.items
    # The flow's segment stage (no manifest segments) hands over what the diagnosis would detect.
    assert diagnose_segments(trial, detected) == diagnose_segments(trial)
    # And the diagnosis uses what it is handed, not a detection of its own.
    fewer = replace(detected, items=detected.items[1:])
    dropped = detected.items[0]
    assert all((s.t_start, s.dof) != (dropped.t_start, dropped.dof) for s in diagnose_segments(trial, fewer).items)
