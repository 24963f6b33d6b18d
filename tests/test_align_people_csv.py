"""CSV as people write it, end to end from a trial manifest: the manifest's column map renames the
time column, time in milliseconds on one file and ISO 8601 timestamps on the other, semicolon
separators with decimal commas, units by name suffix (``_deg``, ``_degs``, ``_kn``), named in the
summary; two recordings become two runs with their absolute times."""

from __future__ import annotations

import math
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import pytest

from pipeline.flow import load_trial, segment_trial
from pipeline.manifest import load_manifest
from pipeline.sim import simulate
from pipeline.sim.manoeuvres import chain, rudder_step
from pipeline.vessel import load_vessel

ROOT = Path(__file__).resolve().parents[1]
VESSEL_PATH = ROOT / "vessel_configs" / "aauship.toml"
VESSEL = load_vessel(VESSEL_PATH)
START = datetime(2024, 6, 3, 9, 47, 1, tzinfo=timezone.utc)


@pytest.fixture(scope="module")
def truth():
    d = np.diag(VESSEL.damping)
    sched = chain(rudder_step(math.radians(10), 15.0, 15.0, {"tau_x": float(d[0])}), rest_s=5.0)
    return simulate(VESSEL, sched, seed=11).truth.iloc[::10].reset_index(drop=True)  # 10 Hz


def _comma(x: float, digits: int) -> str:
    return f"{x:.{digits}f}".replace(".", ",")


def _write(path: Path, time_name: str, time_texts, truth) -> Path:
    rows = [f"{time_name};Kurs_deg;Drehrate_degs;Fahrt_kn;Ruder"]
    for stamp, (_, row) in zip(time_texts, truth.iterrows()):
        rows.append(";".join([stamp, _comma(math.degrees(row.psi), 6), _comma(math.degrees(row.r), 6),
                              _comma(math.hypot(row.u, row.v) / 0.514444, 6), _comma(row.cmd_delta, 6)]))
    path.write_text("\n".join(rows) + "\n")
    return path


def test_a_csv_as_people_write_it_runs_from_a_manifest(truth, tmp_path):
    t = truth["t"].to_numpy()
    # Milliseconds, said by the suffix of the time column's own name, which the manifest renames.
    _write(tmp_path / "morning.csv", "Zeit_ms", [str(int(round(1000 * x))) for x in t], truth)
    later = START + timedelta(hours=2)
    _write(tmp_path / "noon.csv", "Zeitstempel", [(later + timedelta(seconds=float(x))).isoformat().replace("+00:00", "Z")
                                   for x in t], truth)
    (tmp_path / "trial.toml").write_text(
        f'name = "people"\nvessel = "{VESSEL_PATH}"\nlogs = ["morning.csv", "noon.csv"]\n'
        '[columns]\nZeit_ms = "t"\nZeitstempel = "t"\nKurs_deg = "psi"\nDrehrate_degs = "r"\nFahrt_kn = "sog"\nRuder = "delta"\n')
    man = load_manifest(tmp_path / "trial.toml")
    trial = load_trial(man.logs, VESSEL, columns=man.columns, units=man.units)

    # Two recordings: one without absolute time (milliseconds from its start), one with ISO times.
    assert len(trial.runs) == 2
    noon = [r for r in trial.runs if math.isfinite(r.start_time)]
    assert len(noon) == 1 and noon[0].start_time == pytest.approx(later.timestamp(), abs=1e-3)
    assert trial.fs == pytest.approx(10.0)
    # Values in SI after the comma decimals and the units: heading and rate in rad, speed in m/s.
    for k, run in enumerate(trial.runs):
        data = trial.run_data(k)
        psi = np.interp(t[5:-5], data["t"] - run.t_start, data["psi"])
        # Heading compared on the circle (the aligner wraps it to [-pi, pi)).
        np.testing.assert_allclose(np.angle(np.exp(1j * (psi - truth["psi"].to_numpy()[5:-5]))), 0.0, atol=1e-6)
        r = np.interp(t[5:-5], data["t"] - run.t_start, data["r"])
        np.testing.assert_allclose(r, truth["r"].to_numpy()[5:-5], atol=1e-6)
        sog = np.interp(t[5:-5], data["t"] - run.t_start, data["sog"])
        np.testing.assert_allclose(sog, np.hypot(truth["u"], truth["v"]).to_numpy()[5:-5], atol=1e-5)
    # Units from the suffixes of the renamed columns (no [units] table), each named in the summary.
    text = "\n".join(s.text() for s in trial.summaries)
    for said in ("separator ';', decimal ','", "'Kurs_deg' read as psi in deg", "'Drehrate_degs' read as r in deg/s",
                 "'Fahrt_kn' read as sog in knots", "ISO timestamps in 'Zeitstempel'", "'Zeit_ms' in ms"):
        assert said in text, said
    # And the rudder steps are found in each run.
    segs = segment_trial(trial)
    assert {s.run for s in segs.items if s.kind == "rudder_step"} == {0, 1}
