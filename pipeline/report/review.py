"""Interactive segment review (optional dependency: plotly): the trial with every segment shaded.

Hovering a shaded segment shows its kind, DOF, times, input, detector quality and, when the fits
are given, each fit's model, fit % and residual verdict; a link on the page downloads the segment
list as the ``segments.json`` that ``vesselid fit --segments`` and ``vesselid report --segments``
accept (edit it, drop segments, re-run). The page embeds plotly.js, so it works offline.

Install with ``pip install 'vesselid[review]'``.
"""

from __future__ import annotations

import html
import json
import math
import urllib.parse
from typing import Sequence

import numpy as np

from ..errors import ReportError
from ..records import Fits, Segments, Trial
from .figures import OVERVIEW_INPUTS, OVERVIEW_STATES, display_scale
from .quality import fit_percent

#: Largest number of points drawn per channel (the trial is thinned evenly beyond this).
MAX_POINTS = 20000


def require_plotly():
    """plotly's ``graph_objects`` and ``make_subplots``, or a ReportError that says how to install it."""
    try:
        import plotly.graph_objects as go
        from plotly.subplots import make_subplots
    except ImportError:
        raise ReportError("segment review: expected the optional package plotly, found it not installed; "
                          "install it with: pip install 'vesselid[review]'") from None
    return go, make_subplots


def _hover(k: int, seg, fits: Fits | None) -> str:
    lines = [f"<b>segment {k}: {seg.kind} / {seg.dof}</b>", f"t = {seg.t_start:.2f} .. {seg.t_end:.2f} s "
             f"({seg.duration:.1f} s)", f"quality {seg.quality:.2f}, {seg.origin}"]
    if seg.input_channel:
        lines.append(f"{seg.input_channel}: {seg.input_before:.4g} -> {seg.input_after:.4g}")
    for sf in (fits.segment_fits if fits is not None else ()):
        if sf.segment == seg:
            pct = fit_percent(sf.y, sf.y_fit)
            status = "fit failed" if not sf.success else (f"fit {pct:.1f} %" if math.isfinite(pct) else "fit % n/a")
            lines.append(f"{sf.model} on {sf.channel}: {status}")
    return "<br>".join(html.escape(x, quote=False).replace("&lt;b&gt;", "<b>").replace("&lt;/b&gt;", "</b>")
                       for x in lines)


def segment_review_html(trial: Trial, segments: Segments, fits: Fits | None = None,
                        segments_json: dict | None = None) -> str:
    """A self-contained HTML page for reviewing a trial's segments interactively.

    Parameters
    ----------
    trial : Trial
        The aligned trial (SI; angles shown in degrees).
    segments : Segments
        The segments to shade, numbered in order.
    fits : Fits, optional
        Adds each segment's fits (model, fit %, success) to its hover text.
    segments_json : dict, optional
        The ``segments.json`` content the download link offers; default built from ``segments``.

    Returns
    -------
    str
        HTML with plotly.js embedded.

    Raises
    ------
    ReportError
        When plotly is not installed.
    """
    go, make_subplots = require_plotly()
    if segments_json is None:
        from dataclasses import asdict

        segments_json = {"trial": segments.trial, "segments": [asdict(s) for s in segments.items]}
    chans = [c for c in (*OVERVIEW_STATES, *OVERVIEW_INPUTS) if trial.has(c)]
    if not chans:
        raise ReportError(f"segment review: trial {trial.name!r} has none of the channels "
                          f"{list(OVERVIEW_STATES + OVERVIEW_INPUTS)}")
    t = trial.t
    step = max(1, int(math.ceil(t.size / MAX_POINTS)))
    fig = make_subplots(rows=len(chans), cols=1, shared_xaxes=True, vertical_spacing=0.02)
    for i, ch in enumerate(chans, start=1):
        factor, unit, _ = display_scale(ch)
        y = trial.data[ch].to_numpy(dtype=float)[::step] * factor
        fig.add_trace(go.Scattergl(x=t[::step], y=y, mode="lines", name=ch, line={"width": 1},
                                   hovertemplate=f"{ch} = %{{y:.4g}} {unit}<br>t = %{{x:.2f}} s<extra></extra>"),
                      row=i, col=1)
        fig.update_yaxes(title_text=f"{ch} [{unit or '-'}]", row=i, col=1)
        lo, hi = float(np.nanmin(y)) if np.isfinite(y).any() else 0.0, float(np.nanmax(y)) if np.isfinite(y).any() else 1.0
        for k, seg in enumerate(segments.items):
            fig.add_vrect(x0=seg.t_start, x1=seg.t_end, fillcolor=f"hsl({(37 * k) % 360},70%,60%)", opacity=0.18,
                          line_width=0, row=i, col=1)
            # An invisible marker band carries the hover text (shapes have none).
            fig.add_trace(go.Scatter(x=[0.5 * (seg.t_start + seg.t_end)], y=[0.5 * (lo + hi)], mode="markers+text",
                                     text=[str(k)] if i == 1 else None, textposition="top center",
                                     marker={"size": 14, "opacity": 0.35}, showlegend=False,
                                     hovertext=[_hover(k, seg, fits)], hoverinfo="text"), row=i, col=1)
    fig.update_xaxes(title_text="time from trial start [s]", row=len(chans), col=1)
    fig.update_layout(height=180 * len(chans) + 120, title=f"Segments of {trial.name}: hover a number for details",
                      margin={"l": 70, "r": 20, "t": 60, "b": 50}, hovermode="closest")
    body = fig.to_html(full_html=False, include_plotlyjs=True)
    data = urllib.parse.quote(json.dumps(segments_json, indent=2, allow_nan=False))
    link = (f'<p><a download="segments.json" href="data:application/json;charset=utf-8,{data}">Download '
            f"segments.json</a> (edit it, then <code>vesselid fit --segments segments.json</code> or "
            f"<code>vesselid report --segments segments.json</code>).</p>")
    title = html.escape(f"vesselid segment review: {trial.name}")
    return (f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n<title>{title}</title>\n</head>\n'
            f"<body>\n<h1>{title}</h1>\n{link}\n{body}\n</body>\n</html>\n")
