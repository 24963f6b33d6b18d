"""Thruster maps (pipeline.fit.thrusters) and added mass from thrust steps (pipeline.fit.added_mass):
the [thrusters] schema is validated with clear errors, a linear gain and a bollard-pull table map
commands to thrust, and a simulated vessel's [added_mass] is recovered within 3 sigma."""

from __future__ import annotations

import inspect
import math
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from pipeline.align import align
from pipeline.errors import ConfigError, FitError
from pipeline.fit import fit_trial
from pipeline.fit.added_mass import effective_mass_from_step, fit_added_mass
from pipeline.fit.extend import extend_fits
from pipeline.fit.thrusters import ThrusterMap, parse_thrusters
from pipeline.records import Trial
from pipeline.sim import chain, simulate, step_and_coast
from pipeline.sim.sensors import default_sensors
from pipeline.vessel import parse_vessel

def single_dof_fits(trial, segments, vessel):
    """fit_trial without the joint extension (whether or not fit_trial already runs extend_fits)."""
    if "extend" in inspect.signature(fit_trial).parameters:
        return fit_trial(trial, segments, vessel, extend=False)
    return fit_trial(trial, segments, vessel)


# A bollard-pull style table: command [%] -> thrust [N], convex like a propeller's.
TABLE = [[0.0, 0.0], [20.0, 1.0], [40.0, 2.5], [60.0, 4.5], [80.0, 7.0], [100.0, 10.0]]
DOC = {"name": "aauship-am", "rigid_body": {"mass": 13.0, "inertia": [0.0654, 1.089, 1.107]},
       "restoring": {"roll": 6.97, "pitch": 131.8},
       "added_mass": {"surge": 3.0, "yaw": 0.2},
       "damping": {"diagonal": [2.86, 32.5, 0.1094, 7.203, 0.26285]}}
SENSORS = tuple(replace(s, rate=min(s.rate, 50.0)) for s in default_sensors())


# --------------------------------------------------------------------------- schema
def test_linear_gain_with_offset_and_table_maps():
    maps = parse_thrusters({"surge": {"gain": 0.2746, "offset": 97.7, "input": "tau_x"},
                            "yaw": {"table": [[-1, -0.5], [0, 0], [1, 0.4]], "input": "tau_n", "relative_stderr": 0.1}})
    assert maps["surge"].kind == "gain" and maps["surge"].thrust(197.7) == pytest.approx(27.46)
    assert maps["yaw"].kind == "table" and maps["yaw"].unit == "N m"
    assert np.allclose(maps["yaw"].thrust([-0.5, 0.5]), [-0.25, 0.2])
    assert maps["yaw"].relative_stderr == 0.1
    assert "table of 3 points" in maps["yaw"].describe() and "gain" in maps["surge"].describe()
    # The input defaults to the DOF's generalised force channel.
    assert parse_thrusters({"sway": {"gain": 1.0}})["sway"].input == "tau_y"
    assert parse_thrusters(None) == {} and parse_thrusters({}) == {}


def test_table_refuses_commands_outside_its_range():
    m = ThrusterMap("surge", "tau_x", table=((60.0, 0.0), (180.0, 36.0)))
    with pytest.raises(FitError, match=r"within the table's range \[60, 180\], found 50 to 200"):
        m.thrust(np.array([50.0, 100.0, 200.0]))


@pytest.mark.parametrize("section, match", [
    ({"heave": {"gain": 1.0}}, r"unknown DOF 'heave'; expected one of \['surge', 'sway', 'yaw'\]"),
    ({"surge": {"gain": 1.0, "scale": 2}}, r"unknown key\(s\) \['scale'\]; allowed"),
    ({"surge": {"gain": 1.0, "table": [[0, 0], [1, 1]]}}, "exactly one of 'gain' or 'table', found both"),
    ({"surge": {"input": "tau_x"}}, "exactly one of 'gain' or 'table', found neither"),
    ({"surge": {"table": [[0, 0], [0, 1]]}}, r"strictly increasing commands, found \[0.0, 0.0\]"),
    ({"surge": {"table": [[0, 0]]}}, "at least 2 finite"),
    ({"surge": {"table": [[0, "a"], [1, 2]]}}, r"\[\[command, thrust\], ...\] pairs of numbers"),
    ({"surge": {"table": [[0, 0], [1, 1]], "offset": 3}}, "'offset' belongs to a linear 'gain' map"),
    ({"surge": {"gain": 0.0}}, "non-zero thrust per command unit"),
    ({"surge": {"gain": 1.0, "input": "pwm3"}}, "expected a canonical input channel"),
    ({"surge": {"gain": 1.0, "relative_stderr": -0.1}}, "expected >= 0"),
    ({"surge": 3.0}, "expected a table with gain or table"),
])
def test_bad_thruster_sections_name_what_was_expected(section, match):
    with pytest.raises(ConfigError, match=match):
        parse_thrusters(section, "boat.toml [thrusters]")


def test_bad_thrusters_are_refused_when_read_and_by_the_fit():
    # Types and keys: refused when the vessel config is read (pipeline.config_schema), before any work.
    with pytest.raises(ConfigError, match=r"thrusters.surge.gain: expected a finite number, found 'x'"):
        parse_vessel({**DOC, "thrusters": {"surge": {"gain": "x"}}})
    # What a schema cannot judge (commands that do not increase): refused by the fit stage.
    vessel = parse_vessel({**DOC, "thrusters": {"surge": {"table": [[100, 7.0], [60, 0.0]]}}})
    trial = Trial("t", pd.DataFrame({"t": np.arange(10.0), "u": np.zeros(10)}), 1.0)
    fits = single_dof_fits(trial, type("S", (), {"items": (), "trial": "t"})(), vessel)
    with pytest.raises(ConfigError, match=r"table: expected strictly increasing commands"):
        fit_added_mass(fits, trial, vessel)


