"""Helpers of the damping-structure benchmarks (benchmarks/damping_structure.py, realdata_structure.py):
the chance reading of a coverage row, the CE6 records without the first second after each cut, and
the Otter's pitched-payload inertia (skipped without PythonVehicleSimulator)."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _load(name: str):
    sys.path.insert(0, str(ROOT / "benchmarks"))
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault(name, mod)
    spec.loader.exec_module(mod)
    return mod


def _binom_tail(n: int, p: float, ks) -> float:
    return sum(math.comb(n, k) * p**k * (1 - p) ** (n - k) for k in ks)


def test_row_chance_matches_the_binomial_sums():
    ds = _load("damping_structure")
    text = ds.row_chance(30, 36)
    below = _binom_tail(30, 0.95, range(0, 27))  # 26/30 = 86.7 % is below 90 %
    above = _binom_tail(30, 0.95, range(30, 31))  # 30/30 is above 98 %
    assert f"{below:.1%}" in text and f"{above:.1%}" in text
    assert f"{36 * below:.1f} are expected below" in text
    text100 = ds.row_chance(100, 36)
    assert f"{_binom_tail(100, 0.95, range(0, 90)):.1%}" in text100
    assert f"{_binom_tail(100, 0.95, range(99, 101)):.1%}" in text100


def test_trimmed_drops_the_first_samples_and_too_short_records():
    rs = _load("realdata_structure")
    from pipeline.fit.quadratic import MIN_RECORD_SAMPLES, DofRecord

    long = DofRecord("a", "coast_down", np.arange(40.0), {"x": np.arange(40.0) * 2}, 0.1, "rate", "sog")
    short = DofRecord("b", "coast_down", np.arange(20.0 + MIN_RECORD_SAMPLES - 1), {}, 0.1, "rate", "sog")
    out = rs._trimmed([long, short], 20)
    assert [r.label for r in out] == ["a"]
    assert out[0].y[0] == 20.0 and out[0].inputs["x"][0] == 40.0 and out[0].y.size == 20
    assert long.y.size == 40  # the input is not modified


def test_otter_payload_inertia_reproduces_the_one_dof_surge_bias():
    ds = _load("damping_structure")
    if not (ds.PVS / "python_vehicle_simulator").is_dir():
        pytest.skip(f"PythonVehicleSimulator not found at {ds.PVS} (PVS_PATH)")
    sys.path.insert(0, str(ds.PVS))
    extra, share, x_u = ds.otter_payload_inertia()
    # m_p g |M_uq| / G_qq of PVS's Otter: 25 kg * 9.81 * 19.75 / 2743.37.
    assert extra == pytest.approx(25 * 9.81 * 19.75 / 2743.37, rel=1e-3)
    assert 0.015 < share < 0.025
    assert x_u == pytest.approx(-77.554 * 85.5 / (85.5 + extra), rel=1e-3)
