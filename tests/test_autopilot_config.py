"""AutopilotConfig: TOML contents and round trip, input readers, rudder limits, ArduPilot export,
the stage's files and HTML section, and a meta-test that the public API documents its parameters."""

import json
import math
import tomllib

import numpy as np
import pytest

import pipeline.autopilot as ap
from pipeline.autopilot.config import (DEFAULT_MAX_ANGLE, DEFAULT_MAX_RATE, ardupilot_params,
                                       build_autopilot_config, read_autopilot_toml, read_coefficients_json,
                                       read_waves_json, write_ardupilot_params, write_autopilot_toml)
from pipeline.autopilot.design import build_autopilot, nomoto_from_fits
from pipeline.autopilot.outputs import write_autopilot_outputs_and_section
from pipeline.errors import AutopilotError
from pipeline.model.waves import WaveParams
from pipeline.records import Estimate, Fits
from pipeline.vessel import parse_vessel

K_SEED, T_SEED = 0.1561, 72.4385


def _coefficients(tmp_path, k=K_SEED, t=T_SEED, name="coefficients.json", **extra):
    doc = {"vessel": "cargo", "convention": "...", "damping_matrix": {"dofs": list("uvpqr")},
           "coefficients": {
               "K_nomoto": {"value": k, "stderr": 0.004, "ci95": [0.148, 0.164], "unit": "1/s", "n_segments": 2,
                            "method": "sine", "success": True, "message": "", "consistency_p": 0.4},
               "T_nomoto": {"value": t, "stderr": 2.5, "ci95": [67.5, 77.3], "unit": "s"},
               "X_u": {"value": None, "stderr": None, "success": False, "message": "no coast-down"}},
           "future_key": {"anything": 1}}
    doc.update(extra)
    p = tmp_path / name
    p.write_text(json.dumps(doc))
    return p


def test_toml_holds_every_number_a_controller_needs(tmp_path):
    coefs = read_coefficients_json(_coefficients(tmp_path))
    cfg = build_autopilot_config(coefs.K, coefs.T, crossover=0.1, K_stderr=coefs.K_stderr, T_stderr=coefs.T_stderr,
                                 sources=(coefs.source,))
    out = write_autopilot_toml(cfg, tmp_path / "sub" / "autopilot.toml")
    doc = tomllib.loads(out.read_text())
    assert doc["ts"] == 0.1
    assert set(doc["model"]) >= {"K", "T", "K_stderr", "T_stderr"}
    assert set(doc["wave"]) >= {"omega0", "lambda", "kw"}
    assert set(doc["pd"]) >= {"kpd", "td", "tf"}
    assert set(doc["kalman"]) >= {"ad", "bd", "ed", "c", "qd", "r", "p0", "x0"}
    assert np.array(doc["kalman"]["ad"]).shape == (5, 5)
    assert np.array(doc["kalman"]["ed"]).shape == (5, 2)
    assert len(doc["kalman"]["bd"]) == 5 and doc["kalman"]["c"] == [0.0, 1.0, 1.0, 0.0, 0.0]
    assert doc["pd"]["kpd"] == pytest.approx(0.836, abs=5e-4) and doc["pd"]["tf"] == pytest.approx(8.391, abs=5e-4)
    prov = doc["provenance"]
    assert prov["version"] and prov["sources"][0]["role"] == "coefficients"
    assert len(prov["sources"][0]["sha256"]) == 64
    assert any("default" in n for n in prov["notes"])  # defaults are stated, not hidden
    assert doc["rudder"]["max_angle"] == pytest.approx(math.radians(35.0))
    assert not list(tmp_path.glob("sub/.autopilot.toml.*"))  # no temporary left behind


def test_toml_round_trip(tmp_path):
    cfg = build_autopilot_config(K_SEED, T_SEED, waves=WaveParams(0.8, 0.1, 0.01),
                                 waves_stderr={"omega0": 0.01, "lambda": 0.02, "kw": math.nan}, r=1e-6)
    back = read_autopilot_toml(write_autopilot_toml(cfg, tmp_path / "a.toml"))
    assert back.K == cfg.K and back.T == cfg.T and back.pd == cfg.pd and back.waves == cfg.waves
    assert math.isnan(back.K_stderr)  # NaN is left out of the file, not written
    assert back.waves_stderr == {"omega0": 0.01, "lambda": 0.02}
    for name in ("ad", "bd", "ed", "c", "qd", "p0", "x0", "q"):
        np.testing.assert_array_equal(getattr(back.kalman, name), getattr(cfg.kalman, name))
    assert back.kalman.r == cfg.kalman.r


