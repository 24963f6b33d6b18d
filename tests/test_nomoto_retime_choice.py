"""Re-timing on the distance sailed chosen by the held-out data, not by the sign of the speed change.

A first-order Nomoto ship whose speed changes in a 10 deg turn (settling in 60 s) is fitted plain and re-timed on
the first 65 % of the step's window; the one that predicts the held-out yaw rate better by the F test wins
(:func:`pipeline.fit.nomoto_segment.choose_retiming`). A ship whose K and T scale with the speed is re-timed
whether its speed rises (Clarke83) or falls (by 9 %); a ship whose K and T do not scale with the speed, while its
logged speed falls (the tanker: rudder in the propeller race), is not; at 3 % the held-out end decides nothing.
Where neither wins, the two fits' difference is carried into the combined K and T as a model term.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from pipeline.fit.nomoto_quality import RETIME_TERM, judge_nomoto, retime_term
from pipeline.fit.nomoto_records import NomotoRecord
from pipeline.fit.nomoto_retime import retime_record
from pipeline.fit.nomoto_segment import choose_retiming
from pipeline.fit.segment_fit import failed_segment_fit
from pipeline.model.integrate import integrate_rk4
from pipeline.model.nomoto import NomotoParams, nomoto_rhs
from pipeline.records import Estimate, Segment

K0, T0, U0 = 0.08, 20.0, 6.0
FS, H = 5.0, 0.05
T_SURGE = 60.0


def _ship_rhs(t, x, d, params):
    """``[psi, r, u]``: Nomoto (K and T scaled by u when ``scaled``); u settles to ``U0 (1 + speed_gain sin^2 d)``."""
    speed_gain, scaled = params
    s = x[2] / U0 if scaled else 1.0
    psi_r = nomoto_rhs(t, x[:2], d, NomotoParams(K=K0 * s, T=T0 / s))
    return np.array([psi_r[0], psi_r[1], (U0 * (1.0 + speed_gain * math.sin(d[0]) ** 2) - x[2]) / T_SURGE])


def _step(speed_gain: float, scaled: bool, seed: int = 0, lead: float = 60.0, hold: float = 240.0):
    """A 10 deg step (5 deg/s) from a settled straight run: the record and the logged (noisy, smoothed) speed."""
    fine = np.arange(0.0, lead + hold + H / 2, H)
    rudder = np.clip((fine - lead) * math.radians(5.0), 0.0, math.radians(10.0))
    x = integrate_rk4(_ship_rhs, np.array([0.0, 0.0, U0]), fine, rudder[:, None], (speed_gain, scaled))
    every = int(round(1 / (FS * H)))
    t, psi, r, u, delta = fine[::every], x[::every, 0], x[::every, 1], x[::every, 2], rudder[::every]
    rng = np.random.default_rng(seed)
    psi = psi + math.radians(0.2) * rng.standard_normal(t.size)
    r = r + math.radians(0.05) * rng.standard_normal(t.size)
    drive = np.concatenate([0.5 * (delta[:-1] + delta[1:]), delta[-1:]])
    return NomotoRecord(t=t, delta=drive, psi=psi, r=r, name="step"), u


@pytest.mark.parametrize("gain", [3.0, -3.0])
def test_a_speed_scaled_ship_is_re_timed_whether_its_speed_rises_or_falls(gain):
    # 3 sin^2(10 deg) = 9 %: the speed rises or falls 9 % in the turn (the sign rule re-timed only a rise).
    rec, u = _step(gain, scaled=True)
    choice = choose_retiming(rec, retime_record(rec, u, U0), u, U0)
    assert choice.retime, choice.note
    assert choice.note.startswith("re-timed chosen: held-out yaw rate"), choice.note


def test_a_ship_whose_k_does_not_follow_its_falling_speed_is_not_re_timed():
    # The tanker's case: the speed falls 9 % in the turn, but K and T stay (the rudder in the propeller race).
    rec, u = _step(-3.0, scaled=False, seed=1)
    choice = choose_retiming(rec, retime_record(rec, u, U0), u, U0)
    assert not choice.retime, choice.note
    assert choice.note.startswith("constant speed chosen"), choice.note


@pytest.mark.parametrize("scaled", [True, False])
def test_a_small_speed_change_the_held_out_end_cannot_judge_carries_the_difference(scaled):
    # 3 % (Clarke83's rise): neither fit wins, the constant-speed record is kept and the difference noted.
    rec, u = _step(1.0, scaled=scaled)
    choice = choose_retiming(rec, retime_record(rec, u, U0), u, U0)
    assert not choice.retime and choice.note.startswith("neither wins"), choice.note
    parts = choice.note.split("; ")
    dk = next(float(p.split("+-")[1].split(" ")[0]) for p in parts if p.startswith(f"{RETIME_TERM} K: +-"))
    assert 0.005 * K0 < dk < 0.05 * K0, choice.note


def _fit(k: float, note: str, t0: float) -> object:
    seg = Segment("rudder_step", "yaw", t0, t0 + 80.0, "delta", 0.0, math.radians(10.0))
    sf = failed_segment_fit(seg, "nomoto_oe", "", "")
    return replace(sf, success=True, params={"K": k, "T": T0}, stderr={"K": 0.002 * K0, "T": 0.01 * T0},
                   message=f"OE; {note}")


def test_a_difference_neither_fit_wins_is_carried_in_the_combined_error():
    dk = 0.02 * K0
    note = f"neither wins: ...; {RETIME_TERM} K: +-{dk:.6g} 1/s; {RETIME_TERM} T: +-0.5 s"
    # Steps of one amplitude (no amplitude line), K 0.2 % apart from step to step.
    fits = [_fit(K0 * (1 + 0.001 * (-1) ** i), note if i == 1 else "plain", 100.0 * i) for i in range(4)]
    assert retime_term(fits, "K") == pytest.approx(dk) and retime_term(fits, "T") == pytest.approx(0.5)
    est = {"K_nomoto": Estimate("K_nomoto", K0, 0.001 * K0, (0.999 * K0, 1.001 * K0), "1/s", 4, "m",
                                per_segment=tuple(f.params["K"] for f in fits))}
    out = judge_nomoto(est, fits)["K_nomoto"]
    assert out.stderr >= dk, out.message
    assert out.ci95[0] <= K0 - 1.9 * dk and "re-timing term" in out.message, out.message
