"""The joint damping fit's sparse path (pipeline.fit.quadratic): the sparse Jacobian equals column-wise
finite differences, the shared block of the HAC covariance from it equals the dense sandwich, and the
LSMR solve of a many-segment problem gives the dense exact solve's coefficients."""

from __future__ import annotations

import numpy as np
import pytest

import pipeline.fit.quadratic as quadratic
from pipeline.fit.quadratic import DofRecord, fit_dof, problem, shared_hac_covariance, start_vector
from pipeline.fit.robust_covariance import hac_covariance
from pipeline.model.vessel5dof import simulate_dof

DT = 0.1
M = 13.0


def surge_records(n_rec: int, seed: int, a: float = 0.22, b: float = 0.9) -> list[DofRecord]:
    """Steps and coast-downs of one surge model with coloured noise, forces varied per record."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n_rec):
        n = int(rng.integers(80, 160))
        force = rng.uniform(5.0, 25.0)
        step = i % 2 == 0
        f = np.full(n, force if step else 0.0)
        u0 = 0.0 if step else float(np.sqrt(force / M / b))
        u = simulate_dof(np.array([u0]), (f / M)[None, :], DT, a, b)[0]
        noise = np.convolve(rng.normal(0, 0.01, n + 4), np.ones(5) / 5, mode="valid")
        y = u + noise
        y[rng.integers(0, n, 3)] = np.nan
        out.append(DofRecord(f"s{i}", "step" if step else "coast_down", y, {"tau_x": f}, 0.01, "rate", "u"))
    return out


def roll_records(n_rec: int, seed: int) -> list[DofRecord]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n_rec):
        n = 150
        phi0 = rng.uniform(0.05, 0.2)
        x = simulate_dof(np.array([[0.0, phi0]]), np.zeros((1, n)), DT, 0.6, 1.5, 9.0)[0]
        angle = i % 2 == 0
        y = (x[:, 1] + 0.01 if angle else x[:, 0]) + rng.normal(0, 0.003, n)
        out.append(DofRecord(f"r{i}", "free_decay", y, {}, 0.003, "angle" if angle else "rate",
                             "phi" if angle else "p"))
    return out


@pytest.mark.parametrize("dof, records", [("surge", surge_records(5, 1)), ("roll", roll_records(4, 2))])
def test_sparse_jacobian_equals_columnwise_differences(dof, records):
    p = problem(records, dof, DT, M if dof == "surge" else float("nan"), "quadratic")
    theta = start_vector(p)
    theta[1] = 0.5  # b away from 0
    free = np.ones((len(records), p.n_loc), bool)
    jac = p.jacobian(theta, p.mask, free)
    assert jac.format == "csr"
    dense = jac.toarray()
    r0 = p.residuals(theta, p.mask)
    for j in range(theta.size):
        h = 1e-6 * max(abs(theta[j]), 1e-3)
        th = theta.copy()
        th[j] += h
        col = (p.residuals(th, p.mask) - r0) / h
        np.testing.assert_allclose(dense[:, j], col, rtol=1e-6, atol=1e-6 * max(np.abs(col).max(), 1e-12))
    # A row holds the shared columns and only its own record's locals.
    ng = len(p.names)
    rec_of_row = np.broadcast_to(np.arange(len(records))[:, None], p.mask.shape)[p.mask]
    for i in range(len(records)):
        other = np.ones(theta.size, bool)
        other[:ng] = False
        other[ng + i * p.n_loc: ng + (i + 1) * p.n_loc] = False
        assert not np.any(dense[rec_of_row == i][:, other])


@pytest.mark.parametrize("dof, records", [("surge", surge_records(12, 3)), ("roll", roll_records(6, 4))])
def test_shared_hac_equals_dense_sandwich(dof, records):
    p = problem(records, dof, DT, M if dof == "surge" else float("nan"), "quadratic")
    theta = start_vector(p)
    theta[1] = 0.3
    loc_free = np.ones((len(records), p.n_loc), bool)
    if p.second:
        loc_free[:, 2] = p.angle
    keep = np.concatenate([np.ones(len(p.names), bool), loc_free.ravel()])
    jac = p.jacobian(theta, p.mask, loc_free)[:, keep]
    r = p.residuals(theta, p.mask)
    groups = np.broadcast_to(np.arange(len(records))[:, None], p.mask.shape)[p.mask]
    ng = len(p.names)
    cov, rho = shared_hac_covariance(jac, r, groups, ng)
    ref = hac_covariance(jac.toarray(), r, groups)
    assert rho == pytest.approx(ref.rho)
    np.testing.assert_allclose(cov, ref.covariance[:ng, :ng], rtol=1e-6,
                               atol=1e-9 * np.abs(ref.covariance[:ng, :ng]).max())


def test_sparse_lsmr_solve_matches_dense_exact(monkeypatch):
    records = surge_records(12, 5)
    fits = {}
    for label, limit in (("sparse", 2), ("dense", 10_000)):
        monkeypatch.setattr(quadratic, "DENSE_MAX_PARAMETERS", limit)
        lin = fit_dof(records, "surge", DT, M, "linear")
        quad = fit_dof(records, "surge", DT, M, "quadratic", start=np.concatenate([lin.values, lin.initial_states]))
        fits[label] = (lin, quad)
    for s in (0, 1):
        sp, de = fits["sparse"][s], fits["dense"][s]
        assert sp.success and de.success
        assert np.all(np.abs(sp.values - de.values) < 1e-3 * de.stderr), (sp.values, de.values, de.stderr)
        np.testing.assert_allclose(sp.stderr, de.stderr, rtol=1e-4)
    # and the truth (a = 0.22, b = 0.9) within three standard errors of the quadratic fit
    q = fits["sparse"][1]
    assert abs(q.values[0] - 0.22) < 3 * q.stderr[0] and abs(q.values[1] - 0.9) < 3 * q.stderr[1]


def test_jacobian_base_point_reused_from_the_residuals_bit_for_bit(monkeypatch):
    """The solver's residual matrix at the accepted point is the Jacobian's base point: the same
    solution bit for bit as recomputing it, with one simulation fewer per Jacobian."""
    records = surge_records(4, 6)
    p = problem(records, "surge", DT, M, "quadratic")
    theta0 = start_vector(p)
    calls = {"sim": 0, "jac": 0}
    simulate, jacobian = type(p).simulate, type(p).jacobian

    def counted_simulate(self, theta):
        calls["sim"] += 1
        return simulate(self, theta)

    def counted_jacobian(self, *args, **kwargs):
        calls["jac"] += 1
        return jacobian(self, *args, **kwargs)

    monkeypatch.setattr(type(p), "simulate", counted_simulate)
    monkeypatch.setattr(type(p), "jacobian", counted_jacobian)
    reused = quadratic.solve(p, theta0, p.mask, max_nfev=15)
    with_reuse = dict(calls)

    def fresh_jacobian(self, theta, mask, free_locals, r0=None):
        calls["jac"] += 1
        return jacobian(self, theta, mask, free_locals)  # base point recomputed

    calls.update(sim=0, jac=0)
    monkeypatch.setattr(type(p), "jacobian", fresh_jacobian)
    recomputed = quadratic.solve(p, theta0, p.mask, max_nfev=15)
    assert reused.tobytes() == recomputed.tobytes()
    assert with_reuse["jac"] == calls["jac"] > 0
    assert calls["sim"] - with_reuse["sim"] == calls["jac"]
