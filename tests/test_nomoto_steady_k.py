"""K from the steady levels of rudder steps where the Nomoto structure is undecided.

PythonVehicleSimulator's tanker at 20 m (complex poles and a zero: T1 + T2 = 30.2 s, T1 T2 = 277 s^2,
T3 = 20.9 s) keeps the first order on its commanded steps because the second order is not identifiable per
step under noise; the first order's K then carries the structure's bias (-1.74 % noise-free), while a step's
K, a steady-state gain, is read without any structure from the turn rates between the steady holds. Here
(1) a second-order ship of that shape, one 10 deg step between 180 s holds with the benchmark's sensor
noise: the secant is within its error of K, and (2) the combined K is replaced by the steady levels' K where
the fits carry that note, with the speed term, and left alone where they do not.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy import signal

from pipeline.fit.nomoto_quality import STEADY_K, judge_nomoto
from pipeline.fit.nomoto_records import NomotoRecord
from pipeline.fit.nomoto_segment import NomotoWindow
from pipeline.fit.nomoto_steady import step_secant, steady_level_note
from pipeline.fit.segment_fit import failed_segment_fit
from pipeline.records import Estimate, Segment

K, T1T2, T12, T3 = -0.0057, 276.5, 30.2, 20.88
HOLD, FS = 180.0, 5.0


def _window(seed: int, before_deg: float, after_deg: float, t_start: float = 0.0) -> NomotoWindow:
    t = np.arange(-HOLD, HOLD, 1 / FS)
    d0, d1 = math.radians(before_deg), math.radians(after_deg)
    delta = np.where(t < 0, d0, d1)
    # The hold before started from its own steady level (d0's turn): simulate the change only.
    _, r_dev, _ = signal.lsim(signal.TransferFunction([K * T3, K], [T1T2, T12, 1.0]), delta - d0, t - t[0])
    r = K * d0 + r_dev
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (r[1:] + r[:-1]) / FS)])
    rng = np.random.default_rng(seed)
    psi = psi + math.radians(0.2) * rng.standard_normal(t.size)
    r = r + math.radians(0.05) * rng.standard_normal(t.size)
    seg = Segment("rudder_step", "yaw", t_start, t_start + HOLD, "delta", d0, d1)
    rec = NomotoRecord(t + t_start, delta, psi, r, "step")
    return NomotoWindow(seg, rec, ("psi", "r"), (), (), t)


@pytest.mark.parametrize("seed", range(4))
def test_a_steps_secant_reads_k_of_a_second_order_ship_within_its_error(seed):
    c = step_secant(_window(seed, 0.0, 10.0), tau=8.0)
    assert c.ok, c.reason
    assert abs(c.value - K) < 3 * c.stderr, (c.value, c.stderr)
    # The compass's slope over 90 s reads each level to about 1 % of the step's turn rate.
    assert c.stderr < 0.02 * abs(K)


def test_steps_combine_into_a_note_only_for_steps():
    wins = [_window(0, 0.0, 10.0, 0.0), _window(1, 10.0, 0.0, 180.0), _window(2, 0.0, -10.0, 360.0)]
    note = steady_level_note(wins, [8.0] * 3, "the transient's structure is undecided")
    assert note.startswith(f"{STEADY_K}: the transient's structure is undecided: K = "), note
    value = float(note.split(": K = ")[1].split(" ")[0])
    assert value == pytest.approx(K, rel=0.01)
    zig = replace(wins[0], segment=replace(wins[0].segment, kind="zigzag"))
    assert steady_level_note([zig] + wins[1:], [8.0] * 3, "x") == ""


def _fit(k, before, after, message):
    seg = Segment("rudder_step", "yaw", 0.0, 180.0, "delta", math.radians(before), math.radians(after))
    return replace(failed_segment_fit(seg, "nomoto_oe", "", ""), success=True, params={"K": k, "T": 8.0},
                   stderr={"K": 2e-5, "T": 0.8}, message=message)


def _estimates(ks, se=2e-4):
    return {"K_nomoto": Estimate("K_nomoto", float(np.mean(ks)), se, (-0.0062, -0.0053), "1/s", len(ks), "m",
                                 per_segment=tuple(ks))}


def test_the_combined_k_is_the_steady_levels_where_the_fits_carry_them():
    note = (f"{STEADY_K}: the transient's structure is undecided (first order kept, second order not resolved): "
            f"K = -0.0057333 +- 3.2e-05 1/s (the turn rate per rudder angle between steady holds, 2 steps)")
    speed = "speed lost in the turns: 0.01 of the straight-run speed (u 5.46 m/s at the straighter end, 5.406 m/s)"
    ks = [-0.00560, -0.00561]
    k = judge_nomoto(_estimates(ks), [_fit(ks[0], 0, 10, f"OE; {speed}; {note}"),
                                      _fit(ks[1], 10, 0, f"OE; {speed}; {note}")])["K_nomoto"]
    assert k.value == pytest.approx(-0.0057333)
    # Its error: the levels' and the speed term (the levels are read at the turns' speed).
    assert 3.2e-5 < k.stderr < 5e-5, k.message
    assert STEADY_K in k.message and "the fits' combination" in k.message, k.message
    # A steady K less precise than the fits' (holds too short to settle) leaves the fits' value.
    wide = note.replace("+- 3.2e-05", "+- 3e-4")
    kept = judge_nomoto(_estimates(ks), [_fit(ks[0], 0, 10, f"OE; {wide}"), _fit(ks[1], 10, 0, f"OE; {wide}")])
    assert kept["K_nomoto"].value == pytest.approx(np.mean(ks))
    # Without the note the fits' combination stands.
    plain = judge_nomoto(_estimates(ks), [_fit(ks[0], 0, 10, "OE"), _fit(ks[1], 10, 0, "OE")])["K_nomoto"]
    assert plain.value == pytest.approx(np.mean(ks)) and STEADY_K not in plain.message


def test_steady_levels_not_linear_in_the_rudder_mark_k_unsure():
    # Steps out of a turn whose secant is 12 % larger than into it: the steady turn rate is not linear.
    wins = [_window(0, 0.0, 10.0, 0.0), _window(1, 10.0, 0.0, 180.0), _window(2, 0.0, -10.0, 360.0),
            _window(3, -10.0, 0.0, 540.0)]
    for i in (1, 3):
        rec = wins[i].rec
        wins[i] = replace(wins[i], rec=replace(rec, psi=rec.psi * 1.12))
    note = steady_level_note(wins, [8.0] * 4, "undecided")
    assert "superposition broken: 2 steps into a turn give K" in note, note
    fits = [_fit(-0.0057, 0, 10, f"OE; {note}"), _fit(-0.0057, 10, 0, f"OE; {note}")]
    k = judge_nomoto(_estimates([-0.0057, -0.0057], se=1e-3), fits)["K_nomoto"]
    assert not k.success and k.message.startswith("unsure: nonlinear: 2 steps into a turn"), k.message


def _curved_window(seed: int, before_deg: float, after_deg: float, t_start: float) -> NomotoWindow:
    """:func:`_window` of a rudder whose effect saturates, ``delta (1 + a delta^2)`` with ``a = -0.656 1/rad^2``
    (the secant -2.0 % at 10 deg, -0.5 % at 5 deg: PythonVehicleSimulator's Clarke83 ``sin 2 delta``)."""
    win = _window(seed, before_deg, after_deg, t_start)
    t = win.t_rel
    d0, d1 = math.radians(before_deg), math.radians(after_deg)
    f = lambda d: d * (1 - 0.656 * d * d)  # noqa: E731
    _, r_dev, _ = signal.lsim(signal.TransferFunction([K * T3, K], [T1T2, T12, 1.0]),
                              np.where(t < 0, 0.0, f(d1) - f(d0)), t - t[0])
    r = K * f(d0) + r_dev
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (r[1:] + r[:-1]) / FS)])
    rng = np.random.default_rng(seed)
    rec = replace(win.rec, psi=psi + math.radians(0.2) * rng.standard_normal(t.size),
                  r=r + math.radians(0.05) * rng.standard_normal(t.size))
    return replace(win, rec=rec)


