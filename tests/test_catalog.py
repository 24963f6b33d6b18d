"""The trial catalogue without the pipeline: schema migration, transactional replace, version
keeping, compare (Holm), trend (drift), export and the CLI's errors, on a real DuckDB file."""

from __future__ import annotations

import hashlib
import math
from datetime import datetime, timezone
from pathlib import Path

import duckdb
import numpy as np
import pandas as pd
import pytest

from pipeline.catalog import Catalog, CatalogError, SCHEMA_VERSION, TrialIdentity, TrialRecord
from pipeline.catalog.schema import current_version
from pipeline.catalog.stats import coefficient_trend, compare_trials, fit_drift, holm
from pipeline.catalog.trial_job import identify_trial, model_structure
from pipeline.cli import main


def record(name: str, values: dict[str, tuple[float, float]], version: str = "0.1.0", vessel: str = "boat",
           day: float = 0.0, files_hash: str | None = None, status: str = "ok") -> TrialRecord:
    """A hand-made trial record (what a worker returns), with coefficients name -> (value, stderr)."""
    fh = files_hash or f"hash-{name}"
    ident = TrialIdentity(trial_id=hashlib.sha256(f"{fh}\n{version}".encode()).hexdigest()[:16],
                          name=name, manifest=Path(f"/trials/{name}.toml"),
                          files=({"role": "manifest", "path": f"/trials/{name}.toml", "sha256": fh, "size_bytes": 10},),
                          files_hash=fh, package_version=version)
    t0 = datetime(2025, 4, 1, tzinfo=timezone.utc).timestamp() + day * 86400
    trial = {"manifest_path": str(ident.manifest), "report_dir": None, "mode": "quick", "command": "test",
             "processed_at": datetime.now(timezone.utc).timestamp(), "status": status,
             "error": None if status == "ok" else "boom", "vessel_hash": f"v-{vessel}", "vessel_name": vessel,
             "started_utc": t0, "date_source": "test", "lat": 57.0, "lon": 9.9, "place_source": "test",
             "duration_s": 1.0}
    coefs = tuple({"name": k, "value": v, "stderr": s, "ci_low": v - 2 * s, "ci_high": v + 2 * s, "unit": "kg/s",
                   "n_segments": 2, "structure": "first-order exponential", "method": "m", "success": True,
                   "message": "", "consistency_p": None} for k, (v, s) in values.items())
    return TrialRecord(ident, trial, {"config_hash": f"v-{vessel}", "name": vessel, "config_path": "x",
                                      "config_text": "name='x'"}, coefficients=coefs,
                       segments=({"seg_index": 0, "kind": "step", "dof": "surge", "t_start": 1.0, "t_end": 2.0},))


def count(cat: Catalog, table: str) -> int:
    return int(cat.query(f"SELECT count(*) AS n FROM {table}")["n"].iloc[0])


def test_new_catalogue_is_at_current_schema_version(tmp_path):
    with Catalog(tmp_path / "c.duckdb", create=True) as cat:
        assert cat.version == SCHEMA_VERSION
        assert current_version(cat.con) == SCHEMA_VERSION
    with Catalog(tmp_path / "c.duckdb") as cat:  # reopening does not migrate twice
        assert count(cat, "schema_version") == SCHEMA_VERSION


def test_catalogue_from_a_newer_vesselid_is_refused(tmp_path):
    path = tmp_path / "c.duckdb"
    Catalog(path, create=True).close()
    con = duckdb.connect(str(path))
    con.execute("INSERT INTO schema_version VALUES (?, now())", [SCHEMA_VERSION + 1])
    con.close()
    with pytest.raises(CatalogError, match="newer vesselid"):
        Catalog(path)


def test_missing_catalogue_and_non_duckdb_file_are_clear_errors(tmp_path):
    with pytest.raises(CatalogError, match="expected a DuckDB file at .*found nothing"):
        Catalog(tmp_path / "none.duckdb")
    bad = tmp_path / "bad.duckdb"
    bad.write_text("not a database")
    with pytest.raises(CatalogError, match="expected a DuckDB file"):
        Catalog(bad)


def test_same_files_same_version_replaces_different_version_keeps_both(tmp_path):
    with Catalog(tmp_path / "c.duckdb", create=True) as cat:
        cat.write(record("t1", {"X_u": (-2.9, 0.01)}, files_hash="aaaa"))
        cat.write(record("t1", {"X_u": (-2.8, 0.01), "N_r": (-0.26, 0.001)}, files_hash="aaaa"))
        assert count(cat, "trials") == 1
        assert sorted(cat.coefficients(cat.resolve("t1")["trial_id"])["name"]) == ["N_r", "X_u"]
        assert count(cat, "segments") == 1 and count(cat, "files") == 1
        cat.write(record("t1", {"X_u": (-2.7, 0.01)}, version="0.2.0", files_hash="aaaa"))
        assert count(cat, "trials") == 2
        # The name resolves to the newest processing of the same files.
        assert cat.resolve("t1")["package_version"] == "0.2.0"


