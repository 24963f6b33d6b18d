"""PD heading autopilot: the seed's numbers, loop margins, the discrete controller, bad input."""

import math

import numpy as np
import pytest
import scipy.signal

from pipeline.autopilot.pd import (discretise_pd, loop_frequency_response, loop_margins, margin_table,
                                   pd_gains)
from pipeline.errors import AutopilotError

# The seed (TTK4115 boat lab, part III): omega_c = 0.1 rad/s, 50 deg, K = 0.1561 1/s, T = 72.4385 s.
K_SEED, T_SEED = 0.1561, 72.4385


def test_reproduces_seed_gains():
    g = pd_gains(K_SEED, T_SEED, crossover=0.1, phase_margin=math.radians(50.0))
    assert g.tf == pytest.approx(8.391, abs=5e-4)
    assert g.kpd == pytest.approx(0.836, abs=5e-4)
    assert g.td == T_SEED


def test_design_plant_has_design_crossover_and_margin():
    g = pd_gains(K_SEED, T_SEED, 0.1, math.radians(50.0))
    wc, pm = loop_margins(K_SEED, T_SEED, g)
    assert wc == pytest.approx(0.1, rel=1e-6)
    assert math.degrees(pm) == pytest.approx(50.0, abs=1e-4)
    assert abs(loop_frequency_response(np.array([0.1]), K_SEED, T_SEED, g)[0]) == pytest.approx(1.0, rel=1e-9)


def test_other_designs_hit_their_targets():
    for wc_target, pm_deg in ((0.05, 40.0), (0.3, 65.0), (1.0, 30.0)):
        g = pd_gains(1.7, 4.2, wc_target, math.radians(pm_deg))
        wc, pm = loop_margins(1.7, 4.2, g)
        assert wc == pytest.approx(wc_target, rel=1e-6)
        assert math.degrees(pm) == pytest.approx(pm_deg, abs=1e-4)


def test_margin_table_covers_confidence_box():
    g = pd_gains(K_SEED, T_SEED, crossover=0.1)
    rows = margin_table(K_SEED, T_SEED, 0.005, 3.0, g)
    assert len(rows) == 5
    assert rows[0]["crossover"] == pytest.approx(0.1, rel=1e-6)
    # a plant with more gain crosses over later
    hi_k = [r for r in rows if r["K"] > K_SEED]
    assert all(r["crossover"] > 0.09 for r in hi_k)
    assert len(margin_table(K_SEED, T_SEED, math.nan, math.nan, g)) == 1


def test_discrete_pd_matches_continuous_step_response():
    g = pd_gains(K_SEED, T_SEED)
    ts = 0.1
    d = discretise_pd(g, ts)
    n = 600
    e = np.ones(n)
    z, out = 0.0, []
    for k in range(n):
        out.append(d.output(z, e[k]))
        z = d.next_state(z, e[k])
    sys = scipy.signal.lti([g.kpd * g.td, g.kpd], [g.tf, 1.0])
    t = ts * np.arange(n)
    _, y, _ = scipy.signal.lsim(sys, e, t)
    np.testing.assert_allclose(out, y, rtol=1e-6, atol=1e-9)
    assert out[0] == pytest.approx(g.kpd * g.td / g.tf)  # the high-frequency gain hits the rudder first


@pytest.mark.parametrize("kwargs, match", [
    (dict(K=0.0, T=72.0), "Nomoto K"),
    (dict(K=-0.1, T=72.0), "Nomoto K"),
    (dict(K=0.1, T=float("nan")), "Nomoto T"),
    (dict(K=0.1, T=72.0, crossover=0.0), "crossover"),
    (dict(K=0.1, T=72.0, phase_margin=math.radians(90.0)), "phase margin"),
    (dict(K=0.1, T=72.0, phase_margin=0.0), "phase margin"),
])
def test_bad_design_input(kwargs, match):
    with pytest.raises(AutopilotError, match=match):
        pd_gains(**kwargs)


def test_bad_sample_time():
    with pytest.raises(AutopilotError, match="sample time"):
        discretise_pd(pd_gains(K_SEED, T_SEED), 0.0)
