"""Damping structure chosen by held-out error: quadratic truth -> quadratic, linear truth -> linear,
terms within 3 standard errors, ``--model linear`` forced, coefficients.json carries every term."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from pipeline.fit.quadratic import TERM_NAMES, SteadyPoint, dof_records, fit_dof
from pipeline.fit.structure import apply_structures, select_structure
from pipeline.model.vessel5dof import simulate_dof
from pipeline.records import Estimate, Fits, Segment, Segments, Trial
from pipeline.report.coefficients_json import dumps
from pipeline.vessel import parse_vessel

M = 13.0
FS = 20.0


def surge_trial(d1: float, d2: float, seed: int, noise: float = 0.01) -> tuple[Trial, Segments]:
    """Two surge steps + coast-downs simulated with the one-DOF model, white noise on u."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / FS
    blocks, segs, t0 = [], [], 0.0
    for force in (8.0, 20.0):
        n_on, n_off = int(40 * FS), int(40 * FS)
        f = np.concatenate([np.full(n_on, force), np.zeros(n_off)]) / M
        u = simulate_dof(np.array([0.0]), f[None, :], dt, d1 / M, d2 / M)[0]
        t = t0 + np.arange(u.size) * dt
        blocks.append(pd.DataFrame({"t": t, "u": u + rng.normal(0, noise, u.size), "tau_x": f * M}))
        segs += [Segment("step", "surge", t[0], t[n_on - 1], "tau_x", 0.0, force),
                 Segment("coast_down", "surge", t[n_on], t[-1], "tau_x", force, 0.0)]
        t0 = t[-1] + dt
    data = pd.concat(blocks, ignore_index=True)
    return Trial("surge", data, FS), Segments("surge", tuple(segs))


VESSEL = parse_vessel({"name": "boat", "rigid_body": {"mass": M, "inertia": [1.0, 1.0, 1.0], "cg": [0, 0, 0]}})


def test_quadratic_truth_selects_quadratic_within_three_sigma():
    trial, segs = surge_trial(2.86, 12.7, seed=1)
    recs = dof_records(trial, segs.items, "surge")
    ch = select_structure(recs, "surge", 1 / FS, M)
    assert ch.selected == "quadratic" and ch.significant
    q = ch.fits["quadratic"].terms
    for name, truth in (("X_u", -2.86), ("X_|u|u", -12.7)):
        value, se, _ = q[name]
        assert abs(value - truth) < 3 * se, (name, value, se)
        assert abs(value - truth) < 0.05 * abs(truth)
    assert ch.heldout_rmse["quadratic"] < 0.7 * ch.heldout_rmse["linear"]
    assert "linear" in ch.fits and "X_u" in ch.fits["linear"].terms  # the loser is kept


def test_linear_truth_keeps_linear():
    trial, segs = surge_trial(2.86, 0.0, seed=2)
    ch = select_structure(dof_records(trial, segs.items, "surge"), "surge", 1 / FS, M)
    assert ch.selected == "linear" and not ch.significant
    value, se, _ = ch.fits["linear"].terms["X_u"]
    assert abs(value + 2.86) < 3 * se
    # The quadratic fit of linear truth scatters about zero.
    qv, qse, _ = ch.fits["quadratic"].terms["X_|u|u"]
    assert abs(qv) < 3 * qse


def test_forced_linear_and_unknown_model():
    trial, segs = surge_trial(2.86, 12.7, seed=3)
    recs = dof_records(trial, segs.items, "surge")
    ch = select_structure(recs, "surge", 1 / FS, M, model="linear")
    assert ch.selected == "linear" and ch.requested == "linear" and "forced" in ch.message
    from pipeline.errors import FitError
    with pytest.raises(FitError, match="expected one of"):
        select_structure(recs, "surge", 1 / FS, M, model="cubic")


