"""Only a dropout of a channel a DOF uses (or of an input) ends its segments and cuts its windows.

A GNSS that drops out for a few seconds every ten (a log rate that aliases the fixes) leaves a yaw
record of gyro, compass and rudder whole; before, every channel's gap ended every DOF's segments and
cut every window, so a ship's yaw windows shrank to seconds and the diagnosis refused the trial
(randomised seed 20, r027) or left yaw out (seed 19, r006).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.diagnose import diagnose
from pipeline.diagnose.problem import build_problems
from pipeline.diagnose.segments import diagnose_segments
from pipeline.flow import load_trial
from pipeline.segment import segment_trial
from pipeline.segment.replay import dof_channels, extend_segments, gaps_of


def _yaw_log(tmp_path, seed: int = 0, delay: float = 0.0, fs: float = 10.0, minutes: float = 12.0,
             t_const: float = 5.0):
    """First-order yaw (K = 0.2 1/s, T = ``t_const`` [s]) driven by rudder steps held 5-8 T; gyro,
    compass and rudder at ``fs`` without a gap, GNSS speed and course missing 3 s of every 10 s."""
    rng = np.random.default_rng(seed)
    n = int(minutes * 60 * fs)
    t = np.arange(n) / fs
    hold = (rng.uniform(5, 8, 400) * t_const * fs).astype(int)
    edges = np.cumsum(hold)
    edges = edges[edges < n]
    levels = rng.choice([-1, 1], len(edges) + 1) * rng.uniform(0.1, 0.3, len(edges) + 1)
    delta = np.repeat(levels, np.diff(np.concatenate([[0], edges, [n]])))
    k = int(round(delay * fs))
    act = np.concatenate([np.full(k, delta[0]), delta[:n - k]]) if k else delta
    r = np.zeros(n)
    for i in range(n - 1):
        r[i + 1] = r[i] + (-r[i] + 0.2 * act[i]) / t_const / fs
    psi = np.angle(np.exp(1j * np.cumsum(r) / fs))
    sog = np.full(n, 3.0) + rng.normal(0, 0.02, n)
    cog = np.angle(np.exp(1j * (psi + rng.normal(0, 0.01, n))))
    out = (t % 10.0) >= 7.0
    sog[out] = np.nan
    cog[out] = np.nan
    path = tmp_path / f"yaw_{seed}_{delay:g}.csv"
    pd.DataFrame({"t": t, "r": r + rng.normal(0, 0.002, n), "psi": psi + rng.normal(0, 0.002, n),
                  "delta": delta, "sog": sog, "cog": cog}).to_csv(path, index=False)
    return load_trial([path])


def test_gnss_gap_does_not_interrupt_yaw_but_its_own_channels(tmp_path):
    trial = _yaw_log(tmp_path)
    assert {g.channel for g in trial.gaps} >= {"sog", "cog"}
    assert not gaps_of(trial, dof_channels(trial, "yaw", ("delta",)))
    # Every gap here is a GNSS gap: it interrupts speed over ground, and the surge speed derived from it.
    assert gaps_of(trial, ("sog",)) == trial.gaps
    assert gaps_of(trial, dof_channels(trial, "surge")) == trial.gaps


def test_yaw_segments_and_windows_run_through_gnss_gaps(tmp_path):
    trial = _yaw_log(tmp_path)
    # Every rudder step is detected, also one made while the GNSS was out (6 of 22 here).
    delta = trial.data["delta"].to_numpy()
    detected = [s for s in segment_trial(trial).items if s.dof == "yaw"]
    assert len(detected) == int(np.sum(np.diff(delta) != 0))
    steps = [s for s in extend_segments(trial, list(detected)) if s.dof == "yaw"]
    # Held 25-40 s: a segment cut at every GNSS gap would last at most 7 s.
    assert steps and max(s.t_end - s.t_start for s in steps) > 15.0
    yaw = next(p for p in build_problems(trial, diagnose_segments(trial)) if p.dof == "yaw")
    assert max(w.t1 - w.t0 for w in yaw.windows) > 10.0


def test_late_rudder_of_a_slow_ship_named_through_gnss_gaps(tmp_path):
    # T = 20 s: windows cut at every GNSS gap (7 s) hold a third of a time constant.
    rep = diagnose(_yaw_log(tmp_path, seed=1, delay=3.0, fs=5.0, minutes=25.0, t_const=20.0))
    assert rep.effect == "actuator_delay" and rep.dof == "yaw"
    tau = {p.name: p.value for p in rep.verdict.params}["tau_d"]
    assert 2.0 < tau < 4.0
