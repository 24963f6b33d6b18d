"""One fit result shape (:class:`pipeline.records.FitResult`): every fitter's output converts to it,
and the report's coefficients.json is read from it."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import scipy.signal

from pipeline.autopilot.config import read_coefficients_json
from pipeline.autopilot.waves_fit import fit_wave_spectrum
from pipeline.diagnose.candidates import Fitted
from pipeline.fit.first_order import DECAY_PARAMS, decay, decay_jacobian
from pipeline.fit.least_squares import fit_least_squares
from pipeline.fit.nomoto_oe import NomotoRecord, fit_nomoto
from pipeline.fit.segment_fit import build_segment_fit
from pipeline.model.waves import WaveParams, simulate_waves
from pipeline.records import DampingFit, Estimate, FitParameter, FitResult, Fits, Segment, confidence_interval
from pipeline.report.coefficients_json import fits_to_dict, write_coefficients_json
from pipeline.report.fit_results import as_fit_result
from pipeline.report.rows import coefficient_rows


def _decay_data(seed=3):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 20.0, 0.05)
    y = decay(t, 1.2, 4.5) + 0.005 * rng.standard_normal(t.size)
    return t, y


def test_least_squares_and_segment_fit_convert_with_units_and_intervals():
    t, y = _decay_data()
    res = fit_least_squares(lambda tt, p: decay(tt, *p), lambda tt, p: decay_jacobian(tt, *p), t, y,
                            [1.0, 3.0], DECAY_PARAMS, [-np.inf, 0.1], [np.inf, 100.0])
    fr = res.to_fit_result("first_order_decay", {"T": "s", "y0": "m/s"})
    assert isinstance(fr, FitResult) and fr.names == ("y0", "T") and fr.nvarys == 2
    assert fr.value("T") == pytest.approx(res.value("T")) and abs(fr.value("T") - 4.5) < 5 * fr.stderr("T")
    assert fr.params["T"].unit == "s" and fr.ndata == t.size and fr.success
    assert fr.aic == pytest.approx(res.aic) and fr.bic == pytest.approx(res.bic)
    np.testing.assert_allclose(fr.covariance, res.covariance)
    lo, hi = fr.params["T"].ci95
    assert lo < fr.value("T") < hi and (hi - lo) / 2 == pytest.approx(1.96 * fr.stderr("T"), rel=0.01)

    seg = Segment(kind="coast_down", dof="surge", t_start=10.0, t_end=30.0, input_channel="tau_x")
    sf = build_segment_fit(seg, "first_order_decay", "u", t, y, res, key_params=("T",))
    fs = sf.to_fit_result()
    assert fs.params["y0"].unit == "m/s" and fs.params["T"].unit == "s"      # channel unit for amplitudes
    assert fs.value("T") == pytest.approx(sf.params["T"]) and fs.stderr("T") == pytest.approx(sf.stderr["T"])
    assert "coast_down surge segment 10.00-30.00 s" in fs.provenance["data"]
    assert as_fit_result(sf).params == fs.params


def test_nomoto_fit_converts_and_flags_failure_honestly():
    h, K, T = 0.1, 0.156, 20.0
    t = np.arange(0.0, 300.0, h)
    delta = np.radians(10.0) * np.sign(np.sin(2 * np.pi * t / 60.0))
    a, b = np.array([[0.0, 1.0], [0.0, -1.0 / T]]), np.array([[0.0], [K / T]])
    sysd = scipy.signal.cont2discrete((a, b, np.array([[1.0, 0.0]]), np.zeros((1, 1))), h, method="zoh")
    _, psi, _ = scipy.signal.dlsim(sysd[:4] + (h,), delta, t=t)
    psi = psi[:, 0] + np.radians(0.05) * np.random.default_rng(1).standard_normal(t.size)
    fit = fit_nomoto([NomotoRecord(t, delta, psi=psi)], noise="white", bias=False)
    fr = as_fit_result(fit)
    assert fr.model == "nomoto1_oe" and fr.success == (fit.converged and not fit.at_bound)
    assert fr.params["K"].unit == "1/s" and fr.params["T"].unit == "s" and fr.params["psi0"].unit == "rad"
    assert fr.value("T") == pytest.approx(fit.T) and fr.stderr("K") == pytest.approx(fit.error("K"))
    assert abs(fr.value("T") - T) < 5 * fr.stderr("T")
    assert fr.aic == pytest.approx(fit.aic) and fr.covariance.shape == (len(fit.names),) * 2


def test_wave_fit_and_diagnosis_candidate_convert():
    fs_hz = 10.0
    t = np.arange(0.0, 1200.0, 1 / fs_hz)
    truth = WaveParams(omega0=0.8, lam=0.1, kw=0.01)
    wf = fit_wave_spectrum(simulate_waves(t, truth, np.random.default_rng(5)), fs_hz)
    fr = as_fit_result(wf)
    # The wave-spectrum fitter returns the one shape itself (a FitResult with its Welch PSD): no conversion.
    assert fr is wf and isinstance(fr, FitResult)
    assert fr.names == ("omega0", "lam", "kw") and fr.params["omega0"].unit == "rad/s"
    assert abs(fr.value("omega0") - truth.omega0) < 3 * fr.stderr("omega0") and fr.stderr("kw") > 0
    assert fr.success and fr.statistics["sigma"] == pytest.approx(
        fr.value("kw") / (2 * fr.value("lam") * fr.value("omega0")))

    cand = as_fit_result(Fitted(params={"T": 3.0, "k_tau_x": 0.2, "tau": 0.4}, effect_params=("tau",), sse=1.5))
    # The diagnosis keeps values only: the converted result must not invent error bars.
    assert cand.params["T"].unit == "s" and all(math.isnan(p.stderr) for p in cand.params.values())
    assert "held-out" in cand.message and np.isnan(cand.covariance).all()


def _fits() -> Fits:
    D = np.full((5, 5), np.nan)
    D[0, 0] = 2.86
    ok = Estimate("X_u", -2.86, 0.02, confidence_interval(-2.86, 0.02, 40), "kg/s", 3, "first-order decay fits")
    bad = Estimate("T_nomoto", 5000.0, 3000.0, (math.nan, math.nan), "s", 1, "nomoto", success=False,
                   message="T beyond 100 record lengths")
    K = Estimate("K_nomoto", 0.3, 0.01, confidence_interval(0.3, 0.01, math.inf), "1/s", 2, "nomoto")
    return Fits(vessel="test", estimates={"X_u": ok, "T_nomoto": bad, "K_nomoto": K}, segment_fits=(),
                damping_matrix=D, damping_stderr=np.full((5, 5), np.nan))


def test_fits_convert_and_the_report_reads_that_shape(tmp_path):
    fits = _fits()
    fr = fits.to_fit_result()
    assert not fr.success and "T_nomoto" in fr.message          # one failed coefficient fails the set
    assert fr.covariance[0, 0] == pytest.approx(0.02 ** 2) and math.isnan(fr.covariance[0, 1])
    doc = fits_to_dict(fits)
    for name, par in fr.params.items():
        entry = doc["coefficients"][name]
        assert entry["unit"] == par.unit and entry["n_segments"] == par.n_segments
        if par.success:
            assert entry["value"] == pytest.approx(par.value) and entry["stderr"] == pytest.approx(par.stderr)
            assert entry["ci95"] == pytest.approx(list(par.ci95))
        else:
            assert entry["value"] is None and "5000" in entry["message"]   # rejected value only in the text
    rows = {r.name: r for r in coefficient_rows(fits)}
    assert rows["X_u"].identified and not rows["T_nomoto"].identified
    # The autopilot reads coefficients.json back; its record converts to the same shape.
    path = write_coefficients_json(_fits_with_T(fits), tmp_path / "coefficients.json")
    back = as_fit_result(read_coefficients_json(path))
    assert back.value("K") == pytest.approx(0.3) and back.stderr("T") == pytest.approx(0.5)
    assert back.params["K"].unit == "1/s" and json.loads(path.read_text())["vessel"] == "test"


def _fits_with_T(fits: Fits) -> Fits:
    est = dict(fits.estimates)
    est["T_nomoto"] = Estimate("T_nomoto", 8.0, 0.5, confidence_interval(8.0, 0.5, math.inf), "s", 2, "nomoto")
    return Fits(vessel=fits.vessel, estimates=est, segment_fits=(), damping_matrix=fits.damping_matrix,
                damping_stderr=fits.damping_stderr)


def test_bad_shapes_are_refused_with_what_was_expected():
    with pytest.raises(ValueError, match=r"covariance expected shape \(1, 1\)"):
        FitResult("m", {"a": FitParameter("a", 1.0)}, np.zeros((2, 2)))
    with pytest.raises(ValueError, match="stored under 'a' is named 'b'"):
        FitResult("m", {"a": FitParameter("b", 1.0)}, np.zeros((1, 1)))
    with pytest.raises(TypeError, match="expected one of .*NomotoFit.*found str"):
        as_fit_result("not a fit")


def test_damping_fit_converts_terms_and_shared_parameters():
    cov = np.array([[4e-4, 1e-5], [1e-5, 9e-4]])
    fit = DampingFit(dof="surge", structure="quadratic", names=("a", "b"), values=np.array([0.22, 0.9]),
                     stderr=np.array([0.01, 0.02]), covariance=np.diag([1e-4, 4e-4]),
                     terms={"X_u": (-2.86, 0.02, "kg/s"), "X_|u|u": (-11.7, 0.03, "kg/m")}, term_covariance=cov,
                     rmse=1.02, lag1=0.1, n=400, dof_resid=396, inertia=13.0)
    terms = fit.to_fit_result()
    assert terms.names == ("X_u", "X_|u|u") and terms.params["X_|u|u"].unit == "kg/m"
    np.testing.assert_allclose(terms.covariance, cov)
    assert terms.params["X_u"].ci95 == pytest.approx(confidence_interval(-2.86, 0.02, 396))
    shared = fit.shared_fit_result()
    assert shared.names == ("a", "b") and shared.stderr("b") == pytest.approx(0.02)
    assert shared.statistics["inertia"] == 13.0 and shared.ndata == 400
    # Without a mass there are no Fossen terms: the shared parameters stand in.
    bare = DampingFit(dof="surge", structure="linear", names=("a",), values=np.array([0.2]), stderr=np.array([0.01]),
                      covariance=np.array([[1e-4]]), terms={}, term_covariance=np.zeros((0, 0)), rmse=1.0, lag1=0.0,
                      n=100, dof_resid=99)
    assert bare.to_fit_result().names == ("a",)


def test_autopilot_config_gives_the_coefficients_its_design_used():
    from pipeline.autopilot.config import build_autopilot_config

    waves = WaveParams(omega0=0.8, lam=0.1, kw=0.02)
    cfg = build_autopilot_config(0.3, 8.0, K_stderr=0.01, T_stderr=0.4, waves=waves,
                                 waves_stderr={"omega0": 0.05, "lambda": 0.02}, wave_source="test")
    fr = as_fit_result(cfg)
    assert fr.names == ("K", "T", "omega0", "lam", "kw")
    assert (fr.value("K"), fr.stderr("K"), fr.params["K"].unit) == (0.3, 0.01, "1/s")
    assert (fr.value("T"), fr.stderr("T"), fr.params["T"].unit) == (8.0, 0.4, "s")
    assert fr.stderr("lam") == 0.02 and fr.value("omega0") == 0.8
    assert math.isnan(fr.stderr("kw"))   # not in waves_stderr: no error bar, not a made-up one
    assert np.isnan(fr.covariance).all()  # K, T and the waves come from different fits


def test_extinction_carries_the_derived_damping_with_its_errors():
    from pipeline.records import Extinction

    cov = np.array([[4e-4, -1e-4], [-1e-4, 9e-4]])
    ext = Extinction("combined", np.linspace(0.2, 0.05, 6), np.linspace(0.04, 0.01, 6), 0.12, 0.3, cov, 0.14, 0.01,
                     2.1, 0.02, 55.0, 4.0, 80.0, 9.0, 70.0, 5.0, 0.1, 12.0, 0.3, 2)
    fr = as_fit_result(ext)
    assert fr.names == ("a", "b", "a_linear", "wn", "B1", "B2", "B_eq", "inertia_fit")
    assert fr.stderr("b") == pytest.approx(0.03) and np.array_equal(fr.covariance[:2, :2], cov)
    assert (fr.value("B_eq"), fr.stderr("B_eq"), fr.params["B_eq"].unit) == (70.0, 5.0, "kg m^2/s")
    assert fr.params["wn"].unit == "rad/s" and fr.statistics["amplitude"] == 0.1
    assert np.isnan(fr.covariance[2:, :]).all()   # derived quantities: errors only, no covariance claimed