def test_name_shared_by_different_files_is_ambiguous(tmp_path):
    with Catalog(tmp_path / "c.duckdb", create=True) as cat:
        cat.write(record("t1", {"X_u": (-2.9, 0.01)}, files_hash="aaaa"))
        cat.write(record("t1", {"X_u": (-2.9, 0.01)}, files_hash="bbbb"))
        with pytest.raises(CatalogError, match="expected one trial, found 2"):
            cat.resolve("t1")
        tid = cat.query("SELECT trial_id FROM trials LIMIT 1")["trial_id"].iloc[0]
        assert cat.resolve(tid[:6])["trial_id"] == tid


def test_a_failed_write_leaves_the_catalogue_as_it_was(tmp_path):
    with Catalog(tmp_path / "c.duckdb", create=True) as cat:
        cat.write(record("t1", {"X_u": (-2.9, 0.01)}, files_hash="aaaa"))
        bad = record("t1", {"X_u": (-2.5, 0.01)}, files_hash="aaaa")
        # A row that violates NOT NULL fails half-way through the inserts.
        bad_coef = dict(bad.coefficients[0], name=None)
        bad = TrialRecord(bad.identity, bad.trial, bad.vessel, coefficients=(bad_coef,))
        with pytest.raises(duckdb.Error):
            cat.write(bad)
        c = cat.coefficients(cat.resolve("t1")["trial_id"])
        assert c["value"].tolist() == [-2.9]
        assert count(cat, "trials") == 1 and count(cat, "segments") == 1


def test_holm_controls_the_family():
    p = np.array([0.01, 0.04, 0.03, 0.005, np.nan])
    # sorted 0.005 (<= .05/4), 0.01 (<= .05/3), 0.03 (> .05/2) stops
    assert holm(p).tolist() == [True, False, False, True, False]
    assert not holm(np.array([0.02, 0.03])).any() or holm(np.array([0.02, 0.03])).tolist() == [True, True]


def test_compare_flags_only_the_changed_coefficient(tmp_path):
    with Catalog(tmp_path / "c.duckdb", create=True) as cat:
        cat.write(record("a", {"X_u": (-2.90, 0.01), "N_r": (-0.2600, 0.001), "K_p": (-0.11, 0.001)}))
        cat.write(record("b", {"X_u": (-3.05, 0.01), "N_r": (-0.2612, 0.001), "Y_v": (-30.0, 1.0)}))
        df, text = compare_trials(cat, "a", "b")
    assert "Holm" in text
    row = df.set_index("coefficient")
    assert row.loc["X_u", "diff"] == pytest.approx(-0.15)
    assert row.loc["X_u", "se_diff"] == pytest.approx(math.hypot(0.01, 0.01))
    assert row.loc["X_u", "z"] == pytest.approx(-0.15 / math.hypot(0.01, 0.01))
    assert bool(row.loc["X_u", "beyond"]) and not bool(row.loc["N_r", "beyond"])
    assert "not identified in trial B" in row.loc["K_p", "note"]
    assert "not identified in trial A" in row.loc["Y_v", "note"]


def test_fit_drift_recovers_a_known_slope():
    rng = np.random.default_rng(4)
    x = np.arange(10.0)
    se = np.full(10, 0.02)
    y = 3.0 + 0.05 * x + rng.normal(0, 0.02, 10)
    a, b, b_se, p, chi2 = fit_drift(x, y, se)
    assert abs(b - 0.05) < 3 * b_se and p < 1e-6
    _, b0, b0_se, p0, _ = fit_drift(x, 3.0 + rng.normal(0, 0.02, 10), se)
    assert p0 > 0.01 and abs(b0) < 3 * b0_se


def test_trend_finds_drift_on_one_vessel_only(tmp_path):
    rng = np.random.default_rng(7)
    with Catalog(tmp_path / "c.duckdb", create=True) as cat:
        for k in range(6):
            cat.write(record(f"f{k}", {"X_u": (-2.9 * 1.02 ** k + rng.normal(0, 0.01), 0.01)}, vessel="fouled", day=7 * k))
            cat.write(record(f"c{k}", {"X_u": (-2.9 + rng.normal(0, 0.01), 0.01)}, vessel="clean", day=7 * k))
        cat.write(record("two-a", {"X_u": (-2.9, 0.01)}, vessel="short"))
        trends = {t.vessel: t for t in coefficient_trend(cat, "X_u")}
        with pytest.raises(CatalogError, match="no 'Q_z'"):
            coefficient_trend(cat, "Q_z")
    assert trends["fouled"].significant and trends["fouled"].slope < 0
    assert trends["fouled"].rel_slope * 7 == pytest.approx(-0.02 * 1.05, rel=0.15)
    assert not trends["clean"].significant
    assert "need 3 or more" in trends["short"].note and math.isnan(trends["short"].slope)
    assert trends["fouled"].x_label.startswith("days")


