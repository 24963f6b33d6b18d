"""The log's timing of the commands: a command sampled by a slower log is recorded late.

A 50 Hz controller's thrust command logged at 2 Hz is written at the first log sample after each
switch, on average a quarter of a second late; held from there, the model's input starts late.
The diagnosis estimates that advance once per DOF (:mod:`pipeline.diagnose.timing`), shared by the
baseline and every candidate; an event log (switches on its own samples) needs none, and a true
actuator delay is still named.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pipeline.diagnose import diagnose
from pipeline.diagnose.problem import build_problems
from pipeline.diagnose.segments import diagnose_segments
from pipeline.diagnose.timing import advance_input, input_timing
from pipeline.flow import load_trial


def test_advance_input_shifts_earlier_and_holds_the_end():
    u = np.array([0.0, 0.0, 1.0, 1.0, 2.0])
    assert np.allclose(advance_input(u, 1.0), [0.0, 1.0, 1.0, 2.0, 2.0])
    assert np.allclose(advance_input(u, 0.5), [0.0, 0.5, 1.0, 1.5, 2.0])
    assert np.allclose(advance_input(u, 0.0), u)


def _surge_log(tmp_path, seed: int, log_hz: float, on_grid: bool, delay: float = 0.0):
    # First-order surge (T = 4 s, gain 0.05 m/s per N), commands held 15-30 s, simulated at 50 Hz.
    rng = np.random.default_rng(seed)
    fs, n = 50.0, int(50.0 * 900)
    step = int(fs / log_hz)
    hold = (rng.uniform(15, 30, 200) * fs).astype(int)
    if on_grid:
        hold = hold // step * step
    edges = np.cumsum(hold)
    edges = edges[edges < n]
    tau = np.repeat(rng.uniform(5, 40, len(edges) + 1), np.diff(np.concatenate([[0], edges, [n]])))
    k = int(round(delay * fs))
    act = np.concatenate([np.full(k, tau[0]), tau[:n - k]]) if k else tau
    u = np.zeros(n)
    for i in range(n - 1):
        u[i + 1] = u[i] + (-u[i] + 0.05 * act[i]) / 4.0 / fs
    sl = slice(0, n, step)
    path = tmp_path / f"surge_{seed}_{log_hz:g}_{on_grid}_{delay:g}.csv"
    t = np.arange(n) / fs
    pd.DataFrame({"t": t[sl], "u": u[sl] + rng.normal(0, 0.005, len(t[sl])), "tau_x": tau[sl]}).to_csv(path, index=False)
    return load_trial([path])


def _advance(trial) -> float:
    segs = diagnose_segments(trial)
    p = build_problems(trial, segs)[0]
    return input_timing(p)[1]


def test_sampled_command_is_advanced_by_about_half_a_log_sample(tmp_path):
    adv = _advance(_surge_log(tmp_path, 0, 2.0, on_grid=False))
    assert 0.1 <= adv <= 0.4


def test_event_logged_command_is_not_advanced(tmp_path):
    assert _advance(_surge_log(tmp_path, 1, 2.0, on_grid=True)) <= 0.1


@pytest.mark.parametrize("on_grid", [False, True])
def test_clean_and_delayed_sampled_commands(tmp_path, on_grid):
    clean = diagnose(_surge_log(tmp_path, 2, 2.0, on_grid))
    assert clean.effect is None and not clean.unexplained
    late = diagnose(_surge_log(tmp_path, 3, 2.0, on_grid, delay=1.0))
    assert late.effect == "actuator_delay"
    tau = {p.name: p.value for p in late.verdict.params}["tau_d"]
    assert 0.4 < tau < 1.2
