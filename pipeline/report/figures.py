"""Report figures: one per segment fit (data, fit, residual) and a trial overview.

Figures are built on :class:`matplotlib.figure.Figure` with the Agg canvas directly, not through
``pyplot``: no global figure registry or backend switch, so the report can run next to other code
(an interactive session, another thread) without closing or stealing its figures. Angles are
radians inside the pipeline and are converted to degrees here, for display only; every label that
was converted says so.
"""

from __future__ import annotations

import io
import math
import os
import re
from pathlib import Path
from typing import Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from matplotlib.transforms import blended_transform_factory

from ..errors import ReportError
from ..records import CHANNEL_UNITS, INPUT_UNITS, SEGMENT_KINDS, Segment, SegmentFit, Trial
from .rows import finite, format_number, format_uncertain
from ..atomic import atomic_write_bytes

#: Resolution of every PNG [dots per inch].
DPI = 120
#: Trial channels the overview shows, when present (states first, then every input).
OVERVIEW_STATES: tuple[str, ...] = ("u", "v", "r", "phi", "theta")
OVERVIEW_INPUTS: tuple[str, ...] = tuple(INPUT_UNITS)
#: Name of the trial overview figure.
OVERVIEW_NAME = "segments.png"
#: Most samples drawn per line of a time series: a figure 1300 px wide shows no more. Longer series
#: are reduced to the minimum and maximum of each of ``MAX_PLOT_POINTS / 2`` equal buckets
#: (:func:`envelope`), so every peak and dropout stays visible.
MAX_PLOT_POINTS = 4000
#: Most markers drawn per series of a segment-fit figure; longer series show every k-th sample.
MAX_MARKERS = 1500
#: Most segment fits drawn as figures in one report (a 2-hour trial has hundreds of segments;
#: every fit stays in the quality table). :func:`figure_selection` picks which: the failed fits, then
#: the worst and the best of each group of one segment kind, DOF and channel. 24 holds the bundled
#: sample trial's 22 fits whole, and a 2-hour trial's 3 failed fits plus the worst and best of each of
#: its 10 groups (benchmarks/scaling.py); each fit drawn costs ~0.2-0.3 s CPU with its residual figure.
MAX_FIT_FIGURES = 24

_SAFE = re.compile(r"[^A-Za-z0-9_-]+")


def display_scale(channel: str) -> tuple[float, str, str]:
    """Factor, unit and label note to show ``channel`` (degrees for angles).

    Parameters
    ----------
    channel : str
        Canonical channel name (``CHANNEL_UNITS``); ``name@sensor`` is accepted.

    Returns
    -------
    factor : float
        Multiply SI values by this for display.
    unit : str
        Displayed unit.
    note : str
        ``" (converted from rad/s for display)"`` or empty.
    """
    unit = CHANNEL_UNITS.get(channel.split("@")[0], "")
    if unit.startswith("rad"):
        shown = "deg" + unit[3:]
        return math.degrees(1.0), shown, f" (converted from {unit} for display)"
    return 1.0, unit, ""


def axis_label(channel: str) -> str:
    """Axis label with the displayed unit: ``r [deg/s] (converted from rad/s for display)``.

    Parameters
    ----------
    channel : str
        Canonical channel name; an unknown channel gets ``[-]``.

    Returns
    -------
    str
        The label.
    """
    _, unit, note = display_scale(channel)
    return f"{channel} [{unit or '-'}]{note}"


def safe_name(text: str) -> str:
    """File-name-safe token: letters, digits, ``_`` and ``-`` only.

    Parameters
    ----------
    text : str
        Any text (segment kind, DOF).

    Returns
    -------
    str
        Runs of other characters replaced by ``_``; ``x`` when nothing is left.
    """
    return _SAFE.sub("_", str(text)).strip("_") or "x"


