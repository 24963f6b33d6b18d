"""CE6 Limfjord logs (real data, internal testing only): the throttle cuts of the surge coast-down
runs are found from the GPS speed alone, fitted, and listed in the report.

Skips when ``../shared/realdata/ce6-boat-limfjord-2022`` is absent. The authors' own start of the
deceleration interval (``virtualmassResults.txt``) is an independent check of the cut times.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CE6 = ROOT.parent / "shared" / "realdata" / "ce6-boat-limfjord-2022"

pytestmark = [pytest.mark.realdata,
              pytest.mark.skipif(not (CE6 / "Estimations").is_dir(),
                                 reason="real data folder ../shared/realdata/ce6-boat-limfjord-2022 absent")]


def _script():
    spec = importlib.util.spec_from_file_location("ce6_coastdowns", ROOT / "benchmarks" / "ce6_coastdowns.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def summary(tmp_path_factory):
    out = tmp_path_factory.mktemp("ce6")
    return _script().run(CE6, out), out


def test_every_virtualmass_run_gives_one_coast_down_at_the_cut(summary):
    s, _ = summary
    runs = [f for f in s["files"] if f["folder"] == "Boat test 2/VirtualMass"]
    assert len(runs) == 8
    for f in runs:
        assert len(f["segments"]) == 1, (f["file"], f["rejected"])
        seg = f["segments"][0]
        # The authors picked the start of their deceleration interval by eye from the same data.
        assert abs(seg["t_start"] - seg["authors_cut"]) < 0.5, f["file"]
        assert seg["fit_success"] and seg["channel"] == "sog"
        # Newey-West standard errors where the residuals are serially correlated (1 Hz speed over
        # ground; pipeline/fit/first_order.py): 11 % of T on the widest run, was under 10 % before.
        assert 2.0 < seg["T"] < 30.0 and 0 < seg["T_stderr"] < 0.15 * seg["T"]


def test_turning_runs_are_not_coast_downs(summary):
    s, _ = summary
    rot = [f for f in s["files"] if f["folder"] == "Boat test 2/RotDrag"]
    assert rot and not any(f["segments"] for f in rot)
    assert any(r["reason"].startswith("turning") for f in rot for r in f["rejected"])
    steady = [f for f in s["files"] if "TransDrag" in f["folder"]]
    assert steady and not any(f["segments"] for f in steady)


def test_the_report_lists_the_coast_downs(summary):
    s, out = summary
    run = next(f for f in s["files"] if f["file"].endswith("VirtualMass/throt12098W.txt"))
    page = (out / run["report"]).read_text()
    assert "coast_down" in page and "input-free coast-down from sog" in page
    assert "Coast-down detection" in page
    md = (out / "summary.md").read_text()
    for f in s["files"]:
        for seg in f["segments"]:
            assert f"| {f['file']} | {seg['t_start']:.2f} |" in md
    e, w = s["directions"]["E"], s["directions"]["W"]
    assert e["n"] == w["n"] == 4 and math.isfinite(e["T_mean"]) and math.isfinite(w["T_mean"])
