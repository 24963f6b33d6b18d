"""The autopilot section of the HTML report: a title and a self-contained HTML fragment.

Figures are embedded as base64 PNG data URIs, so the fragment can be pasted into any page. Numbers
are shown in degrees and seconds (a report is an edge of the pipeline).
"""

from __future__ import annotations

import base64
import html
import math
from typing import Mapping

from ..records import AutopilotResult
from ..text_format import number, plus_minus
from .closed_loop import CASE_LABELS, CASES


#: Below this magnitude a metric (degrees, seconds, fractions) is printed as 0: a value such as
#: 1.55e-268 is the simulation's round-off, not a measurement.
ZERO = 1e-9


def _f(x, fmt: str = ".4g", unit: str = "") -> str:
    return number(x, fmt, missing="&mdash;", unit=unit, zero=ZERO)


def _pm(v: float, se: float, fmt: str = ".4g", unit: str = "") -> str:
    return plus_minus(v, se, fmt, unit=unit, missing="&mdash;", no_stderr=" (no standard error)")


def _img(png: bytes, alt: str) -> str:
    return (f'<img alt="{html.escape(alt)}" style="max-width:100%" '
            f'src="data:image/png;base64,{base64.b64encode(png).decode()}"/>')


def _table(head: list[str], rows: list[list[str]], caption: str = "") -> str:
    cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
    th = "".join(f"<th>{h}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f'<table class="autopilot">{cap}<thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>'


def autopilot_html_section(result: AutopilotResult, figures: bool = True,
                           images: Mapping[str, bytes] | None = None) -> tuple[str, str]:
    """Title and HTML fragment of the autopilot section.

    Parameters
    ----------
    result : AutopilotResult
        From :func:`pipeline.autopilot.build_autopilot`.
    figures : bool
        Embed the closed-loop and wave-fit figures.
    images : Mapping[str, bytes], optional
        PNGs already made, keyed ``closed_loop_<scenario>`` and ``wave_fit``; missing ones are drawn.

    Returns
    -------
    tuple of str
        ``(title, html_fragment)``.
    """
    from .figures import closed_loop_figure, wave_fit_figure
    from .waves_fit import course_kw, course_sigma

    cfg = result.config
    imgs = dict(images or {})
    deg = math.degrees
    parts = []
    used = cfg.to_fit_result().params
    parts.append(_table(
        ["quantity", "value"],
        [["Nomoto K", _pm(used["K"].value, used["K"].stderr, ".4g", "1/s")],
         ["Nomoto T", _pm(used["T"].value, used["T"].stderr, ".4g", "s")],
         ["wave omega<sub>0</sub>", _pm(used["omega0"].value, used["omega0"].stderr, ".4g", "rad/s")],
         ["wave &lambda;", _pm(used["lam"].value, used["lam"].stderr, ".3g")],
         ["wave K<sub>w</sub>", _pm(used["kw"].value, used["kw"].stderr, ".4g", "rad s<sup>-1/2</sup>")],
         ["wave model source", html.escape(cfg.wave_source)],
         ["PD K<sub>pd</sub>, T<sub>d</sub>, T<sub>f</sub>",
          f"{cfg.pd.kpd:.4g}, {cfg.pd.td:.4g} s, {cfg.pd.tf:.4g} s"],
         ["design crossover, phase margin", f"{cfg.pd.crossover:.3g} rad/s, {deg(cfg.pd.phase_margin):.1f} deg"],
         ["rudder limit, rate", f"&plusmn;{deg(cfg.rudder_max_angle):.1f} deg, {deg(cfg.rudder_max_rate):.3g} deg/s "
                                f"({html.escape(cfg.rudder_source)})"],
         ["sample time", f"{cfg.ts:g} s"],
         ["compass noise R (sampled variance)", f"{cfg.kalman.r:.3g} rad<sup>2</sup> "
                                                f"({deg(math.sqrt(cfg.kalman.r)):.3g} deg RMS)"],
         ["process noise Q (continuous, w<sub>w</sub>, w<sub>b</sub>)",
          f"{cfg.kalman.q[0, 0]:.3g}, {cfg.kalman.q[1, 1]:.3g} rad<sup>2</sup>/s"]],
        caption="Autopilot design. SI units, angles in radians unless marked; Nomoto psi/delta = K/(s(Ts+1)); "
                "PD delta = K_pd (1 + T_d s)/(1 + T_f s) (psi_r - psi), T_d = T."))

    parts.append(_table(
        ["model variant (seed part IV)", "states", "rank / n", "condition number"],
        [[html.escape(k), ", ".join(v["states"]), f"{v['rank']} / {v['n']}" + ("" if v["observable"] else " (not observable)"),
          _f(v["condition"], ".3g")] for k, v in result.observability.items()],
        caption="Observability of the Kalman filter's model variants (compass y = psi + psi_w)."))

    parts.append(_table(
        ["plant K [1/s]", "plant T [s]", "crossover [rad/s]", "phase margin [deg]"],
        [[_f(m["K"]), _f(m["T"]), _f(m["crossover"], ".3g"), _f(deg(m["phase_margin"]) if math.isfinite(m["phase_margin"]) else math.nan, ".1f")]
         for m in result.margins],
        caption="PD loop on the identified model and at the corners of its 95 % (K, T) box (1.96 standard errors each)."))

    chk = result.check
    if chk is not None:
        rows = []
        for s in chk.scenarios:
            for c in CASES:
                m = chk.run(s.name, c).metrics.to_dict()
                settle = (_f(m["settling_time_s"], ".0f", "s") if m["settling_time_s"] is not None
                          else f"not within &plusmn;{m['settle_band_deg']:.1f} deg")
                rows.append([html.escape(s.name), html.escape(CASE_LABELS[c]), _f(m["steady_error_deg"], ".2f"),
                             settle, _f(m["rms_rudder_rate_deg_s"], ".3g"), _f(m["max_rudder_swing_5s_deg"], ".3g"),
                             _f(m["max_command_swing_5s_deg"], ".3g"), _f(m["rate_limited_fraction"], ".0%"),
                             _f(m["heading_estimate_rms_deg"], ".3g"), _f(m["bias_estimate_deg"], ".2f"),
                             _f(m["heading_swing_deg"], ".2f") + (" <b>limit cycle</b>" if m["limit_cycle"] else "")])
        parts.append(_table(
            ["scenario", "controller", "steady error [deg]", "settling time", "RMS rudder rate [deg/s]",
             "max rudder swing in 5 s [deg]", "max command swing in 5 s [deg]", "time at rate limit",
             "RMS psi_hat - psi [deg]", "mean b_hat [deg]", "steady heading swing [deg]"],
            rows,
            caption="Closed-loop check (simulated, seeded). Steady values over the last quarter of the run; "
                    "settling within 5 % of the step; swings of the applied rudder and of the controller's command."))
        scen = "; ".join(f"<b>{html.escape(s.name)}</b>: {html.escape(s.description)}" for s in chk.scenarios)
        parts.append(f"<p>Scenarios: {scen}. Heading step {deg(chk.scenarios[0].psi_ref):.0f} deg at t = 0.</p>")
        sea = next((s for s in chk.scenarios if s.current_bias != 0 or s.waves is not None), None)
        if sea is not None:
            a, b, c = (chk.run(sea.name, k).metrics for k in CASES)
            parts.append(
                "<p>Measured in scenario <b>" + html.escape(sea.name) + "</b>: "
                f"PD on the compass leaves a steady heading error of {deg(a.steady_error):.2f} deg against the "
                f"current ({deg(sea.current_bias):.1f} deg rudder bias; K<sub>pd</sub> = {cfg.pd.kpd:.3g} predicts "
                f"b/K<sub>pd</sub> = {deg(sea.current_bias / cfg.pd.kpd):.2f} deg), and its rudder chases the waves: "
                f"{deg(a.max_swing_cmd):.1f} deg of commanded and {deg(a.max_swing):.1f} deg of applied swing within 5 s, "
                f"at the rate limit {a.rate_limited:.0%} of the time. Wave filtering cuts the swing to "
                f"{deg(b.max_swing):.2f} deg and the RMS rudder rate from {deg(a.rms_rudder_rate):.2f} to "
                f"{deg(b.rms_rudder_rate):.2f} deg/s but keeps the {deg(b.steady_error):.2f} deg error; bias "
                f"feed-forward removes it ({deg(c.steady_error):.2f} deg).</p>")
        if figures:
            for s in chk.scenarios:
                png = imgs.get(f"closed_loop_{s.name}") or closed_loop_figure(chk, s.name)
                parts.append(f"<details><summary>Closed-loop figure, scenario {html.escape(s.name)}</summary>"
                             + _img(png, f"closed loop, scenario {s.name}") + "</details>")
    if result.wave_fit is not None:
        f = result.wave_fit
        w, st = f.params, f.statistics
        parts.append(
            f"<p>Wave model fitted by least squares to the Welch PSD of the wave-induced heading "
            f"(Hann, {f.nperseg} samples, {f.fs:.3g} Hz, band {f.band[0]:.3g}&ndash;{f.band[1]:.3g} rad/s): "
            f"omega<sub>0</sub> = {_pm(w['omega0'].value, w['omega0'].stderr, '.4f', 'rad/s')}, "
            f"&lambda; = {_pm(w['lam'].value, w['lam'].stderr, '.3f')}, "
            f"K<sub>w</sub> = {_pm(w['kw'].value, w['kw'].stderr, '.4g')}, &sigma; = {_pm(st['sigma'], st['sigma_se'], '.4g')} with "
            f"&sigma;<sup>2</sup> the peak of the PSD and K<sub>w</sub> = 2&lambda;omega<sub>0</sub>&sigma;. "
            f"PSD convention: two-sided per rad/s for unit-intensity w<sub>w</sub>; the course's convention "
            f"gives &sigma; = {course_sigma(f):.4g}, K<sub>w</sub> = {course_kw(f):.4g} (divided by &radic;&pi;)."
            + (f" Note: {html.escape(f.message)}." if f.message else "") + "</p>")
        if figures:
            parts.append(_img(imgs.get("wave_fit") or wave_fit_figure(f), "wave spectrum fit"))
    ap = result.ardupilot
    parts.append("<details><summary>ArduPilot Rover parameters</summary>")
    parts.append(_table(["ArduPilot parameter", "value"], [[k, f"{v:.4g}"] for k, v in sorted(ap.params.items())],
                        caption="ArduPilot Rover steering equivalent of the PD design (rate loop with pole at "
                                "1/T_f, angle P = K_pd K)."))
    parts.append("</details>")
    notes = list(cfg.notes) + list(ap.notes)
    if notes:
        parts.append(f"<details><summary>{len(notes)} design notes</summary><ul>"
                     + "".join(f"<li>{html.escape(n)}</li>" for n in notes) + "</ul></details>")
    return "Heading autopilot and Kalman filter", "\n".join(parts)
