"""Tests of the report stage: the coefficients.json contract, tables, figures, HTML and atomic writes.

Inputs are built by hand with AAUSHIP-like numbers (13 kg hull; Fossen signs, D positive) and
seeded noise, and every file is written into ``tmp_path``.
"""

from __future__ import annotations

import copy
import html as html_lib
import json
import math
import re

import numpy as np
import pandas as pd
import pytest

from pipeline.errors import OutputError, ReportError
from pipeline.records import Estimate, Fits, Gap, Segment, SegmentFit, Segments, Trial
from pipeline.report import (ReportPaths, damping_from_dict, fits_to_dict, load_coefficients,
                             write_report)
from pipeline import atomic as atomic_mod
from pipeline.report import coefficients_json, figures, html as html_mod, quality, summary, tables
from pipeline.report.rows import STANDARD_COEFFICIENTS, format_uncertain
from pipeline.atomic import TEMP_PREFIX, atomic_write_text
from pipeline.report.coefficients_json import COEFFICIENT_KEYS
from pipeline.report.tables import latex_escape

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
MASS = 13.0  # kg, AAUSHIP


def _reject_constant(token):
    raise AssertionError(f"non-strict JSON token {token}")


def _est(name, value, stderr, unit, n=3, method="weighted mean of first-order decay fits", **kw):
    ci = (value - 1.96 * stderr, value + 1.96 * stderr)
    return Estimate(name=name, value=value, stderr=stderr, ci95=ci, unit=unit, n_segments=n,
                    method=method, **kw)


def _coast_down_fit(rng) -> SegmentFit:
    """Surge coast-down u = u0 exp(-t/tau), tau = m / d_u (first-order decay, AAUSHIP method one)."""
    seg = Segment(kind="coast_down", dof="surge", t_start=12.0, t_end=32.0, input_channel="tau_x",
                  input_before=4.3, input_after=0.0, quality=0.92, origin="detected")
    t = np.arange(0.0, 20.0, 0.1)
    u0, tau = 1.5, MASS / 2.86
    y_fit = u0 * np.exp(-t / tau)
    y = y_fit + rng.normal(0.0, 0.02, t.size)
    return SegmentFit(segment=seg, model="first_order_decay", channel="u", param_names=("u0", "tau"),
                      params={"u0": u0, "tau": tau}, stderr={"u0": 0.006, "tau": 0.048},
                      covariance=np.diag([0.006, 0.048]) ** 2, t=t, y=y, y_fit=y_fit, rmse=0.02,
                      aic=-1560.0, bic=-1553.4, success=True)


def _roll_decay_fit(rng) -> SegmentFit:
    """Roll free decay phi = A exp(-zeta w t) cos(w_d t) [rad] (AAUSHIP method two)."""
    seg = Segment(kind="free_decay", dof="roll", t_start=60.0, t_end=70.0, quality=0.8, origin="manifest",
                  label="roll release <basin>")
    t = np.arange(0.0, 10.0, 0.02)
    A, zeta, w = 0.2, 0.08, 3.0
    wd = w * math.sqrt(1 - zeta ** 2)
    y_fit = A * np.exp(-zeta * w * t) * np.cos(wd * t)
    y = y_fit + rng.normal(0.0, 0.004, t.size)
    return SegmentFit(segment=seg, model="damped_oscillation", channel="phi",
                      param_names=("A", "zeta", "omega_n"), params={"A": A, "zeta": zeta, "omega_n": w},
                      stderr={"A": 0.002, "zeta": 0.0031, "omega_n": 0.004}, covariance=np.eye(3) * 1e-5,
                      t=t, y=y, y_fit=y_fit, rmse=0.004, aic=-5500.0, bic=-5487.0, success=True)


def _failed_fit() -> SegmentFit:
    seg = Segment(kind="rudder_step", dof="yaw", t_start=90.0, t_end=96.0, input_channel="delta",
                  input_before=0.0, input_after=0.17, quality=0.3)
    t = np.arange(0.0, 6.0, 0.1)
    y = 0.05 * (1 - np.exp(-t / 2.0))
    return SegmentFit(segment=seg, model="first_order_step", channel="r", param_names=("K", "T"),
                      params={"K": math.nan, "T": math.nan}, stderr={"K": math.nan, "T": math.nan},
                      covariance=np.full((2, 2), np.nan), t=t, y=y, y_fit=np.full_like(t, np.nan),
                      rmse=math.nan, aic=math.nan, bic=math.nan, success=False,
                      message="did not converge in 200 iterations: segment shorter than 3 T")


