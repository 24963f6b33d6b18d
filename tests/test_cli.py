"""The vesselid CLI: contracts (exit codes, files written) and bad input (clear errors, no traceback)."""

from __future__ import annotations

import json
import re
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


def test_every_command_has_help(capsys):
    # The installed console script once (a real process), then every subcommand's --help in process.
    exe = shutil.which("vesselid", path=str(Path(sys.executable).parent))
    assert exe, "console script vesselid is installed in the venv"
    top = subprocess.run([exe, "--help"], capture_output=True, text=True)
    assert top.returncode == 0
    commands = ("ingest", "align", "segment", "fit", "report", "waves", "autopilot", "diagnose", "export",
                "batch", "catalog", "simulate", "run")
    for cmd in commands:
        assert cmd in top.stdout
        with pytest.raises(SystemExit) as done:
            main([cmd, "--help"])
        assert done.value.code == 0, cmd
        assert "usage:" in capsys.readouterr().out, cmd


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
    # The whole report (autopilot and diagnosis sections included) in a real browser.
    from chromium import chromium_binary, probe

    if chromium_binary() is not None:
        got = probe(rep / "report.html")
        assert got["images"] >= len(list(rep.glob("fit_*.png"))) and got["broken"] == [], got
        assert got["scrollWidth"] <= got["innerWidth"], got
        assert got["firstTableInSummary"] and got["summaryBottom"] <= got["innerHeight"], got


# --------------------------------------------------------------------------- issue 15: a CLI read in one minute
def test_version_is_what_the_report_footer_prints(capsys):
    from pipeline import __version__

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"vesselid {__version__}"


@pytest.mark.parametrize("argv, expected", [
    (["fit", "--vessel", VESSEL_TOML, "{log}", "--json", "{tmp}"], "--json {tmp}: expected a file name, found a folder"),
    (["fit", "--vessel", VESSEL_TOML, "{log}", "--json", "{tmp}/no/such/o.json"], "expected an existing folder"),
    (["report", "--vessel", VESSEL_TOML, "{log}", "--out", "{tmp}/afile"], "expected a report folder, found a file"),
    (["report", "--vessel", VESSEL_TOML, "{log}", "--out", "{tmp}/other"], "found a folder with other files"),
    (["run", "{tmp}/m.toml", "--out", "{tmp}/other"], "found a folder with other files"),
])
def test_outputs_are_checked_before_any_work(capsys, monkeypatch, surge_log, tmp_path, argv, expected):
    import pipeline.flow

    def no_work(*a, **k):
        raise AssertionError("work started before the output path was checked")

    monkeypatch.setattr(pipeline.flow, "load_trial", no_work)
    monkeypatch.setattr(pipeline.flow, "read_logs", no_work)
    (tmp_path / "afile").write_text("x")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "thesis.tex").write_text("mine")
    (tmp_path / "m.toml").write_text(f'name = "m"\nvessel = "{VESSEL_TOML}"\nlogs = ["{surge_log}"]\n')
    fill = lambda a: str(a).format(log=surge_log, tmp=tmp_path)  # noqa: E731
    code, _, err = run_cli(capsys, *map(fill, argv))
    assert code == 2 and err.startswith("error: ") and fill(expected) in err, err
    assert (tmp_path / "other" / "thesis.tex").read_text() == "mine"


