"""Every DOF with a measured channel is analysed, with or without an input of its own (issue 12,
deliverable 1): sway driven only through coupling, and a DOF faster than the log.

The trials: AAUSHIP's sea trial without its sway push (surge steps, yaw step, rudder steps, a
zig-zag), sway moved only by the yaw rate through a withheld coupling ``Y_r`` (the simulator's
coupling effect), body velocities derived from GNSS speed and course. The user's segments name the
surge and yaw manoeuvres only (no sway segment: nothing was done in sway). Before this change the
sway DOF had no input and no segment, so it was not analysed and the coupling was missed; the clean
trial (no coupling: sway does not move) must stay without a sway problem and without an effect.

Randomised seed 41 r021 of benchmarks/diagnose.py (AAUSHIP at 1.7 Hz; sway's time constant 0.4 s is
under the 0.58 s log interval): its sway windows were cut into blocks of 2.5 time constants, one or
two samples each, and all dropped.
"""

from __future__ import annotations

import sys
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    if str(ROOT / "benchmarks") not in sys.path:
        sys.path.insert(0, str(ROOT / "benchmarks"))
    import diagnose as bench

    return bench


@lru_cache(maxsize=None)
def _trial(y_r: float, tmp: str, rate: float = 5.0, seed: int = 1, noise: str = "nominal"):
    """AAUSHIP without sway, roll and pitch manoeuvres, sway coupled to yaw by ``y_r`` [N s/rad]."""
    import pandas as pd

    from pipeline.flow import load_trial
    from pipeline.sim import Effects, simulate
    from pipeline.sim.manoeuvres import Schedule
    from pipeline.sim.sensors import default_sensors
    from pipeline.sim.writers import write_log

    bench = _bench()
    v = bench.vessels()["aauship"]
    s = bench.schedule(v)
    s = Schedule(tuple(m for m in s.manoeuvres if not any(w in m.name for w in ("sway", "roll", "pitch"))))
    c = np.zeros((5, 5))
    c[1, 4] = y_r
    res = simulate(v, s, Effects(coupling=c if y_r else None), sensors=default_sensors(noise), seed=seed,
                   dt=0.01, actuator_rate=50.0)
    folder = Path(tmp) / f"yr{y_r}_{rate}_{seed}_{noise}"
    folder.mkdir(parents=True, exist_ok=True)
    path = Path(write_log(res.log, folder / "t.csv", vessel=v))
    df, _ = bench.thin_log(pd.read_csv(path), rate)
    df.to_csv(path, index=False)
    return load_trial([path], v), v


def _no_sway_segments(trial):
    """The detected segments less any of sway (a manifest of the surge and yaw manoeuvres)."""
    from pipeline.diagnose.segments import diagnose_segments
    from pipeline.records import Segments

    segs = diagnose_segments(trial)
    return Segments(segs.trial, tuple(s for s in segs.items if s.dof != "sway"))


@pytest.fixture(scope="module")
def tmp_trials(tmp_path_factory):
    return str(tmp_path_factory.mktemp("sway_coupling"))


def test_sway_driven_only_by_yaw_is_analysed(tmp_trials):
    from pipeline.diagnose.problem import build_problems

    trial, v = _trial(3.0, tmp_trials)
    assert not trial.has("tau_y") or not np.nanmax(np.abs(trial.data["tau_y"].to_numpy(float))) > 0
    probs = {p.dof: p for p in build_problems(trial, _no_sway_segments(trial), v)}
    # Before: no sway problem (no input of its own, no segment of its own).
    assert "sway" in probs, sorted(probs)
    p = probs["sway"]
    assert p.inputs == () and "r" in p.regressors and p.derived_from is not None
    assert len(p.windows) >= 2


def test_clean_sway_stays_unanalysed(tmp_trials):
    from pipeline.diagnose.problem import build_problems

    trial, v = _trial(0.0, tmp_trials)
    probs = {p.dof for p in build_problems(trial, _no_sway_segments(trial), v)}
    # Without coupling AAUSHIP's sway stays in its (GNSS-derived) noise through the turns.
    assert "sway" not in probs, sorted(probs)