# --------------------------------------------------------------------------- effective mass
def test_effective_mass_from_one_step_and_its_error():
    # D = 4.5 N / 1.5734 m/s, T = 16 kg / D.
    d_true, m_true = 2.86, 16.0
    du = 4.5 / d_true
    cov = np.diag([1e-6, 1e-6, 1e-4])
    d, se_d, m, se_m = effective_mass_from_step(0.0, du, m_true / d_true, cov, 0.0, 4.5, "change")
    assert d == pytest.approx(d_true) and m == pytest.approx(m_true)
    # dm/dT = D: se_m is at least D se_T.
    assert se_m >= d_true * 1e-2 * 0.99
    _, se_d2, _, se_m2 = effective_mass_from_step(0.0, du, m_true / d_true, cov, 0.0, 4.5, "change", 0.05)
    assert se_m2 == pytest.approx(math.hypot(se_m, 0.05 * m_true))
    d_lvl, *_ = effective_mass_from_step(0.2, du, m_true / d_true, cov, 0.0, 4.5, "level")
    assert d_lvl == pytest.approx(d_true)


# --------------------------------------------------------------------------- simulated truth
@pytest.fixture(scope="module")
def thrust_trial():
    """Surge steps at 2.5 N and 7 N and a yaw step, logged as a thrust *command* (surge, %)."""
    vessel = parse_vessel(DOC)
    schedule = chain(step_and_coast("surge", 2.5, 35, 35), step_and_coast("surge", 7.0, 35, 35),
                     step_and_coast("yaw", 0.13, 30, 30), rest_s=5)
    res = simulate(vessel, schedule, sensors=SENSORS, seed=21)
    trial = align([res.log], name="thrust")
    # The log holds the command: invert the table (the simulator applied newtons).
    forces, cmds = np.array(TABLE)[:, 1], np.array(TABLE)[:, 0]
    data = trial.data.copy()
    data["tau_x"] = np.interp(data["tau_x"].to_numpy(), forces, cmds)
    trial = Trial(trial.name, data, trial.fs, trial.gaps, trial.sources, trial.notes)
    segs = type(res.segments)(res.segments.trial, tuple(
        replace(s, input_before=float(np.interp(s.input_before, forces, cmds)),
                input_after=float(np.interp(s.input_after, forces, cmds))) if s.input_channel == "tau_x" else s
        for s in res.segments.items))
    mapped = parse_vessel({**DOC, "thrusters": {"surge": {"input": "tau_x", "table": TABLE},
                                                "yaw": {"gain": 1.0}}})
    return trial, segs, mapped, single_dof_fits(trial, segs, mapped)


def test_added_mass_is_recovered_from_thrust_steps(thrust_trial):
    trial, segs, vessel, fits = thrust_trial
    est = fit_added_mass(fits, trial, vessel)
    for name, truth, tol in (("X_udot", -3.0, 0.15), ("N_rdot", -0.2, 0.25)):
        e = est[name]
        assert e.success, (name, e.message)
        assert abs(e.value - truth) < 3 * e.stderr, (name, e.value, e.stderr)
        assert abs(e.value - truth) < tol * abs(truth), (name, e.value)
        assert "consistent" in e.message and "m_eff" in e.message
    assert est["X_udot"].unit == "kg" and est["N_rdot"].unit == "kg m^2"
    assert est["X_udot"].n_segments == 2 and "thruster table of 6 points" in est["X_udot"].method
    xu = est["X_u_thrust"]
    assert xu.success and abs(xu.value + 2.86) < 3 * xu.stderr


def test_extend_fits_adds_added_mass_only_where_thrust_is_mapped(thrust_trial):
    trial, segs, vessel, fits = thrust_trial
    # Surge segments only: the grey-box part has nothing lateral to fit and stays quick.
    surge = type(segs)(segs.trial, tuple(s for s in segs.items if s.dof == "surge"))
    ext = extend_fits(single_dof_fits(trial, surge, vessel), trial, surge, vessel)
    assert "X_udot" in ext.estimates and "Y_vdot" not in ext.estimates
    assert ext.estimates["X_udot"].success and not ext.estimates["N_r_thrust"].success
    plain = parse_vessel(DOC)
    assert "X_udot" not in extend_fits(single_dof_fits(trial, surge, plain), trial, surge, plain).estimates


def test_understated_thrust_gives_negative_added_mass_and_says_so(thrust_trial):
    trial, segs, _, fits = thrust_trial
    half = [[c, f / 2] for c, f in TABLE]
    vessel = parse_vessel({**DOC, "thrusters": {"surge": {"table": half}}})
    e = fit_added_mass(fits, trial, vessel)["X_udot"]
    assert e.value > 0 and "negative added mass" in e.message and "INCONSISTENT" in e.message


def test_no_step_in_a_mapped_dof_says_what_to_run(thrust_trial):
    trial, segs, _, fits = thrust_trial
    vessel = parse_vessel({**DOC, "thrusters": {"sway": {"gain": 1.0}}})
    e = fit_added_mass(fits, trial, vessel)["Y_vdot"]
    assert not e.success and "no sway step" in e.message and "tau_y" in e.message
