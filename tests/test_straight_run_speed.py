"""The straight run a trial opens with (``nomoto_segment.straight_run_speed``): its length is judged to within the
sample interval in which the rudder moved.

The CSV loader rebuilds a log's clock as ``t0 + i / fs`` with the sample rate it reads from the file; on
PythonVehicleSimulator's commanded zig-zags (benchmarks/independent.py, rudder commanded at t = 30.0 s) ``fs``
came out 5.000000000000018 Hz and the move a float hair under 30 s, so a straight run as long as
``RETIME_LEAD_SECONDS`` was rejected as shorter. The rudder moved somewhere in the interval before the first
sample that shows it, so the run's length is known to within one interval: a run is too short only when it falls
short by more than half of one.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from pipeline.fit.nomoto_segment import RETIME_LEAD_SECONDS, straight_run_speed
from pipeline.records import Trial

#: The sample rate the loader read from a benchmark log written at 5 Hz [Hz].
FS_READ = 5.000000000000018


def _trial(move_at: float, fs: float = FS_READ, duration: float = 200.0) -> Trial:
    """A log at ``fs`` whose rudder goes to 10 deg at the first sample at or after ``move_at`` [s] (to within a
    microsecond) after a straight run at 3.26 m/s; the speed falls 1 % in the turn."""
    t = np.arange(int(round(duration * fs))) / fs
    turn = t >= move_at - 1e-6
    r = np.where(turn, 0.01, 0.0)
    data = pd.DataFrame({"t": t, "psi": np.cumsum(r) / fs, "r": r, "u": np.where(turn, 3.2274, 3.26),
                         "delta": np.where(turn, math.radians(10.0), 0.0)})
    return Trial("ship", data, fs)


def test_a_run_of_exactly_the_lead_length_is_taken_on_a_clock_a_hair_short():
    trial = _trial(RETIME_LEAD_SECONDS)
    t = np.asarray(trial.t, float)
    first = float(t[np.flatnonzero(trial.data["delta"].to_numpy() > 0)[0]])
    assert RETIME_LEAD_SECONDS - 1e-9 < first < RETIME_LEAD_SECONDS  # the hair
    ref = straight_run_speed(trial)
    assert ref is not None, "a 30 s straight run was rejected as shorter than 30 s"
    ch, u0, lead = ref
    assert ch == "u" and u0 == pytest.approx(3.26) and lead == pytest.approx(RETIME_LEAD_SECONDS, abs=1e-6)
    # The same run on an exact clock (10 Hz: the move at sample 300, 30.0 s to the last bit).
    assert straight_run_speed(_trial(RETIME_LEAD_SECONDS, fs=10.0)) is not None


def test_a_run_shorter_than_the_lead_by_more_than_half_a_sample_is_not():
    # One sample (0.2 s at 5 Hz, twice the tolerance) and 2 s short: too short, whatever the clock's last bits.
    for short in (0.2, 2.0):
        assert straight_run_speed(_trial(RETIME_LEAD_SECONDS - short)) is None, short
        assert straight_run_speed(_trial(RETIME_LEAD_SECONDS - short, fs=5.0)) is None, short
    # The tolerance is half the sample interval, not a fixed epsilon: at 2 Hz a move one interval (0.5 s) early is
    # short, one a hair late on a clock read a hair fast is not.
    assert straight_run_speed(_trial(RETIME_LEAD_SECONDS - 0.5, fs=2.0, duration=400.0)) is None
    assert straight_run_speed(_trial(RETIME_LEAD_SECONDS, fs=2.0 * (1 + 1e-14), duration=400.0)) is not None
