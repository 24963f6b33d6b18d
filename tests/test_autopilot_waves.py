"""Wave-spectrum fit: recovery of simulated parameters, PSD convention, the course record, readers."""

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from pipeline.autopilot.cli import add_waves_parser, cmd_waves
from pipeline.autopilot.waves_fit import (COURSE_SCALE, course_kw, fit_wave_record, fit_wave_spectrum,
                                          read_heading_record, wave_params, welch_psd)
from pipeline.records import FitResult
from pipeline.errors import AutopilotError
from pipeline.model.waves import WaveParams, simulate_waves, wave_psd

TRUE = WaveParams(omega0=0.78, lam=0.09, kw=0.0096)
FS = 10.0
BOATLAB = Path(__file__).resolve().parents[1].parent / "shared" / "realdata" / "ttk4115-boatlab"


def _record(seed, duration=4000.0, params=TRUE):
    t = np.arange(0.0, duration, 1.0 / FS)
    return t, simulate_waves(t, params, np.random.default_rng(seed))


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_fit_recovers_simulated_parameters_within_standard_errors(seed):
    _, y = _record(seed)
    fit = fit_wave_spectrum(y, FS)
    assert fit.success, fit.message
    # The fitter returns the one fit-result shape: parameters with value, stderr and unit, covariance.
    assert isinstance(fit, FitResult) and fit.names == ("omega0", "lam", "kw")
    assert [p.unit for p in fit.params.values()] == ["rad/s", "", "rad s^-1/2"]
    assert np.allclose(np.sqrt(np.diag(fit.covariance)), [fit.stderr(n) for n in fit.names])
    for name, true, tol in (("omega0", TRUE.omega0, 0.03), ("lam", TRUE.lam, 0.3), ("kw", TRUE.kw, 0.2)):
        est, se = fit.value(name), fit.stderr(name)
        assert 0 < se < tol * true
        assert abs(est - true) < 3 * se, (est, true, se)
        assert abs(est - true) < tol * true
    sigma_true = TRUE.kw / (2 * TRUE.lam * TRUE.omega0)
    st = fit.statistics
    assert abs(st["sigma"] - sigma_true) < 3 * st["sigma_se"]
    # sigma^2 is the model's PSD peak, at omega0 exactly
    assert wave_psd(np.array([fit.value("omega0")]), wave_params(fit))[0] == pytest.approx(st["sigma"]**2, rel=1e-12)
    # a correctly specified model scatters as the Welch estimate predicts
    assert st["rel_residual_std"] < 2 * st["expected_rel_std"]


def test_psd_convention_matches_the_simulator_variance():
    _, y = _record(5, duration=8000.0)
    omega, p = welch_psd(y, FS)
    # two-sided per rad/s: var = (1/2pi) * 2 * int_0^inf P d omega
    var_psd = np.trapezoid(p, omega) / math.pi
    var_model = TRUE.kw**2 / (4 * TRUE.lam * TRUE.omega0)  # unit-intensity w_w through H(s)
    assert np.var(y) == pytest.approx(var_model, rel=0.1)
    assert var_psd == pytest.approx(np.var(y), rel=0.02)
    fit = fit_wave_spectrum(y, FS)
    assert course_kw(fit) == pytest.approx(fit.value("kw") * COURSE_SCALE)


def test_standard_errors_are_calibrated_over_seeds():
    z = []
    for seed in range(20, 32):
        _, y = _record(seed, duration=3000.0)
        f = fit_wave_spectrum(y, FS)
        z.append([(f.value(n) - getattr(TRUE, n)) / f.stderr(n) for n in ("omega0", "lam", "kw")])
    z = np.array(z)
    # 36 z-scores: their RMS should be near one (not two, as a fit that ignored the Welch bins'
    # correlation would give, nor a half)
    rms = float(np.sqrt(np.mean(z**2)))
    assert 0.6 < rms < 1.5, rms
    assert np.all(np.abs(z) < 4)


def test_guess_band_and_explicit_band():
    _, y = _record(1)
    f = fit_wave_spectrum(y, FS, band=(0.4, 1.6))
    assert f.band == (0.4, 1.6)
    assert abs(f.value("omega0") - TRUE.omega0) < 3 * f.stderr("omega0")
    with pytest.raises(AutopilotError, match="at least 8 Welch bins"):
        fit_wave_spectrum(y, FS, band=(0.78, 0.79))
    with pytest.raises(AutopilotError, match="low < high"):
        fit_wave_spectrum(y, FS, band=(1.0, 0.5))