def test_a_dof_faster_than_the_log_keeps_its_windows(tmp_trials):
    from pipeline.diagnose.problem import build_problems
    from pipeline.diagnose.segments import diagnose_segments
    from pipeline.flow import load_trial
    from pipeline.sim import Effects, simulate
    from pipeline.sim.sensors import default_sensors
    from pipeline.sim.writers import write_log
    import pandas as pd

    bench = _bench()
    v = bench.vessels()["aauship"]
    s = bench.schedule(v)
    res = simulate(v, s, Effects(), sensors=default_sensors("low"), seed=3, dt=0.01, actuator_rate=50.0)
    folder = Path(tmp_trials) / "slowlog"
    folder.mkdir(parents=True, exist_ok=True)
    path = Path(write_log(res.log, folder / "t.csv", vessel=v))
    df, rate = bench.thin_log(pd.read_csv(path), 1.7)
    df.to_csv(path, index=False)
    trial = load_trial([path], v)
    assert trial.fs < 2.0
    probs = {p.dof: p for p in build_problems(trial, diagnose_segments(trial), v)}
    # Before: sway (T 0.4 s, log interval 0.59 s) had only blocks of 1-2 samples and was dropped.
    assert "sway" in probs, sorted(probs)
    assert probs["sway"].inputs == ("tau_y",)


@pytest.mark.slow  # about 15 s CPU: two simulations and two diagnoses (make test-ci)
def test_withheld_sway_coupling_is_found_and_clean_is_null(tmp_trials):
    from pipeline.diagnose import diagnose

    trial, v = _trial(3.0, tmp_trials)
    rep = diagnose(trial, v, segments=_no_sway_segments(trial))
    sel = [(e.effect, e.dof) for e in rep.effects]
    # Before: [] (sway not analysed).
    assert sel and sel[0] == ("coupling", "sway"), sel
    assert rep.effects[0].shrink > 50.0
    trial0, v0 = _trial(0.0, tmp_trials)
    rep0 = diagnose(trial0, v0, segments=_no_sway_segments(trial0))
    assert rep0.effects == () or not rep0.effects, [(e.effect, e.dof) for e in rep0.effects]


def sway_set(out=print) -> None:
    """The small coupling-driven sway set of benchmarks/RESULTS.md ("Sway through coupling (diag18)"):
    ``Y_r`` 0 (clean), 1.5 and 3 N s/rad, log rates 2 and 10 Hz, seeds 1 and 2 (noise low and high),
    each diagnosed with the user's segments (no sway segment) and with the detected ones. Run as
    ``CI=1 .venv/bin/python tests/test_diagnose_sway_coupling.py``."""
    import tempfile

    from pipeline.diagnose import diagnose
    from pipeline.diagnose.segments import diagnose_segments

    with tempfile.TemporaryDirectory() as tmp:
        for y_r in (0.0, 1.5, 3.0):
            for rate in (2.0, 10.0):
                for seed, noise in ((1, "low"), (2, "high")):
                    trial, v = _trial(y_r, tmp, rate, seed, noise)
                    for mode, segs in (("manifest", _no_sway_segments(trial)), ("detected", diagnose_segments(trial))):
                        rep = diagnose(trial, v, segments=segs)
                        sel = [f"{e.effect}/{e.dof} {e.shrink:.1f}%" for e in rep.effects]
                        gaps = {d.dof: round(d.gap, 2) for d in rep.dofs}
                        out(f"Y_r {y_r:g} {rate:g} Hz seed {seed} {noise:5s} {mode:8s} sway analysed "
                            f"{'sway' in gaps}, gap {gaps.get('sway', float('nan')):.2f}: {sel or 'null'}")


if __name__ == "__main__":
    sway_set()
