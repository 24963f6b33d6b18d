"""Figures of the autopilot stage: closed-loop runs and the wave-spectrum fit, as PNG bytes.

Matplotlib's object API with the Agg canvas is used (no pyplot), so nothing global is switched and
figures can be made from threads or alongside other stages' plotting. Axes are in degrees and
seconds: figures are an edge of the pipeline.
"""

from __future__ import annotations

import io
import textwrap

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..records import ClosedLoopCheck, WaveFit
from .closed_loop import CASE_LABELS, CASES
from .waves_fit import course_sigma, model_psd

_COLOURS = {"pd": "tab:red", "pd_kalman": "tab:blue", "pd_kalman_ff": "tab:green"}


def _png(fig: Figure) -> bytes:
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return buf.getvalue()


def closed_loop_figure(check: ClosedLoopCheck, scenario: str, zoom: float = 60.0) -> bytes:
    """Heading, rudder and a zoom on the steady rudder for the three cases of one scenario.

    Parameters
    ----------
    check : ClosedLoopCheck
        Runs.
    scenario : str
        Scenario name (``model``, ``sea``).
    zoom : float
        Length of the zoomed window at the end of the run [s].

    Returns
    -------
    bytes
        PNG image.
    """
    d = np.degrees
    fig = Figure(figsize=(9.0, 9.0))
    ax_h, ax_d, ax_z, ax_b = fig.subplots(4, 1)
    first = check.run(scenario, CASES[0])
    t = first.t
    ax_h.plot(t, d(np.full_like(t, first.scenario.psi_ref)), "k--", lw=1, label="reference")
    if first.scenario.waves is not None or first.scenario.noise_var > 0:
        ax_h.plot(t, d(first.y), color="0.75", lw=0.5, label="compass (PD alone)")
    for case in CASES:
        run = check.run(scenario, case)
        m = run.metrics.to_dict()
        err = m["steady_error_deg"]
        ax_h.plot(t, d(run.psi), color=_COLOURS[case], lw=1.2,
                  label=f"{CASE_LABELS[case]}: steady error {err:.2f} deg")
        ax_d.plot(t, d(run.delta), color=_COLOURS[case], lw=0.8, label=CASE_LABELS[case])
        w = t >= t[-1] - zoom
        ax_z.plot(t[w], d(run.delta[w]), color=_COLOURS[case], lw=1.0,
                  label=f"max swing in 5 s: {m['max_rudder_swing_5s_deg']:.2f} deg "
                        f"(command {m['max_command_swing_5s_deg']:.2f} deg)")
        if case != "pd":
            ax_b.plot(t, d(run.b_hat), color=_COLOURS[case], lw=1.0, label=f"b_hat, {CASE_LABELS[case]}")
    ax_b.plot(t, d(np.full_like(t, first.scenario.current_bias)), "k--", lw=1, label="true bias (current)")
    ax_h.set_ylabel("heading [deg]")
    ax_d.set_ylabel("rudder [deg]")
    ax_z.set_ylabel("rudder [deg]")
    ax_b.set_ylabel("bias [deg]")
    ax_b.set_xlabel("time [s]")
    ax_z.set_title(f"last {zoom:g} s", fontsize=9)
    for ax in (ax_h, ax_d, ax_z, ax_b):
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    title = textwrap.fill(f"Heading autopilot, scenario '{scenario}': {first.scenario.description}", 110)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return _png(fig)


def wave_fit_figure(fit: WaveFit) -> bytes:
    """Welch PSD of the wave record and the fitted second-order model, linear and logarithmic.

    Parameters
    ----------
    fit : WaveFit

    Returns
    -------
    bytes
        PNG image.
    """
    fig = Figure(figsize=(9.0, 4.0))
    ax_lin, ax_log = fig.subplots(1, 2)
    w = fit.omega[1:]
    p = fit.psd[1:]
    hi = min(4.0 * fit.value("omega0"), w[-1])
    sel = w <= hi
    wm = np.linspace(w[0], hi, 800)
    par = fit.params
    label = (f"fit: omega0 {par['omega0'].value:.4f}+-{par['omega0'].stderr:.2g} rad/s, "
             f"lambda {par['lam'].value:.3f}+-{par['lam'].stderr:.2g}, K_w {par['kw'].value:.4g}+-{par['kw'].stderr:.2g}")
    for ax, log in ((ax_lin, False), (ax_log, True)):
        ax.plot(w[sel], p[sel], color="0.4", lw=0.8, label="Welch PSD (two-sided, per rad/s)")
        ax.plot(wm, model_psd(wm, fit), color="tab:red", lw=1.5, label=label)
        ax.axvspan(fit.band[0], fit.band[1], color="tab:blue", alpha=0.08, label="fitted band")
        ax.set_xlabel("omega [rad/s]")
        ax.grid(True, alpha=0.3)
        if log:
            ax.set_yscale("log")
    ax_lin.set_ylabel("P(omega) [rad^2 s]")
    ax_lin.legend(fontsize=6, loc="upper right")
    fig.suptitle(textwrap.fill(f"Wave-induced heading spectrum: sigma = sqrt(peak PSD) = {fit.statistics['sigma']:.4g} rad s^0.5 "
                               f"(course convention {course_sigma(fit):.4g}); K_w = 2 lambda omega0 sigma", 110),
                 fontsize=9)
    fig.tight_layout()
    return _png(fig)
