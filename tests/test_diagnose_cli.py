"""``vesselid diagnose``: the JSON contract, figures, and bad input (errors name what was expected
and what was found, exit code 2, no traceback)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.cli import main
from diagnose_synthetic import simulated_trial
from pipeline.sim import Effects, sea_trial
from pipeline.vessel import parse_vessel

SHIP = parse_vessel({"name": "small", "nomoto": {"K": 0.5, "T": 5.0}})
CANDIDATE_KEYS = {"effect", "dof", "gap_before", "gap_after", "shrink", "significant"}
DOF_NAMES = {"surge", "sway", "heave", "roll", "pitch", "yaw"}


@pytest.fixture(scope="module")
def delayed_log(tmp_path_factory):
    """A small rudder ship's sea trial with a 0.3 s actuator delay, as canonical CSV, and its
    vessel TOML holding only ``name`` (a rudder ship's minimal config)."""
    folder = tmp_path_factory.mktemp("diagnose_cli")
    _, path = simulated_trial(SHIP, sea_trial(SHIP), Effects(actuator_delay=0.3), folder, "delayed", seed=5)
    toml = folder / "ship.toml"
    toml.write_text('name = "small"\n')
    return path, toml


@pytest.fixture(scope="module")
def cli_outputs(delayed_log, tmp_path_factory):
    """One ``vesselid diagnose --json --plots`` run on the delayed trial: (JSON path, plots folder, printed text)."""
    import contextlib
    import io

    log, toml = delayed_log
    folder = tmp_path_factory.mktemp("diagnose_cli_out")
    out, plots = folder / "diag.json", folder / "plots"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = main(["diagnose", "--vessel", str(toml), str(log), "--json", str(out), "--plots", str(plots)])
    assert code == 0
    return out, plots, printed.getvalue()


def test_contract(cli_outputs):
    out, _, printed = cli_outputs
    doc = json.loads(out.read_text())
    assert doc["verdict"] == {"effect": "actuator_delay", "dof": "yaw"}
    assert isinstance(doc["gap_before"], float) and isinstance(doc["gap_after"], float)
    assert doc["gap_after"] < doc["gap_before"]
    assert doc["candidates"], "every tested candidate is listed"
    for c in doc["candidates"]:
        assert CANDIDATE_KEYS <= set(c)
        assert c["dof"] in DOF_NAMES and isinstance(c["significant"], bool)
        assert c["shrink"] is None or isinstance(c["shrink"], float)
    assert any(c["significant"] and c["effect"] == "actuator_delay" for c in doc["candidates"])
    assert "verdict: actuator_delay in yaw" in printed


def test_plots_and_html_section(delayed_log, cli_outputs):
    from pipeline.diagnose import diagnose
    from pipeline.diagnose.html import diagnose_html_section
    from pipeline.flow import load_trial

    log, _ = delayed_log
    _, plots, _ = cli_outputs
    names = sorted(p.name for p in plots.iterdir())
    assert "diagnose_where.png" in names and "diagnose_overlay_yaw.png" in names
    assert all((plots / n).stat().st_size > 1000 for n in names)
    report = diagnose(load_trial([log], SHIP), SHIP)
    title, fragment = diagnose_html_section(report)
    assert title and "actuator_delay" in fragment and "diagnose_overlay_yaw.png" in fragment
    assert "<script" not in fragment


def test_clean_trial_contract_has_null_verdict(tmp_path):
    _, path = simulated_trial(SHIP, sea_trial(SHIP), Effects(), tmp_path, "clean", seed=2)
    toml = tmp_path / "ship.toml"
    toml.write_text('name = "small"\n')
    out = tmp_path / "diag.json"
    assert main(["diagnose", "--vessel", str(toml), str(path), "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["verdict"] == {"effect": None, "dof": None}
    assert doc["gap_after"] == doc["gap_before"]
    assert not any(c["significant"] for c in doc["candidates"])


def _error(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "Traceback" not in err
    return err


def test_missing_log_file(delayed_log, tmp_path, capsys):
    _, toml = delayed_log
    err = _error(capsys, ["diagnose", "--vessel", str(toml), str(tmp_path / "nope.csv"), "--json",
                          str(tmp_path / "o.json")])
    assert "expected" in err and "nope.csv" in err


def test_empty_log(delayed_log, tmp_path, capsys):
    _, toml = delayed_log
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    err = _error(capsys, ["diagnose", "--vessel", str(toml), str(empty), "--json", str(tmp_path / "o.json")])
    assert "expected" in err


def test_non_monotonic_time(delayed_log, tmp_path, capsys):
    _, toml = delayed_log
    bad = tmp_path / "back.csv"
    bad.write_text("t,r,delta\n0.0,0.0,0.0\n0.2,0.01,0.1\n0.1,0.02,0.1\n")
    err = _error(capsys, ["diagnose", "--vessel", str(toml), str(bad), "--json", str(tmp_path / "o.json")])
    assert "increasing" in err


def test_wrong_unit_degrees_in_radian_column(delayed_log, tmp_path, capsys):
    _, toml = delayed_log
    t = np.arange(0, 20, 0.1)
    bad = tmp_path / "deg.csv"
    bad.write_text("t,r,delta\n" + "\n".join(f"{x:.2f},{10.0 * np.sin(x):.4f},{20.0 if x > 5 else 0.0}" for x in t))
    err = _error(capsys, ["diagnose", "--vessel", str(toml), str(bad), "--json", str(tmp_path / "o.json")])
    assert "expected" in err and "found" in err


def test_no_response_channel(delayed_log, tmp_path, capsys):
    _, toml = delayed_log
    t = np.arange(0, 60, 0.1)
    bad = tmp_path / "noresp.csv"
    bad.write_text("t,delta\n" + "\n".join(f"{x:.2f},{0.1 if 10 < x < 30 else 0.0}" for x in t))
    err = _error(capsys, ["diagnose", "--vessel", str(toml), str(bad), "--json", str(tmp_path / "o.json")])
    assert "expected" in err and "found" in err


def test_no_manoeuvre_at_all(delayed_log, tmp_path, capsys):
    _, toml = delayed_log
    t = np.arange(0, 60, 0.1)
    rng = np.random.default_rng(0)
    flat = tmp_path / "flat.csv"
    flat.write_text("t,r\n" + "\n".join(f"{x:.2f},{0.001 * rng.standard_normal():.5f}" for x in t))
    err = _error(capsys, ["diagnose", "--vessel", str(toml), str(flat), "--json", str(tmp_path / "o.json")])
    assert "expected" in err and "found" in err


def test_bad_vessel_config(delayed_log, tmp_path, capsys):
    log, _ = delayed_log
    toml = tmp_path / "bad.toml"
    toml.write_text('name = "x"\nmass = 3\n')
    err = _error(capsys, ["diagnose", "--vessel", str(toml), str(log), "--json", str(tmp_path / "o.json")])
    assert "mass" in err and "allowed" in err


def test_json_into_missing_folder(delayed_log, tmp_path, capsys):
    log, toml = delayed_log
    err = _error(capsys, ["diagnose", "--vessel", str(toml), str(log), "--json", str(tmp_path / "no" / "o.json")])
    assert "expected an existing folder" in err


def test_required_arguments(delayed_log, capsys):
    log, toml = delayed_log
    with pytest.raises(SystemExit) as exc:
        main(["diagnose", str(log), "--json", "o.json"])
    assert exc.value.code == 2
    with pytest.raises(SystemExit) as exc:
        main(["diagnose", "--vessel", str(toml), str(log)])
    assert exc.value.code == 2
    assert "--json" in capsys.readouterr().err