@pytest.fixture
def fits() -> Fits:
    rng = np.random.default_rng(20240611)
    est = {
        "X_u": _est("X_u", -2.86, 0.03, "kg/s"),
        "Y_v": _est("Y_v", -32.8, 1.1, "kg/s", n=2),
        "Y_r": Estimate(name="Y_r", value=math.nan, stderr=math.nan, ci95=(math.nan, math.nan),
                        unit="kg m/s", n_segments=0, method="", success=False,
                        message="no segment excites sway and yaw together <coupled>"),
        "K_p": _est("K_p", -0.31, 0.04, "kg m^2/s", n=1, method="damped oscillation"),
        "M_q": _est("M_q", -1.2, 0.2, "kg m^2/s", n=1, method="damped oscillation"),
        "N_v": Estimate(name="N_v", value=0.75, stderr=math.nan, ci95=(math.nan, math.nan), unit="kg m/s",
                        n_segments=1, method="least squares", message="covariance singular: one segment only"),
        "N_r": _est("N_r", -0.49, 0.02, "kg m^2/s", consistency_p=0.003, per_segment=(-0.45, -0.52, -0.50)),
        "K_nomoto": _est("K_nomoto", 0.42, 0.02, "1/s", n=4, method="first-order step, weighted mean"),
        "T_nomoto": _est("T_nomoto", 2.1, 0.2, "s", n=4, method="first-order step, weighted mean"),
    }
    D = np.full((5, 5), np.nan)
    D_se = np.full((5, 5), np.nan)
    for k, (d, se) in enumerate([(2.86, 0.03), (32.8, 1.1), (0.31, 0.04), (1.2, 0.2), (0.49, 0.02)]):
        D[k, k], D_se[k, k] = d, se
    D[4, 1] = -0.75  # -N_v
    return Fits(vessel="aauship", estimates=est,
                segment_fits=(_coast_down_fit(rng), _roll_decay_fit(rng), _failed_fit()),
                damping_matrix=D, damping_stderr=D_se)


@pytest.fixture
def trial(fits) -> Trial:
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 110.0, 0.1)
    u = np.where(t < 12, 1.5, 1.5 * np.exp(-(t - 12) / 4.55))
    phi = np.where((t >= 60) & (t < 70), 0.2 * np.exp(-0.24 * (t - 60)) * np.cos(3 * (t - 60)), 0.0)
    delta = np.where(t >= 90, 0.17, 0.0)
    data = pd.DataFrame({"t": t, "u": u + rng.normal(0, 0.01, t.size), "v": rng.normal(0, 0.01, t.size),
                         "r": 0.07 * (1 - np.exp(-np.clip(t - 90, 0, None) / 2.1)), "phi": phi,
                         "theta": rng.normal(0, 0.002, t.size), "delta": delta,
                         "tau_x": np.where(t < 12, 4.3, 0.0)})
    data.loc[(t > 40) & (t < 42), "u"] = np.nan
    return Trial(name="aauship sea trial 1", data=data, fs=10.0, gaps=(Gap("u", 40.0, 42.0),),
                 sources=("trials/sample/aauship.csv",), notes=("v derived from GPS course",))


# --------------------------------------------------------------------------- JSON contract
def test_json_is_strict_and_follows_the_contract(fits, tmp_path):
    paths = write_report(fits, tmp_path / "out")
    text = paths.coefficients_json.read_text()
    assert "NaN" not in text and "Infinity" not in text
    data = json.loads(text, parse_constant=_reject_constant)

    assert list(data) == ["vessel", "convention", "damping_matrix", "coefficients"]
    assert data["vessel"] == "aauship"
    assert data["convention"] == fits.convention
    dm = data["damping_matrix"]
    assert list(dm) == ["dofs", "values", "stderr"]
    assert dm["dofs"] == ["u", "v", "p", "q", "r"]
    assert len(dm["values"]) == 5 and all(len(r) == 5 for r in dm["values"])
    assert dm["values"][0][0] == pytest.approx(2.86)  # D positive diagonal
    assert dm["values"][4][1] == pytest.approx(-0.75)
    assert dm["values"][1][4] is None and dm["stderr"][1][4] is None
    assert dm["stderr"][0][0] == pytest.approx(0.03)

    coefs = data["coefficients"]
    assert list(coefs)[:13] == ["X_u", "Y_v", "Y_p", "Y_r", "K_v", "K_p", "K_r", "M_q", "N_v", "N_p", "N_r",
                                "K_nomoto", "T_nomoto"]
    for name, entry in coefs.items():
        assert list(entry) == list(COEFFICIENT_KEYS), name
        assert len(entry["ci95"]) == 2
    x_u = coefs["X_u"]
    assert x_u["value"] == pytest.approx(-2.86) and x_u["stderr"] == pytest.approx(0.03)
    assert x_u["ci95"] == pytest.approx([-2.86 - 1.96 * 0.03, -2.86 + 1.96 * 0.03])
    assert (x_u["unit"], x_u["n_segments"], x_u["success"], x_u["consistency_p"]) == ("kg/s", 3, True, None)
    y_r = coefs["Y_r"]
    assert y_r["value"] is None and y_r["stderr"] is None and y_r["ci95"] == [None, None]
    assert y_r["success"] is False and "sway and yaw" in y_r["message"]
    # Coefficients the fit stage did not return are still listed, as not identified, with a reason.
    assert coefs["K_v"]["value"] is None and coefs["K_v"]["success"] is False
    assert coefs["K_v"]["message"] and coefs["K_v"]["unit"] == "kg m/s"
    assert coefs["N_v"]["value"] == pytest.approx(0.75) and coefs["N_v"]["stderr"] is None
    assert coefs["N_r"]["consistency_p"] == pytest.approx(0.003)
    assert coefs["K_nomoto"]["unit"] == "1/s" and coefs["T_nomoto"]["value"] == pytest.approx(2.1)


