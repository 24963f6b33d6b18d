"""Grey-box fit of the coupled lateral damping (pipeline.fit.greybox) and extend_fits: the casadi
model is the project's 5-DOF right-hand side, its Jacobian matches finite differences, a coupled
AAUSHIP-like vessel is recovered through sway steps, zig-zags and roll decays within 3 sigma, and
trials that do not excite the coupling get the coefficients flagged with the manoeuvre to run.
All simulations are seeded; sensors at 50 Hz keep the tests fast."""

from __future__ import annotations

import copy
import inspect
import math
from dataclasses import replace

import numpy as np
import pytest

from pipeline.align import align
from pipeline.errors import FitError
from pipeline.fit import fit_trial
from pipeline.fit.extend import extend_fits
from pipeline.fit.casadi_jit import compile_function
from pipeline.fit.greybox import (COEFFICIENTS, COUPLED, NX, STATES, UNITS, _Problem, build_records,
                                  fit_coupled_damping, generalised_force, lateral_segments, step_function)
from pipeline.model import Vessel5DofParams, integrate_rk4, params_from_vessel, vessel5dof_rhs
from pipeline.records import Segments, Trial
from pipeline.sim import chain, free_decay, rudder_step, simulate, step_and_coast, zigzag
from pipeline.sim.sensors import default_sensors
from pipeline.vessel import parse_vessel

def single_dof_fits(trial, segments, vessel):
    """fit_trial without the joint extension (whether or not fit_trial already runs extend_fits)."""
    if "extend" in inspect.signature(fit_trial).parameters:
        return fit_trial(trial, segments, vessel, extend=False)
    return fit_trial(trial, segments, vessel)


# The AAUSHIP seed's full linear damping (u v p q r), positive convention.
D_SEED = np.array([[2.86, 0, 0, 0, 0],
                   [0, 32.5, -0.00503, 0, 0.09263],
                   [0, -0.975, 0.1094, 0, 0.01273],
                   [0, 0, 0, 7.2030, 0],
                   [0, 0.975, -0.00069, 0, 0.26285]])
COUPLED_DOC = {"name": "aauship-coupled", "rigid_body": {"mass": 13.0, "inertia": [0.0654, 1.089, 1.107]},
               "restoring": {"roll": 6.97, "pitch": 131.8}, "damping": {"matrix": D_SEED.tolist()},
               # A rudder with a sway force, as a ship's has: a zig-zag then moves sway and yaw apart.
               "rudder": {"yaw_moment": 0.45, "sway_force": 2.0}}
VESSEL = parse_vessel(COUPLED_DOC)
TRUTH = {n: -D_SEED[ij] for n, ij in COEFFICIENTS.items()}
SENSORS = tuple(replace(s, rate=min(s.rate, 50.0)) for s in default_sensors())
Z20 = math.radians(20)


def _trial(schedule, seed):
    res = simulate(VESSEL, schedule, sensors=SENSORS, seed=seed)
    return align([res.log], name=f"coupled-{seed}"), res.segments


@pytest.fixture(scope="module")
def coupled_trial():
    """Sway step and coast-down, a 20/20 zig-zag at 1 m/s, a roll free decay."""
    schedule = chain(step_and_coast("sway", 9.75, 3, 3), zigzag(Z20, Z20, 50, {"tau_x": 2.86}),
                     free_decay("roll", math.radians(20), 5), rest_s=4)
    trial, segs = _trial(schedule, seed=1)
    return trial, segs, single_dof_fits(trial, segs, VESSEL)


