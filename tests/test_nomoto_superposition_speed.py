"""A superposition break caused by the ship's speed changing in its turns is reported as such.

PythonVehicleSimulator's Clarke83 ship speeds up by 2.9 % in its 10 deg turns (its surge settles at a time
constant of its length in seconds), and its steps into a turn give T 18-27 % above the steps out of one
(noise-free), so the combined T is rightly unsure; the reason named only "a nonlinearity, or an estimator
bias". Here a first-order Nomoto ship whose K and T scale with a speed that rises with the rudder (K = K0 U /
U0, T = T0 U0 / U; the speed settles at 60 s towards U0 (1 + 0.3 sin^2 delta)), logged with its speed, through
the user's path (CSV -> segments -> fits): its steps are candidates for the re-timing on the distance sailed, which
their held-out ends cannot decide at 3 % (ident40), so T is unsure with the speed clause; a ship of constant speed (Norrbin's cubic term instead) must not get the clause that
names a logged speed change.
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.fit import fit_trial
from pipeline.flow import load_trial
from pipeline.model.nomoto import NomotoParams, nomoto_rhs
from pipeline.segment import detect_segments
from pipeline.vessel import parse_vessel

K0, T0, U0 = 0.08, 20.0, 6.0
HOLD, FS, H = 150.0, 5.0, 0.05
RATE = math.radians(5.0)     # rudder rate [rad/s]
T_SURGE = 60.0               # the speed's time constant [s]


def _log(speed_gain: float, n3: float, seed: int, pattern_deg=(0, 10, 0, -10, 0, 5, 0)) -> np.ndarray:
    """Rudder steps (``pattern_deg``) held 150 s at 5 Hz with sensor noise; the speed settles towards
    ``U0 (1 + speed_gain sin^2 delta)`` and scales K and T; ``n3`` Norrbin's cubic term [s^2/rad^2]."""
    pattern = [math.radians(p) for p in pattern_deg]
    x, u, d, rows = np.zeros(2), U0, 0.0, []
    every = int(round(1 / (FS * H)))
    for k in range(int(HOLD * len(pattern) / H) + 1):
        t = k * H
        if k % every == 0:
            rows.append((t, x[0], x[1], u, d))
        target = pattern[min(int(t // HOLD), len(pattern) - 1)]
        d += float(np.clip(target - d, -RATE * H, RATE * H))
        p = NomotoParams(K=K0 * u / U0, T=T0 * U0 / u, n3=n3)
        k1 = nomoto_rhs(0, x, (d,), p)
        k2 = nomoto_rhs(0, x + H / 2 * k1, (d,), p)
        k3 = nomoto_rhs(0, x + H / 2 * k2, (d,), p)
        k4 = nomoto_rhs(0, x + H * k3, (d,), p)
        x = x + H / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        u += H * (U0 * (1.0 + speed_gain * math.sin(d) ** 2) - u) / T_SURGE
    t, psi, r, u, delta = np.array(rows).T
    rng = np.random.default_rng(seed)
    psi = psi + math.radians(0.2) * rng.standard_normal(t.size)
    r = r + math.radians(0.05) * rng.standard_normal(t.size)
    u = u + 0.01 * rng.standard_normal(t.size)
    delta = delta + math.radians(0.1) * rng.standard_normal(t.size)
    psi = (psi + math.pi) % (2 * math.pi) - math.pi
    return np.column_stack([t, psi, r, u, delta])


def _estimates(speed_gain: float, n3: float, tmp_path, **kw):
    path = tmp_path / f"steps_{speed_gain:g}_{n3:g}.csv"
    np.savetxt(path, _log(speed_gain, n3, 0, **kw), delimiter=",", header="t,psi,r,u,delta", comments="", fmt="%.9g")
    trial = load_trial([path])
    return fit_trial(trial, detect_segments(trial), parse_vessel({"name": "speedy"}), extend=False).estimates


def test_a_speed_change_in_the_turns_the_held_out_end_cannot_judge_is_not_hidden(tmp_path):
    # ident38 re-timed these steps because their speed rises (by up to 3 %); ident40 lets each step's held-out
    # yaw rate choose (tests/test_nomoto_retime_choice.py), which at 3 % decides nothing: the steps stay at
    # constant speed with the difference as a term, and T is unsure by the steps' superposition, the clause naming
    # the logged speed change (as before ident38). Nothing marked success misses its interval.
    est = _estimates(1.0, 0.0, tmp_path)
    t, k = est["T_nomoto"], est["K_nomoto"]
    for e, ref in ((t, T0), (k, K0)):
        assert not e.success or e.ci95[0] <= ref <= e.ci95[1], e.message
    assert not t.success and "logged speed" in t.message, t.message
    assert "re-timing term" in t.message or "re-timing term" in k.message, (t.message, k.message)


def test_a_ship_of_constant_speed_gets_no_speed_clause(tmp_path):
    # Norrbin's cubic term breaks superposition in T on equal 10 deg steps (tests/test_nomoto_quality_superposition.py).
    est = _estimates(0.0, 150.0, tmp_path, pattern_deg=(0, 10, 0, -10, 0, 10, 0, -10, 0))
    t = est["T_nomoto"]
    assert not t.success and "rudder steps into a turn give T" in t.message, t.message
    assert "logged speed" not in t.message and "logged speed" not in est["K_nomoto"].message