def test_rejected_value_never_reaches_the_value_field(fits):
    est = dict(fits.estimates)
    est["M_q"] = _est("M_q", -1.9, 0.4, "kg m^2/s", success=False, message="decay too short")
    d = fits_to_dict(Fits(fits.vessel, est, (), fits.damping_matrix, fits.damping_stderr))
    assert d["coefficients"]["M_q"]["value"] is None
    assert "decay too short" in d["coefficients"]["M_q"]["message"]
    assert "-1.9" in d["coefficients"]["M_q"]["message"]


def test_load_coefficients_round_trip(fits, tmp_path):
    paths = write_report(fits, tmp_path)
    data = load_coefficients(paths.coefficients_json)
    assert data == fits_to_dict(fits)
    D, D_se = damping_from_dict(data)
    np.testing.assert_array_equal(D, fits.damping_matrix)
    np.testing.assert_array_equal(D_se, fits.damping_stderr)


def _good(fits):
    return fits_to_dict(fits)


@pytest.mark.parametrize("mutate, expected", [
    (lambda d: d.pop("coefficients"), "missing key 'coefficients'"),
    (lambda d: d["damping_matrix"].update(dofs=["u", "v", "r"]), "damping_matrix.dofs: expected"),
    (lambda d: d["damping_matrix"]["values"].pop(), "damping_matrix.values: expected a list of 5 rows"),
    (lambda d: d["damping_matrix"]["stderr"][2].__setitem__(3, "0.1"),
     "damping_matrix.stderr[2][3]: expected a number or null, found str"),
    (lambda d: d["coefficients"].pop("T_nomoto"), "missing ['T_nomoto']"),
    (lambda d: d["coefficients"]["X_u"].pop("stderr"), "coefficients.X_u: missing keys ['stderr']"),
    (lambda d: d["coefficients"]["X_u"].update(value="-2.86"), "coefficients.X_u.value: expected a number"),
    (lambda d: d["coefficients"]["Y_v"].update(ci95=[1.0]), "coefficients.Y_v.ci95: expected [lo, hi]"),
    (lambda d: d["coefficients"]["N_r"].update(success="yes"), "coefficients.N_r.success: expected true"),
    (lambda d: d.update(vessel=None), "vessel: expected a string, found null"),
])
def test_load_coefficients_rejects_malformed_structure(fits, tmp_path, mutate, expected):
    data = _good(fits)
    mutate(data)
    path = tmp_path / "coefficients.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ReportError, match=re.escape(expected)):
        load_coefficients(path)


@pytest.mark.parametrize("text, expected", [
    ('{"vessel": NaN}', "NaN is not valid JSON; expected null"),
    ('{"vessel": "a",', "not valid JSON at line 1"),
    ("", "empty file"),
    ("[1, 2]", "expected a JSON object at top level, found list"),
])
def test_load_coefficients_rejects_bad_json(tmp_path, text, expected):
    path = tmp_path / "c.json"
    path.write_text(text)
    with pytest.raises(ReportError, match=re.escape(expected)):
        load_coefficients(path)


def test_load_coefficients_missing_file(tmp_path):
    with pytest.raises(ReportError, match="no such file"):
        load_coefficients(tmp_path / "nope.json")


# --------------------------------------------------------------------------- tables
def test_latex_tables(fits, tmp_path):
    tex = write_report(fits, tmp_path).coefficients_tex.read_text()
    for cmd in (r"\toprule", r"\midrule", r"\bottomrule", r"\label{tab:derivatives}",
                r"\label{tab:time-constants}", r"\label{tab:damping}"):
        assert cmd in tex
    caption = re.search(r"\\caption\{Identified.*\}\n\\label\{tab:derivatives\}", tex)
    assert caption and latex_escape(fits.convention) in caption.group(0)
    assert "SI units" in caption.group(0)
    for sym in ("$X_{u}$", "$Y_{v}$", "$Y_{p}$", "$Y_{r}$", "$K_{v}$", "$K_{p}$", "$K_{r}$", "$M_{q}$",
                "$N_{v}$", "$N_{p}$", "$N_{r}$", "$K$ (Nomoto)", "$T$ (Nomoto)"):
        assert sym + " &" in tex, sym
    assert r"$-2.860 \pm 0.030$" in tex  # value to the precision of a 2-digit stderr
    assert r"$-32.8 \pm 1.1$" in tex
    assert r"$[-2.919, -2.801]$" in tex
    assert r"kg\,m$^{2}$/s" in tex
    y_r = next(line for line in tex.splitlines() if line.startswith("$Y_{r}$"))
    assert "not identified" in y_r and r"\textsuperscript" in y_r
    # The reason is printed (escaped), and so is why N_v has no error bar.
    assert r"no segment excites sway and yaw together \textless{}coupled\textgreater{}" in tex
    assert "standard error not available: covariance singular" in tex
    assert "chi-square p = 0.003" in tex
    # Derivatives in one table, time constants and gains in the other.
    deriv = tex[:tex.index(r"\label{tab:derivatives}")]
    assert "$X_{u}$ &" in deriv and "(Nomoto)" not in deriv
    assert "$K$ (Nomoto)" in tex[tex.index(r"\label{tab:derivatives}"):tex.index(r"\label{tab:time-constants}")]
    damping = tex[tex.index(r"\label{tab:time-constants}"):]
    assert r"$u$ & $2.860 \pm 0.030$ & -- & -- & -- & --" in damping
    assert r"$r$ & -- & $-0.7500$ & --" in damping
    assert tex.count(r"\begin{table}") == tex.count(r"\end{table}") == 3
    # Balanced braces outside escaped ones: a LaTeX compile would otherwise fail.
    stripped = tex.replace(r"\{", "").replace(r"\}", "")
    assert stripped.count("{") == stripped.count("}")


