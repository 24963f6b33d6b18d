"""A lone 10/10 zig-zag of a second-order ship whose speed rises in its turns, fitted on the distance sailed.

The ship: second-order Nomoto with a complex pole pair and a zero (Clarke83-like, T1 + T2 = 13.47 s,
T1 T2 = 64.3 s^2, T3 = 10.81 s, first-order equivalent T = 2.66 s, K = 0.0869 1/s), whose time constants
scale with ``U0 / u`` and gain with ``u / U0`` (a linear manoeuvring model with damping linear and rudder force
quadratic in the speed), whose rudder lift grows as ``sin(2 delta) / 2`` and whose speed rises towards
``U0 (1 + sin^2 delta)`` in the turns (+3 % at 10 deg, as PythonVehicleSimulator's Clarke83 ship), with a
1 s servo lag, the rudder logged as measured. At constant time the record mixes faster and slower dynamics;
re-timed on the distance sailed it is the model at ``U0``. The same ship slowing 6 % in its turns is not
re-timed: its K and T carry the loss as a model term.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pipeline.fit import fit_trial
from pipeline.fit.nomoto_segment import prepare_window
from pipeline.fit.nomoto_quality import STRUCTURE_TERM, STRUCTURE_UNDECIDED
from pipeline.fit.nomoto_structure import lone_segment_fit
from pipeline.fit.nomoto_zigzag import (CURVATURE_NOTE, SERVO_T_SHARE, SPEED_LOSS_FACTOR, SPEED_LOSS_TERM,
                                        retimed_zigzag_fit, retimed_zigzag_window, rudder_curvature_term)
from pipeline.flow import load_trial
from pipeline.model.nomoto import nomoto2_sum_product
from pipeline.segment import detect_segments
from pipeline.vessel import parse_vessel

K0, T12, T1T2, T3 = 0.0869, 13.47, 64.3, 10.81
T_EQ = T12 - T3
U0, T_SURGE, T_SERVO = 3.26, 60.0, 1.0
AMP = math.radians(10.0)
H, FS = 0.05, 5.0


def _zigzag_log(speed_gain: float, seed: int = 0, commanded: bool = False) -> pd.DataFrame:
    """The ship's 10/10 zig-zag (30 s straight run first) logged at 5 Hz with the benchmark's sensor noise (the
    rudder's measured angle, or its command)."""
    a1, a0, b1, b0 = nomoto2_sum_product(K0, T12, T1T2, T3)
    x = np.zeros(3)          # psi, r U0 / u, x2 in the distance-sailed time
    u, d, dc = U0, 0.0, 0.0
    rows = []
    every = int(round(1.0 / (FS * H)))
    for k in range(int(300.0 / H) + 1):
        t = k * H
        if k % every == 0:
            if t >= 30.0:
                dc = AMP if dc == 0.0 else dc
                if dc > 0 and x[0] > AMP:
                    dc = -AMP
                elif dc < 0 and x[0] < -AMP:
                    dc = AMP
            rows.append((t, x[0], x[1] * u / U0, u, dc if commanded else d))
        v = 0.5 * math.sin(2.0 * d)
        scale = u / U0
        xdot = scale * np.array([x[1], -a1 * x[1] + x[2] + b1 * v, -a0 * x[1] + b0 * v])
        x = x + H * xdot
        u += H * (U0 * (1.0 + speed_gain * math.sin(d) ** 2) - u) / T_SURGE
        d += H * (dc - d) / T_SERVO
    t, psi, r, u, delta = np.array(rows).T
    rng = np.random.default_rng(1000 * seed + 17)
    psi = psi + math.radians(0.2) * rng.standard_normal(t.size)
    r = r + math.radians(0.05) * rng.standard_normal(t.size)
    if not commanded:
        delta = delta + math.radians(0.1) * rng.standard_normal(t.size)
    psi = (psi + math.pi) % (2 * math.pi) - math.pi
    return pd.DataFrame({"t": t, "psi": psi, "r": r, "u": u, "delta": delta})


def _trial_and_window(speed_gain: float, tmp: str, commanded: bool = False):
    path = Path(tmp) / "zigzag.csv"
    _zigzag_log(speed_gain, commanded=commanded).to_csv(path, index=False)
    trial = load_trial([path])
    segs = detect_segments(trial)
    zz = [s for s in segs.items if s.dof == "yaw" and s.kind == "zigzag"]
    assert len(zz) == 1, [s.kind for s in segs.items]
    return trial, segs, prepare_window(trial, zz[0], zz[0].t_start, zz[0].t_end)


def test_rudder_curvature_term_is_the_lift_shortfall_of_sin_two_delta():
    assert rudder_curvature_term(AMP) == pytest.approx(1.0 - math.sin(2 * AMP) / (2 * AMP))
    assert rudder_curvature_term(-AMP) == pytest.approx(0.0203, abs=5e-4)
    for bad in (0.0, math.nan):
        with pytest.raises(ValueError, match="expected a positive finite angle in rad"):
            rudder_curvature_term(bad)


def test_a_zigzag_whose_speed_rises_is_re_timed_and_one_of_constant_speed_is_not():
    with tempfile.TemporaryDirectory() as tmp:
        trial, _, win = _trial_and_window(1.0, tmp)
        retimed = retimed_zigzag_window(trial, win)
        assert retimed is not None
        assert retimed.rec.t.size > win.rec.t.size       # it sails faster than U0: more distance-sailed time
        assert "re-timed on the distance sailed" in retimed.notes[-1]
    with tempfile.TemporaryDirectory() as tmp:
        trial, _, win = _trial_and_window(0.0, tmp)
        assert retimed_zigzag_window(trial, win) is None


def test_the_re_timed_second_order_gives_k_within_3_percent_and_t_with_a_covering_interval():
    with tempfile.TemporaryDirectory() as tmp:
        trial, segs, win = _trial_and_window(1.0, tmp)
        sf = retimed_zigzag_fit(trial, win, retimed_zigzag_window(trial, win))
        assert sf is not None and "T3" in sf.params
        assert CURVATURE_NOTE in sf.message
        fits = fit_trial(trial, segs, parse_vessel({"name": "zz"}), extend=False)
    k, t = fits.estimates["K_nomoto"], fits.estimates["T_nomoto"]
    assert k.success, k.message
    assert abs(k.value / K0 - 1.0) < 0.03, (k.value, k.message)
    assert k.ci95[0] <= K0 <= k.ci95[1]
    assert t.ci95[0] <= T_EQ <= t.ci95[1], (t.value, t.ci95, t.message)
    assert t.success or t.message.startswith("unsure")


def test_a_zigzag_that_slows_in_its_turns_carries_the_speed_loss_as_a_term_on_k_and_t():
    with tempfile.TemporaryDirectory() as tmp:
        trial, segs, win = _trial_and_window(-2.0, tmp)   # 6 % slower at 10 deg
        assert retimed_zigzag_window(trial, win) is None
        zz = [i for i, s in enumerate(segs.items) if s.kind == "zigzag"][0]
        sf = lone_segment_fit(trial, segs.items[zz], zz, win)[zz]
    loss = 1.0 - float(np.min(_zigzag_log(-2.0)["u"])) / U0
    assert 0.04 < loss < 0.08
    for name in ("K", "T"):
        notes = [p for p in sf.message.split("; ") if p.startswith(f"{STRUCTURE_TERM} {name}: +-")]
        assert any(SPEED_LOSS_TERM in p for p in notes), sf.message
        term = max(float(p.split("+-")[1].split(" ")[0]) for p in notes)
        assert term >= SPEED_LOSS_FACTOR * 0.9 * loss * abs(sf.params[name])
    with tempfile.TemporaryDirectory() as tmp:
        trial, segs, win = _trial_and_window(0.0, tmp)
        zz = [i for i, s in enumerate(segs.items) if s.kind == "zigzag"][0]
        sf = lone_segment_fit(trial, segs.items[zz], zz, win)[zz]
    assert SPEED_LOSS_TERM not in sf.message


def test_with_the_rudder_logged_as_a_command_t_is_unsure_and_carries_the_servo_term():
    with tempfile.TemporaryDirectory() as tmp:
        trial, segs, win = _trial_and_window(1.0, tmp, commanded=True)
        assert win.servo
        sf = retimed_zigzag_fit(trial, win, retimed_zigzag_window(trial, win))
        assert sf is not None and "t_servo" in sf.params
        fits = fit_trial(trial, segs, parse_vessel({"name": "zz"}), extend=False)
    assert f"{STRUCTURE_UNDECIDED} T:" in sf.message
    terms = [float(p.split("+-")[1].split(" ")[0]) for p in sf.message.split("; ")
             if p.startswith(f"{STRUCTURE_TERM} T: +-")]
    assert terms and max(terms) >= SERVO_T_SHARE * abs(sf.params["T"]) * 0.999
    t = fits.estimates["T_nomoto"]
    assert not t.success
    assert t.ci95[0] <= T_EQ <= t.ci95[1], (t.value, t.ci95)
