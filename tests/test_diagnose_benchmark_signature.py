"""The diagnosis benchmark's accounting (issue 12): each true effect's noise-free signature in noise
units, and the detection threshold measured on it (benchmarks/diagnose.py)."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    """benchmarks/diagnose.py, imported by name from its folder."""
    if str(ROOT / "benchmarks") not in sys.path:
        sys.path.insert(0, str(ROOT / "benchmarks"))
    return importlib.import_module("diagnose")


def test_detection_threshold_is_where_nine_in_ten_are_found():
    b = _bench()
    rows = [(0.5, False), (1.0, False), (2.0, True), (3.0, False), (4.0, True), (5.0, True), (6.0, True),
            (7.0, True), (8.0, True), (9.0, True), (10.0, True), (11.0, True), (12.0, True)]
    # From 4.0 up every trial is found; from 2.0 up 10 of 11 (91 %); from 1.0 up 10 of 12 (83 %).
    assert b.detection_threshold(rows) == 2.0
    # 2 of 3 from the lowest, and fewer than 3 trials above any higher value: no threshold.
    assert b.detection_threshold([(1.0, True), (2.0, False), (3.0, True)]) is None
    assert b.detection_threshold([(1.0, True), (2.0, True), (3.0, True)]) == 1.0


def test_a_weaker_thruster_has_a_signature_and_a_clean_twin_none():
    b = _bench()
    case = b.random_cases(1, 31, ("imbalance",))[0]
    sig = b.effect_signatures(case)
    assert len(sig) == 1
    ch = sig[0]["channels"]
    # A thruster pushing less than its allocation turns the boat: the yaw rate carries it, well above
    # the gyro noise; the signature is the largest channel's.
    assert ch["r"][0] > 1.0 and sig[0]["rms"] == max(v[0] for v in ch.values())
    assert np.isclose(sig[0]["snr"], max(v[0] * np.sqrt(v[1]) for v in ch.values()))
    assert b.effect_signatures(b.random_cases(1, 31, ("twin_clean",))[0]) == []


def test_the_noise_free_trial_is_the_trial_without_its_noise():
    b = _bench()
    import tempfile

    case = b.random_cases(1, 31, ("imbalance",))[0]
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "a").mkdir()
        (Path(tmp) / "b").mkdir()
        fa, _, ta = b.make_random_trial(case, Path(tmp) / "a")
        fb, _, tb = b.make_random_trial(case, Path(tmp) / "b", quiet=True)
        (t1, y1), (t2, y2) = b._responses(fa), b._responses(fb)
    assert ta == tb and np.array_equal(t1, t2)
    d = y1["r"] - y2["r"]
    ok = np.isfinite(d)
    # The twin's gyro noise is 0.002 rad/s times the drawn level (0.5, 1 or 2).
    level = {"low": 0.5, "nominal": 1.0, "high": 2.0}[ta["noise"]]
    assert abs(np.std(d[ok]) / (0.002 * level) - 1.0) < 0.1
