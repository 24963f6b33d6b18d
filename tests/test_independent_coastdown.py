"""The coast-down row of benchmarks/independent.py on Fossen's PythonVehicleSimulator (skipped without it):
Clarke83's surge damping X_u from a thrust cut, through the user's path (CSV, segmenter, fit)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

PVS = os.environ.get("PVS_PATH", "/work/pvs/src")
pytestmark = pytest.mark.skipif(not Path(PVS, "python_vehicle_simulator").is_dir(),
                                reason=f"PythonVehicleSimulator not found at {PVS!r} (set PVS_PATH)")


@pytest.mark.slow
def test_clarke83_coastdown_gives_x_u_within_one_percent():
    from benchmarks import independent as bench

    v = bench.load_pvs()
    truth = bench.coastdown_truth(v)
    out = bench.coastdown_one((bench.simulate_coastdown(v), truth, 0))
    assert out["segments"] == ["coast_down"], out
    est = out["X_u"]
    assert est["success"], est["message"]
    assert est["value"] == pytest.approx(truth["X_u"], rel=0.01)
    assert est["ci"][0] <= truth["X_u"] <= est["ci"][1]
    assert out["peer"] == pytest.approx(truth["X_u"], rel=0.02)
