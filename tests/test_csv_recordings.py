"""CSV as people write it: several recordings stacked in one file, each named in a run column and
each with its own time from about zero (pool decays repeated, coast-downs of a day in one table)."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pipeline.errors import IngestError
from pipeline.fit import fit_trial
from pipeline.flow import load_trial, read_logs, segment_trial
from pipeline.ingest import read_log, read_recordings
from pipeline.vessel import load_vessel

ROOT = Path(__file__).resolve().parents[1]
VESSEL = load_vessel(ROOT / "vessel_configs" / "aauship.toml")
REALDATA = Path(os.environ.get("VESSELID_REALDATA", "/work/shared/realdata")) / "aauship-2014-trials" / "csv"


def _roll_decay(seed: int, fs: float = 100.0, span: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """A pool roll decay of AAUSHIP (free oscillation from 20 deg) sampled from about t = 0, in degrees."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, span, 1 / fs) + rng.uniform(-0.05, 0.05)
    wn, zeta = math.sqrt(VESSEL.restoring["roll"] / VESSEL.inertia[0]), 0.0815
    wd = wn * math.sqrt(1 - zeta**2)
    s = np.clip(t, 0, None)
    phi = 20 * np.exp(-zeta * wn * s) * (np.cos(wd * s) + zeta * wn / wd * np.sin(wd * s))
    return t, phi + rng.normal(0, 0.02, t.size)


def _stacked(path: Path, names=("Test 1", "Test 2", "Test 3"), col: str = "series") -> Path:
    frames = []
    for k, name in enumerate(names):
        t, phi = _roll_decay(k + 1)
        frames.append(pd.DataFrame({col: name, "kind": "measured", "t_s": t, "phi_deg": phi}))
    pd.concat(frames).to_csv(path, index=False)
    return path


def test_recordings_stacked_in_one_csv_are_read_one_per_series(tmp_path):
    p = _stacked(tmp_path / "roll.csv")
    logs = read_recordings(p)
    assert [log.source for log in logs] == [f"{p}#Test 1", f"{p}#Test 2", f"{p}#Test 3"]
    for log in logs:
        phi = log.channels["phi"]
        assert phi.t.size == 300 and np.all(np.diff(phi.t) > 0)
        assert abs(np.degrees(phi.values).max() - 20) < 1.0  # unit from the suffix
        assert any("recording: rows with series" in w for w in log.summary.warnings)
    # The flow reads every recording; align makes each its own run (no absolute time, same channels).
    trial = load_trial([p], VESSEL)
    assert len(trial.run_list()) == 3


def test_a_pool_decay_file_of_three_releases_fits_k_p_with_its_error(tmp_path):
    p = _stacked(tmp_path / "roll.csv")
    trial = load_trial([p], VESSEL)
    segs = segment_trial(trial)
    decays = [s for s in segs.items if s.kind == "free_decay" and s.dof == "roll"]
    assert len(decays) == 3 and len({s.run for s in decays}) == 3
    est = fit_trial(trial, segs, VESSEL, extend=False).estimates["K_p"]
    truth = -np.diag(VESSEL.damping)[2]
    assert est.success and est.stderr > 0, est.message
    # The simulated decay uses zeta = 0.0815 (the config's 0.1094 kg m^2/s within 0.5 %).
    assert abs(est.value - truth) < 0.03 * abs(truth), (est.value, est.stderr, truth)


def test_a_run_column_mapped_in_the_column_map_splits_even_with_increasing_time(tmp_path):
    rows = pd.DataFrame({"t": np.arange(20.0), "leg": ["a"] * 10 + ["b"] * 10, "r": np.zeros(20)})
    p = tmp_path / "legs.csv"
    rows.to_csv(p, index=False)
    assert len(read_recordings(p)) == 1                       # 'leg' is not a run column by name
    assert [log.source for log in read_recordings(p, columns={"leg": "run"})] == [f"{p}#a", f"{p}#b"]
    rows.rename(columns={"leg": "run"}).to_csv(p, index=False)
    assert len(read_recordings(p)) == 1                       # increasing time: one recording, labelled rows
    assert "run" not in read_log(p).channels


def test_time_that_starts_again_without_a_run_column_names_the_way_out(tmp_path):
    p = tmp_path / "two.csv"
    pd.DataFrame({"t": [0.0, 1.0, 2.0, 0.0, 1.0], "r": [0.0] * 5}).to_csv(p, index=False)
    with pytest.raises(IngestError, match=r"expected strictly increasing time in 't'.*several recordings in one "
                                          r"file\? A column naming each row's recording"):
        read_logs([p])


def test_a_run_column_with_an_empty_cell_is_refused(tmp_path):
    p = tmp_path / "gap.csv"
    pd.DataFrame({"series": ["a", "a", None, "b"], "t": [0.0, 1.0, 0.0, 1.0], "r": [0.0] * 4}).to_csv(p, index=False)
    with pytest.raises(IngestError, match=r"expected a recording name in column 'series' on every row, found an "
                                          r"empty cell on data row 3"):
        read_recordings(p)


@pytest.mark.skipif(not REALDATA.is_dir(), reason="shared real data not present")
def test_the_2014_vicon_roll_decays_read_without_editing_the_file():
    """Thesis figure data: Test 1-3 and their Average stacked, time from about 0 in each."""
    logs = read_recordings(REALDATA / "roll_free_decay_starboard_down_vicon.csv")
    assert [log.source.rsplit("#", 1)[1] for log in logs] == ["Test 1", "Test 2", "Test 3", "Average"]
    assert all(abs(np.degrees(log.channels["phi"].values).max() - 22) < 2.5 for log in logs)


def test_a_recording_labelled_unlike_the_others_is_named(tmp_path):
    """A regression curve stacked with the measured runs (kind = fit) is read but named in the summary."""
    p = tmp_path / "coast.csv"
    frames = [pd.DataFrame({"series": f"Test {k}", "kind": "measured", "t_s": np.arange(10.0) - 1,
                            "u_mps": 1.5 * np.exp(-0.2 * np.arange(10.0))}) for k in (1, 2)]
    frames.append(pd.DataFrame({"series": "Regression", "kind": "fit", "t_s": np.arange(10.0),
                                "u_mps": 1.5 * np.exp(-0.2 * np.arange(10.0))}))
    pd.concat(frames).to_csv(p, index=False)
    logs = {log.source.rsplit("#", 1)[1]: log for log in read_recordings(p)}
    assert any("column 'kind' is 'fit' here and 'measured' in most" in w for w in logs["Regression"].summary.warnings)
    assert not any("here and" in w for w in logs["Test 1"].summary.warnings)
