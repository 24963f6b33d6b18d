"""Superposition across K and T, tested with the user's path (CSV -> segments -> fits) on a simulated
Norrbin ship: when rudder steps into a turn and back out of it break superposition in T, K is an
effective value at the steps' amplitude too and must not be marked success."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.fit import fit_trial
from pipeline.flow import load_trial
from pipeline.model.nomoto import NomotoParams, nomoto_rhs
from pipeline.segment import detect_segments
from pipeline.vessel import parse_vessel

K, T = 0.08, 20.0            # PythonVehicleSimulator's frigate at 6 m/s
HOLD, FS, H = 150.0, 5.0, 0.05
RATE = math.radians(5.0)     # rudder rate [rad/s]


def _log(n3: float, seed: int) -> np.ndarray:
    """Equal 10 deg steps 0, +10, 0, -10, ... held 150 s, Norrbin's ``n3`` [s^2/rad^2], 5 Hz with sensor noise."""
    a = math.radians(10.0)
    pattern = [0.0, a, 0.0, -a, 0.0, a, 0.0, -a, 0.0]
    p = NomotoParams(K=K, T=T, n3=n3)
    x, d, rows = np.zeros(2), 0.0, []
    every = int(round(1 / (FS * H)))
    for k in range(int(HOLD * len(pattern) / H) + 1):
        t = k * H
        if k % every == 0:
            rows.append((t, x[0], x[1], d))
        target = pattern[min(int(t // HOLD), len(pattern) - 1)]
        d += float(np.clip(target - d, -RATE * H, RATE * H))
        k1 = nomoto_rhs(0, x, (d,), p)
        k2 = nomoto_rhs(0, x + H / 2 * k1, (d,), p)
        k3 = nomoto_rhs(0, x + H / 2 * k2, (d,), p)
        k4 = nomoto_rhs(0, x + H * k3, (d,), p)
        x = x + H / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    t, psi, r, delta = np.array(rows).T
    rng = np.random.default_rng(seed)
    psi = psi + math.radians(0.2) * rng.standard_normal(t.size)
    r = r + math.radians(0.05) * rng.standard_normal(t.size)
    delta = delta + math.radians(0.1) * rng.standard_normal(t.size)
    psi = (psi + math.pi) % (2 * math.pi) - math.pi
    return np.column_stack([t, psi, r, np.full(t.size, 6.0), delta])


def _estimates(n3: float, seed: int, tmp_path):
    path = tmp_path / f"steps_{n3:g}_{seed}.csv"
    np.savetxt(path, _log(n3, seed), delimiter=",", header="t,psi,r,u,delta", comments="", fmt="%.9g")
    trial = load_trial([path])
    return fit_trial(trial, detect_segments(trial), parse_vessel({"name": "norrbin"}), extend=False).estimates


@pytest.mark.parametrize("seed", [0])
def test_k_of_a_norrbin_ship_is_unsure_when_t_breaks_superposition(seed, tmp_path):
    est = _estimates(150.0, seed, tmp_path)
    k, t = est["K_nomoto"], est["T_nomoto"]
    # T: steps into a turn against steps out of one (the ship's own test); K the same both ways.
    assert not t.success and "rudder steps into a turn give T" in t.message, t.message
    # K is 2-3 % low (the cubic term cuts the 10 deg turn rate) with an interval that misses.
    assert -0.04 < (k.value - K) / K < -0.015, k.value
    assert not k.success, k.message
    assert k.message.startswith("unsure: nonlinear: K is an effective value at the steps' amplitude"), k.message


def test_k_and_t_of_the_linear_ship_stay_success(tmp_path):
    est = _estimates(0.0, 0, tmp_path)
    k, t = est["K_nomoto"], est["T_nomoto"]
    assert k.success and t.success, (k.message, t.message)
    assert abs(k.value - K) < 3 * k.stderr and abs(t.value - T) < 3 * t.stderr
    assert "unsure" not in k.message and "unsure" not in t.message
