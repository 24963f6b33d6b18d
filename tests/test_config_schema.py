"""One schema for the vessel TOML and the trial manifest: good configs pass, every table's bad
values are refused before any work with the place, what was expected and what was found."""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path

import pytest

from pipeline.config_schema import MANIFEST_SCHEMA, VESSEL_SCHEMA, validate
from pipeline.errors import ConfigError
from pipeline.manifest import load_manifest
from pipeline.vessel import load_vessel, parse_vessel

ROOT = Path(__file__).resolve().parents[1]

GOOD_EXTRAS = {
    "thrusters": {"surge": {"input": "tau_x", "gain": 0.27, "offset": 97.7, "relative_stderr": 0.05},
                  "yaw": {"table": [[60, 0.0], [100, 7.0]]}},
    "topics": {"/imu/data": "imu", "/fix": "navsatfix@gps"},
    "sensors": {"gps": {"lever_arm": [0.5, 0.2, -0.3]}, "gps2": {"lever_arm": [-0.5, 0.2, -0.3], "suffix": "@gps2"},
                "dual": {"antennas": ["gps2", "gps"], "mounting_yaw": 0.0}},
}


def _vessel_doc():
    with open(ROOT / "vessel_configs" / "aauship.toml", "rb") as f:
        return tomllib.load(f) | copy.deepcopy(GOOD_EXTRAS)


def test_shipped_configs_and_every_optional_table_pass():
    for path in sorted((ROOT / "vessel_configs").glob("*.toml")):
        load_vessel(path)
    for path in sorted((ROOT / "trials").rglob("*.toml")):
        validate(tomllib.loads(path.read_text()), MANIFEST_SCHEMA, str(path))
    vessel = parse_vessel(_vessel_doc(), "v.toml")
    assert vessel.extra["thrusters"]["surge"]["gain"] == 0.27      # passed through untouched
    assert set(VESSEL_SCHEMA[1]) >= {"sensors", "thrusters", "topics", "actuators"}
    assert set(MANIFEST_SCHEMA[1]) >= {"autopilot", "runs", "columns", "units", "inputs", "segments"}


@pytest.mark.parametrize("section, value, expected", [
    ("thrusters", {"surge": {"gain": "x"}}, r"thrusters.surge.gain: expected a finite number, found 'x'"),
    ("thrusters", {"roll": {"gain": 1.0}}, r"thrusters: unknown key\(s\) \['roll'\]"),
    ("thrusters", {"surge": {"gain": 1.0, "bias": 2}}, r"thrusters.surge: unknown key\(s\) \['bias'\]"),
    ("topics", {"/imu": 3}, r"topics./imu: expected a string, found 3"),
    ("sensors", {"gps": {"lever_arm": [1.0, 2.0]}}, r"sensors.gps.lever_arm: expected a list of 3 finite numbers"),
    ("sensors", {"gps": {"height": 1.0}}, r"sensors.gps: expected a table with keys lever_arm, suffix or .*antennas"),
    ("rudder", {"max_rate": -1.0}, r"rudder.max_rate: expected a positive number, found -1.0"),
    ("actuators", [{"source": "servo", "channel": 1, "target": "delta", "pwm_span": 0.0}],
     r"actuators\[0\].pwm_span: expected a positive number, found 0.0"),
    ("mass", 13.0, r"unknown key\(s\) \['mass'\]"),
])
def test_bad_vessel_tables_name_place_expected_and_found(section, value, expected):
    doc = _vessel_doc()
    doc[section] = value
    with pytest.raises(ConfigError, match=expected):
        parse_vessel(doc, "v.toml")


def test_all_problems_reported_at_once_and_input_not_modified():
    doc = _vessel_doc()
    doc["topics"] = {"/imu": 1}
    doc["rudder"] = {"max_angle": -1.0}
    before = copy.deepcopy(doc)
    with pytest.raises(ConfigError, match="2 problems") as exc:
        validate(doc, VESSEL_SCHEMA, "v.toml")
    assert "topics./imu" in str(exc.value) and "rudder.max_angle" in str(exc.value)
    assert doc == before


def _manifest(tmp_path, body: str) -> Path:
    (tmp_path / "log.csv").write_text("t,u\n0,1\n")
    vessel = (ROOT / "vessel_configs" / "aauship.toml").as_posix()
    path = tmp_path / "trial.toml"
    path.write_text(f'vessel = "{vessel}"\nlogs = ["log.csv"]\n' + body)
    return path


def test_good_manifest_with_every_table(tmp_path):
    man = load_manifest(_manifest(tmp_path, 'fs = 50.0\nsegments_mode = "add"\n[columns]\nheading = "psi"\n'
                                            '[units]\nheading = "deg"\n[inputs]\ndelta = "measured"\n'
                                            '[autopilot]\ncrossover = 0.5\nphase_margin_deg = 60.0\n'
                                            '[[runs]]\nname = "a"\nlogs = ["log.csv"]\n'
                                            '[[segments]]\nkind = "coast_down"\ndof = "surge"\nt_start = 1.0\n'
                                            't_end = 5.0\n'))
    assert man.options == {"autopilot": {"crossover": 0.5, "phase_margin_deg": 60.0}} and man.fs == 50.0


@pytest.mark.parametrize("body, expected", [
    ('[waves]\nomega0 = 0.8\n', r"waves: no stage reads a manifest \[waves\] table"),
    ('[autopilot]\ncrossover = "fast"\n', r"autopilot.crossover: expected a positive number, found 'fast'"),
    ('[autopilot]\ngain = 1.0\n', r"autopilot: unknown key\(s\) \['gain'\]"),
    ('[[runs]]\nname = "a"\nlogs = ["log.csv"]\ncolour = "red"\n', r"runs\[0\]: unknown key\(s\) \['colour'\]"),
    ('[[segments]]\nkind = "spin"\ndof = "surge"\nt_start = 1.0\nt_end = 2.0\n',
     r"segments\[0\].kind: expected one of 'coast_down'"),
    ('[[segments]]\nkind = "step"\ndof = "surge"\nt_start = "late"\nt_end = 2.0\n',
     r"segments\[0\].t_start: expected a finite number, found 'late'"),
    ('segments_mode = "merge"\n', r"segments_mode: expected one of 'replace', 'add', found 'merge'"),
])
def test_bad_manifest_tables_are_refused_before_any_work(tmp_path, body, expected):
    with pytest.raises(ConfigError, match=expected):
        load_manifest(_manifest(tmp_path, body))
