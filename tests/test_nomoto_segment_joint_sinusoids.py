"""Sinusoids at two frequencies fitted jointly: the model structure read across the frequencies.

Each sinusoid alone is matched by a first-order model whatever the ship; a ship beyond the first order
shows as a first-order T that changes with the frequency (:func:`pipeline.fit.nomoto_segment.frequency_spread`).
Records: a linear Nomoto ship (the project's own model) simulated on a fine grid, 5 Hz logs with
compass, gyro and rudder-sensor noise as PythonVehicleSimulator's benchmark adds them.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.signal

from pipeline.fit.nomoto_oe import NomotoRecord, fit_nomoto
from pipeline.fit.nomoto_segment import choose_order, frequency_spread
from pipeline.model import discretise
from pipeline.model.nomoto import ORDER2_SUM_PRODUCT, nomoto_matrices

H = 0.2
#: PythonVehicleSimulator's tanker at 20 m, linearised (benchmarks/RESULTS.md): complex poles and a zero.
TANKER = (-0.0057024, 30.204, 276.53, 20.883)
#: Its first-order equivalent T = T1 + T2 - T3 [s].
TANKER_T = TANKER[1] - TANKER[3]


def _sine_record(order, dyn, omega, periods, seed, name):
    """One sinusoid of 10 deg at ``omega`` [rad/s] from a steady straight run, logged at 5 Hz."""
    sub = 20
    h = H / sub
    n = int(periods * 2 * math.pi / omega / H)
    t = np.arange(n) * H
    fine_t = np.arange(n * sub) * h
    d = math.radians(10.0) * np.sin(omega * fine_t)
    a, b = nomoto_matrices(order, dyn)
    ad, bd = discretise.zoh(a, b, h)
    # The rudder held over each fine step (the zero-order hold the model was discretised with).
    _, _, xs = scipy.signal.dlsim((ad, bd, np.eye(a.shape[0]), np.zeros((a.shape[0], 1)), h), d)
    rng = np.random.default_rng(seed)
    psi = xs[::sub, 0] + math.radians(0.2) * rng.standard_normal(n)
    r = xs[::sub, 1] + math.radians(0.05) * rng.standard_normal(n)
    rudder = d[::sub] + math.radians(0.1) * rng.standard_normal(n)
    return NomotoRecord(t=t, delta=rudder, psi=psi, r=r, name=name)


def _pair(order, dyn, scale, seed):
    """The benchmark's sinusoid pair for a ship of time scale ``scale`` [s]: 2/scale and 0.5/scale rad/s."""
    return [_sine_record(order, dyn, 2.0 / scale, 2.7, seed, "fast"),
            _sine_record(order, dyn, 0.5 / scale, 3.0, seed + 1, "slow")]


def test_second_order_ship_chosen_across_sinusoid_frequencies():
    # The jointly fitted first order is a compromise weighted by the records' heading swing: its misfit
    # sits on the fast record, whose 0.7 deg swing the 0.2 deg compass noise dominates, so the held-out
    # error shrinks by a few percent only and leaving that record out leaves no gain. The first order
    # was kept, and K and T were combined from the two frequencies' first-order matches (the tanker:
    # K +8 %, T +27 %).
    recs = _pair(ORDER2_SUM_PRODUCT, TANKER, TANKER[1], seed=4)
    choice = choose_order(recs, ("psi", "r"), ())
    assert choice.order == ORDER2_SUM_PRODUCT, choice.note
    assert "differ across their frequencies" in choice.note
    # Each record alone: a first-order T of its own frequency, far from the ship's equivalent T.
    alone = [fit_nomoto(r, order=1, noise="white", channels=("psi", "r")).T for r in recs]
    assert alone[0] > 1.3 * TANKER_T and alone[1] > 1.05 * TANKER_T
    joint = fit_nomoto(recs, order=ORDER2_SUM_PRODUCT, noise="white", channels=("psi", "r"))
    assert abs(joint.K / TANKER[0] - 1) < 0.02
    assert abs(joint.T / TANKER_T - 1) < 0.1


def test_first_order_ship_keeps_the_first_order_across_sinusoid_frequencies():
    recs = _pair(1, (TANKER[0], TANKER_T), TANKER_T, seed=4)
    choice = choose_order(recs, ("psi", "r"), ())
    assert choice.order == 1, choice.note
    n = [int(round(0.65 * r.t.size)) for r in recs]
    parts = [NomotoRecord(t=r.t[:k], delta=r.delta[:k], psi=r.psi[:k], r=r.r[:k], name=r.name) for r, k in zip(recs, n)]
    spread = frequency_spread(parts, ("psi", "r"), ())
    assert not spread.material and "do not differ materially" in spread.note
