"""Inertia coupling of the vessel config: when a one-DOF damping fit is said to be unsure."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.fit.coupling import UNSURE_DELTA, coupling_note, effective_inertia_change
from pipeline.fit.quadratic import DofRecord, fit_dof
from pipeline.model.vessel5dof import simulate_dof
from pipeline.vessel import parse_vessel


def otter_like(xg: float):
    return parse_vessel({"name": "t", "rigid_body": {"mass": 80.0, "inertia": [10.0, 30.0, 30.0], "cg": [xg, 0.0, 0.0]},
                         "added_mass": {"sway": 82.5, "yaw": 10.7},
                         "damping": {"diagonal": [77.0, 162.5, 60.0, 60.0, 42.65]}})


def test_static_bound_and_damped_coupled_dof():
    m = np.diag([10.0, 100.0, 1.0, 1.0, 40.0])
    m[1, 4] = m[4, 1] = 12.0
    undamped, names = effective_inertia_change(m, None, "yaw", 5.0)
    assert names == ["sway"] and undamped == pytest.approx(12.0**2 / (100.0 * 40.0))  # Schur complement
    d = np.diag([1.0, 100.0, 1.0, 1.0, 1.0])  # sway damps at 1/s, yaw moves at 5/s
    damped, _ = effective_inertia_change(m, d, "yaw", 5.0)
    assert damped == pytest.approx(undamped * 5.0 / 6.0)
    held, _ = effective_inertia_change(m, None, "yaw", 5.0, restoring=np.diag([0.0, 1e6, 0, 0, 0]))
    assert held < 0.01 * undamped  # a coupled DOF held by a stiff spring takes no part
    assert effective_inertia_change(m, None, "surge", 5.0) == (0.0, [])


def test_note_only_when_the_config_couples_the_dof():
    t = np.arange(0, 20, 0.05)
    force = np.zeros((2, t.size))
    y = simulate_dof(np.array([0.3, 0.6]), force, 0.05, 1.0, 11.0)
    recs = [DofRecord(f"c{i}", "coast_down", y[i], {}, 0.002, "rate", "r") for i in range(2)]
    coupled, plain = otter_like(0.153), otter_like(0.0)
    fit = fit_dof(recs, "yaw", 0.05, coupled.effective_mass("yaw"), "quadratic")
    note = coupling_note(coupled, "yaw", fit)
    assert note.startswith("unsure: the vessel config couples yaw with sway") and "%" in note
    assert coupling_note(plain, "yaw", fit) == ""
    delta, _ = effective_inertia_change(coupled.mass_matrix(), coupled.damping, "yaw", 1.0 + 11.0 * 0.6)
    assert delta > UNSURE_DELTA