def test_casadi_step_is_the_shared_5dof_rhs():
    """The symbolic step (unknown D entries through tau - D_theta nu) equals RK4 of vessel5dof_rhs."""
    rng = np.random.default_rng(3)
    est = tuple(COEFFICIENTS)
    d_fixed = D_SEED.copy()
    for n in est:
        d_fixed[COEFFICIENTS[n]] = 0.0
    params = Vessel5DofParams(M=VESSEL.mass_matrix(), D=d_fixed, G=VESSEL.restoring_matrix())
    step = step_function(params, est, 0.02, 2)
    theta = np.array([D_SEED[COEFFICIENTS[n]] for n in est])
    full = params_from_vessel(VESSEL)
    x10 = np.zeros(10)
    idx = (1, 2, 3, 4, 7, 8)
    x10[list(idx)] = rng.normal(0, 0.2, 6)
    tau = np.zeros((50, 5))
    tau[:, [1, 2, 4]] = rng.normal(0, 1.0, (50, 3))
    ref = integrate_rk4(vessel5dof_rhs, x10, np.arange(50) * 0.02, tau, full, substeps=2)
    x = x10[list(idx)]
    for k in range(49):
        x = np.asarray(step(x, tau[k], theta)).ravel()
    # Surge is held at rest in the grey-box model; with y_g = z_g = 0 it does not couple.
    assert np.allclose(x, ref[-1, list(idx)], atol=1e-12)


def test_jacobian_matches_central_differences(coupled_trial):
    trial, segs, fits = coupled_trial
    seg = Segments(segs.trial, tuple(s for s in lateral_segments(segs) if s.kind == "free_decay"))
    records = build_records(trial, seg.items, VESSEL)
    est = tuple(COEFFICIENTS)
    d_fixed = D_SEED.copy()
    for n in est:
        d_fixed[COEFFICIENTS[n]] = 0.0
    params = Vessel5DofParams(M=VESSEL.mass_matrix(), D=d_fixed, G=VESSEL.restoring_matrix())
    scale = np.array([abs(D_SEED[COEFFICIENTS[n]]) + 0.01 for n in est])
    prob = _Problem(records, est, params, scale, np.full(NX, 0.1), 0.02, 1, 60, jit=False)
    rng = np.random.default_rng(4)
    z = np.concatenate([rng.uniform(0.5, 1.5, len(est)), prob.node_guess() + rng.normal(0, 0.1, prob.n_z - len(est))])
    w = prob.weights(np.full(NX, 0.01))
    rho = np.linspace(1.0, 3.0, prob.n_def)
    jac = prob.jacobian(z, w, rho).toarray()
    fd = np.empty_like(jac)
    for j in range(prob.n_z):
        h = 1e-6 * max(1.0, abs(z[j]))
        zp, zm = z.copy(), z.copy()
        zp[j] += h
        zm[j] -= h
        fd[:, j] = (prob.residual(zp, w, rho) - prob.residual(zm, w, rho)) / (2 * h)
    assert prob.n_def > 0  # the decay spans more than one shooting interval
    assert np.max(np.abs(jac - fd)) < 1e-6 * max(1.0, np.max(np.abs(jac)))


def test_compiled_and_virtual_machine_rollouts_agree():
    params = Vessel5DofParams(M=VESSEL.mass_matrix(), D=np.diag(np.diag(D_SEED)), G=VESSEL.restoring_matrix())
    step = step_function(params, ("Y_r", "N_v"), 0.02, 1).mapaccum("roll", 30)
    fast, compiled, note = compile_function(step, jit=True)
    rng = np.random.default_rng(5)
    args = (rng.normal(0, 0.1, NX), rng.normal(0, 1, (5, 30)), np.tile([[0.1], [0.9]], (1, 30)))
    assert np.allclose(np.asarray(fast(*args)), np.asarray(step(*args)), atol=1e-13)
    if not compiled:
        pytest.skip(f"no working C compiler: the virtual machine was used for both ({note})")


