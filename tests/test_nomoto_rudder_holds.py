"""A measured rudder hold broken by one noise spike stays one hold: the step's window runs on to the
next real rudder change (seen on a PythonVehicleSimulator Clarke83 log: a 81 s step cut to 22 s)."""

from __future__ import annotations

import math

import numpy as np

from pipeline.segment.rudder import classify_changes, find_holds

FS = 5.0


def _measured(levels_deg, hold_s, spike_at=None, seed=0):
    rng = np.random.default_rng(seed)
    u = np.concatenate([np.full(int(hold_s * FS), math.radians(v)) for v in levels_deg])
    u = u + math.radians(0.1) * rng.standard_normal(u.size)
    if spike_at is not None:
        u[int(spike_at * FS)] += math.radians(1.0)
    return u


def test_noise_spike_does_not_end_a_hold():
    u = _measured([0, 10, 0], 80.0, spike_at=102.0)
    holds = find_holds(u, FS, math.radians(0.1))
    assert len(holds) >= 4                       # the spike splits the 10 deg hold ...
    steps, varying = classify_changes(holds, FS, math.radians(2.0))
    assert len(steps) == 2 and not varying
    first = steps[0]
    # ... but the step's hold after the change runs to the next change at 160 s, not to the spike.
    assert first.after.i_end / FS > 155.0
    assert abs(first.size - math.radians(10.0)) < math.radians(0.1)
    assert steps[1].before == first.after


def test_without_spike_the_holds_are_unchanged():
    u = _measured([0, 10, 0], 80.0)
    steps, _ = classify_changes(find_holds(u, FS, math.radians(0.1)), FS, math.radians(2.0))
    assert len(steps) == 2 and steps[0].after.i_end / FS > 155.0


def test_noise_free_record_is_a_command():
    from pipeline.segment.rudder import is_command_like, is_noise_free

    t = np.arange(0.0, 235.0, 1 / FS)
    sine = math.radians(10.0) * np.sin(0.08 * t)          # a logged, computed command
    assert is_noise_free(sine) and not is_command_like(sine)
    noisy = sine + math.radians(0.1) * np.random.default_rng(1).standard_normal(t.size)
    assert not is_noise_free(noisy)                        # a rudder angle sensor's record