def test_config_does_not_mutate_inputs():
    rudder = {"max_angle": 0.5, "max_rate": 0.1}
    before = dict(rudder)
    cfg = build_autopilot_config(K_SEED, T_SEED, rudder=rudder)
    assert rudder == before
    assert cfg.rudder_max_angle == 0.5 and cfg.rudder_max_rate == 0.1


def test_rudder_limits_from_vessel_config_and_defaults(tmp_path):
    vessel = parse_vessel({"name": "boat", "rudder": {"max_angle": 0.6109, "max_rate": 0.2618},
                           "nomoto": {"K": 0.17, "T": 65.0}})
    res = build_autopilot(read_coefficients_json(_coefficients(tmp_path)), vessel=vessel, check=False)
    assert res.config.rudder_max_angle == 0.6109 and res.config.rudder_max_rate == 0.2618
    assert "vessel config" in res.config.rudder_source
    bare = build_autopilot_config(K_SEED, T_SEED)
    assert bare.rudder_max_angle == DEFAULT_MAX_ANGLE
    assert math.degrees(bare.rudder_max_rate) == pytest.approx(65.0 / 28.0)
    assert bare.rudder_max_rate == DEFAULT_MAX_RATE
    assert any("SOLAS" in n for n in bare.notes)


@pytest.mark.parametrize("kwargs, match", [
    (dict(rudder={"max_angle": 35.0}), "radians below pi/2"),
    (dict(rudder={"max_rate": 0.0}), "max_rate"),
    (dict(rudder={"max_speed": 1.0}), "unknown key"),
    (dict(waves=WaveParams(0.0, 0.1, 0.01)), "omega0"),
    (dict(ts=-1.0), "sample time"),
])
def test_bad_config_input(kwargs, match):
    with pytest.raises(AutopilotError, match=match):
        build_autopilot_config(K_SEED, T_SEED, **kwargs)