def test_markdown_tables(fits, tmp_path):
    md = write_report(fits, tmp_path).coefficients_md.read_text()
    assert "| Coefficient | Value ± std. error | 95 % CI | Unit | Segments | Method |" in md
    assert "|---|---:|---|---|---:|---|" in md
    assert "| `X_u` | -2.860 ± 0.030 | [-2.919, -2.801] | kg/s | 3 |" in md
    assert re.search(r"\| `Y_r` \| not identified \[b\] \| -- \|", md)
    assert "| `N_v` | 0.7500 ± n/a [" in md
    rows = [line for line in md.splitlines() if line.startswith("| `")]
    assert len(rows) == len(STANDARD_COEFFICIENTS)
    assert all(line.count("|") == 7 for line in rows)
    assert "| **u** | 2.860 ± 0.030 | -- | -- | -- | -- |" in md
    assert "Sign convention: M nu_dot + D nu = tau" in md


@pytest.mark.parametrize("value, stderr, expected", [
    (-2.8612, 0.0312, ("-2.861", "0.031", 0)),
    (-2.86, 0.03, ("-2.860", "0.030", 0)),
    (1.234, 0.0996, ("1.23", "0.10", 0)),
    (12345.0, 67.0, ("12345", "67", 0)),
    (-1.5e-5, 2.1e-7, ("-1.500", "0.021", -5)),
    (3.2e6, 4.5e4, ("3.200", "0.045", 6)),
    (0.123456, math.nan, ("0.1235", None, 0)),
    (-0.0001, 0.05, ("0.000", "0.050", 0)),
])
def test_number_formatting(value, stderr, expected):
    f = format_uncertain(value, stderr)
    assert (f.value, f.stderr, f.exponent) == expected


# --------------------------------------------------------------------------- figures
def test_figures_are_valid_pngs(fits, trial, tmp_path):
    paths = write_report(fits, tmp_path, trial=trial)
    names = [p.name for p in paths.fit_figures]
    # A fit figure per fit, a residual-analysis figure per successful fit.
    assert names == ["fit_00_coast_down_surge.png", "resid_00_coast_down_surge.png", "fit_01_free_decay_roll.png",
                     "resid_01_free_decay_roll.png", "fit_02_rudder_step_yaw.png"]
    assert paths.overview_figure.name == "segments.png"
    for p in (*paths.fit_figures, paths.overview_figure):
        data = p.read_bytes()
        assert data[:8] == PNG_MAGIC, p
        assert len(data) > 10_000, p
    # 120 dpi: the PNG pHYs chunk holds pixels per metre (120 / 0.0254 = 4724).
    data = paths.fit_figures[0].read_bytes()
    i = data.index(b"pHYs")
    assert int.from_bytes(data[i + 4:i + 8], "big") == round(120 / 0.0254)


def test_figure_labels_show_degrees_and_parameters(fits):
    fig = figures.plot_segment_fit(fits.segment_fits[1], index=1)
    top, bottom = fig.axes
    assert top.get_ylabel() == "phi [deg] (converted from rad for display)"
    assert bottom.get_ylabel() == "residual [deg]"
    assert "free_decay / roll" in fig._suptitle.get_text()
    assert "zeta = 0.0800 ± 0.0031" in top.get_title(loc="left")
    data_line = top.get_lines()[0]
    assert np.max(np.abs(data_line.get_ydata())) == pytest.approx(math.degrees(0.2), rel=0.1)
    failed = figures.plot_segment_fit(fits.segment_fits[2], index=2)
    assert "FIT FAILED: did not converge" in failed.axes[0].get_title(loc="left")


def test_trial_overview_without_segments_uses_fit_segments(fits, trial, tmp_path):
    paths = write_report(fits, tmp_path, trial=trial)
    page = paths.html.read_text()
    table = page[page.index('id="segment-table"'):]
    table = table[:table.index("</table>")]
    assert table.count("<tr><td class=\"num\">") == 3  # one segment-table row per fitted segment
    assert paths.overview_figure.name == "segments.png"


