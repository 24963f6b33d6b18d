"""Figures of the diagnosis: where the gap lives, the candidates, residual spectra, and overlays.

Built on :class:`matplotlib.figure.Figure` with the Agg canvas directly (no ``pyplot`` state), as
the report's figures are. Angles and angular rates are shown in degrees, and their labels say so.
"""

from __future__ import annotations

import io
import math
import re
from pathlib import Path
from typing import Mapping

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..atomic import atomic_path
from ..errors import DiagnoseError
from ..records import ANGLE_CHANNELS, CHANNEL_UNITS
from ..records import GapReport, Trace

#: Resolution of every PNG [dots per inch].
DPI = 110
#: Figure file names (``{dof}`` is replaced by the DOF name).
NAMES: Mapping[str, str] = {
    "where": "diagnose_where.png",
    "candidates": "diagnose_candidates.png",
    "spectra": "diagnose_spectra.png",
    "overlay": "diagnose_overlay_{dof}.png",
    "replay": "diagnose_replay_{dof}.png",
}
_CATEGORY_COLOURS = {"channel": "#345", "segment kind": "#3a7", "frequency band": "#c63", "speed": "#77b",
                     "input amplitude": "#b7a"}
_SAFE = re.compile(r"[^A-Za-z0-9_-]+")


def _new(width: float, height: float, fixed: bool = False) -> Figure:
    """A figure of ``width`` x ``height`` inches: constrained layout (labels of any length fit; the
    layout pass draws the figure once more), or, with ``fixed``, fixed margins [inches: 0.45 top,
    0.5 bottom] for panels whose labels are short (the spectra and traces: ~35 % less CPU measured
    on the 2-hour trial of benchmarks/scaling.py, as the report's own figures)."""
    if not fixed:
        fig = Figure(figsize=(width, height), layout="constrained")
    else:
        fig = Figure(figsize=(width, height))
        fig.subplots_adjust(left=0.1, right=0.98, top=1.0 - 0.45 / height, bottom=0.5 / height, hspace=0.45)
    FigureCanvasAgg(fig)
    return fig


def _display(channel: str) -> tuple[float, str]:
    """Factor and unit for display: radians shown in degrees."""
    unit = CHANNEL_UNITS.get(channel, "")
    if channel in ANGLE_CHANNELS or unit == "rad":
        return 180 / math.pi, "deg"
    if unit == "rad/s":
        return 180 / math.pi, "deg/s"
    return 1.0, unit


def plot_where(report: GapReport, top: int = 18) -> Figure:
    """Horizontal bars: the places holding the largest shares of the baseline's excess gap.

    Parameters
    ----------
    report : GapReport
        The diagnosis.
    top : int
        Most places shown.
    """
    places = [p for p in report.places if p.share > 0][:top]
    fig = _new(8.5, 0.32 * max(len(places), 3) + 1.4)
    ax = fig.add_subplot()
    if not places:
        ax.text(0.5, 0.5, "no gap above the sensor noise anywhere", ha="center", va="center", transform=ax.transAxes)
        ax.set_axis_off()
        return fig
    y = np.arange(len(places))[::-1]
    ax.barh(y, [100 * p.share for p in places], color=[_CATEGORY_COLOURS.get(p.category, "#888") for p in places])
    ax.set_yticks(y, [f"{p.dof}: {p.category}: {p.name}" for p in places], fontsize=8)
    ax.set_xlabel("share of the baseline's held-out excess gap [%] (categories overlap; ranked within the trial)",
                  fontsize=8)
    ax.set_title(f"{report.trial}: where the model disagrees with the boat", fontsize=10)
    for yy, p in zip(y, places):
        ax.text(100 * p.share, yy, f" gap {p.gap:.3g}", va="center", fontsize=7)
    return fig


def plot_candidates(report: GapReport) -> Figure:
    """Held-out shrink of every candidate's DOF gap; significant ones green (a green bar below the dashed
    minimum is significant through one of the DOF's channels, see :mod:`pipeline.diagnose.significance`).

    Parameters
    ----------
    report : GapReport
        The diagnosis.
    """
    dofs = list(dict.fromkeys(c.dof for c in report.candidates))
    fig = _new(8.5, 2.3 * max(len(dofs), 1) + 0.6)
    if not dofs:
        fig.add_subplot().set_axis_off()
        return fig
    axes = fig.subplots(len(dofs), 1, squeeze=False)[:, 0]
    for ax, dof in zip(axes, dofs):
        cs = sorted((c for c in report.candidates if c.dof == dof), key=lambda c: c.label)
        x = np.arange(len(cs))
        vals = [max(c.shrink, -50.0) for c in cs]
        colours = ["#2a6" if c.significant else "#bbb" for c in cs]
        ax.bar(x, vals, color=colours, edgecolor="#333")
        # The significance rule asks the shrink of one channel of the DOF (pipeline.diagnose.significance),
        # so a green bar below the line is significant through one channel, not the DOF gap drawn here.
        ax.axhline(report.thresholds.get("min_shrink_percent", 0.0), color="#a33", lw=0.8, ls="--",
                   label="minimum shrink, asked of one channel of the DOF")
        ax.legend(loc="upper right", fontsize=7, frameon=False)
        ax.set_xticks(x, [c.label for c in cs], rotation=20, ha="right", fontsize=8)
        ax.set_ylabel("held-out shrink [%]", fontsize=8)
        ax.set_title(f"{dof}: baseline gap {cs[0].gap_before:.3g} (noise units); green = significant", fontsize=9)
        ax.set_ylim(min(min(vals) - 5, -5), 105)
    return fig