def test_coupled_terms_recovered_within_three_sigma(coupled_trial):
    trial, segs, fits = coupled_trial
    ext = extend_fits(fits, trial, segs, VESSEL)
    # The seed's couplings that these manoeuvres excite, and a tolerance on each.
    for name, tol in (("Y_r", 0.25), ("N_v", 0.02), ("K_v", 0.02), ("K_r", 0.15), ("Y_v", 0.01), ("K_p", 0.01),
                      ("N_r", 0.01)):
        key = f"{name}_joint" if name in ("Y_v", "K_p", "N_r") else name
        est = ext.estimates[key]
        assert est.success, (name, est.message)
        err = est.value - TRUTH[name]
        assert abs(err) < 3 * est.stderr, f"{name}: {est.value:.5g} +- {est.stderr:.2g}, truth {TRUTH[name]:.5g}"
        assert abs(err) < tol * abs(TRUTH[name]), (name, est.value, TRUTH[name])
        assert est.unit == UNITS[name] and "grey-box" in est.method and "Levenberg-Marquardt" in est.method
        i, j = COEFFICIENTS[name]
        if key == name:
            assert ext.damping_matrix[i, j] == pytest.approx(-est.value)
            assert ext.damping_stderr[i, j] == pytest.approx(est.stderr)
        elif name in fits.estimates:
            # The single-DOF diagonal stays the matrix's and the table's value.
            assert ext.estimates[name] == fits.estimates[name]
            assert ext.damping_matrix[i, j] == pytest.approx(fits.damping_matrix[i, j])
        else:
            # No single-DOF value (the zig-zag is not a yaw coast-down): the matrix takes the joint one.
            assert ext.damping_matrix[i, j] == pytest.approx(-est.value)
            assert "takes the joint value" in est.message
    # Y_p and N_p of the seed are tiny: identified as near zero, or flagged; never far off.
    for name in ("Y_p", "N_p"):
        est = ext.estimates[name]
        if est.success:
            assert abs(est.value - TRUTH[name]) < 3 * est.stderr
    # The single-DOF diagonal is quoted in the message of the joint one.
    assert "single-DOF Y_v = " in ext.estimates["Y_v_joint"].message


def test_extend_fits_returns_a_new_record_and_leaves_the_input_alone(coupled_trial):
    trial, segs, fits = coupled_trial
    before = copy.deepcopy(fits)
    data_before = trial.data.copy()
    ext = extend_fits(fits, trial, segs, VESSEL)
    assert ext is not fits
    assert fits.estimates.keys() == before.estimates.keys()
    assert np.array_equal(fits.damping_matrix, before.damping_matrix, equal_nan=True)
    assert trial.data.equals(data_before)
    assert set(COUPLED) <= set(ext.estimates)
    assert ext.segment_fits == fits.segment_fits


def test_trial_without_sway_motion_flags_the_sway_yaw_coupling_and_names_the_manoeuvre():
    """Yaw step and coast-down with tau_n and a roll decay: sway barely moves, so Y_v and N_v are
    confounded (only N_r - N_v Y_r / Y_v is seen)."""
    schedule = chain(step_and_coast("yaw", 0.13, 25, 25), free_decay("roll", math.radians(20), 5), rest_s=4)
    trial, segs = _trial(schedule, seed=2)
    fits = single_dof_fits(trial, segs, VESSEL)
    ext = extend_fits(fits, trial, segs, VESSEL)
    for name, key in (("Y_v", "Y_v_joint"), ("N_v", "N_v")):
        est = ext.estimates[key]
        assert not est.success and math.isnan(est.value) and math.isnan(est.stderr)
        assert f"{name} not identified by this trial" in est.message
        assert "to determine it run" in est.message
    assert "sway step" in ext.estimates["N_v"].message and "zig-zag" in ext.estimates["N_v"].message
    assert math.isnan(ext.damping_matrix[4, 1])
    # What is determined is reported as conditional on what was held.
    assert "conditional on" in ext.estimates["N_r_joint"].message


def test_trial_without_lateral_segments_flags_every_coupling():
    schedule = chain(step_and_coast("surge", 2.86, 15, 15), rest_s=3)
    trial, segs = _trial(schedule, seed=3)
    fits = single_dof_fits(trial, segs, VESSEL)
    ext = extend_fits(fits, trial, segs, VESSEL)
    for name in COUPLED:
        est = ext.estimates[name]
        assert not est.success and "expected zig-zags" in est.message and "to determine it run" in est.message
    assert np.isnan(ext.damping_matrix[1, 4]) and ext.damping_matrix[0, 0] == pytest.approx(fits.damping_matrix[0, 0])
    with pytest.raises(FitError, match="expected zig-zags"):
        fit_coupled_damping(trial, segs, VESSEL)


