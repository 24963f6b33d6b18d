"""Vessel config: parse/load of the TOML, its error messages, M_RB, and the actuator PWM map.

Every config is written into ``tmp_path`` or given as a dict; the bundled AAUSHIP file is read
as it ships.
"""

from __future__ import annotations


import numpy as np
import pytest

from pipeline.errors import ConfigError
from pipeline.vessel import ActuatorMap, load_vessel, parse_vessel

from conftest import AAUSHIP_TOML as AAUSHIP  # noqa: E402 - the config file itself (loading it is tested here)
RB = {"mass": 13.0, "inertia": [0.0654, 1.089, 1.107]}


def _skew(r):
    """Fossen's cross-product operator S(r), S(a) b = a x b."""
    x, y, z = r
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


# --------------------------------------------------------------------------- load / parse
def test_load_aauship_values():
    v = load_vessel(AAUSHIP)
    assert v.name == "aauship"
    assert v.path == str(AAUSHIP)
    assert v.mass == 13.0
    np.testing.assert_array_equal(v.inertia, [0.0654, 1.089, 1.107])
    np.testing.assert_array_equal(v.cg, [0.0, 0.0, 0.0])
    assert v.restoring == {"roll": 6.97, "pitch": 131.8}
    np.testing.assert_array_equal(v.damping, np.diag([2.86, 32.5, 0.1094, 7.203, 0.26285]))
    assert v.quadratic_damping is None
    assert v.rudder["yaw_moment"] == 0.45 and v.rudder["max_angle"] == 0.6109
    assert v.has_rigid_body
    assert [(a.source, a.channel, a.target) for a in v.actuators] == [
        ("servo", 1, "delta"), ("servo", 3, "tau_x"), ("servo", 4, "tau_y"), ("servo", 5, "tau_n")]
    # reverse_scale not given -> symmetric (the full scale)
    assert v.actuators[0].reverse_scale == pytest.approx(0.6109)
    assert v.actuators[1].reverse_scale == 10.0
    # The comment in the TOML promises K = yaw_moment / D_r and T = Izz / D_r.
    assert v.rudder["yaw_moment"] / v.damping[4, 4] == pytest.approx(1.712, abs=1e-3)
    assert v.effective_mass("yaw") / v.damping[4, 4] == pytest.approx(4.21, abs=5e-3)


def test_minimal_rudder_ship_has_no_rigid_body():
    v = parse_vessel({"name": "ship", "nomoto": {"K": 0.156, "T": 72.4}})
    assert v.name == "ship" and v.mass is None and not v.has_rigid_body
    assert v.nomoto == {"K": 0.156, "T": 72.4}
    with pytest.raises(ConfigError, match=r"mass and rigid_body.inertia are needed"):
        v.rigid_body_mass_matrix()


