"""``vesselid autopilot`` and ``vesselid waves`` handlers through their own argparse parsers."""

import argparse
import json
import math
import tomllib

import numpy as np
import pytest

from pipeline.autopilot.cli import add_autopilot_parser, add_waves_parser, cmd_autopilot
from pipeline.errors import AutopilotError


def _parser():
    ap = argparse.ArgumentParser(prog="vesselid")
    sub = ap.add_subparsers(dest="command")
    add_waves_parser(sub)
    add_autopilot_parser(sub)
    return ap


def _coefficients(tmp_path, k=0.1561, t=72.4385):
    p = tmp_path / "coefficients.json"
    p.write_text(json.dumps({"vessel": "cargo", "coefficients": {
        "K_nomoto": {"value": k, "stderr": 0.004, "unit": "1/s"},
        "T_nomoto": {"value": t, "stderr": 2.5, "unit": "s"}}}))
    return p


def _run(tmp_path, *argv):
    args = _parser().parse_args(["autopilot", "--coefficients", str(_coefficients(tmp_path)),
                                 "--out", str(tmp_path / "autopilot.toml"), *argv])
    return args.func(args)


def test_help_exits_zero():
    for cmd in ("autopilot", "waves"):
        with pytest.raises(SystemExit) as e:
            _parser().parse_args([cmd, "--help"])
        assert e.value.code == 0


def test_autopilot_writes_the_seed_design(tmp_path, capsys):
    assert _run(tmp_path, "--crossover", "0.1") == 0  # the seed's omega_c
    doc = tomllib.loads((tmp_path / "autopilot.toml").read_text())
    assert doc["pd"]["tf"] == pytest.approx(8.391, abs=5e-4)
    assert doc["pd"]["kpd"] == pytest.approx(0.836, abs=5e-4)
    assert doc["pd"]["td"] == pytest.approx(72.4385)
    assert doc["model"] == {"K": 0.1561, "T": 72.4385, "K_stderr": 0.004, "T_stderr": 2.5}
    out = capsys.readouterr().out
    assert "kpd = 0.8363" in out and "note:" in out


def test_autopilot_options(tmp_path):
    waves = tmp_path / "waves.json"
    waves.write_text(json.dumps({"omega0": {"value": 0.8, "stderr": 0.01}, "lambda": {"value": 0.1, "stderr": 0.01},
                                 "kw": {"value": 0.01, "stderr": 0.001}}))
    vessel = tmp_path / "v.toml"
    vessel.write_text('name = "boat"\n[rudder]\nmax_angle = 0.5\nmax_rate = 0.1\n')
    ap_file = tmp_path / "steer.param"
    assert _run(tmp_path, "--waves", str(waves), "--vessel", str(vessel), "--crossover", "0.05",
                "--phase-margin", "60", "--ts", "0.2", "--noise-std-deg", "0.1", "--q-wave", "1",
                "--ardupilot", str(ap_file)) == 0
    doc = tomllib.loads((tmp_path / "autopilot.toml").read_text())
    assert doc["ts"] == 0.2
    assert doc["wave"]["omega0"] == 0.8 and doc["wave"]["omega0_stderr"] == 0.01
    assert doc["pd"]["crossover"] == 0.05 and math.degrees(doc["pd"]["phase_margin"]) == pytest.approx(60.0)
    assert doc["rudder"]["max_angle"] == 0.5 and doc["rudder"]["max_rate"] == 0.1
    assert doc["kalman"]["r"] == pytest.approx(math.radians(0.1) ** 2)
    assert doc["kalman"]["q"][0][0] == 1.0
    roles = {s["role"] for s in doc["provenance"]["sources"]}
    assert roles == {"coefficients", "waves", "vessel"}
    assert "ATC_STR_ANG_P" in ap_file.read_text()


def test_compass_noise_from_a_still_record(tmp_path):
    rng = np.random.default_rng(4)
    sd = math.radians(0.05)
    t = 0.1 * np.arange(3000)
    still = tmp_path / "still.csv"
    np.savetxt(still, np.column_stack([t, 1.0 + sd * rng.standard_normal(len(t))]), delimiter=",",
               header="t,psi", comments="")
    assert _run(tmp_path, "--still", str(still)) == 0
    doc = tomllib.loads((tmp_path / "autopilot.toml").read_text())
    assert doc["kalman"]["r"] == pytest.approx(sd**2, rel=0.1)
    assert any("still record" in n for n in doc["provenance"]["notes"])