def test_missing_roll_channel_holds_the_roll_couplings(coupled_trial):
    trial, segs, fits = coupled_trial
    no_roll = Trial(trial.name, trial.data.drop(columns=["p", "phi"]), trial.fs)
    gb = fit_coupled_damping(no_roll, segs, VESSEL, fits.damping_matrix)
    assert "K_v" not in gb.names and "no roll channel" in gb.fixed["K_v"]
    assert {"Y_r", "N_v", "Y_v", "N_r"} <= set(gb.names)
    assert "p" not in gb.outputs and "phi" not in gb.outputs


def test_vessel_without_rigid_body_is_left_to_the_nomoto_fits(coupled_trial):
    trial, segs, fits = coupled_trial
    nomoto_only = parse_vessel({"name": "ship"})
    ext = extend_fits(fits, trial, segs, nomoto_only)
    assert not set(COUPLED) & set(ext.estimates)
    assert np.array_equal(ext.damping_matrix, fits.damping_matrix, equal_nan=True)


def test_rudder_map_enters_the_generalised_force(coupled_trial):
    trial, _, _ = coupled_trial
    tau = generalised_force(trial, VESSEL)
    delta = trial.data["delta"].to_numpy()
    ok = np.isfinite(delta)
    assert np.allclose(tau[ok, 4] - np.nan_to_num(trial.data["tau_n"].to_numpy()[ok]) if "tau_n" in trial.data
                       else tau[ok, 4], 0.45 * delta[ok])
    assert np.all(tau[:, 0] == 0.0)


def test_grey_box_residual_tests_cover_every_record_and_channel(coupled_trial):
    trial, segs, fits = coupled_trial
    gb = fit_coupled_damping(trial, segs, VESSEL, fits.damping_matrix)
    assert len(gb.residual_tests) == len(gb.records) * len(gb.outputs)
    assert set(gb.outputs) <= set(STATES)
    assert gb.converged and gb.max_defect < 0.1 and 0.5 < gb.s2 < 2.0
    # Residuals of the right model are white on the IMU channels.
    assert all(t.white for t in gb.residual_tests if t.name.split()[1] in ("p", "r"))


def test_an_unexpected_failure_of_the_joint_fit_does_not_cost_the_single_dof_results(coupled_trial, monkeypatch):
    import pipeline.fit.extend as extend

    def broken(*args, **kwargs):
        raise RuntimeError("casadi exploded")

    monkeypatch.setattr(extend, "joint_fit", broken)
    trial, segs, fits = coupled_trial
    ext = extend_fits(fits, trial, segs, VESSEL)
    for name, est in fits.estimates.items():
        new = ext.estimates[name].value
        assert new == est.value or (math.isnan(est.value) and math.isnan(new))
    est = ext.estimates["N_v"]
    assert not est.success and "RuntimeError: casadi exploded" in est.message


def test_a_free_decay_starts_its_own_record():
    """A hull released by hand jumps in state: the record before it must not run into it."""
    import pandas as pd

    from pipeline.records import Segment

    t = np.arange(0.0, 40.0, 0.02)
    trial = Trial("adjacent", pd.DataFrame({"t": t, "r": np.zeros(t.size), "phi": np.zeros(t.size)}), 50.0)
    segs = (Segment("coast_down", "yaw", 0.0, 20.0), Segment("free_decay", "roll", 19.99, 30.0),
            Segment("step", "yaw", 30.5, 35.0))
    recs = build_records(trial, segs, VESSEL)
    assert len(recs) == 2
    assert recs[0].t[-1] < 19.99 and recs[1].t[0] >= 19.99 and recs[1].t[-1] == pytest.approx(35.0)
    assert len(recs[1].labels) == 2  # the step 0.5 s after the decay continues its record


def test_a_trial_without_segments_gets_nothing_added(coupled_trial):
    trial, _, fits = coupled_trial
    empty = Segments("none", ())
    base = single_dof_fits(trial, empty, VESSEL)
    ext = extend_fits(base, trial, empty, VESSEL)
    assert ext.estimates == base.estimates and np.isnan(ext.damping_matrix).all()


