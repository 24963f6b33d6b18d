"""Steady-state maps (pipeline.fit.steady_map): drag curve with uncertainty, config section, joint fit."""

import math

import numpy as np
import pytest

from pipeline.errors import ConfigError, FitError
from pipeline.fit.quadratic import SteadyPoint
from pipeline.fit.steady_map import fit_drag_curve, steady_points
from pipeline.fit.structure import apply_structures
from pipeline.records import Fits
from pipeline.vessel import parse_vessel
from test_fit_structure import M, surge_trial

D1, D2 = 2.86, 12.7


def _points(seed, n=8, se=0.3):
    rng = np.random.default_rng(seed)
    u = np.linspace(0.3, 1.6, n)
    f = D1 * u + D2 * u * u + rng.normal(0, se, n)
    return [SteadyPoint(float(a), float(b), 0.0, se, "test") for a, b in zip(u, f)]


def test_drag_curve_recovers_linear_and_quadratic_terms_with_calibrated_errors():
    hits = 0
    for seed in range(40):
        c = fit_drag_curve(_points(seed))
        hits += abs(c.values[1] + D2) <= 1.96 * c.stderr[1]
    assert 0.85 <= hits / 40 <= 1.0
    c = fit_drag_curve(_points(0))
    assert c.names == ("X_u", "X_|u|u") and c.units == ("kg/s", "kg/m")
    drag, se = c.drag(1.0)
    assert abs(drag - (D1 + D2)) < 4 * se
    lin = fit_drag_curve(_points(0), quadratic=False)
    assert lin.birge > 1.0  # a straight line through a parabola: scatter beyond the errors, errors scaled


def test_config_section_parsed_with_clear_errors():
    v = parse_vessel({"name": "b", "steady_state": {"surge": {"speed": [0.5, 1.0], "force": [4.0, 15.0],
                                                              "force_se": 0.5, "source": "bollard"}}})
    pts = steady_points(v.extra["steady_state"])
    assert [p.speed for p in pts["surge"]] == [0.5, 1.0] and pts["surge"][0].force_se == 0.5
    assert pts["surge"][0].speed_se == 0.0 and pts["surge"][0].source == "bollard"
    with pytest.raises(ConfigError, match="expected a DOF"):
        steady_points({"roll": {"speed": [1.0], "force": [1.0], "force_se": 1.0}})
    with pytest.raises(ConfigError, match="force: expected 2"):
        steady_points({"surge": {"speed": [1.0, 2.0], "force": [1.0], "force_se": 1.0}})
    with pytest.raises(ConfigError, match="unknown key"):
        steady_points({"surge": {"speed": [1.0], "force": [1.0], "force_se": 1.0, "thrust": 2}})
    with pytest.raises(ConfigError, match="force_se > 0"):
        steady_points({"surge": {"speed": [1.0], "force": [1.0], "force_se": 0.0}})
    with pytest.raises(FitError, match="at least 3 steady points"):
        fit_drag_curve(_points(0, n=2))


def test_steady_points_from_the_config_enter_the_joint_fit():
    trial, segs = surge_trial(D1, D2, seed=7, noise=0.03)
    base = {"name": "boat", "rigid_body": {"mass": M, "inertia": [1.0, 1.0, 1.0], "cg": [0, 0, 0]}}
    pts = _points(1, se=0.2)
    table = {"surge": {"speed": [p.speed for p in pts], "force": [p.force for p in pts], "force_se": 0.2}}
    d = np.full((5, 5), np.nan)
    fits = Fits("boat", {}, (), d, d.copy())
    plain = apply_structures(fits, trial, segs.items, parse_vessel(base))
    joint = apply_structures(fits, trial, segs.items, parse_vessel({**base, "steady_state": table}))
    q0 = plain.structures["surge"].fits["quadratic"].terms["X_|u|u"]
    q1 = joint.structures["surge"].fits["quadratic"].terms["X_|u|u"]
    assert abs(q1[0] + D2) < 3 * q1[1]
    assert q1[1] < q0[1]  # the steady points add information on the drag curve
    assert math.isfinite(joint.estimates["X_u"].value)