def test_report_dir_runs_the_closed_loop_check(tmp_path, capsys):
    assert _run(tmp_path, "--report-dir", str(tmp_path / "rep")) == 0
    doc = json.loads((tmp_path / "rep" / "closed_loop.json").read_text())
    sea = doc["metrics"]["sea"]["cases"]
    assert sea["pd"]["steady_error_deg"] > 2.0 and abs(sea["pd_kalman_ff"]["steady_error_deg"]) < 0.5
    assert (tmp_path / "rep" / "autopilot.html").read_text().count("<img") == 2
    assert "steady error" in capsys.readouterr().out


@pytest.mark.parametrize("argv, match", [
    (["--phase-margin", "95"], "--phase-margin: expected degrees between 0 and 90"),
    (["--phase-margin", "nan"], "--phase-margin"),
    (["--crossover", "0"], "--crossover: expected a positive number"),
    (["--ts", "-0.1"], "--ts"),
    (["--noise-std-deg", "0"], "--noise-std-deg"),
    (["--q-bias", "-1"], "--q-bias"),
    (["--waves", "/nonexistent/waves.json"], "no such file"),
    (["--vessel", "/nonexistent/v.toml"], "--vessel: vessel config"),
])
def test_autopilot_bad_arguments(tmp_path, argv, match):
    with pytest.raises(AutopilotError, match=match):
        _run(tmp_path, *argv)


def test_autopilot_missing_nomoto(tmp_path):
    p = tmp_path / "c.json"
    p.write_text(json.dumps({"coefficients": {"K_nomoto": {"value": 0.1}, "T_nomoto": {"value": None}}}))
    args = _parser().parse_args(["autopilot", "--coefficients", str(p), "--out", str(tmp_path / "a.toml")])
    with pytest.raises(AutopilotError, match="T_nomoto"):
        args.func(args)
    assert not (tmp_path / "a.toml").exists()


def test_vessel_with_unknown_key_is_reported(tmp_path):
    v = tmp_path / "v.toml"
    v.write_text('name = "boat"\n[rudder]\nmax_angel = 0.5\n')
    with pytest.raises(AutopilotError, match="max_angel"):
        _run(tmp_path, "--vessel", str(v))


def test_still_and_noise_std_are_exclusive(tmp_path):
    with pytest.raises(SystemExit):
        _parser().parse_args(["autopilot", "--coefficients", "c.json", "--out", "a.toml",
                              "--still", "s.csv", "--noise-std-deg", "0.1"])


def test_handler_signature_is_the_namespace():
    args = _parser().parse_args(["autopilot", "--coefficients", "c.json", "--out", "a.toml"])
    assert args.func is cmd_autopilot and args.phase_margin == 50.0 and args.crossover is None


def test_default_crossover_is_the_one_run_uses(tmp_path):
    """vesselid autopilot and vesselid run share one default: omega_c = CROSSOVER_TIMES_T / T."""
    from pipeline.autopilot.pd import CROSSOVER_TIMES_T, default_crossover
    from pipeline.flow import design_autopilot
    from pipeline.records import Estimate, Fits
    import numpy as np

    assert _run(tmp_path) == 0
    doc = tomllib.loads((tmp_path / "autopilot.toml").read_text())
    assert doc["pd"]["crossover"] == pytest.approx(CROSSOVER_TIMES_T / 72.4385)
    est = {"K_nomoto": Estimate("K_nomoto", 0.1561, 0.004, (0.148, 0.164), "1/s", 1, "test"),
           "T_nomoto": Estimate("T_nomoto", 72.4385, 2.5, (67.5, 77.3), "s", 1, "test")}
    nan = np.full((5, 5), np.nan)
    flow = design_autopilot(Fits("cargo", est, (), nan, nan))
    assert flow.config.pd.crossover == pytest.approx(doc["pd"]["crossover"], rel=1e-12)
    assert flow.config.pd.kpd == pytest.approx(doc["pd"]["kpd"], rel=1e-12)
    assert default_crossover(72.4385) == pytest.approx(0.1, rel=1e-3)
