"""vesselid export: each target read back with its own parser (XML, YAML, PythonVehicleSimulator)."""

from __future__ import annotations

import importlib.util
import json
import math
import os
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline.cli import main
from pipeline.export import model_from_coefficients
from pipeline.export.ardupilot import RANGES, ardupilot_params
from pipeline.export.vrx import PLUGIN_PARAMETERS
from pipeline.model.vessel5dof import simulate_dof
from pipeline.vessel import load_vessel

ROOT = Path(__file__).resolve().parents[1]
VESSEL = ROOT / "vessel_configs" / "aauship.toml"
PVS = Path(os.environ.get("PVS_PATH", "/work/pvs/src"))
D = [2.86, 32.5, 0.1094, 7.203, 0.26285]
D2 = [12.7, 60.0, None, None, 0.3]


def coefficients(tmp_path: Path, k: float = 1.712, t: float = 4.212) -> Path:
    """A coefficients.json as the fit stage writes it (standard keys + the structure fields)."""
    dm = [[D[i] if i == j else None for j in range(5)] for i in range(5)]
    se = [[0.01 if i == j else None for j in range(5)] for i in range(5)]
    names = ("X_u", "Y_v", "K_p", "M_q", "N_r")
    coefs = {n: {"value": -D[i], "stderr": 0.01, "ci95": [-D[i] - 0.02, -D[i] + 0.02], "unit": "kg/s",
                 "n_segments": 2, "method": "m", "success": True, "message": "", "consistency_p": None}
             for i, n in enumerate(names)}
    for n, v in (("K_nomoto", k), ("T_nomoto", t)):
        coefs[n] = {"value": v, "stderr": 0.01, "ci95": [v - 0.02, v + 0.02], "unit": "", "n_segments": 2,
                    "method": "m", "success": True, "message": "", "consistency_p": None}
    for n in ("Y_p", "Y_r", "K_v", "K_r", "N_v", "N_p"):
        coefs[n] = {"value": None, "stderr": None, "ci95": [None, None], "unit": "kg m/s", "n_segments": 0,
                    "method": "", "success": False, "message": "not identified", "consistency_p": None}
    data = {"vessel": "aauship", "convention": "Fossen", "damping_matrix": {"dofs": list("uvpqr"), "values": dm,
                                                                             "stderr": se},
            "coefficients": coefs, "quadratic_damping": {"dofs": list("uvpqr"), "values": D2,
                                                         "stderr": [0.1, 1.0, None, None, 0.01]}}
    path = tmp_path / "coefficients.json"
    path.write_text(json.dumps(data))
    return path


def export(tmp_path: Path, target: str, vessel: bool = True, coef: Path | None = None) -> tuple[int, Path]:
    out = tmp_path / ("identified_vessel.py" if target == "pvs" else f"model.{target}")
    args = ["export", "--coefficients", str(coef or coefficients(tmp_path)), "--to", target, "--out", str(out)]
    return main(args + (["--vessel", str(VESSEL)] if vessel else [])), out


def test_vrx_block_parses_and_names_only_plugin_parameters(tmp_path):
    rc, out = export(tmp_path, "vrx")
    assert rc == 0
    root = ET.fromstring(out.read_text())
    assert root.tag == "plugin" and root.get("filename") == "libusv_gazebo_dynamics_plugin.so"
    tags = [c.tag for c in root]
    assert set(tags) <= set(PLUGIN_PARAMETERS), set(tags) - set(PLUGIN_PARAMETERS)
    vals = {c.tag: c.text for c in root}
    assert float(vals["xU"]) == pytest.approx(2.86) and float(vals["xUU"]) == pytest.approx(12.7)
    assert float(vals["nRR"]) == pytest.approx(0.3) and float(vals["kPP"]) == 0.0