def test_steady_points_join_the_transient_fit():
    trial, segs = surge_trial(2.86, 12.7, seed=4)
    recs = dof_records(trial, segs.items, "surge")
    speeds = np.array([0.5, 1.0, 1.5])
    steady = [SteadyPoint(float(u), float(2.86 * u + 12.7 * u * u), 0.01, 0.2, "table") for u in speeds]
    with_ss = fit_dof(recs, "surge", 1 / FS, M, "quadratic", steady)
    value, se, _ = with_ss.terms["X_|u|u"]
    assert abs(value + 12.7) < 3 * se


def test_fits_and_coefficients_json_carry_every_term():
    trial, segs = surge_trial(2.86, 12.7, seed=5)
    d = np.full((5, 5), np.nan)
    est = {"X_u": Estimate("X_u", -8.0, 0.1, (-8.2, -7.8), "kg/s", 2, "single-DOF")}
    fits = Fits("boat", est, (), d, d.copy())
    out = apply_structures(fits, trial, segs.items, VESSEL)
    assert out.structures["surge"].selected == "quadratic"
    assert out.estimates["X_|u|u"].success and math.isclose(out.damping_matrix[0, 0], -out.estimates["X_u"].value)
    assert fits.estimates["X_u"].value == -8.0  # input not modified
    data = json.loads(dumps(out))
    ms = data["model_structure"]["surge"]
    assert set(ms["heldout_rmse"]) == {"linear", "quadratic"}
    q = ms["models"]["quadratic"]
    assert set(q["terms"]) == set(TERM_NAMES["surge"])
    for term in q["terms"].values():
        assert {"value", "stderr", "ci95", "unit"} <= set(term)
    corr = np.array(q["correlation"]["matrix"], float)
    assert corr.shape == (2, 2) and np.allclose(np.diag(corr), 1.0)
    assert data["quadratic_damping"]["values"][0] == pytest.approx(-out.estimates["X_|u|u"].value)
    assert data["covariance"]["names"] == ["X_u", "X_|u|u"]
    pc = q["parameter_covariance"]
    assert pc["names"][:2] == ["a", "b"] and np.array(pc["matrix"], float).shape == (len(pc["names"]),) * 2
    assert np.sqrt(pc["matrix"][1][1]) == pytest.approx(q["parameters"]["b"]["stderr"])


def test_cli_model_flag_is_parsed_and_checked(capsys):
    from pipeline.cli import build_parser

    args = build_parser().parse_args(["fit", "--vessel", "v.toml", "log.csv", "--json", "o.json", "--model", "linear"])
    assert args.model == "linear"
    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args(["fit", "--vessel", "v.toml", "log.csv", "--json", "o.json", "--model", "cubic"])
    assert exc.value.code == 2 and "invalid choice" in capsys.readouterr().err


def test_drift_offset_recovers_damping_from_speed_over_ground_with_a_current():
    # Speed over ground = speed through the water + a current along the track, different per segment.
    trial, segs = surge_trial(2.86, 12.7, seed=4)
    data = trial.data.copy()
    for i, seg in enumerate(segs.items):
        inside = (data["t"] >= seg.t_start) & (data["t"] <= seg.t_end)
        data.loc[inside, "u"] += 0.15 * (-1) ** i
    recs = dof_records(Trial("surge", data, FS), segs.items, "surge")
    plain = select_structure(recs, "surge", 1 / FS, M)
    drift = select_structure(recs, "surge", 1 / FS, M, drift=True)
    value, se, _ = drift.fits["quadratic"].terms["X_|u|u"]
    assert drift.selected == "quadratic" and abs(value + 12.7) < 3 * se
    assert abs(drift.fits["quadratic"].terms["X_u"][0] + 2.86) < 3 * drift.fits["quadratic"].terms["X_u"][1]
    assert drift.heldout_rmse["quadratic"] < 0.5 * min(plain.heldout_rmse.values())
    offsets = drift.fits["quadratic"].initial_states.reshape(len(recs), 2)[:, 1]
    assert np.allclose(offsets, [0.15 * (-1) ** i for i in range(len(recs))], atol=0.02)
