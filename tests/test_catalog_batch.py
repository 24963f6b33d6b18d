"""``vesselid batch`` on a tree of real simulated trials (DataFlash logs written by the simulator,
read back by the pipeline): the catalogue fills, compare and trend find the injected fouling, a
batch runs on a real ``dask scheduler`` process, and a batch killed with SIGKILL part-way leaves a
consistent catalogue that a rerun completes."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pipeline.catalog import Catalog
from pipeline.catalog.synthetic import VesselVariant, write_fleet
from pipeline.cli import main

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow
#: Fouling large enough to be unmistakable over 3 trials at the tests' short, low-rate logs.
FLEET = (VesselVariant("fouler", 1.2, 1.1, 0.15, (56.15, 10.21)), VesselVariant("skiff", 1.0, 1.0, 0.0))


def env() -> dict:
    e = dict(os.environ, CI="1")
    e["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + [p for p in e.get("PYTHONPATH", "").split(os.pathsep) if p])
    return e


@pytest.fixture(scope="module")
def tree(tmp_path_factory) -> Path:
    """fouler-01..03 (surge damping +15 %/trial), skiff-01, and one broken manifest."""
    root = tmp_path_factory.mktemp("trials")
    write_fleet(root, 3, FLEET[:1], rate=5.0, rudder=False)
    write_fleet(root, 1, FLEET[1:], rate=5.0, rudder=False)
    broken = root / "broken"
    broken.mkdir()
    (broken / "trial.toml").write_text(f'name = "broken"\nvessel = "{root}/vessels/skiff.toml"\nlogs = ["gone.bin"]\n')
    return root


@pytest.fixture(scope="module")
def filled(tree, tmp_path_factory):
    """The catalogue after one batch over the tree (2 local workers)."""
    out = tmp_path_factory.mktemp("cat")
    cat = out / "cat.duckdb"
    code = main(["batch", str(tree), "--catalog", str(cat), "--workers", "2", "--quick"])
    return cat, code


def test_batch_fills_the_catalogue_and_records_the_failure(filled, capsys):
    cat, code = filled
    assert code == 1  # one trial failed, and says so
    with Catalog(cat) as c:
        trials = c.trials().set_index("name")
        assert sorted(trials.index) == ["broken", "fouler-01", "fouler-02", "fouler-03", "skiff-01"]
        assert (trials.drop("broken")["status"] == "ok").all()
        assert trials.loc["broken", "status"] == "failed" and "expected log files" in trials.loc["broken", "error"]
        ok = trials.drop("broken")
        for t in ok.itertuples():
            assert (Path(t.report_dir) / "report.html").is_file()
            assert t.date_source.startswith("log clock")
            files = c.table("files", t.trial_id)
            assert sorted(files["role"]) == ["log", "manifest", "vessel"] and files["sha256"].str.len().eq(64).all()
            assert len(c.table("segments", t.trial_id)) > 0 and len(c.table("runs", t.trial_id)) == 1
            xu = c.coefficients(t.trial_id).set_index("name").loc["X_u"]
            assert xu["success"] and xu["stderr"] > 0 and xu["ci_low"] < xu["value"] < xu["ci_high"]
        assert ok.loc["fouler-01", "lat"] == pytest.approx(56.15, abs=0.01)
        dates = ok.loc[["fouler-01", "fouler-02"], "started_utc"]
        assert (dates.iloc[1] - dates.iloc[0]).days == 7
        assert c.query("SELECT count(DISTINCT config_hash) AS n FROM vessels")["n"].iloc[0] == 2
    pages = cat.parent / "reports" / "catalog"
    assert (pages / "index.html").is_file()
    page = (pages / "vessel-fouler.html").read_text()
    assert "report.html" in page and "significant drift" in page


def test_second_run_skips_catalogued_trials(filled, tree, capsys):
    cat, _ = filled
    capsys.readouterr()
    code = main(["batch", str(tree), "--catalog", str(cat), "--workers", "1", "--quick"])
    out = capsys.readouterr().out
    assert code == 1 and "4 skipped" in out and "catalogued broken" in out and "catalogued fouler" not in out
    with Catalog(cat) as c:
        assert len(c.trials()) == 5


def test_compare_and_trend_find_the_fouling(filled, capsys, tmp_path):
    cat, _ = filled
    capsys.readouterr()
    assert main(["catalog", "compare", "fouler-01", "fouler-03", "--catalog", str(cat)]) == 0
    out = capsys.readouterr().out
    assert "Holm" in out
    xu = next(line for line in out.splitlines() if line.strip().startswith("X_u "))
    assert "YES" in xu
    assert main(["catalog", "trend", "X_u", "--catalog", str(cat), "--plot", str(tmp_path / "xu.png")]) == 0
    out = capsys.readouterr().out
    fouler = out.split("fouler:")[1].split("skiff:")[0]
    assert "SIGNIFICANT drift" in fouler
    assert "need 3 or more" in out.split("skiff:")[1]
    assert (tmp_path / "xu-fouler.png").is_file()
    with Catalog(cat) as c:
        from pipeline.catalog.stats import coefficient_trend

        tr = next(t for t in coefficient_trend(c, "X_u") if t.vessel == "fouler")
    # Truth: X_u = -D[0,0] grows 15 %/trial compounded, trials 7 days apart.
    per_trial = tr.rel_slope * 7
    assert per_trial == pytest.approx(-0.1611, abs=max(3 * tr.rel_slope_se * 7, 0.02))
    assert main(["catalog", "show", "fouler-02", "--catalog", str(cat)]) == 0
    assert "X_u" in capsys.readouterr().out
    assert main(["catalog", "export", "--catalog", str(cat), "--out", str(tmp_path / "all.parquet")]) == 0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_batch_on_an_existing_dask_scheduler(tree, tmp_path, capsys):
    dask = shutil.which("dask", path=str(Path(sys.executable).parent))
    assert dask, "the dask command is installed with dask[distributed]"
    port = _free_port()
    addr = f"tcp://127.0.0.1:{port}"
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                              env=env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        procs.append(subprocess.Popen([dask, "worker", addr, "--nworkers", "1", "--nthreads", "1", "--no-dashboard"],
                                      env=env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        cat = tmp_path / "sched.duckdb"
        code = main(["batch", str(tree / "skiff"), "--catalog", str(cat), "--scheduler", addr, "--quick"])
        out = capsys.readouterr()
        assert code == 0, out.err
        assert "1 processed" in out.out
        with Catalog(cat) as c:
            t = c.resolve("skiff-01")
            assert t["status"] == "ok" and "--scheduler" in t["command"]
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            p.wait(timeout=30)


def test_scheduler_that_is_not_there_is_a_clear_error(tree, tmp_path, capsys):
    code = main(["batch", str(tree / "skiff"), "--catalog", str(tmp_path / "c.duckdb"),
                 "--scheduler", f"tcp://127.0.0.1:{_free_port()}", "--quick"])
    assert code == 2
    assert "expected a dask.distributed scheduler" in capsys.readouterr().err


def _consistent(cat: Path) -> int:
    """Assert the catalogue holds only whole trials; return the number of processed trials."""
    with Catalog(cat) as c:
        orphans = c.query("SELECT count(*) AS n FROM coefficients WHERE trial_id NOT IN (SELECT trial_id FROM trials)")
        assert orphans["n"].iloc[0] == 0
        ok = c.trials()
        assert ok["trial_id"].is_unique
        for t in ok.itertuples():
            assert t.status == "ok"
            assert len(c.coefficients(t.trial_id)) > 0 and len(c.table("files", t.trial_id)) == 3
            assert (Path(t.report_dir) / "coefficients.json").is_file()
        return len(ok)


def test_sigkill_part_way_leaves_a_consistent_catalogue_that_a_rerun_completes(tree, tmp_path):
    cat = tmp_path / "kill.duckdb"
    trials = tmp_path / "two"
    for name in ("fouler-01", "fouler-02"):
        shutil.copytree(tree / "fouler" / name, trials / name)
    args = [sys.executable, "-m", "pipeline.cli", "batch", str(trials), "--catalog", str(cat),
            "--workers", "1", "--quick"]
    proc = subprocess.Popen(args, env=env(), stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            start_new_session=True)
    try:
        first = proc.stdout.readline()
        assert first.startswith("catalogued fouler-"), first
        # Kill the batch and its Dask workers (one process group) while the next trial is in flight.
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == -signal.SIGKILL
    n = _consistent(cat)
    assert n == 1
    res = subprocess.run(args, env=env(), capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert f"{n} skipped" in res.stdout
    assert _consistent(cat) == 2
    leftovers = [p for p in (tmp_path / "reports").iterdir() if p.name.startswith(".")]
    # A killed trial's partial folder stays hidden (never under the trial's name).
    assert all(".partial-" in p.name for p in leftovers)