def test_ros2_yaml_has_parameter_file_structure(tmp_path):
    rc, out = export(tmp_path, "ros2")
    assert rc == 0
    doc = yaml.safe_load(out.read_text())
    assert len(doc) == 1
    (node, body), = doc.items()
    assert isinstance(node, str) and list(body) == ["ros__parameters"]

    def leaves(x, path=""):
        if isinstance(x, dict):
            for k, v in x.items():
                assert isinstance(k, str) and "|" not in k and " " not in k, k
                yield from leaves(v, f"{path}.{k}")
        else:
            yield path, x

    for path, v in leaves(body["ros__parameters"]):
        if isinstance(v, list):
            assert v and len({type(e) for e in v}) == 1, path  # homogeneous array
            v = v[0]
        assert isinstance(v, (bool, int, float, str)), (path, v)
    p = body["ros__parameters"]
    assert p["damping"]["quadratic"]["X_uu"] == pytest.approx(-12.7)


def test_ardupilot_within_documented_ranges_and_clamped(tmp_path):
    rc, out = export(tmp_path, "ardupilot")
    assert rc == 0
    params = dict(line.split(",") for line in out.read_text().splitlines() if not line.startswith("#"))
    for name, value in params.items():
        lo, hi = RANGES[name]
        assert lo <= float(value) <= hi
    # ArduPilot's own Python tooling (pymavlink, as MAVProxy's "param load") reads the file back.
    from pymavlink.mavparm import MAVParmDict

    parsed = MAVParmDict()
    assert parsed.load(str(out), mav=None)
    assert set(parsed) == set(params)
    assert all(parsed[k] == pytest.approx(float(v)) for k, v in params.items())
    vessel = load_vessel(VESSEL)
    assert float(params["ATC_STR_RAT_MAX"]) == pytest.approx(math.degrees(1.712 * vessel.rudder["max_angle"]), rel=1e-5)
    # A sluggish ship: 1/(K max_rudder) above 3 is clamped and said so.
    data = json.loads(coefficients(tmp_path, k=0.2).read_text())
    values, notes = ardupilot_params(model_from_coefficients(data, vessel))
    assert values["ATC_STR_RAT_FF"] == 3.0 and any("clamped" in n for n in notes)


def test_ardupilot_without_rudder_limit_is_a_clear_error(tmp_path, capsys):
    rc, out = export(tmp_path, "ardupilot", vessel=False)
    assert rc == 2 and not out.exists()
    assert "error: ardupilot: expected the rudder limit" in capsys.readouterr().err


def test_bad_coefficients_file(tmp_path, capsys):
    bad = tmp_path / "c.json"
    bad.write_text("{")
    rc, _ = export(tmp_path, "vrx", coef=bad)
    assert rc == 2 and "not valid JSON" in capsys.readouterr().err
    rc, _ = export(tmp_path, "vrx", coef=tmp_path / "missing.json")
    assert rc == 2 and "no such file" in capsys.readouterr().err


@pytest.mark.skipif(not (PVS / "python_vehicle_simulator").is_dir(), reason="PythonVehicleSimulator not found "
                    "(set PVS_PATH to its src folder)")
def test_pvs_module_runs_in_pythonvehiclesimulator_like_vesselid(tmp_path):
    rc, out = export(tmp_path, "pvs")
    assert rc == 0
    spec = importlib.util.spec_from_file_location("identified_vessel", out)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    sys.path.insert(0, str(PVS))
    try:
        from python_vehicle_simulator.lib.mainLoop import simulate
    finally:
        sys.path.remove(str(PVS))
    dt, n = 0.01, 3000
    vehicle = mod.IdentifiedVessel(tau_step=[8.0, 0, 0, 0, 0, 0.3], t_off=15.0)
    t, sim = simulate(n, dt, vehicle)
    u_pvs, r_pvs = sim[:, 6], sim[:, 11]
    vessel = load_vessel(VESSEL)
    for i, (col, force, pvs) in enumerate(((0, 8.0, u_pvs), (4, 0.3, r_pvs))):
        m = vessel.effective_mass("uvpqr"[col])
        f = np.where(np.arange(n + 1) * dt < 15.0, force, 0.0) / m
        own = simulate_dof(np.array([0.0]), f[None, :], dt, D[col] / m, D2[col] / m)[0]
        # PVS integrates by forward Euler at dt: agreement to within its O(dt) error.
        assert np.max(np.abs(pvs - own)) < 0.01 * np.max(np.abs(own)), col