def test_export_csv_and_parquet(tmp_path):
    with Catalog(tmp_path / "c.duckdb", create=True) as cat:
        cat.write(record("a", {"X_u": (-2.9, 0.01), "N_r": (-0.26, 0.001)}))
        csv = cat.export(tmp_path / "out.csv")
        pq = cat.export(tmp_path / "out.parquet")
        with pytest.raises(CatalogError, match=r"\.csv or \.parquet"):
            cat.export(tmp_path / "out.xlsx")
    a = pd.read_csv(csv)
    b = duckdb.sql(f"SELECT * FROM '{pq}'").df()
    assert sorted(a["coefficient"]) == ["N_r", "X_u"] and len(b) == 2
    assert set(b["stderr"]) == {0.01, 0.001}


def test_identity_changes_with_content_and_version(tmp_path):
    log = tmp_path / "a.csv"
    log.write_text("t,u\n0,1\n1,2\n")
    (tmp_path / "v.toml").write_text('name = "v"\n')
    man = tmp_path / "trial.toml"
    man.write_text('name = "t"\nvessel = "v.toml"\nlogs = ["a.csv"]\n')
    i1 = identify_trial(man)
    assert identify_trial(man).trial_id == i1.trial_id and not i1.problem
    assert identify_trial(man, version="9.9").trial_id != i1.trial_id
    log.write_text("t,u\n0,1\n1,3\n")
    assert identify_trial(man).trial_id != i1.trial_id
    man.write_text('name = "t"\nvessel = "v.toml"\nlogs = ["missing.csv"]\n')
    assert "expected log files" in identify_trial(man).problem


def test_model_structure_is_the_leading_model_name():
    assert model_structure("first-order exponential on 2 steps; inverse-variance mean") == "first-order exponential"
    assert model_structure("grey-box output-error fit of the linear 5-DOF model (x) to 1 record") == \
        "grey-box output-error fit of the linear 5-DOF model"


def test_cli_errors_are_clear(tmp_path, capsys):
    assert main(["catalog", "list", "--catalog", str(tmp_path / "none.duckdb")]) == 2
    assert "error: catalogue: expected a DuckDB file" in capsys.readouterr().err
    with Catalog(tmp_path / "c.duckdb", create=True) as cat:
        cat.write(record("a", {"X_u": (-2.9, 0.01)}))
    assert main(["catalog", "show", "zzz", "--catalog", str(tmp_path / "c.duckdb")]) == 2
    err = capsys.readouterr().err
    assert "trial 'zzz': expected a trial name or id" in err and "Traceback" not in err
    assert main(["batch", str(tmp_path / "nowhere"), "--catalog", str(tmp_path / "c.duckdb")]) == 2
    assert "expected a folder of trial manifests" in capsys.readouterr().err
    assert main(["catalog", "export", "--out", str(tmp_path / "x.txt"), "--catalog", str(tmp_path / "c.duckdb")]) == 2
    assert main(["catalog", "list", "--catalog", str(tmp_path / "c.duckdb")]) == 0
    assert "boat: 1 trial(s)" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [["batch"], ["catalog"], ["catalog", "list"], ["catalog", "show"], ["catalog", "compare"],
                                  ["catalog", "trend"], ["catalog", "export"], ["catalog", "html"]])
def test_every_catalogue_command_has_help(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv + ["--help"])
    assert exc.value.code == 0 and "usage:" in capsys.readouterr().out


def test_html_pages_link_reports_and_show_trends(tmp_path):
    rng = np.random.default_rng(1)
    with Catalog(tmp_path / "c.duckdb", create=True) as cat:
        for k in range(4):
            cat.write(record(f"f{k}", {"X_u": (-2.9 * 1.05 ** k + rng.normal(0, 0.01), 0.01)}, vessel="fouled", day=7 * k))
        cat.write(record("bad", {}, vessel="fouled", status="failed"))
        from pipeline.catalog.html import write_catalog_pages

        pages = write_catalog_pages(cat, tmp_path / "pages")
    assert [p.name for p in pages] == ["index.html", "vessel-fouled.html"]
    text = pages[1].read_text()
    assert "significant drift" in text and "data:image/png;base64," in text and "failed: boom" in text