# --------------------------------------------------------------------------- HTML
def test_html_report(fits, trial, tmp_path):
    segs = Segments(trial=trial.name, items=tuple(sf.segment for sf in fits.segment_fits))
    extra = (("Autopilot", "<p>PD gains <b>Kp = 1.2</b></p>"), ("Diagnosis <draft>", "<p>ok</p>"))
    paths = write_report(fits, tmp_path, trial=trial, segments=segs, extra_sections=extra)
    page = paths.html.read_text()
    assert page.startswith("<!DOCTYPE html>") and "<style>" in page
    assert "vesselid report: aauship" in page
    assert 'id="coefficient-table"' in page and 'id="damping-matrix"' in page
    assert "<i>X</i><sub>u</sub>" in page and "-2.860 ± 0.030" in page
    assert html_lib.escape(fits.convention) in page
    # Self-contained: every figure embedded, none linked.
    assert page.count('src="data:image/png;base64,') == len(paths.fit_figures) + 1
    assert not re.search(r'<img [^>]*src="(?!data:)', page)
    # The summary comes before any other table.
    assert page.index('id="summary"') < page.index("<table")
    summary_part = page[page.index('id="summary"'):page.index("</section>")]
    assert "D_uu = -X_u" in summary_part and "2.860 ± 0.030" in summary_part and "Nomoto T" in summary_part
    assert "model structure" in summary_part
    # Warnings (act on them) apart from notes (information).
    sec = page[page.index('<section id="warnings"'):page.index('<section id="sec-data"')]
    warnings, notes = sec.split("<details>", 1)
    assert "Y_r not identified: no segment excites sway and yaw together &lt;coupled&gt;" in warnings
    assert "fit 2 (rudder_step/yaw) failed: did not converge" in warnings
    assert "chi-square p = 0.003" in warnings
    assert "not estimated by the fit stage: Y_p, K_v, K_r, N_p" in warnings
    assert "N_v: covariance singular" in notes and "N_v" not in warnings
    # Each method once, as a numbered footnote.
    assert page.count('<li id="method-') == 4  # 4 distinct methods among 8 identified rows
    assert page.count('href="#method-1"') == 3  # X_u, Y_v, N_r
    assert 'id="quality-table"' in page and "MATLAB <i>compare</i>" in page
    # Segment table, with escaped labels.
    assert "roll release &lt;basin&gt;" in page and "manifest" in page and "<script" not in page
    # Extra sections: title escaped, fragment inserted as HTML.
    assert "<h2>Diagnosis &lt;draft&gt;</h2>" in page
    assert "<p>PD gains <b>Kp = 1.2</b></p>" in page
    assert "v derived from GPS course" in page


def test_html_flags_damping_that_contradicts_derivatives(fits, tmp_path):
    D = fits.damping_matrix.copy()
    D[0, 0] = -2.86  # sign error: D must be -X_u
    bad = Fits(fits.vessel, fits.estimates, (), D, fits.damping_stderr)
    page = write_report(bad, tmp_path).html.read_text()
    assert "D[0,0] (u,u) = -2.86 but -X_u = 2.86" in page


# --------------------------------------------------------------------------- files and inputs
def test_report_paths_and_atomic_writes_leave_no_temp_files(fits, trial, tmp_path):
    out = tmp_path / "new" / "dir"
    paths = write_report(fits, out, trial=trial)
    assert isinstance(paths, ReportPaths)
    with pytest.raises(AttributeError):
        paths.html = out / "x"  # frozen
    assert paths.out_dir == out
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in paths.files)
    assert {p.name for p in paths.files} >= {"coefficients.json", "coefficients.tex", "coefficients.md",
                                               "report.html", "segments.png"}
    # Writing again replaces the files in place, still without leftovers.
    write_report(fits, out, trial=trial)
    assert not [p for p in out.iterdir() if p.name.startswith(TEMP_PREFIX)]


def test_atomic_write_failure_removes_temp_file(tmp_path):
    target = tmp_path / "taken"
    target.mkdir()
    (target / "keep").write_text("x")
    with pytest.raises(OutputError, match="cannot write"):
        atomic_write_text(target, "data")  # replacing a non-empty folder fails
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken"]


def test_atomic_write_replaces_content(tmp_path):
    path = tmp_path / "a.txt"
    atomic_write_text(path, "old")
    atomic_write_text(path, "new")
    assert path.read_text() == "new"


def test_inputs_are_not_mutated(fits, trial, tmp_path):
    before = copy.deepcopy(fits)
    data_before = trial.data.copy()
    write_report(fits, tmp_path, trial=trial)
    np.testing.assert_array_equal(fits.damping_matrix, before.damping_matrix)
    np.testing.assert_array_equal(fits.damping_stderr, before.damping_stderr)
    for a, b in zip(fits.segment_fits, before.segment_fits):
        np.testing.assert_array_equal(a.y, b.y)
        np.testing.assert_array_equal(a.t, b.t)
        assert a.params == b.params
    assert fits.estimates == before.estimates
    pd.testing.assert_frame_equal(trial.data, data_before)


