"""K and T over speed (pipeline.fit.nomoto_speed) and the autopilot gain schedule that follows them."""

import math

import numpy as np
import pytest

from pipeline.autopilot.design import build_autopilot, coefficients_at_speed, gain_schedule
from pipeline.autopilot.pd import pd_gains
from pipeline.errors import AutopilotError, FitError
from pipeline.fit.nomoto_records import NomotoRecord
from pipeline.fit.nomoto_speed import fit_nomoto_speeds, speed_law
from pipeline.model.nomoto import NomotoParams, nomoto_rhs

L = 10.0  # ship length [m]
K_PRIME, T_PRIME = 2.0, 1.5  # dimensionless Nomoto K' = K L / U, T' = T U / L


def _record(K, T, seed, h=0.5, n=240):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * h
    delta = np.where(t < 5, 0.0, np.where(t < 60, math.radians(10), math.radians(-10)))
    p = NomotoParams(K=K, T=T)
    x, out = np.zeros(2), np.empty((n, 2))
    for j in range(n):
        out[j] = x
        for _ in range(5):
            hh = h / 5
            k1 = nomoto_rhs(0, x, (delta[j],), p)
            k2 = nomoto_rhs(0, x + hh / 2 * k1, (delta[j],), p)
            k3 = nomoto_rhs(0, x + hh / 2 * k2, (delta[j],), p)
            k4 = nomoto_rhs(0, x + hh * k3, (delta[j],), p)
            x = x + hh / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return NomotoRecord(t=t, delta=delta, psi=out[:, 0] + rng.normal(0, math.radians(0.3), n),
                        r=out[:, 1] + rng.normal(0, math.radians(0.1), n))


def _runs(scaled: bool):
    runs = {}
    for i, u in enumerate((1.0, 2.0, 3.0)):
        K, T = (K_PRIME * u / L, T_PRIME * L / u) if scaled else (0.4, 5.0)
        runs[u] = [_record(K, T, 10 * i), _record(K, T, 10 * i + 1)]
    return runs


def test_speed_dependent_K_T_recovered_and_schedule_follows_them():
    m = fit_nomoto_speeds(_runs(scaled=True), length=L)
    assert m.K.speed_dependent and m.T.speed_dependent and m.speed_dependent
    for u in (1.0, 2.0, 3.0):
        kt = m.at(u)
        assert abs(kt["K"] - K_PRIME * u / L) < 4 * kt["K_stderr"] + 1e-3
        assert abs(kt["T"] - T_PRIME * L / u) < 4 * kt["T_stderr"] + 0.05
    for d in m.dimensionless():
        assert d["K_prime"] == pytest.approx(K_PRIME, rel=0.05)
        assert d["T_prime"] == pytest.approx(T_PRIME, rel=0.05)
    sched = gain_schedule(m, [1.0, 2.0, 3.0])
    assert sched.speed_dependent
    kpd = [e.gains.kpd for e in sched.entries]
    td = [e.gains.td for e in sched.entries]
    # Each entry is the PD design on K(U), T(U); faster -> larger K, smaller T -> smaller gain, shorter Td.
    for e in sched.entries:
        ref = pd_gains(e.K, e.T)
        assert e.gains.kpd == pytest.approx(ref.kpd) and e.gains.td == pytest.approx(e.T)
        assert e.worst_phase_margin > 0
    # With the default crossover (omega_c T fixed) and K T constant under Nomoto's scaling, K_pd stays
    # about the same while T_d = T(U) and the crossover follow the speed.
    assert td[0] > td[1] > td[2]
    assert kpd == pytest.approx([kpd[0]] * 3, rel=0.1)
    wc = [e.gains.crossover for e in sched.entries]
    assert wc[0] < wc[1] < wc[2]
    # With one crossover for all speeds, K_pd = omega_c sqrt(1 + (T_f omega_c)^2) / K(U) falls with speed.
    fixed = gain_schedule(m, [1.0, 2.0, 3.0], crossover=0.5)
    kf = [e.gains.kpd for e in fixed.entries]
    assert kf[0] > kf[1] > kf[2]
    mid = fixed.gains_at(1.5)
    assert kf[1] < mid.kpd < kf[0]
    assert fixed.gains_at(10.0).kpd == pytest.approx(kf[-1])


def test_constant_K_T_give_one_set_of_gains():
    m = fit_nomoto_speeds(_runs(scaled=False))
    assert not m.speed_dependent
    assert m.at(1.0)["K"] == pytest.approx(0.4, rel=0.05) and m.at(3.0)["T"] == pytest.approx(5.0, rel=0.05)
    sched = gain_schedule(m, [1.0, 3.0])
    assert sched.entries[0].gains.kpd == pytest.approx(sched.entries[1].gains.kpd)
    assert not sched.speed_dependent


def test_speed_law_errors_and_birge_ratio():
    law = speed_law("K", np.array([1.0, 2.0]), np.array([0.1, 0.2]), np.array([1e-3, 1e-3]))
    assert law.speed_dependent and law.at(3.0)[0] == pytest.approx(0.3)
    scattered = speed_law("T", np.array([1.0, 2.0, 3.0, 4.0]), np.array([5.0, 5.2, 4.8, 5.1]), np.array([0.01] * 4))
    assert scattered.birge > 1.0
    with pytest.raises(FitError, match="finite estimate"):
        speed_law("K", np.array([1.0]), np.array([np.nan]), np.array([0.1]))
    with pytest.raises(FitError, match="positive speeds"):
        fit_nomoto_speeds({-1.0: [_record(0.4, 5.0, 0)]})
    with pytest.raises(AutopilotError, match="positive scheduling speeds"):
        gain_schedule(fit_nomoto_speeds(_runs(scaled=False)), [])


def test_autopilot_built_on_the_model_linearised_at_the_operating_speed():
    m = fit_nomoto_speeds(_runs(scaled=True), length=L)
    c = coefficients_at_speed(m, 2.5, vessel="test")
    assert c.K == pytest.approx(m.at(2.5)["K"]) and c.T == pytest.approx(m.at(2.5)["T"]) and c.K_stderr > 0
    res = build_autopilot(c, check=False)
    assert res.config.K == pytest.approx(c.K) and res.config.pd.td == pytest.approx(c.T)
    with pytest.raises(AutopilotError, match="positive speed"):
        coefficients_at_speed(m, 0.0)