def test_rudder_segments_need_a_rudder_map(coupled_trial):
    trial, segs, fits = coupled_trial
    no_map = parse_vessel({k: v for k, v in COUPLED_DOC.items() if k != "rudder"})
    kept = lateral_segments(segs, no_map)
    assert "zigzag" in {s.kind for s in lateral_segments(segs, VESSEL)}
    assert "zigzag" not in {s.kind for s in kept} and kept
    only_rudder = Segments(segs.trial, tuple(s for s in segs.items if s.kind == "zigzag"))
    with pytest.raises(FitError, match="need \\[rudder\\] yaw_moment or sway_force"):
        fit_coupled_damping(trial, only_rudder, no_map)


def _small_problem(coupled_trial, jit=False, repeat=1):
    trial, segs, _ = coupled_trial
    seg = tuple(s for s in lateral_segments(segs) if s.kind == "free_decay")
    records = build_records(trial, seg, VESSEL) * repeat
    est = tuple(COEFFICIENTS)
    d_fixed = D_SEED.copy()
    for n in est:
        d_fixed[COEFFICIENTS[n]] = 0.0
    params = Vessel5DofParams(M=VESSEL.mass_matrix(), D=d_fixed, G=VESSEL.restoring_matrix())
    scale = np.array([abs(D_SEED[COEFFICIENTS[n]]) + 0.01 for n in est])
    # A small chunk so that the pass over the intervals is split.
    return _Problem(records, est, params, scale, np.full(NX, 0.1), 0.02, 1, 60, jit=jit, chunk=2)


def test_chunked_normal_equations_equal_the_whole_jacobian(coupled_trial):
    """J^T J and J^T r summed chunk by chunk equal those of the Jacobian formed whole."""
    prob = _small_problem(coupled_trial)
    rng = np.random.default_rng(6)
    z = np.concatenate([rng.uniform(0.5, 1.5, prob.k), prob.node_guess() + rng.normal(0, 0.1, prob.n_z - prob.k)])
    w = prob.weights(np.full(NX, 0.01))
    rho = np.linspace(1.0, 3.0, NX)
    jac = prob.jacobian(z, w, rho)
    r = prob.residual(z, w, rho)
    cost, g, h = prob.normal_equations(z, prob._pad_weights(w), prob._rho_nodes(rho))
    assert prob.n_nodes > prob.chunk
    assert cost == pytest.approx(0.5 * r @ r, rel=1e-12)
    assert np.allclose(g, jac.T @ r, rtol=1e-10, atol=1e-10 * np.abs(g).max())
    jtj = (jac.T @ jac).toarray()
    assert np.allclose(h.toarray(), jtj, rtol=1e-10, atol=1e-10 * np.abs(jtj).max())


def test_fisher_on_the_continuity_manifold_equals_the_dense_reduction(coupled_trial):
    """The record-by-record Schur complement equals the single-shooting Fisher information built whole."""
    prob = _small_problem(coupled_trial)
    rng = np.random.default_rng(7)
    z = np.concatenate([rng.uniform(0.5, 1.5, prob.k), prob.node_guess()])
    w = prob.weights(np.full(NX, 0.01))
    _, _, (g_blk, _, e_blk) = prob.evaluate(z, prob._pad_weights(w), gram=True)
    fisher, n_w = prob.effective_fisher(g_blk, e_blk)
    # Dense reference: nodes as functions of [theta, x0 per record] through the defect Jacobian.
    jac = prob.jacobian(z, w, 1.0).toarray()
    j_out, j_def = jac[: prob.n_sim], jac[prob.n_sim:]
    k = prob.k
    t = np.zeros((prob.n_z, n_w))
    t[:k, :k] = np.eye(k)
    row, seen = 0, set()
    for iv in prob.intervals:
        zi = slice(k + NX * iv.node, k + NX * iv.node + NX)
        if iv.record not in seen:
            seen.add(iv.record)
            t[zi, k + NX * iv.record: k + NX * iv.record + NX] = np.eye(NX)
        if not iv.last:
            blk = j_def[row: row + NX]
            t[zi.start + NX: zi.stop + NX] = blk[:, zi] @ t[zi] + blk[:, :k] @ t[:k]
            row += NX
    f_w = (j_out @ t).T @ (j_out @ t)
    a, b, c = f_w[:k, :k], f_w[:k, k:], f_w[k:, k:]
    ref = a - b @ np.linalg.pinv(c, rcond=1e-12, hermitian=True) @ b.T
    assert n_w == k + NX * len(prob.records)
    assert np.allclose(fisher, ref, rtol=1e-7, atol=1e-9 * np.abs(ref).max())