def test_bad_inputs_raise_report_error(fits, tmp_path):
    small = Fits(fits.vessel, fits.estimates, (), np.zeros((4, 4)), np.zeros((4, 4)))
    with pytest.raises(ReportError, match=re.escape("expected shape (5, 5)")):
        write_report(small, tmp_path)
    with pytest.raises(ReportError, match="extra_sections\\[0\\]: expected a \\(title, html_fragment\\)"):
        write_report(fits, tmp_path, extra_sections=[("only title",)])
    with pytest.raises(ReportError, match="expected a pipeline.records.Fits"):
        write_report({"X_u": -2.86}, tmp_path)
    (tmp_path / "file").write_text("x")
    with pytest.raises(ReportError, match="expected a folder"):
        write_report(fits, tmp_path / "file")


def test_minimal_fits_only_nomoto(tmp_path):
    """A rudder ship with unknown mass: only Nomoto K and T, no segment fits, D all NaN."""
    est = {"K_nomoto": _est("K_nomoto", 0.3, 0.01, "1/s"), "T_nomoto": _est("T_nomoto", 5.0, 0.3, "s")}
    nan = np.full((5, 5), np.nan)
    paths = write_report(Fits("rudder_ship", est, (), nan, nan), tmp_path)
    data = load_coefficients(paths.coefficients_json)
    assert all(x is None for row in data["damping_matrix"]["values"] for x in row)
    assert data["coefficients"]["K_nomoto"]["value"] == pytest.approx(0.3)
    assert paths.fit_figures == () and paths.overview_figure is None


def test_further_coefficients_follow_the_standard_ones(fits, tmp_path):
    est = dict(fits.estimates)
    est["N_delta"] = _est("N_delta", 0.54, 0.05, "N m/rad", n=2, method="rudder step")
    paths = write_report(Fits(fits.vessel, est, (), fits.damping_matrix, fits.damping_stderr), tmp_path)
    data = load_coefficients(paths.coefficients_json)
    assert list(data["coefficients"])[-1] == "N_delta"
    assert r"$N_{\delta}$ & $0.540 \pm 0.050$" in paths.coefficients_tex.read_text()
    assert "<i>N</i><sub>&delta;</sub>" in paths.html.read_text()


def test_load_coefficients_accepts_added_keys(fits, tmp_path):
    """The contract may be extended (DESIGN.md: extend, do not break); readers must not choke."""
    data = fits_to_dict(fits)
    data["schema_note"] = "added later"
    data["coefficients"]["X_u"]["per_segment"] = [-2.85, -2.87]
    path = tmp_path / "coefficients.json"
    path.write_text(json.dumps(data))
    assert load_coefficients(path)["coefficients"]["X_u"]["value"] == pytest.approx(-2.86)


# --------------------------------------------------------------------------- in a real browser
def test_report_in_headless_chromium(fits, trial, tmp_path):
    """No broken image, no horizontal overflow at 1280 px, the summary visible without scrolling."""
    from chromium import chromium_binary, probe

    if chromium_binary() is None:
        pytest.skip("no chromium binary (Debian: apt-get install chromium)")
    wide = "<table><tr>" + "".join(f"<td>column_{k}_with_a_long_header</td>" for k in range(30)) + "</tr></table>"
    paths = write_report(fits, tmp_path / "rep", trial=trial, extra_sections=(("Wide", wide),))
    got = probe(paths.html)
    assert got["images"] == len(paths.fit_figures) + 1 and got["broken"] == [], got
    assert got["scrollWidth"] <= got["innerWidth"], got
    assert got["firstTableInSummary"] and 0 <= got["summaryTop"] < got["summaryBottom"] <= got["innerHeight"], got


# --------------------------------------------------------------------------- LaTeX
def test_latex_tables_compile_on_one_page_each(fits, tmp_path):
    """Each table of coefficients.tex compiles with pdflatex (booktabs) and fits on one A4 page."""
    import shutil
    import subprocess

    exe = shutil.which("pdflatex")
    if exe is None:
        pytest.skip("no pdflatex (Debian: apt-get install texlive-latex-recommended)")
    est = dict(fits.estimates)
    long = "a long reason " * 40
    for k in range(12):  # more rows and longer notes than a real trial, to test the one-page claim
        est[f"T_extra{k}"] = _est(f"T_extra{k}", 1.0 + k, 0.1, "s", method=f"method {k} " + long)
    big = Fits(fits.vessel, est, fits.segment_fits, fits.damping_matrix, fits.damping_stderr)
    tex = tables.latex_tables(big, added_mass={})
    blocks = re.findall(r"\\begin\{table\}.*?\\end\{table\}", tex, re.S)
    assert len(blocks) == 3
    for k, block in enumerate(blocks):
        doc = tmp_path / f"t{k}.tex"
        doc.write_text("\\documentclass[a4paper]{article}\n\\usepackage[T1]{fontenc}\n\\usepackage{booktabs}\n"
                       "\\begin{document}\n" + block + "\n\\end{document}\n")
        res = subprocess.run([exe, "-interaction=nonstopmode", "-halt-on-error", doc.name], cwd=tmp_path,
                             capture_output=True, text=True, timeout=120)
        log = (tmp_path / f"t{k}.log").read_text(errors="replace")
        assert res.returncode == 0, log[-2000:]
        assert "Float too large" not in log and "Overfull \\hbox" not in log, log[-2000:]
        pages = re.search(r"Output written on .*?\((\d+) page", log)
        assert pages and int(pages.group(1)) == 1, log[-500:]


