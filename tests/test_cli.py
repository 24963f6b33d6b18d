"""The vesselid CLI: contracts (exit codes, files written) and bad input (clear errors, no traceback)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.cli import main
from pipeline.sim import chain, simulate, step_and_coast
from pipeline.sim.writers import write_log
from pipeline.vessel import load_vessel

ROOT = Path(__file__).resolve().parents[1]
from conftest import AAUSHIP_TOML as VESSEL_TOML  # noqa: E402
VESSEL = load_vessel(VESSEL_TOML)


@pytest.fixture(scope="module")
def surge_log(tmp_path_factory) -> Path:
    """A short real CSV log: surge step and coast-down of the sample vessel."""
    res = simulate(VESSEL, chain(step_and_coast("surge", 4.29, 25.0, 25.0), rest_s=5.0), seed=3)
    return write_log(res.log, tmp_path_factory.mktemp("cli") / "surge.csv")


def run_cli(capsys, *argv: str) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_every_command_has_help():
    exe = shutil.which("vesselid", path=str(Path(sys.executable).parent))
    assert exe, "console script vesselid is installed in the venv"
    top = subprocess.run([exe, "--help"], capture_output=True, text=True)
    assert top.returncode == 0
    for cmd in ("ingest", "align", "segment", "fit", "report", "simulate", "run"):
        assert cmd in top.stdout
        res = subprocess.run([exe, cmd, "--help"], capture_output=True, text=True)
        assert res.returncode == 0 and "usage:" in res.stdout, cmd


def test_fit_writes_json_contract(capsys, surge_log, tmp_path):
    out = tmp_path / "coef.json"
    code, stdout, err = run_cli(capsys, "fit", "--vessel", VESSEL_TOML, surge_log, "--json", out)
    assert code == 0, err
    doc = json.loads(out.read_text())
    assert doc["vessel"] == "aauship"
    assert doc["damping_matrix"]["dofs"] == ["u", "v", "p", "q", "r"]
    xu = doc["coefficients"]["X_u"]
    assert set(xu) >= {"value", "stderr", "ci95", "unit", "n_segments", "method"}
    assert xu["value"] == pytest.approx(-2.86, rel=0.02)
    assert doc["damping_matrix"]["values"][1][1] is None, "sway not excited: null, not a number"


def test_segment_prints_table_and_plots(capsys, surge_log, tmp_path):
    png = tmp_path / "seg.png"
    code, stdout, err = run_cli(capsys, "segment", surge_log, "--plot", png, "--json", tmp_path / "s.json")
    assert code == 0, err
    assert "coast_down" in stdout and "step" in stdout
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    segs = json.loads((tmp_path / "s.json").read_text())["segments"]
    assert {s["kind"] for s in segs} >= {"step", "coast_down"}


@pytest.mark.parametrize("cmd", ["ingest", "align", "segment", "fit", "report"])
def test_empty_file_is_a_clear_error(capsys, tmp_path, cmd):
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    extra = {"fit": ["--vessel", VESSEL_TOML, "--json", tmp_path / "o.json"],
             "report": ["--vessel", VESSEL_TOML, "--out", tmp_path / "r"]}.get(cmd, [])
    code, _, err = run_cli(capsys, cmd, empty, *extra)
    assert code != 0
    assert err.startswith("error: ") and "empty" in err and "Traceback" not in err


def test_truncated_tlog_is_reported(capsys, surge_log, tmp_path):
    tlog = write_log(simulate(VESSEL, chain(step_and_coast("surge", 4.29, 10.0, 10.0)), seed=1).log,
                     tmp_path / "t.tlog", vessel=VESSEL)
    cut = tmp_path / "cut.tlog"
    cut.write_bytes(tlog.read_bytes()[:37])  # less than one complete message after the first
    code, out, err = run_cli(capsys, "ingest", "--vessel", VESSEL_TOML, cut)
    if code == 0:
        assert "truncated" in out
    else:
        assert err.startswith("error: ")


def test_non_monotonic_time(capsys, tmp_path):
    p = tmp_path / "back.csv"
    p.write_text("t,u\n0.0,1.0\n0.1,0.9\n0.05,0.8\n")
    code, _, err = run_cli(capsys, "ingest", p)
    assert code != 0 and "strictly increasing" in err and "row" in err


def test_missing_channel_for_fit(capsys, tmp_path):
    p = tmp_path / "only_psi.csv"
    t = np.arange(0, 10, 0.1)
    p.write_text("t,psi\n" + "\n".join(f"{a:.2f},{0.01 * a:.4f}" for a in t) + "\n")
    code, out, err = run_cli(capsys, "fit", "--vessel", VESSEL_TOML, p, "--json", tmp_path / "o.json")
    # Nothing to fit is not a crash: the JSON says every coefficient is not identified and why.
    if code == 0:
        doc = json.loads((tmp_path / "o.json").read_text())
        assert all(v["value"] is None for v in doc["coefficients"].values())
    else:
        assert err.startswith("error: ")


def test_unknown_config_key(capsys, surge_log, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(VESSEL_TOML.read_text().replace("[restoring]", "[restoring]\nheave = 3.0"))
    code, _, err = run_cli(capsys, "fit", "--vessel", bad, surge_log, "--json", tmp_path / "o.json")
    assert code != 0 and "heave" in err and "allowed" in err


def test_segment_too_short_to_fit(capsys, surge_log, tmp_path):
    seg = tmp_path / "short.json"
    seg.write_text(json.dumps({"trial": "x", "segments": [
        {"kind": "coast_down", "dof": "surge", "t_start": 30.0, "t_end": 30.05, "input_channel": "tau_x",
         "input_before": 4.29, "input_after": 0.0, "quality": 1.0, "origin": "manifest", "label": ""}]}))
    out = tmp_path / "o.json"
    code, stdout, err = run_cli(capsys, "fit", "--vessel", VESSEL_TOML, surge_log, "--segments", seg, "--json", out)
    text = stdout + err + (out.read_text() if out.exists() else "")
    assert "expected" in text and "found" in text, "the failure names what was expected and what was found"
    if code == 0:
        assert json.loads(out.read_text())["coefficients"]["X_u"]["value"] is None


def test_run_manifest_errors(capsys, tmp_path):
    code, _, err = run_cli(capsys, "run", tmp_path / "none.toml")
    assert code != 0 and "expected a TOML file" in err
    bad = tmp_path / "trial.toml"
    bad.write_text('vessel = "x.toml"\nlogs = ["nope.csv"]\ncolour = 1\n')
    code, _, err = run_cli(capsys, "run", bad)
    assert code != 0 and "colour" in err


@pytest.mark.slow  # a whole simulated day through every stage: make test-all
def test_simulate_then_run_end_to_end(capsys, tmp_path):
    log = tmp_path / "sim.csv"
    code, _, err = run_cli(capsys, "simulate", "--vessel", VESSEL_TOML, "--out", log, "--seed", "5")
    assert code == 0, err
    manifest = tmp_path / "trial.toml"
    manifest.write_text(f'name = "e2e"\nvessel = "{VESSEL_TOML}"\nlogs = ["sim.csv"]\n')
    before = log.stat().st_mtime_ns, log.read_bytes()[:1000]
    code, _, err = run_cli(capsys, "run", manifest, "--out", tmp_path / "rep")
    assert code == 0, err
    assert (log.stat().st_mtime_ns, log.read_bytes()[:1000]) == before, "input files are never modified"
    rep = tmp_path / "rep"
    for name in ("coefficients.json", "coefficients.tex", "coefficients.md", "report.html", "segments.json"):
        assert (rep / name).is_file(), name
    assert list(rep.glob("*.png")), "one figure per fit"
    assert not [p for p in rep.iterdir() if p.name.endswith(".tmp")], "atomic writes leave no temp files"