def test_coefficients_reader_errors(tmp_path):
    with pytest.raises(AutopilotError, match="no such file"):
        read_coefficients_json(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(AutopilotError, match="expected JSON"):
        read_coefficients_json(bad)
    bad.write_text("[1, 2]")
    with pytest.raises(AutopilotError, match="JSON object"):
        read_coefficients_json(bad)
    bad.write_text(json.dumps({"vessel": "x"}))
    with pytest.raises(AutopilotError, match="'coefficients'"):
        read_coefficients_json(bad)
    bad.write_text(json.dumps({"coefficients": {"T_nomoto": {"value": 70.0}}}))
    with pytest.raises(AutopilotError, match=r"coefficients\.K_nomoto, found only \['T_nomoto'\]"):
        read_coefficients_json(bad)
    bad.write_text(json.dumps({"coefficients": {"K_nomoto": {"value": None, "message": "no rudder steps"},
                                                "T_nomoto": {"value": 70.0}}}))
    with pytest.raises(AutopilotError, match="K_nomoto.value, found None .no rudder steps."):
        read_coefficients_json(bad)
    bad.write_text(json.dumps({"coefficients": {"K_nomoto": {"value": 0.1}, "T_nomoto": {"value": "70"}}}))
    with pytest.raises(AutopilotError, match="T_nomoto.value"):
        read_coefficients_json(bad)
    ok = read_coefficients_json(_coefficients(tmp_path))
    assert (ok.K, ok.K_stderr, ok.T, ok.T_stderr, ok.vessel) == (K_SEED, 0.004, T_SEED, 2.5, "cargo")


def test_negative_nomoto_gain_is_refused(tmp_path):
    coefs = read_coefficients_json(_coefficients(tmp_path, k=-0.15))
    with pytest.raises(AutopilotError, match="Nomoto K: expected a positive number"):
        build_autopilot(coefs, check=False)


def test_waves_reader(tmp_path):
    p = tmp_path / "w.json"
    p.write_text(json.dumps({"omega0": {"value": 0.8, "stderr": 0.01}, "lambda": {"value": 0.1, "stderr": None},
                             "kw": 0.01, "sigma": {"value": 0.06}}))
    params, se = read_waves_json(p)
    assert params == WaveParams(0.8, 0.1, 0.01) and se == {"omega0": 0.01}
    p.write_text(json.dumps({"omega0": 0.8, "kw": 0.01}))
    with pytest.raises(AutopilotError, match="positive number for lambda"):
        read_waves_json(p)
    p.write_text(json.dumps({"omega0": -0.8, "lambda": 0.1, "kw": 0.01}))
    with pytest.raises(AutopilotError, match="positive number for omega0"):
        read_waves_json(p)
    with pytest.raises(AutopilotError, match="no such file"):
        read_waves_json(tmp_path / "none.json")


def test_read_autopilot_toml_errors(tmp_path):
    with pytest.raises(AutopilotError, match="no such file"):
        read_autopilot_toml(tmp_path / "x.toml")
    p = tmp_path / "a.toml"
    p.write_text("ts = 0.1\n[model]\nK = 0.1\n[wave]\n[pd]\n[rudder]\n[kalman]\n")
    with pytest.raises(AutopilotError, match="expected key 'omega0'"):
        read_autopilot_toml(p)
    p.write_text("ts = [")
    with pytest.raises(AutopilotError, match="valid TOML"):
        read_autopilot_toml(p)


def test_nomoto_from_fits():
    est = {"K_nomoto": Estimate("K_nomoto", 0.15, 0.01, (0.13, 0.17), "1/s", 2, "sine"),
           "T_nomoto": Estimate("T_nomoto", 70.0, 3.0, (64.0, 76.0), "s", 2, "sine")}
    fits = Fits(vessel="v", estimates=est, segment_fits=(), damping_matrix=np.full((5, 5), np.nan),
                damping_stderr=np.full((5, 5), np.nan))
    c = nomoto_from_fits(fits)
    assert (c.K, c.T, c.K_stderr, c.T_stderr) == (0.15, 70.0, 0.01, 3.0)
    failed = Fits(vessel="v", estimates={**est, "T_nomoto": Estimate("T_nomoto", math.nan, math.nan,
                                                                       (math.nan, math.nan), "s", 0, "",
                                                                       success=False, message="no steps")},
                  segment_fits=(), damping_matrix=np.zeros((5, 5)), damping_stderr=np.zeros((5, 5)))
    with pytest.raises(AutopilotError, match="no steps"):
        nomoto_from_fits(failed)


def test_ardupilot_mapping_reproduces_the_pd_loop(tmp_path):
    cfg = build_autopilot_config(1.712, 4.21, crossover=0.5, rudder={"max_angle": 0.6109, "max_rate": 0.2618})
    p = ardupilot_params(cfg).params
    kd = cfg.K * cfg.rudder_max_angle
    # rate loop with feed-forward: (1 + P K dmax) / (T s + 1 + P K dmax) -> pole at 1/T_f
    assert (1 + p["ATC_STR_RAT_P"] * kd) / cfg.T == pytest.approx(1.0 / cfg.pd.tf)
    assert p["ATC_STR_RAT_FF"] * kd == pytest.approx(1.0)
    # angle loop: ANG_P / (s (1 + T_f s)) equals K_pd K / (s (1 + T_f s))
    assert p["ATC_STR_ANG_P"] == pytest.approx(cfg.pd.kpd * cfg.K)
    assert p["ATC_STR_RAT_MAX"] == pytest.approx(math.degrees(kd))
    out = write_ardupilot_params(cfg, tmp_path / "steer.param")
    lines = [ln for ln in out.read_text().splitlines() if not ln.startswith("#")]
    assert {ln.split(",")[0] for ln in lines} == set(p)
    # a slow cargo ship is flagged against ArduPilot's documented ranges
    slow = ardupilot_params(build_autopilot_config(K_SEED, T_SEED))
    assert any("outside ArduPilot's documented range" in n for n in slow.notes)


def test_stage_outputs_and_html_section(tmp_path):
    res = build_autopilot(read_coefficients_json(_coefficients(tmp_path)), duration=300.0)
    files, section = write_autopilot_outputs_and_section(res, tmp_path / "report")
    assert set(files) >= {"config", "ardupilot", "closed_loop", "figure_model", "figure_sea", "html"}
    doc = json.loads(files["closed_loop"].read_text())
    assert doc["observability"]["current and waves"]["rank"] == 5
    assert doc["metrics"]["sea"]["cases"]["pd"]["steady_error_deg"] > 2.0
    assert files["figure_sea"].read_bytes()[:4] == b"\x89PNG"
    title, frag = ap.autopilot_html_section(res)
    # The section the report page gets from the files' writer (figures drawn once) is the one drawn afresh.
    assert section == (title, frag)
    assert "autopilot" in title.lower()
    assert frag.count("<img") == 2 and "<table" in frag
    assert "steady heading error" in frag and "feed-forward removes it" in frag
    title2, frag2 = ap.autopilot_html_section(build_autopilot(read_coefficients_json(_coefficients(tmp_path)),
                                                              check=False), figures=False)
    assert "<img" not in frag2 and "ArduPilot" in frag2