# --------------------------------------------------------------------------- the report folder as a whole
def test_atomic_folder_swaps_in_whole_and_keeps_the_old_one_on_failure(tmp_path):
    out = tmp_path / "rep"
    out.mkdir()
    (out / "coefficients.json").write_text("old")
    (out / "fit_07_old.png").write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with atomic_mod.atomic_folder(out) as stage:
            (stage / "coefficients.json").write_text("half")
            raise RuntimeError("interrupted")
    assert sorted(p.name for p in out.iterdir()) == ["coefficients.json", "fit_07_old.png"]
    assert (out / "coefficients.json").read_text() == "old"
    with atomic_mod.atomic_folder(out) as stage:
        (stage / "coefficients.json").write_text("new")
    assert [p.name for p in out.iterdir()] == ["coefficients.json"] and (out / "coefficients.json").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rep"], "no staging or old folder left"
    mine = tmp_path / "thesis"
    mine.mkdir()
    (mine / "chapter1.tex").write_text("x")
    with pytest.raises(OutputError, match="other files"):
        with atomic_mod.atomic_folder(mine):
            pass


# --------------------------------------------------------------------------- summary, quality, wrong-but-parsing inputs
def test_fit_percent_is_matlab_compare():
    y = np.array([0.0, 1.0, 2.0, 3.0])
    assert quality.fit_percent(y, y) == pytest.approx(100.0)
    assert quality.fit_percent(y, np.full(4, y.mean())) == pytest.approx(0.0)
    assert quality.fit_percent(y, y + 0.5) == pytest.approx(100 * (1 - 1.0 / np.sqrt(5.0)))
    assert math.isnan(quality.fit_percent(np.ones(4), np.ones(4)))


def test_summary_flags_not_identified_and_missing_added_mass(fits):
    est = dict(fits.estimates)
    est["T_nomoto"] = Estimate("T_nomoto", math.nan, math.nan, (math.nan, math.nan), "s", 0, "", False,
                               "not identified: not identified: no rudder step")
    f = Fits(fits.vessel, est, (), fits.damping_matrix, fits.damping_stderr)
    rows = {r.label: r for r in summary.summary_rows(f, [], added_mass={"sway": 10.0})}
    assert rows["Nomoto T"].value == "not identified"
    assert rows["Nomoto T"].flags == ("not identified: no rudder step",)
    assert "added mass taken as 0" in rows["D_uu = -X_u"].flags
    assert "added mass taken as 0" not in rows["D_vv = -Y_v"].flags
    assert rows["D_rr = -N_r"].ci == "[0.451, 0.529]"  # D = -N_r: the interval flips with the sign
    found = summary.findings(f, [])
    assert "T_nomoto not identified: no rudder step" in found.warnings
    tex = tables.latex_tables(f, added_mass={})
    assert "added mass in surge taken as zero" in tex


def test_gain_and_mass_damping_disagreeing_by_a_unit_factor_is_a_warning(fits):
    est = dict(fits.estimates)
    est["D_gain_surge"] = _est("D_gain_surge", 0.00286, 1e-5, "kg/s")  # tau_x logged in kN
    f = Fits(fits.vessel, est, (), fits.damping_matrix, fits.damping_stderr)
    (w,) = summary.gain_mass_consistency(f)
    assert "surge" in w and "0.001 x" in w and "tau_x (N, not kN)" in w
    est["D_gain_surge"] = _est("D_gain_surge", 2.7, 0.05, "kg/s")  # added mass: a few % apart, fine
    assert summary.gain_mass_consistency(Fits(fits.vessel, est, (), fits.damping_matrix, fits.damping_stderr)) == ()


def test_diagnosis_headline_says_what_is_unexplained():
    from types import SimpleNamespace as NS

    none = NS(gap_before=4.2, gap_after=4.2, verdict=None, places=(NS(share=0.6, dof="yaw", category="speed",
                                                                        name="fast"),), shrink=0.0)
    text = summary.diagnosis_headline(none)
    assert "No candidate effect explains the gap" in text and "4.2 x the sensor noise, unexplained" in text
    assert "yaw" in text
    assert summary.diagnosis_headline(None) == ""