@pytest.mark.realdata
def test_course_wave_record():
    path = BOATLAB / "wave.mat"
    if not path.is_file():
        pytest.skip("../shared/realdata/ttk4115-boatlab/wave.mat not present")
    fit = fit_wave_record(read_heading_record(path))
    # SOURCE.md and the seed: Welch peak at omega0 = 0.7823 rad/s, sqrt(peak) = 0.0385 in the course convention
    assert fit.peak_omega == pytest.approx(0.7823, abs=1e-3)
    assert math.sqrt(fit.peak_psd) * COURSE_SCALE == pytest.approx(0.0385, abs=5e-4)
    assert fit.success
    assert 0.76 < fit.value("omega0") < 0.80 and fit.stderr("omega0") < 0.02
    assert abs(fit.value("lam") - 0.09) < 2 * fit.stderr("lam")  # the seed's choice from a grid of four values
    assert course_kw(fit) == pytest.approx(0.0054, abs=3 * fit.stderr("kw") * COURSE_SCALE)
    assert "irregular" in fit.message and "degrees" in fit.message
    csv = BOATLAB / "wave_psi_w.csv"
    if csv.is_file():
        fit_csv = fit_wave_record(read_heading_record(csv))
        assert fit_csv.value("omega0") == pytest.approx(fit.value("omega0"), rel=1e-6)


def _args(**kw):
    ns = dict(column=None, unit=None, nperseg=None, band=None, plot=None)
    ns.update(kw)
    return argparse.Namespace(**ns)


def test_cmd_waves_csv_round_trip(tmp_path, capsys):
    t, y = _record(2)
    log = tmp_path / "heading.csv"
    np.savetxt(log, np.column_stack([t, np.degrees(y)]), delimiter=",", header="t,psi_w_deg", comments="")
    out = tmp_path / "waves.json"
    png = tmp_path / "waves.png"
    assert cmd_waves(_args(log=str(log), json=str(out), plot=str(png))) == 0
    doc = json.loads(out.read_text())
    for key in ("omega0", "lambda", "kw", "sigma"):
        assert set(doc[key]) >= {"value", "stderr", "unit"}
        assert doc[key]["stderr"] > 0
    assert abs(doc["omega0"]["value"] - TRUE.omega0) < 3 * doc["omega0"]["stderr"]
    assert len(doc["source"]["sha256"]) == 64
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert "omega0 =" in capsys.readouterr().out


def test_cmd_waves_mat_like_the_course_file(tmp_path):
    t, y = _record(3)
    mat = tmp_path / "wave.mat"
    scipy.io.savemat(mat, {"psi_w": np.vstack([t, np.degrees(y)])})
    out = tmp_path / "w.json"
    cmd_waves(_args(log=str(mat), json=str(out)))
    doc = json.loads(out.read_text())
    assert abs(doc["lambda"]["value"] - TRUE.lam) < 3 * doc["lambda"]["stderr"]


def test_parser_help_and_options():
    ap = argparse.ArgumentParser(prog="vesselid")
    sub = ap.add_subparsers()
    add_waves_parser(sub)
    a = ap.parse_args(["waves", "x.csv", "--json", "o.json", "--band", "0.3", "2", "--unit", "deg"])
    assert a.func is cmd_waves and a.band == [0.3, 2.0] and a.unit == "deg"
    with pytest.raises(SystemExit) as e:
        ap.parse_args(["waves", "--help"])
    assert e.value.code == 0