def test_non_positive_definite_damping_is_an_error(capsys, surge_log, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(VESSEL_TOML.read_text().replace("diagonal = [2.86,", "diagonal = [-2.86,"))
    code, _, err = run_cli(capsys, "fit", "--vessel", bad, surge_log, "--json", tmp_path / "o.json")
    assert code == 2 and "positive definite" in err and "bad.toml" in err and "-2.86" in err


def test_errors_name_the_input_without_exception_names(capsys, tmp_path):
    folder = tmp_path / "coef_dir"
    folder.mkdir()
    code, _, err = run_cli(capsys, "autopilot", "--coefficients", folder, "--out", tmp_path / "a.toml")
    assert code == 2 and str(folder) in err and "folder" in err
    assert not re.search(r"(Value|OS|IsADirectory|FileNotFound|Key|Type)Error", err)


def test_fit_prints_a_summary_table_and_short_warnings_once(capsys, surge_log, tmp_path):
    code, out, err = run_cli(capsys, "fit", "--vessel", VESSEL_TOML, surge_log, "--json", tmp_path / "o.json")
    assert code == 0, err
    assert "D_uu = -X_u" in out and "Nomoto K" in out and "model structure" in out
    assert re.search(r"D_uu = -X_u\s+2\.8\d* \+- ", out), out
    assert "not identified: not identified" not in out + err
    assert all(len(line) <= 200 for line in (out + err).splitlines()), "one line per message, detail in JSON"
    warnings = [line for line in err.splitlines() if line.startswith("warning: ")]
    assert len(warnings) == len(set(warnings))


def test_force_in_kilonewton_is_caught(capsys, surge_log, tmp_path):
    """tau_x logged in kN parses fine; the gain-vs-mass damping check flags it (factor 1000)."""
    import pandas as pd

    df = pd.read_csv(surge_log)
    df["tau_x"] = df["tau_x"] / 1000.0
    kn = tmp_path / "surge_kN.csv"
    df.to_csv(kn, index=False)
    code, out, err = run_cli(capsys, "fit", "--vessel", VESSEL_TOML, kn, "--json", tmp_path / "o.json")
    assert code == 0, err
    assert "warning: surge: damping from the step gain" in err and "tau_x (N, not kN)" in err, err


@pytest.mark.slow
def test_report_and_run_write_the_same_report_and_a_rerun_replaces_the_folder(capsys, surge_log, tmp_path):
    manifest = tmp_path / "trial.toml"
    manifest.write_text(f'name = "surge"\nvessel = "{VESSEL_TOML}"\nlogs = ["{surge_log}"]\n')
    a, b = tmp_path / "by_run", tmp_path / "by_report"
    b.mkdir()
    (b / "coefficients.json").write_text("{}")          # an earlier report folder ...
    (b / "fit_99_gone_surge.png").write_bytes(b"old")  # ... with a figure this run does not make
    code, out, err = run_cli(capsys, "run", manifest, "--out", a)
    assert code == 0, err
    assert "D_uu = -X_u" in out
    code, _, err = run_cli(capsys, "report", "--vessel", VESSEL_TOML, surge_log, "--out", b)
    assert code == 0, err
    assert sorted(p.name for p in a.iterdir()) == sorted(p.name for p in b.iterdir())
    assert not (b / "fit_99_gone_surge.png").exists()
    assert json.loads((a / "coefficients.json").read_text()) == json.loads((b / "coefficients.json").read_text())
    strip = lambda p: re.sub(r"<footer>.*</footer>", "", p.read_text(), flags=re.S)  # noqa: E731
    assert strip(a / "report.html") == strip(b / "report.html")
    footer = (b / "report.html").read_text().split("<footer>")[1]
    assert "vesselid report --vessel" in footer and surge_log.name in footer and "created 20" in footer
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".vesselid-")], "no staging folder left"


def test_segment_review_page_offers_the_segments_json_fit_reads(capsys, surge_log, tmp_path):
    """Optional plotly page: segments shaded with hover text; its download link is a valid --segments file."""
    pytest.importorskip("plotly")
    from urllib.parse import unquote

    page = tmp_path / "review.html"
    code, out, err = run_cli(capsys, "segment", surge_log, "--review", page)
    assert code == 0, err
    text = page.read_text()
    assert "segment 0: step \\u002f surge" in text and "plotly" in text.lower()  # plotly escapes "/"
    m = re.search(r'download="segments.json" href="data:application/json;charset=utf-8,([^"]+)"', text)
    seg_file = tmp_path / "from_review.json"
    seg_file.write_text(unquote(m.group(1)))
    code, out, err = run_cli(capsys, "fit", "--vessel", VESSEL_TOML, surge_log, "--segments", seg_file,
                             "--json", tmp_path / "c.json", "--review", tmp_path / "fit_review.html")
    assert code == 0, err
    # With fits, the hover text gives each segment's fit % (MATLAB compare).
    assert re.search(r"on u: fit \d+\.\d %", (tmp_path / "fit_review.html").read_text())
    assert json.loads((tmp_path / "c.json").read_text())["coefficients"]["X_u"]["value"] == pytest.approx(-2.86, rel=0.02)
    from chromium import chromium_binary, probe

    if chromium_binary() is not None:
        got = probe(page)
        assert got["broken"] == [] and got["scrollWidth"] <= got["innerWidth"], got


def test_numeric_warnings_do_not_reach_the_user(monkeypatch, tmp_path, capsys):
    """A floating-point RuntimeWarning inside a command is not printed; other warnings are."""
    import warnings

    import pipeline.cli as cli

    def noisy(args):
        np.log(np.array([-1.0]))            # invalid value: RuntimeWarning
        warnings.warn("kept", UserWarning)  # another category still reaches the user
        return 0

    monkeypatch.setattr(cli, "cmd_run", noisy)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        assert main(["run", str(tmp_path)]) == 0
    categories = [w.category for w in seen]
    assert RuntimeWarning not in categories
    assert UserWarning in categories