# --------------------------------------------------------------------------- long trials
def test_envelope_keeps_every_peak_and_gap_of_a_long_series():
    t = np.arange(360_000) / 50.0  # two hours at 50 Hz
    y = np.sin(0.05 * t)
    y[123_457] = 9.0  # one spike
    y[200_000:201_000] = np.nan  # a 20 s dropout
    tt, yy = figures.envelope(t, y, max_points=4000)
    assert tt.size <= 4000 and np.all(np.diff(tt) >= 0)
    assert np.nanmax(yy) == 9.0 and tt[np.nanargmax(yy)] == t[123_457]
    assert np.nanmin(yy) == pytest.approx(-1.0, abs=1e-6)
    inside = (tt > t[200_100]) & (tt < t[200_900])
    assert inside.any() and np.isnan(yy[inside]).all()
    short_t, short_y = figures.envelope(t[:100], y[:100])
    assert np.array_equal(short_t, t[:100]) and np.array_equal(short_y, y[:100])


def test_figure_selection_spreads_a_bounded_number_over_kinds():
    rng = np.random.default_rng(3)
    many = [_coast_down_fit(rng) for _ in range(10)] + [_roll_decay_fit(rng) for _ in range(6)] + [_failed_fit()]
    pct = [50.0 + k for k in range(10)] + [80.0 - k for k in range(6)] + [math.nan]
    assert figures.figure_selection(many[:5], pct[:5], limit=5) == (0, 1, 2, 3, 4)
    chosen = figures.figure_selection(many, pct, limit=5)
    # The failed fit, then the worst and the best of each kind.
    assert chosen == (0, 9, 10, 15, 16)
    assert len(figures.figure_selection(many, pct, limit=12)) == 12


def test_a_report_of_many_fits_draws_at_most_the_limit(fits, trial, tmp_path, monkeypatch):
    rng = np.random.default_rng(5)
    many = copy.copy(fits)
    object.__setattr__(many, "segment_fits", tuple(_coast_down_fit(rng) for _ in range(6)) + (_failed_fit(),))
    monkeypatch.setattr(figures, "MAX_FIT_FIGURES", 3)
    paths = write_report(many, tmp_path, trial=trial)
    fit_pngs = sorted(p.name for p in paths.fit_figures if p.name.startswith("fit_"))
    assert len(fit_pngs) == 3 and "fit_06_rudder_step_yaw.png" in fit_pngs
    assert sorted(p.name for p in tmp_path.glob("fit_*.png")) == fit_pngs
    page = paths.html.read_text()
    assert "Figures for 3 of the 7 segment fits" in page
    assert page.count('<details id="fit-') == 7  # every fit still listed


def test_long_segment_figure_thins_its_markers(fits):
    sf = fits.segment_fits[0]
    t = np.arange(0.0, 200.0, 0.02)
    long = copy.copy(sf)
    for name, value in (("t", t), ("y", 1.5 * np.exp(-t / 4.5)), ("y_fit", 1.5 * np.exp(-t / 4.5))):
        object.__setattr__(long, name, value)
    fig = figures.plot_segment_fit(long, index=0)
    data_line = fig.axes[0].get_lines()[0]
    assert len(data_line.get_xdata()) <= figures.MAX_MARKERS
    assert "1 in 7 of 10000 samples shown" in data_line.get_label()


def test_report_lists_the_runs_with_files_offsets_and_spans(trial):
    from pipeline.records import Run

    runs = (Run("noon", ("b_noon.bin", "gnss.ubx"), offsets={"b_noon.bin": 0.0, "gnss.ubx": -2.06},
                offset_stderr={"b_noon.bin": 0.0, "gnss.ubx": 0.01}, start_time=1714910400.0, t_start=0.0,
                t_end=50.0, reason="absolute times overlap"),
            Run("pool <roll>", ("pool.csv",), t_start=55.0, t_end=109.9,
                reason="no absolute time; the same channels as run 0: a separate recording"))
    two = Trial(name=trial.name, data=trial.data, fs=trial.fs, runs=runs)
    part = html_mod.trial_section_html(two)
    table = part[part.index('id="runs-table"'):part.index("</table>")]
    assert "2 run(s)" in table and table.count("<tr><td") == 2
    assert "gnss.ubx (-2.060 ± 0.01)" in table and "2024-05-05T12:00:00.000+00:00" in table
    assert "pool &lt;roll&gt;" in table and "unknown (no absolute clock)" in table
    assert "absolute times overlap" in table and "a separate recording" in table
    assert ">55.00<" in table and ">109.90<" in table
    one = html_mod.trial_section_html(trial)
    assert "1 run(s)" in one and "one run (no grouping recorded)" in one


def test_figures_drawn_in_worker_processes_equal_a_serial_report(fits, trial, tmp_path):
    """The figures drawn side by side in worker processes (pipeline.parallel) are the serial ones, byte for byte,
    and a caller that drew them already (figures_written) gets the same report."""
    one = write_report(fits, tmp_path / "one", trial=trial, jobs=1)
    two = write_report(fits, tmp_path / "two", trial=trial, jobs=2)
    assert [p.name for p in one.files] == [p.name for p in two.files]
    for a, b in zip(one.files, two.files):
        assert a.read_bytes() == b.read_bytes(), a.name
    qual = [quality.segment_quality(sf, trial) for sf in fits.segment_fits]
    again = write_report(fits, tmp_path / "two", trial=trial, qualities=qual, figures_written=True)
    assert again.fit_figures == two.fit_figures and again.html.read_bytes() == two.html.read_bytes()