def test_steady_levels_that_lean_to_a_rudder_curvature_mark_k_unsure():
    # Steps of 10 and 5 deg whose secants follow the curvature, the slope test short of significance (p = 0.11):
    # the constant K (-1.3 % at these amplitudes) and K0 differ by 2.5 %, so the constant is not marked success
    # (measured on PythonVehicleSimulator's Clarke83 re-timed with waves: the secants' K -1.2 to -1.9 % marked
    # success with the interval missing on 8 of 10 seeds before this test read them).
    steps = [(0, 10), (10, 0), (0, -10), (-10, 0), (0, 5), (5, 0)]
    wins = [_curved_window(30 + i, b, a, 360.0 * i) for i, (b, a) in enumerate(steps)]
    note = steady_level_note(wins, [8.0] * 6, "undecided")
    assert "rudder-amplitude model not kept" in note and "superposition broken: K may change with the rudder amplitude" in note, note
    fits = [_fit(-0.0057, 0, 10, f"OE; {note}"), _fit(-0.0057, 10, 0, f"OE; {note}")]
    k = judge_nomoto(_estimates([-0.0057, -0.0057], se=1e-3), fits)["K_nomoto"]
    assert not k.success and k.message.startswith("unsure: nonlinear: K may change with the rudder amplitude"), k.message
