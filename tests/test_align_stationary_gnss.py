"""A receiver at rest: identical fixes with their own time stamps are measurements, not held copies."""

from pathlib import Path

import numpy as np
import pytest

from pipeline.align import align
from pipeline.ingest import read_log
from pipeline.records import Channel

DATA = Path(__file__).parent / "data"


def test_stationary_nmea_receiver_keeps_every_fix():
    """gpsd's Quectel LC79D capture: 30 GGA/RMC epochs at 1 Hz, position unchanged to 1e-6 minute."""
    log = read_log(DATA / "gpsd" / "quectelLC79D.log")
    assert np.ptp(log.channels["lat"].values) == 0.0  # the premise: every fix is identical
    trial = align([log])
    assert trial.data["t"].iloc[-1] == pytest.approx(29.0)
    assert int(np.isfinite(trial.data["lat"].to_numpy()).sum()) == 30


def test_csv_logger_rows_still_collapse_held_fixes(tmp_path):
    """A 10 Hz logger holding a 1 Hz fix: the repeats are copies (one fix per second is kept)."""
    t = np.arange(0.0, 30.0, 0.1)
    fix = np.floor(t)
    path = tmp_path / "held.csv"
    rows = ["t,lat,lon,sog,r"] + [f"{a:.1f},{57 + 1e-5 * b:.7f},{9 + 2e-5 * b:.7f},{1 + 0.01 * b:.3f},{0.01 * np.sin(a):.5f}"
                                  for a, b in zip(t, fix)]
    path.write_text("\n".join(rows) + "\n")
    trial = align([read_log(path)])
    assert any("hold" in n and "fixes" in n for n in trial.notes)