def test_load_missing_file_and_bad_toml(tmp_path):
    with pytest.raises(ConfigError, match="vessel config: expected a TOML file, found nothing at"):
        load_vessel(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\n[rigid_body\nmass = 1\n')
    with pytest.raises(ConfigError, match="expected valid TOML, found a parse error"):
        load_vessel(bad)


def test_load_reports_path_in_errors(tmp_path):
    p = tmp_path / "boat.toml"
    p.write_text('name = "boat"\ncolour = "red"\n')
    with pytest.raises(ConfigError) as exc:
        load_vessel(p)
    assert str(p) in str(exc.value) and "colour" in str(exc.value)


# --------------------------------------------------------------------------- unknown keys
def test_unknown_top_level_key_names_key_and_allowed():
    with pytest.raises(ConfigError) as exc:
        parse_vessel({"name": "x", "colour": "red"})
    msg = str(exc.value)
    assert "'colour'" in msg
    for allowed in ("name", "rigid_body", "added_mass", "restoring", "damping", "nomoto", "rudder", "actuators"):
        assert f"'{allowed}'" in msg


@pytest.mark.parametrize("section, key, allowed", [
    ("rigid_body", "weight", ("mass", "inertia", "cg")),
    ("restoring", "yaw", ("roll", "pitch")),
    ("damping", "cubic", ("matrix", "diagonal", "quadratic")),
    ("nomoto", "k", ("K", "T")),
    ("added_mass", "heave", ("surge", "sway", "roll", "pitch", "yaw")),
    ("rudder", "area", ("max_angle", "max_rate", "yaw_moment", "sway_force")),
])
def test_unknown_section_key_names_section_key_and_allowed(section, key, allowed):
    with pytest.raises(ConfigError) as exc:
        parse_vessel({"name": "x", section: {key: 1.0}})
    msg = str(exc.value)
    assert f"{section}: unknown key(s) ['{key}']" in msg
    for a in allowed:
        assert f"'{a}'" in msg


def test_unknown_actuator_key_names_key_and_allowed():
    doc = {"name": "x", "actuators": [{"source": "servo", "channel": 1, "target": "delta"},
                                      {"source": "servo", "channel": 2, "target": "tau_x", "gain": 2.0}]}
    with pytest.raises(ConfigError) as exc:
        parse_vessel(doc)
    msg = str(exc.value)
    assert "actuators[1]" in msg and "'gain'" in msg
    for a in ("source", "channel", "target", "pwm_trim", "pwm_span", "full_scale", "reverse_scale"):
        assert f"'{a}'" in msg


@pytest.mark.parametrize("actuator, match", [
    ({"source": "servo", "channel": 1}, r"actuators\[0\]: missing key\(s\) \['target'\]"),
    ({"source": "pwm", "channel": 1, "target": "delta"},
     r"actuators\[0\].source: expected one of 'servo', 'rc', 'motor', 'servo_control', found 'pwm'"),
    ({"source": "rc", "channel": 1, "target": "rudder"}, r"target: expected one of .*'delta'.*found 'rudder'"),
    ({"source": "rc", "channel": 1, "target": "delta", "pwm_span": 0}, r"pwm_span: expected a positive number, found 0"),
    ({"source": "rc", "channel": 1, "target": "delta", "full_scale": "big"}, r"full_scale: expected a finite number, found 'big'"),
])
def test_bad_actuator_entries(actuator, match):
    with pytest.raises(ConfigError, match=match):
        parse_vessel({"name": "x", "actuators": [actuator]})


# --------------------------------------------------------------------------- types and values
@pytest.mark.parametrize("doc, match", [
    ({"name": "x", "rigid_body": {**RB, "mass": "13"}}, r"rigid_body.mass: expected a positive number, found '13'"),
    ({"name": "x", "rigid_body": {**RB, "mass": True}}, r"rigid_body.mass: expected a positive number, found True"),
    ({"name": "x", "rigid_body": {**RB, "mass": -1.0}}, r"rigid_body.mass: expected a positive number, found -1.0"),
    ({"name": "x", "rigid_body": {**RB, "inertia": [1.0, 2.0]}}, r"rigid_body.inertia: expected a list of 3 positive numbers, found \[1.0, 2.0\]"),
    ({"name": "x", "rigid_body": {**RB, "inertia": ["a", 1, 1]}}, r"rigid_body.inertia\[0\]: expected a positive number, found 'a'"),
    ({"name": "x", "rigid_body": {**RB, "inertia": [1.0, 0.0, 1.0]}}, r"rigid_body.inertia\[1\]: expected a positive number, found 0.0"),
    ({"name": "x", "rigid_body": {**RB, "cg": [0.0, 0.0]}}, r"rigid_body.cg: expected a list of 3 finite numbers, found \[0.0, 0.0\]"),
    ({"name": "x", "rigid_body": 13.0}, r"rigid_body: expected a table with keys mass, inertia, cg, found 13.0"),
    ({"name": "x", "added_mass": {"surge": -1.0}}, r"added_mass.surge: expected a number >= 0, found -1.0"),
    ({"name": "x", "restoring": {"roll": "stiff"}}, r"restoring.roll: expected a finite number, found 'stiff'"),
    ({"name": "x", "damping": {"diagonal": [1, 2, 3]}}, r"damping.diagonal: expected a list of 5 finite numbers, found \[1, 2, 3\]"),
    ({"name": "x", "damping": {"matrix": [[1.0] * 4] * 4}}, r"damping.matrix: expected a 5x5 array of numbers, found \[\[1.0"),
    ({"name": "x", "damping": {"matrix": np.eye(5).tolist(), "diagonal": [1] * 5}}, r"either matrix or diagonal, found both"),
    ({"name": "x", "damping": {"quadratic": [1, 2]}}, r"damping.quadratic: expected a list of 5 finite numbers, found \[1, 2\]"),
    ({"name": "x", "nomoto": {"K": 0.1, "T": -3.0}}, r"nomoto.T: expected a positive number, found -3.0"),
    ({"name": "x", "nomoto": {"K": float("nan"), "T": 3.0}}, r"nomoto.K: expected a finite number, found nan"),
])
def test_wrong_types_and_values(doc, match):
    with pytest.raises(ConfigError, match=match):
        parse_vessel(doc)


@pytest.mark.parametrize("doc", [{}, {"name": ""}, {"name": 3}, {"rigid_body": RB}])
def test_missing_or_bad_name(doc):
    with pytest.raises(ConfigError, match=r"name: expected a non-empty string, found|missing key\(s\) \['name'\]"):
        parse_vessel(doc)


@pytest.mark.parametrize("rb, present", [({"mass": 13.0}, "mass"), ({"inertia": [1.0, 1.0, 1.0]}, "inertia")])
def test_mass_without_inertia_and_vice_versa(rb, present):
    with pytest.raises(ConfigError) as exc:
        parse_vessel({"name": "x", "rigid_body": rb})
    assert "expected both mass and inertia" in str(exc.value) and f"['{present}']" in str(exc.value)


# --------------------------------------------------------------------------- mass matrices
def test_mrb_reduces_to_diagonal_when_cg_zero():
    v = load_vessel(AAUSHIP)
    m_rb = v.rigid_body_mass_matrix()
    np.testing.assert_array_equal(m_rb, np.diag([13.0, 13.0, 0.0654, 1.089, 1.107]))
    np.testing.assert_array_equal(v.mass_matrix(), m_rb)  # no [added_mass] in the file
    assert v.effective_mass("surge") == 13.0 and v.effective_mass("r") == 1.107


def test_added_mass_adds_on_the_diagonal():
    v = parse_vessel({"name": "x", "rigid_body": RB, "added_mass": {"surge": 1.5, "yaw": 0.2}})
    np.testing.assert_allclose(v.mass_matrix() - v.rigid_body_mass_matrix(), np.diag([1.5, 0, 0, 0, 0.2]))
    assert v.effective_mass("surge") == pytest.approx(14.5)
    with pytest.raises(ConfigError, match="unknown DOF 'heave'"):
        v.effective_mass("heave")


@pytest.mark.parametrize("cg", [[0.0, 0.0, 0.0], [0.03, 0.0, 0.03], [0.1, -0.05, 0.08], [-0.2, 0.1, -0.15]])
def test_mrb_symmetric_positive_definite(cg):
    v = parse_vessel({"name": "x", "rigid_body": {**RB, "cg": cg}})
    m = v.rigid_body_mass_matrix()
    assert m.shape == (5, 5)
    np.testing.assert_array_equal(m, m.T)
    assert np.linalg.eigvalsh(m).min() > 0


def test_mrb_parallel_axis_and_coupling_terms():
    m, (ixx, iyy, izz) = 13.0, RB["inertia"]
    xg, yg, zg = 0.1, -0.05, 0.08
    v = parse_vessel({"name": "x", "rigid_body": {**RB, "cg": [xg, yg, zg]}})
    mrb = v.rigid_body_mass_matrix()
    # Fossen (2021) eq. 3.44: [[m I, -m S(r_g)], [m S(r_g), I_g - m S(r_g)^2]], heave dropped.
    s = _skew([xg, yg, zg])
    m6 = np.block([[m * np.eye(3), -m * s], [m * s, np.diag([ixx, iyy, izz]) - m * s @ s]])
    keep = [0, 1, 3, 4, 5]
    np.testing.assert_allclose(mrb, m6[np.ix_(keep, keep)], rtol=1e-14, atol=1e-15)
    # The terms spelled out (DOF order u v p q r):
    assert mrb[2, 2] == pytest.approx(ixx + m * (yg**2 + zg**2))
    assert mrb[3, 3] == pytest.approx(iyy + m * (xg**2 + zg**2))
    assert mrb[4, 4] == pytest.approx(izz + m * (xg**2 + yg**2))
    assert mrb[1, 2] == pytest.approx(-m * zg)      # sway-roll: -m z_g
    assert mrb[0, 3] == pytest.approx(m * zg)       # surge-pitch: m z_g
    assert mrb[1, 4] == pytest.approx(m * xg)       # sway-yaw: m x_g
    assert mrb[0, 4] == pytest.approx(-m * yg)      # surge-yaw: -m y_g
    assert mrb[2, 4] == pytest.approx(-m * xg * zg)
    assert mrb[3, 4] == pytest.approx(-m * yg * zg)
    assert mrb[2, 3] == pytest.approx(-m * xg * yg)


def test_restoring_matrix_places_roll_and_pitch():
    g = load_vessel(AAUSHIP).restoring_matrix()
    expected = np.zeros((5, 5))
    expected[2, 2], expected[3, 3] = 6.97, 131.8
    np.testing.assert_array_equal(g, expected)


# --------------------------------------------------------------------------- actuators
def test_actuator_map_asymmetric_reverse_round_trip():
    a = ActuatorMap("servo", 3, "tau_x", pwm_trim=1520.0, pwm_span=380.0, full_scale=10.0, reverse_scale=4.0)
    assert a.to_input(1520.0) == 0.0
    assert a.to_input(1900.0) == pytest.approx(10.0)
    assert a.to_input(1140.0) == pytest.approx(-4.0)
    assert a.to_input(1710.0) == pytest.approx(5.0)
    assert a.to_input(1330.0) == pytest.approx(-2.0)
    pwm = np.linspace(1100.0, 1950.0, 86)
    np.testing.assert_allclose(a.to_pwm(a.to_input(pwm)), pwm, rtol=0, atol=1e-9)
    values = np.array([-4.0, -1.3, -1e-6, 0.0, 1e-6, 2.5, 10.0])
    np.testing.assert_allclose(a.to_input(a.to_pwm(values)), values, rtol=1e-12, atol=1e-12)
    # The same magnitude maps to different PWM distances forward and reverse.
    assert a.to_pwm(2.0) - 1520.0 == pytest.approx(76.0)
    assert 1520.0 - a.to_pwm(-2.0) == pytest.approx(190.0)


def test_actuator_map_parsed_from_config():
    doc = {"name": "x", "actuators": [{"source": "rc", "channel": 3, "target": "tau_x", "pwm_trim": 1490,
                                       "full_scale": 8.0, "reverse_scale": 3.0}]}
    (a,) = parse_vessel(doc).actuators
    assert (a.source, a.channel, a.target, a.pwm_trim, a.pwm_span) == ("rc", 3, "tau_x", 1490.0, 400.0)
    assert a.to_input(1890.0) == pytest.approx(8.0)
    assert a.to_input(1090.0) == pytest.approx(-3.0)
    assert a.to_pwm(-3.0) == pytest.approx(1090.0)


# --------------------------------------------------------------------------- wrong types inside arrays
# These used to escape as a bare ValueError (a traceback at the CLI) instead of a ConfigError.
@pytest.mark.parametrize("matrix", [[["a"] * 5] * 5, [[1.0, 2.0], [3.0]]])
def test_damping_matrix_wrong_type_is_config_error(matrix):
    with pytest.raises(ConfigError, match="damping.matrix"):
        parse_vessel({"name": "x", "damping": {"matrix": matrix}})


def test_actuator_channel_wrong_type_is_config_error():
    with pytest.raises(ConfigError, match="channel"):
        parse_vessel({"name": "x", "actuators": [{"source": "servo", "channel": "one", "target": "delta"}]})


def test_sensor_noise_is_optional_and_checked():
    from pipeline.errors import ConfigError
    from pipeline.vessel import parse_vessel

    assert parse_vessel({"name": "x"}).sensor_noise == {}
    v = parse_vessel({"name": "x", "sensor_noise": {"psi": 0.002, "r": 0.001}})
    assert v.sensor_noise == {"psi": 0.002, "r": 0.001}
    with pytest.raises(ConfigError, match="sensor_noise"):
        parse_vessel({"name": "x", "sensor_noise": {"psi": -0.002}})
    with pytest.raises(ConfigError, match="sensor_noise"):
        parse_vessel({"name": "x", "sensor_noise": {"heading": 0.002}})
