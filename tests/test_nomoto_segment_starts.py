"""A second-order fit started from a first-order one (pipeline/fit/nomoto_segment.py
``first_order_start_values``, pipeline/fit/nomoto_oe.py ``fit_nomoto``) must start *at* that fit: its first
start candidate (a zero cancelling a pole) reproduces the first-order model only with the first order's
initial heading, yaw rate and yaw acceleration. Without them it started thousands of noise variances
above the first order (PythonVehicleSimulator's tanker at 20 m, commanded steps: 2,700-6,000), and the
in-sample gain floor stopped it after 25 evaluations.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.signal

from pipeline.fit.nomoto_oe import GainFloor, fit_nomoto
from pipeline.fit.nomoto_records import NomotoRecord
from pipeline.fit.nomoto_segment import first_order_start_values
from pipeline.model import discretise
from pipeline.model.nomoto import ORDER2_SUM_PRODUCT, nomoto_matrices

H = 0.2
#: A second-order ship with complex poles and a zero (K, T1 + T2, T1 T2, T3), like the tanker at 20 m.
SHIP2 = (-0.0057, 30.2, 276.5, 20.9)


def _simulate(order, dyn, rudder, x0=None):
    a, b = nomoto_matrices(order, dyn)
    ad, bd = discretise.zoh(a, b, H)
    n = a.shape[0]
    _, xs, _ = scipy.signal.dlsim((ad, bd, np.eye(n), np.zeros((n, 1)), H), rudder,
                                  x0=np.zeros(n) if x0 is None else x0)
    return xs


def _step_record(seed, lead=60.0, hold=150.0, name="step"):
    """A measured rudder step 0 -> 10 deg of SHIP2 from a straight run, compass and gyro noise."""
    cmd = np.concatenate([np.zeros(int(lead / H)), np.full(int(hold / H), math.radians(10.0))])
    rng = np.random.default_rng(seed)
    xs = _simulate(ORDER2_SUM_PRODUCT, SHIP2, cmd)
    t = np.arange(cmd.size) * H
    psi = xs[:, 0] + math.radians(0.2) * rng.standard_normal(t.size)
    r = xs[:, 1] + math.radians(0.05) * rng.standard_normal(t.size)
    delta = cmd + math.radians(0.1) * rng.standard_normal(t.size)
    return NomotoRecord(t=t, delta=delta, psi=psi, r=r, name=name)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_second_order_from_the_first_order_fit_is_not_stopped(seed):
    # Main (initial states guessed, yaw acceleration 0): stopped after 25 evaluations on all three seeds,
    # 25-51 noise variances worse than the first order. Here: K within 0.3 % (first order +2.2 to +3.6 %).
    rec = _step_record(seed)
    first = fit_nomoto(rec, order=1, noise="white", channels=("psi", "r"))
    assert first.success, first.message
    start = first_order_start_values(first)
    second = fit_nomoto(rec, order=ORDER2_SUM_PRODUCT, noise="white", channels=("psi", "r"), start=start,
                        gain_floor=GainFloor.from_first_order(first, rec))
    assert {"psi0", "r0"} <= set(start)
    assert second.converged and second.neg2loglik < first.neg2loglik
    assert abs(second.K / SHIP2[0] - 1.0) < 0.01
    assert abs(first.K / SHIP2[0] - 1.0) > 0.015


def test_joint_records_start_at_the_first_order_fit():
    # Two records fitted together: the initial states are named per record (psi0[0], r0[1], ...).
    recs = [_step_record(seed, name=f"step{seed}") for seed in (0, 1)]
    first = fit_nomoto(recs, order=1, noise="white", channels=("psi", "r"))
    start = first_order_start_values(first)
    second = fit_nomoto(recs, order=ORDER2_SUM_PRODUCT, noise="white", channels=("psi", "r"), start=start,
                        gain_floor=GainFloor.from_first_order(first, recs))
    assert {"psi0[0]", "r0[0]", "psi0[1]", "r0[1]"} <= set(start)
    assert abs(second.K / SHIP2[0] - 1.0) < 0.01
