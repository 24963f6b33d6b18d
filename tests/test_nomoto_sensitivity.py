"""The exact Jacobian of the whole-record Nomoto criterion (sensitivity equations) against central
finite differences of the real simulation, for every model order, noise model, servo and several records."""

import math

import numpy as np
import pytest

from pipeline.fit.nomoto_problem import Problem, prepare, start_vector
from pipeline.fit.nomoto_records import NomotoRecord
from pipeline.fit.nomoto_sensitivity import propagate, propagate_outputs
from pipeline.fit.nomoto_zoh import simulate_zoh, zoh_discretise
from pipeline.model.nomoto import nomoto_matrices


def _records():
    rng = np.random.default_rng(1)
    h, n = 0.1, 1500
    t = np.arange(n) * h
    delta = math.radians(10) * np.sign(np.sin(2 * np.pi * t / 40))
    psi = np.cumsum(0.01 * np.sin(t / 7)) + 0.01 * rng.standard_normal(n)
    r = np.gradient(psi, h)
    full = NomotoRecord(t=t, delta=delta, psi=psi, r=r, name="a")
    part = NomotoRecord(t=t[:800], delta=delta[:800], psi=psi[:800], r=r[:800], name="b")
    return full, part


@pytest.mark.parametrize("order, noise, servo, nrec", [
    (1, "white", (), 1), (3, "white", (), 1), (2, "white", (), 2), (1, "waves", (), 1),
    (3, "waves", ("t_servo",), 2), (1, "white", ("t_servo", "rate_servo"), 1)])
def test_exact_jacobian_matches_central_differences(order, noise, servo, nrec):
    recs = list(_records())[:nrec]
    preps = [prepare(r, i, ("psi", "r")) for i, r in enumerate(recs)]
    prob = Problem(preps, order, True, ("psi", "r"), noise, None, None, servo)
    dyn = {1: [0.2, 8.0], 2: [0.2, 8.0, 1.0, 3.0], 3: [0.2, 9.0, 12.0, 3.0]}[order]
    ics = [[0.1, 0.01] + ([0.001] if order != 1 else []) for _ in recs]
    noise0 = (0.8, 0.1, 3.0) if noise == "waves" else ()
    z = start_vector(prob, dyn, 0.01, ics, noise0)
    prob.weights = {"psi": 3.0, "r": 0.5}
    exact = prob.jacobian(z)
    fd = prob.fd_jacobian(z)
    scale = np.maximum(np.abs(fd).max(axis=0), 1e-300)
    # Central differences with a 1e-6 relative step are good to about 1e-7 of the column's size.
    np.testing.assert_array_less(np.abs(exact - fd).max(axis=0) / scale, 1e-5)
    # Another record's initial state does not move this record's residuals: exact zeros.
    if nrec == 2:
        n0 = sum(int(prob.recs[0].mask[ch].sum()) for ch in prob.channels)
        assert np.all(exact[:n0, prob.names.index("r0[1]")] == 0.0)


def test_propagate_reproduces_the_simulation():
    # The sensitivity recursion with v = B u and s0 = x0 is the simulation itself.
    a, b = nomoto_matrices(3, (0.2, 9.0, 12.0, 3.0))
    ad, bd = zoh_discretise(a, b, 0.1)
    u = np.sin(np.arange(500) * 0.05)
    x0 = np.array([0.3, 0.02, -0.001])
    ref = simulate_zoh(ad, bd, x0, u)
    got = propagate(ad, (u[:, None] * bd[:, 0])[:, :, None], x0[:, None])[:, :, 0]
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("order", [1, 2, 3])
def test_propagate_outputs_equals_the_full_recursion(order):
    # Heading and yaw-rate rows of the one-filter-per-output form against the state recursion, for
    # random driving terms and initial values on every state and column.
    dyn = {1: (0.2, 8.0), 2: (0.2, 8.0, 1.0, 3.0), 3: (0.2, 9.0, 12.0, 3.0)}[order]
    a, b = nomoto_matrices(order, dyn)
    ad, _ = zoh_discretise(a, b, 0.1)
    rng = np.random.default_rng(order)
    n, p, nsamp = ad.shape[0], 5, 700
    v = rng.standard_normal((nsamp, n, p))
    s0 = rng.standard_normal((n, p))
    ref = propagate(ad, v, s0)
    got = propagate_outputs(ad, np.ascontiguousarray(v.transpose(2, 1, 0)), s0, (0, 1))
    for state in (0, 1):
        np.testing.assert_allclose(got[state], ref[:, state, :].T, rtol=1e-9, atol=1e-9 * np.abs(ref).max())