def plot_spectra(report: GapReport) -> Figure:
    """PSD of the baseline's held-out residuals with the wave band shaded.

    Parameters
    ----------
    report : GapReport
        The diagnosis.
    """
    specs = [s for s in report.spectra if len(s.omega)]
    fig = _new(8.5, 2.4 * max(len(specs), 1) + 0.4, fixed=True)
    if not specs:
        fig.add_subplot().set_axis_off()
        return fig
    axes = fig.subplots(len(specs), 1, squeeze=False)[:, 0]
    for ax, s in zip(axes, specs):
        ok = (s.omega > 0) & (s.psd > 0)
        ax.loglog(s.omega[ok], s.psd[ok], color="#345", lw=1)
        ax.axvspan(*s.band, color="#c63", alpha=0.15, label="wave band")
        ax.set_ylabel("PSD [noise$^2$ s/rad]", fontsize=8)
        ax.set_title(f"{s.dof}: residual spectrum of {s.channel}", fontsize=9)
        ax.legend(fontsize=7, loc="lower left")
    axes[-1].set_xlabel("frequency [rad/s]", fontsize=8)
    return fig


def plot_traces(traces: list[Trace], title: str) -> Figure:
    """Measured, baseline and (when given) the model with the effect, one panel per channel, each
    with its residuals below (a heading that turns through hundreds of degrees hides a gap of a
    degree; its residual does not).

    Parameters
    ----------
    traces : list[Trace]
        Series to plot, two panels each.
    title : str
        Figure title.
    """
    fig = _new(9.0, 3.6 * max(len(traces), 1) + 0.5, fixed=True)
    if not traces:
        fig.add_subplot().set_axis_off()
        return fig
    axes = fig.subplots(2 * len(traces), 1, squeeze=False, sharex=True,
                        gridspec_kw={"height_ratios": [2, 1] * len(traces)})[:, 0]
    for j, tr in enumerate(traces):
        ax, axr = axes[2 * j], axes[2 * j + 1]
        k, unit = _display(tr.channel)
        ax.plot(tr.t, k * tr.measured, color="#999", lw=0.8, label="measured")
        ax.plot(tr.t, k * tr.baseline, color="#c33", lw=1.0, label="baseline model")
        axr.plot(tr.t, k * (tr.measured - tr.baseline), color="#c33", lw=0.8, label="measured - baseline")
        if tr.effect and np.isfinite(tr.with_effect).any():
            ax.plot(tr.t, k * tr.with_effect, color="#26a", lw=1.0, label=f"with {tr.effect}")
            axr.plot(tr.t, k * (tr.measured - tr.with_effect), color="#26a", lw=0.8,
                     label=f"measured - with {tr.effect}")
        axr.axhline(0.0, color="#333", lw=0.5)
        ax.set_ylabel(f"{tr.channel} [{unit}]", fontsize=8)
        axr.set_ylabel(f"residual [{unit}]", fontsize=8)
        ax.legend(fontsize=7, loc="upper right")
        axr.legend(fontsize=7, loc="upper right")
    axes[0].set_title(title, fontsize=10)
    axes[-1].set_xlabel("time from trial start [s]", fontsize=8)
    return fig


def _save(fig: Figure, path: Path) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.getvalue())
    return path


def figure_names(report: GapReport) -> dict[str, str]:
    """File name of every figure :func:`write_figures` writes for ``report``, by key.

    Parameters
    ----------
    report : GapReport
        The diagnosis.
    """
    out = {k: NAMES[k] for k in ("where", "candidates", "spectra")}
    for dof in dict.fromkeys(t.dof for t in report.traces):
        safe = _SAFE.sub("_", dof)
        out[f"overlay:{dof}"] = NAMES["overlay"].format(dof=safe)
        out[f"replay:{dof}"] = NAMES["replay"].format(dof=safe)
    return out


def write_figures(report: GapReport, folder: str | Path) -> dict[str, Path]:
    """Write every figure of the diagnosis into ``folder``.

    Parameters
    ----------
    report : GapReport
        The diagnosis.
    folder : str or Path
        Output folder (created when missing).

    Returns
    -------
    dict[str, Path]
        Key (as in :func:`figure_names`) -> file written.

    Raises
    ------
    DiagnoseError
        When ``folder`` exists and is not a directory.
    """
    out_dir = Path(folder)
    if out_dir.exists() and not out_dir.is_dir():
        raise DiagnoseError(f"--plots: expected a folder, found a file at {out_dir}")
    out_dir.mkdir(parents=True, exist_ok=True)
    names = figure_names(report)
    written = {
        "where": _save(plot_where(report), out_dir / names["where"]),
        "candidates": _save(plot_candidates(report), out_dir / names["candidates"]),
        "spectra": _save(plot_spectra(report), out_dir / names["spectra"]),
    }
    for dof in dict.fromkeys(t.dof for t in report.traces):
        held = [t for t in report.traces if t.dof == dof and t.kind == "heldout"]
        rep = [t for t in report.traces if t.dof == dof and t.kind == "replay"]
        label = next((t.effect for t in held if t.effect), None)
        written[f"overlay:{dof}"] = _save(plot_traces(held, f"{dof}: held-out windows, measured vs baseline"
                                                      + (f" vs with {label}" if label else "")),
                                          out_dir / names[f"overlay:{dof}"])
        written[f"replay:{dof}"] = _save(plot_traces(rep, f"{dof}: baseline replayed over the whole trial"),
                                         out_dir / names[f"replay:{dof}"])
    return written