def test_jit_code_size_does_not_grow_with_the_data_and_leaves_no_folder(coupled_trial, tmp_path, monkeypatch):
    """The compiled unit is one RK4 sub-step: the same function for a short and a long record, and
    its temporary folder is gone after the compile, also when the compile fails."""
    import glob
    import os
    import tempfile

    import pipeline.fit.casadi_jit as cj

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    prob = _small_problem(coupled_trial, jit=True)
    long_prob = _small_problem(coupled_trial, jit=True, repeat=4)
    assert long_prob.n_nodes == 4 * prob.n_nodes and long_prob.compiled == prob.compiled
    assert prob.substep.n_nodes() == long_prob.substep.n_nodes()
    assert not glob.glob(str(tmp_path / "vesselid-jit-*"))
    # A source-size limit below the step's size: the virtual machine, with the reason.
    monkeypatch.setattr(cj, "MAX_SOURCE_BYTES", 10)
    cj._cached.cache_clear()
    res = cj.compile_function(prob.substep, jit=True)
    assert not res.compiled and "generated code" in res.note and "virtual machine" in res.note
    # A compiler that fails: the same.
    monkeypatch.setattr(cj, "MAX_SOURCE_BYTES", 10 ** 9)
    monkeypatch.setenv("CC", "false")
    monkeypatch.setattr(cj, "_compiler", lambda: "/bin/false")
    cj._cached.cache_clear()
    res = cj.compile_function(prob.substep, jit=True)
    assert not res.compiled and "compiler failed" in res.note
    assert not glob.glob(str(tmp_path / "vesselid-jit-*"))
    # A folder left by a killed process (its pid no longer alive) is removed; a live one is not.
    dead = tmp_path / "vesselid-jit-999999999-abc"
    live = tmp_path / f"vesselid-jit-{os.getpid()}-abc"
    dead.mkdir()
    live.mkdir()
    assert cj.remove_stale_folders(tmp_path) == 1
    assert not dead.exists() and live.exists()
    cj._cached.cache_clear()


def test_record_residual_tests_in_worker_groups_equal_one_loop():
    """The grey-box records' residual tests run as groups of records in 2 worker processes: the same
    tests and long-run variance ratios, in record order, as one loop over the records."""
    from pipeline.fit import greybox
    from pipeline.parallel import ordered_map

    rng = np.random.default_rng(11)
    outputs = ("v", "r", "phi")
    records, y_fit = [], []
    for i in range(5):
        n = 300 + 40 * i
        t = 100.0 * i + 0.1 * np.arange(n)
        tau = np.zeros((n, 5))
        tau[:, 4] = np.sign(np.sin(0.05 * np.arange(n)))
        y = rng.normal(0.0, 0.01, (n, greybox.NX)).cumsum(axis=0) * 0.1
        records.append(greybox.GreyBoxRecord(t, y, tau, (f"s{i}",)))
        y_fit.append(y + rng.normal(0.0, 0.01, y.shape))
    context = (records, y_fit, outputs)
    serial = [greybox._record_residual_tests(context, (i,))[0] for i in range(len(records))]
    grouped = ordered_map(greybox._record_residual_tests, [(0, 1), (2,), (3, 4)], context=context, jobs=2)
    flat = [r for group in grouped for r in group]
    assert len(flat) == len(serial) == 5
    for (tests_a, ratios_a), (tests_b, ratios_b) in zip(serial, flat):
        assert ratios_a == ratios_b and len(ratios_a) == len(outputs)
        assert [t.name for t in tests_a] == [t.name for t in tests_b]
        for a, b in zip(tests_a, tests_b):
            assert a.autocorrelation.tobytes() == b.autocorrelation.tobytes()
            assert (a.ljung_box_p, a.white, a.independent) == (b.ljung_box_p, b.white, b.independent)