def envelope(t: np.ndarray, y: np.ndarray, max_points: int = MAX_PLOT_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """A series reduced for plotting: the minimum and maximum of each bucket, in time order.

    Drawing 360 000 samples into 1 000 pixels costs time and shows nothing more than the envelope:
    each of ``max_points // 2`` equal buckets of samples keeps its smallest and its largest value
    (NaN where the whole bucket is NaN, so gaps stay gaps).

    Parameters
    ----------
    t : numpy.ndarray
        Time [s], increasing.
    y : numpy.ndarray
        Values, same length as ``t``.
    max_points : int
        Most points returned (at least 4).

    Returns
    -------
    t, y : numpy.ndarray
        The reduced series; ``t`` and ``y`` themselves (as float arrays) when already short enough.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    n = y.size
    buckets = max(int(max_points) // 2, 2)
    if n <= 2 * buckets:
        return t, y
    width = -(-n // buckets)
    pad = buckets * width - n
    tp = np.concatenate([t, np.full(pad, np.nan)]).reshape(buckets, width)
    yp = np.concatenate([y, np.full(pad, np.nan)]).reshape(buckets, width)
    finite_y = np.isfinite(yp)
    lo = np.argmin(np.where(finite_y, yp, np.inf), axis=1)
    hi = np.argmax(np.where(finite_y, yp, -np.inf), axis=1)
    first, second = np.minimum(lo, hi), np.maximum(lo, hi)
    rows = np.arange(buckets)
    idx = np.stack([first, second], axis=1)
    tt = tp[rows[:, None], idx].ravel()
    yy = yp[rows[:, None], idx].ravel()
    # A bucket of padding only (or all NaN) keeps its NaN values; its time is the bucket's first.
    t_fill = tp[rows, 0].repeat(2)
    tt = np.where(np.isfinite(tt), tt, t_fill)
    keep = np.isfinite(tt)
    return tt[keep], yy[keep]


def thin(n: int, max_markers: int = MAX_MARKERS) -> int:
    """Stride that keeps at most ``max_markers`` of ``n`` samples as markers (1: every sample).

    Parameters
    ----------
    n : int
        Number of samples.
    max_markers : int
        Most markers drawn.
    """
    return max(1, -(-int(n) // max(int(max_markers), 1)))


def figure_selection(fits: Sequence[SegmentFit], fit_percents: Sequence[float],
                     limit: int = MAX_FIT_FIGURES) -> tuple[int, ...]:
    """Which segment fits get figures: all of them up to ``limit``, else a spread over every kind.

    The figures of a long trial would cost more than its fit and show the same thing hundreds of
    times. Above ``limit`` fits, the figures go first to the failed fits, then, taking each group
    of the same segment kind, DOF and channel in turn, to the worst fit of each group (lowest fit
    %), then the best, then the next worst, ... until ``limit`` are chosen.

    Parameters
    ----------
    fits : Sequence[SegmentFit]
        The segment fits, in report order.
    fit_percents : Sequence[float]
        MATLAB ``compare`` fit % of each (NaN when not known: ranked as the worst).
    limit : int
        Most figures.

    Returns
    -------
    tuple[int, ...]
        Indices into ``fits``, increasing.
    """
    n = len(fits)
    if n <= limit:
        return tuple(range(n))
    chosen: list[int] = [i for i in range(n) if not fits[i].success][:limit]
    groups: dict[tuple[str, str, str], list[int]] = {}
    for i, sf in enumerate(fits):
        if sf.success:
            groups.setdefault((sf.segment.kind, sf.segment.dof, sf.channel), []).append(i)

    def score(i: int) -> float:
        v = fit_percents[i] if i < len(fit_percents) else math.nan
        return float(v) if finite(v) else -math.inf

    # Each group as a queue alternating worst, best, second worst, second best, ...
    queues = []
    for members in groups.values():
        ranked = sorted(members, key=lambda i: (score(i), i))
        order = []
        lo, hi = 0, len(ranked) - 1
        while lo <= hi:
            order.append(ranked[lo])
            if hi != lo:
                order.append(ranked[hi])
            lo, hi = lo + 1, hi - 1
        queues.append(order)
    depth = 0
    while len(chosen) < limit and any(depth < len(q) for q in queues):
        for q in queues:
            if depth < len(q) and len(chosen) < limit:
                chosen.append(q[depth])
        depth += 1
    return tuple(sorted(chosen))


def fit_figure_name(index: int, sf: SegmentFit) -> str:
    """Stable file name of the figure of one segment fit.

    Parameters
    ----------
    index : int
        Position of the fit in ``Fits.segment_fits``.
    sf : SegmentFit
        The fit; its segment's kind and DOF go into the name.

    Returns
    -------
    str
        ``fit_<index>_<kind>_<dof>.png``, index zero-padded to two digits.
    """
    return f"fit_{index:02d}_{safe_name(sf.segment.kind)}_{safe_name(sf.segment.dof)}.png"


def _param_text(sf: SegmentFit) -> str:
    """``tau = 4.52 ± 0.13, u0 = 1.234 ± 0.005`` in SI; says why an error bar is missing."""
    params = sf.to_fit_result().params
    parts = []
    for name, par in params.items():
        v, se = par.value, par.stderr
        if not finite(v):
            parts.append(f"{name} = n/a")
            continue
        f = format_uncertain(v, se)
        txt = f"{f.value} ± {f.stderr}" if f.stderr is not None else f"{f.value} ± n/a"
        if f.exponent:
            txt = f"({txt})e{f.exponent}"
        parts.append(f"{name} = {txt}")
    lines = [", ".join(parts[k:k + 3]) for k in range(0, len(parts), 3)]
    return "\n".join(lines)


def _arrays(sf: SegmentFit) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """Float copies of t, y, y_fit, and why they cannot be drawn (empty when they can)."""
    try:
        t = np.asarray(sf.t, dtype=float).ravel()
        y = np.asarray(sf.y, dtype=float).ravel()
        yf = np.asarray(sf.y_fit, dtype=float).ravel()
    except (TypeError, ValueError) as exc:
        return np.empty(0), np.empty(0), np.empty(0), f"arrays are not numeric ({exc})"
    if not (t.size == y.size == yf.size):
        return t, y, yf, f"t, y and y_fit have different lengths ({t.size}, {y.size}, {yf.size})"
    if t.size == 0:
        return t, y, yf, "the fit holds no samples"
    return t, y, yf, ""


def figure_problem(sf: SegmentFit) -> str:
    """Why the data of a segment fit cannot be plotted.

    Parameters
    ----------
    sf : SegmentFit
        The fit.

    Returns
    -------
    str
        The reason (arrays not numeric, of different lengths, empty); empty when plottable.
    """
    return _arrays(sf)[3]


def plot_segment_fit(sf: SegmentFit, index: int | None = None) -> Figure:
    """Figure of one segment fit: data and fit on top, residual below.

    Parameters
    ----------
    sf : SegmentFit
        The fit; ``t`` [s from segment start], ``y`` and ``y_fit`` [SI unit of ``sf.channel``].
    index : int, optional
        Fit number shown in the title.

    Returns
    -------
    matplotlib.figure.Figure
        With an Agg canvas; the title gives kind, DOF, time span, model, parameters +- standard
        error [SI] and the RMSE. A failed fit is titled in red with its message.
    """
    seg = sf.segment
    factor, unit, _ = display_scale(sf.channel)
    t, y, yf, problem = _arrays(sf)
    # Fixed margins (room for a three-line title): constrained layout took most of the drawing time.
    fig = Figure(figsize=(8.0, 5.6))
    FigureCanvasAgg(fig)
    ax, axr = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    fig.subplots_adjust(left=0.1, right=0.98, bottom=0.09, top=0.8, hspace=0.08)
    head = f"fit {index}: " if index is not None else ""
    title = (f"{head}{seg.kind} / {seg.dof}, t = {seg.t_start:.1f}-{seg.t_end:.1f} s "
             f"({seg.duration:.1f} s); {sf.model} on {sf.channel}")
    sub = _param_text(sf)
    rmse = f"RMSE = {format_number(sf.rmse * factor, 3)} {unit}".rstrip() if finite(sf.rmse) else "RMSE n/a"
    sub = f"{sub}\n{rmse}  (parameters in SI units)" if sub else rmse
    fig.suptitle(title, fontsize=10, fontweight="bold")
    color = "black"
    if not sf.success or problem:
        why = problem or (sf.message or "no reason given")
        sub += f"\nFIT FAILED: {why}" if not sf.success else f"\ncannot plot: {why}"
        color = "tab:red"
    ax.set_title(sub, fontsize=8.5, color=color, loc="left")
    if not problem:
        order = np.argsort(t, kind="stable")
        ts, ys, yfs = t[order], y[order] * factor, yf[order] * factor
        # Thousands of samples as big markers hide the fit line; shrink them with density, and
        # draw every k-th sample of a long record (the legend says so).
        ms = 4.0 if ts.size < 300 else 2.5 if ts.size < 2000 else 1.5
        k = thin(ts.size)
        label = "data" if k == 1 else f"data (1 in {k} of {ts.size} samples shown)"
        ax.plot(ts[::k], ys[::k], "o", ms=ms, color="tab:blue", alpha=0.6, label=label, zorder=2)
        ax.plot(*envelope(ts, yfs), "-", lw=2.0, color="tab:orange", label=f"fit ({sf.model})", zorder=3)
        ax.legend(loc="best", fontsize=8)
        axr.axhline(0.0, color="0.4", lw=0.8)
        axr.plot(ts[::k], (ys - yfs)[::k], "o", ms=ms, color="tab:blue", alpha=0.6)
        if not np.isfinite(yfs).any():
            axr.text(0.5, 0.5, "no residual: the fit gave no model curve", transform=axr.transAxes,
                     ha="center", va="center", fontsize=8, color="tab:red")
    else:
        ax.text(0.5, 0.5, f"no plot: {problem}", transform=ax.transAxes, ha="center", va="center",
                color="tab:red", wrap=True)
    ax.set_ylabel(axis_label(sf.channel), fontsize=9)
    axr.set_ylabel(f"residual [{unit or '-'}]", fontsize=9)
    axr.set_xlabel(f"time from segment start [s] (segment starts at t = {seg.t_start:.2f} s)", fontsize=9)
    for a in (ax, axr):
        a.grid(True, alpha=0.3)
        a.tick_params(labelsize=8)
    return fig


_KIND_COLORS = {k: f"C{i}" for i, k in enumerate(SEGMENT_KINDS)}


def plot_trial_overview(trial: Trial, segments: Sequence[Segment]) -> Figure:
    """Time series of the main trial channels with the segments shaded and labelled by kind.

    Parameters
    ----------
    trial : Trial
        The aligned trial (SI units).
    segments : sequence of Segment
        Segments to shade; each is numbered as in the report's segment table.

    Returns
    -------
    matplotlib.figure.Figure
        One panel per channel present among ``OVERVIEW_STATES`` and ``OVERVIEW_INPUTS``; angles in
        degrees. Gaps in the data are hatched.

    Raises
    ------
    ReportError
        When the trial has no ``t`` column.
    """
    if "t" not in trial.data.columns:
        raise ReportError(f"trial {trial.name!r}: expected a 't' column, found {list(trial.data.columns)}")
    t = trial.data["t"].to_numpy(dtype=float)
    channels = [c for c in OVERVIEW_STATES + OVERVIEW_INPUTS if trial.has(c)]
    n = max(len(channels), 1)
    fig = Figure(figsize=(10.0, 1.0 + 1.5 * n), layout="constrained")
    FigureCanvasAgg(fig)
    axes = np.atleast_1d(fig.subplots(n, 1, sharex=True))
    # Per-panel "(converted from rad ...)" notes crowd stacked panels; the title says it once.
    fig.suptitle(f"Trial {trial.name}: channels and segments (angles converted from rad to deg for "
                 f"display)",
                 fontsize=10, fontweight="bold")
    if not channels:
        axes[0].text(0.5, 0.5, "no state or input channel with finite samples", ha="center",
                     va="center", transform=axes[0].transAxes)
    for ax, ch in zip(axes, channels):
        factor, _, _ = display_scale(ch)
        ax.plot(*envelope(t, trial.data[ch].to_numpy(dtype=float) * factor), lw=0.9, color="k")
        ax.set_ylabel(f"{ch} [{display_scale(ch)[1] or '-'}]", fontsize=8)
        ax.tick_params(labelsize=8)
        ax.grid(True, alpha=0.3)
    kinds_seen = []
    spans: dict[str, list[tuple[float, float]]] = {}
    trans = blended_transform_factory(axes[0].transData, axes[0].transAxes)
    for k, seg in enumerate(segments):
        color = _KIND_COLORS.get(seg.kind, "0.5")
        if seg.kind not in kinds_seen:
            kinds_seen.append(seg.kind)
        spans.setdefault(color, []).append((seg.t_start, seg.t_end))
        # Label at the top of the first panel: number and kind, so the shading maps to the table.
        axes[0].text(0.5 * (seg.t_start + seg.t_end), 0.97, f"{k}: {seg.kind}", transform=trans,
                     ha="center", va="top", fontsize=7, rotation=90, color=color, clip_on=True)
    for ax in axes:
        # Each kind's spans as one collection per panel, full height (what an axvspan per segment
        # draws, without one artist per segment and panel: a 2-hour trial has hundreds of segments).
        for color, ranges in spans.items():
            ax.add_collection(PolyCollection([[(a, 0.0), (a, 1.0), (b, 1.0), (b, 0.0)] for a, b in ranges],
                                             transform=ax.get_xaxis_transform(), facecolors=color, alpha=0.18,
                                             linewidths=0), autolim=False)
    for gap in trial.gaps:
        for ax in axes:
            ax.axvspan(gap.t_start, gap.t_end, facecolor="none", edgecolor="0.5", hatch="///", lw=0)
    handles = [Patch(color=_KIND_COLORS.get(k, "0.5"), alpha=0.35, label=k) for k in kinds_seen]
    if trial.gaps:
        handles.append(Patch(facecolor="none", edgecolor="0.5", hatch="///", label="data gap"))
    if handles:
        fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 6), fontsize=8)
    axes[-1].set_xlabel("time from trial start [s]", fontsize=9)
    if t.size:
        axes[-1].set_xlim(float(np.nanmin(t)), float(np.nanmax(t)))
    elif segments:
        axes[-1].set_xlim(min(s.t_start for s in segments), max(s.t_end for s in segments))
    return fig


def save_figure(fig: Figure, path: str | os.PathLike, dpi: int = DPI) -> Path:
    """Render ``fig`` to PNG and write it atomically.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure.
    path : str or os.PathLike
        Destination ``.png``.
    dpi : int
        Resolution [dots per inch].

    Returns
    -------
    pathlib.Path
        The file written.
    """
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return atomic_write_bytes(path, buf.getvalue())


def resid_figure_name(index: int, sf: SegmentFit) -> str:
    """``resid_<index>_<kind>_<dof>.png``: the residual-analysis figure of fit ``index``.

    Parameters
    ----------
    index : int
        Position of the fit in ``Fits.segment_fits``.
    sf : SegmentFit
        The fit.
    """
    return f"resid_{index:02d}_{safe_name(sf.segment.kind)}_{safe_name(sf.segment.dof)}.png"


def plot_residual_analysis(resid, index: int | None = None) -> Figure:
    """MATLAB ``resid``: residual autocorrelation and residual-input cross-correlation with 95 % bands.

    Parameters
    ----------
    resid : pipeline.fit.residual_tests.ResidualTest
        The test of one segment fit's residuals.
    index : int, optional
        Fit number shown in the title.

    Returns
    -------
    matplotlib.figure.Figure
        Left: ``rho_e(k)``, ``k = 0..M``, band ``+-1.96/sqrt(N)``; right: ``rho_eu(k)``,
        ``k = -M..M``, band ``+-1.96 sqrt(P/N)`` per input, or a note when the input is constant.
    """
    # Fixed margins: constrained layout would double the drawing time of these small panels.
    fig = Figure(figsize=(8.0, 2.6))
    FigureCanvasAgg(fig)
    ax, axc = fig.subplots(1, 2)
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.18, top=0.8, wspace=0.28)
    m = resid.max_lag
    lags = np.arange(resid.autocorrelation.size)
    ax.vlines(lags, 0.0, resid.autocorrelation, color="tab:blue")
    ax.plot(lags, resid.autocorrelation, "o", ms=3, color="tab:blue")
    ax.axhspan(-resid.band, resid.band, color="tab:orange", alpha=0.25, label="95 % band (white)")
    verdict = "white" if resid.white else "NOT white"
    ax.set_title(f"autocorrelation of residuals: {verdict} (Ljung-Box p = {format_number(resid.ljung_box_p, 2)})",
                 fontsize=8.5, color="black" if resid.white else "tab:red")
    ax.set_xlabel("lag [samples]", fontsize=8)
    ax.set_ylabel("rho_e [-]", fontsize=8)
    ax.legend(fontsize=7, loc="upper right")
    if resid.cross_correlation:
        ch, xc = next(iter(resid.cross_correlation.items()))
        band = resid.cross_band.get(ch, math.nan)
        xl = np.arange(-m, m + 1)[:len(xc)]
        axc.vlines(xl, 0.0, xc, color="tab:green")
        axc.plot(xl, xc, "o", ms=3, color="tab:green")
        if finite(band):
            axc.axhspan(-band, band, color="tab:orange", alpha=0.25)
        p = resid.cross_p.get(ch, math.nan)
        ok = resid.independent
        axc.set_title(f"cross-correlation with input {ch}: {'independent' if ok else 'CORRELATED'} "
                      f"(p = {format_number(p, 2)})", fontsize=8.5, color="black" if ok else "tab:red")
        axc.set_xlabel("lag [samples] (negative: residual leads input)", fontsize=8)
        axc.set_ylabel("rho_eu [-]", fontsize=8)
    else:
        axc.text(0.5, 0.5, "input constant over the segment (or none):\nno cross-correlation to test",
                 transform=axc.transAxes, ha="center", va="center", fontsize=8)
        axc.set_axis_off()
    for a in (ax, axc):
        a.tick_params(labelsize=7)
        a.grid(True, alpha=0.3)
    if index is not None:
        fig.suptitle(f"fit {index}: residual analysis ({resid.n} residuals, {m} lags)", fontsize=9)
    return fig