# --------------------------------------------------------------------------- bad input
def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_bad_records(tmp_path):
    with pytest.raises(AutopilotError, match="no such file"):
        read_heading_record(tmp_path / "missing.csv")
    with pytest.raises(AutopilotError, match="empty file"):
        read_heading_record(_write(tmp_path, "empty.csv", ""))
    with pytest.raises(AutopilotError, match="time column"):
        read_heading_record(_write(tmp_path, "notime.csv", "x,psi_w\n1,2\n"))
    with pytest.raises(AutopilotError, match="heading column"):
        read_heading_record(_write(tmp_path, "nocol.csv", "t,r\n0,1\n"))
    with pytest.raises(AutopilotError, match="data rows"):
        read_heading_record(_write(tmp_path, "header.csv", "t,psi_w\n"))
    with pytest.raises(AutopilotError, match="on data row 2"):
        read_heading_record(_write(tmp_path, "text.csv", "t,psi_w\n0,1\n0.1,abc\n"))
    with pytest.raises(AutopilotError, match="at least 512 samples"):
        read_heading_record(_write(tmp_path, "short.csv", "t,psi_w\n" + "".join(f"{k/10},0.1\n" for k in range(50))))
    rows = "".join(f"{k / 10},{math.sin(k / 10)}\n" for k in range(600))
    rows = rows.replace("30.0,", "29.0,", 1)  # one time stamp goes backwards
    with pytest.raises(AutopilotError, match="strictly increasing"):
        read_heading_record(_write(tmp_path, "back.csv", "t,psi_w\n" + rows))
    with pytest.raises(AutopilotError, match="NaN"):
        read_heading_record(_write(tmp_path, "nan.csv", "t,psi_w\n" + "".join(f"{k/10},nan\n" for k in range(600))))
    with pytest.raises(AutopilotError, match=r"\.csv or \.mat"):
        read_heading_record(_write(tmp_path, "x.bin", "abc"))
    with pytest.raises(AutopilotError, match="unit"):
        read_heading_record(_write(tmp_path, "u.csv", "t,psi_w\n0,0\n"), unit="grad")


def test_bad_mat_files(tmp_path):
    mat = tmp_path / "w.mat"
    scipy.io.savemat(mat, {"heading": np.zeros((2, 1000))})
    with pytest.raises(AutopilotError, match=r"expected variable 'psi_w', found \['heading'\]"):
        read_heading_record(mat)
    scipy.io.savemat(mat, {"psi_w": np.zeros((3, 3))})
    with pytest.raises(AutopilotError, match="2 x N"):
        read_heading_record(mat)
    bad = _write(tmp_path, "bad.mat", "not a mat file")
    with pytest.raises(AutopilotError, match="readable .mat"):
        read_heading_record(bad)


def test_bad_series():
    with pytest.raises(AutopilotError, match="constant"):
        fit_wave_spectrum(np.zeros(5000), FS)
    with pytest.raises(AutopilotError, match="sample rate"):
        fit_wave_spectrum(np.ones(5000), 0.0)
    with pytest.raises(AutopilotError, match="at least 512"):
        fit_wave_spectrum(np.ones(100), FS)


def test_white_noise_is_not_a_wave_record(tmp_path):
    rng = np.random.default_rng(0)
    fit = fit_wave_spectrum(rng.standard_normal(20000), FS)
    assert not fit.success or fit.message  # no resonance: flagged, never silently accepted
    t = np.arange(20000) / FS
    log = tmp_path / "noise.csv"
    np.savetxt(log, np.column_stack([t, rng.standard_normal(20000)]), delimiter=",", header="t,psi_w", comments="")
    if not fit.success:
        with pytest.raises(AutopilotError, match="resonant wave spectrum"):
            cmd_waves(_args(log=str(log), json=str(tmp_path / "o.json")))


def test_a_wave_fit_carries_into_the_design_and_its_report_section(tmp_path):
    from pipeline.autopilot.design import build_autopilot
    from pipeline.autopilot.outputs import write_autopilot_outputs_and_section
    from pipeline.records import NomotoCoefficients

    _, y = _record(3, duration=3000.0)
    fit = fit_wave_spectrum(y, FS)
    res = build_autopilot(NomotoCoefficients(K=0.3, K_stderr=0.01, T=8.0, T_stderr=0.4), waves=fit,
                          wave_source="simulated record", check=False)
    cfg = res.config
    assert res.wave_fit is fit and cfg.waves == wave_params(fit)
    assert cfg.waves_stderr == {"omega0": fit.stderr("omega0"), "lambda": fit.stderr("lam"), "kw": fit.stderr("kw")}
    # The design's coefficients carry the fit's errors on to the report's one shape.
    used = cfg.to_fit_result()
    assert used.stderr("kw") == fit.stderr("kw") and used.value("omega0") == fit.value("omega0")
    _, (_, section) = write_autopilot_outputs_and_section(res, tmp_path)
    assert (tmp_path / "wave_fit.png").stat().st_size > 1000
    assert f"{fit.value('omega0'):.4f}" in section and f"{course_kw(fit):.4g}" in section
