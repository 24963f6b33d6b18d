"""``report.html``: one self-contained page (inline CSS; figures embedded as data URIs by
:func:`embed_images`, the same PNGs also beside it in the folder).

Layout: a summary (``id="summary"``, before any other table) with the damping diagonal, Nomoto K
and T, the model structure and the diagnosis headline; a table of contents; warnings apart from
notes; then the sections in flow order (data, segments, coefficients, fit quality, autopilot,
diagnosis); a footer with version, date, command and input hashes.

Every text that comes from data (vessel name, messages, labels, captions) is escaped with
:func:`html.escape`; only the ``extra_sections`` fragments that other stages pass in are inserted
as HTML, since producing HTML is their job.
"""

from __future__ import annotations

import base64
import datetime
import html
import re
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..errors import ReportError
from ..records import DOFS, Fits, Provenance, Segment, Trial
from ..text_format import esc
from .rows import (Markup, check_fits, checked_matrices, coefficient_rows, finite, format_uncertain, note_labels,
                   render_ci, render_number, render_unit)
from .summary import SummaryRow, method_key, method_label
from .tables import GREEK

_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; margin: 1em auto;
       max-width: 1100px; padding: 0 1em; color: #222; line-height: 1.4; }
h1 { border-bottom: 2px solid #345; padding-bottom: .1em; margin: .2em 0 .4em; font-size: 1.5em; }
.tw { overflow-x: auto; max-width: 100%; }
#summary { background: #f4f6f8; border: 1px solid #cdd5dd; padding: .3em .8em; }
#summary h2 { margin: .2em 0; border: none; font-size: 1.15em; }
#summary table { margin: .3em 0; font-size: .88em; }
#summary td, #summary th { padding: .12em .6em; }
.flag { color: #a33; font-weight: 600; }
.headline { margin: .3em 0; }
nav.toc ol { columns: 3; margin: .3em 0; font-size: .9em; }
ul.warnings li { color: #8a3b00; }
details { margin: .4em 0; }
details > summary { cursor: pointer; }
footer { margin-top: 3em; border-top: 1px solid #ccc; font-size: .8em; color: #555; overflow-wrap: anywhere; }
.methods { font-size: .85em; color: #333; }
h2 { margin-top: 2em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 1em 0; font-size: .92em; }
caption { caption-side: top; text-align: left; padding-bottom: .4em; font-size: .92em; color: #333; }
th, td { padding: .25em .7em; text-align: left; vertical-align: top; }
thead th { border-top: 2px solid #222; border-bottom: 1px solid #222; }
tbody tr:last-child td { border-bottom: 2px solid #222; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
td.na { color: #a33; }
.convention { background: #f4f6f8; border-left: 4px solid #345; padding: .5em 1em; }
.notes { font-size: .88em; color: #444; }
figure { margin: 1.5em 0; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: .9em; color: #333; }
pre { background: #f7f7f7; padding: .5em; overflow-x: auto; font-size: .85em; }
"""


def _html_symbol(name: str) -> str:
    """``X_u`` -> ``X<sub>u</sub>``; Nomoto K and T named; anything else escaped as is."""
    if name == "K_nomoto":
        return "<i>K</i> (Nomoto)"
    if name == "T_nomoto":
        return "<i>T</i> (Nomoto)"
    head, sep, sub = name.partition("_")
    if sep and re.fullmatch(r"[A-Za-z]", head) and (re.fullmatch(r"[A-Za-z0-9]+", sub) or sub in GREEK):
        sub_txt = f"&{sub};" if sub in GREEK else esc(sub)
        return f"<i>{esc(head)}</i><sub>{sub_txt}</sub>"
    return esc(name)


#: Numbers and units in HTML (escaped; narrow spaces as ``&nbsp;``).
HTML_MARKUP = Markup(pm=" ± ", power=lambda e: f"×10<sup>{e}</sup>", math=lambda s: s,
                     superscript=lambda p: f"<sup>{p}</sup>", text=lambda p: esc(p).replace(" ", "&nbsp;"))


def method_footnotes(fits: Fits) -> dict[str, int]:
    """Footnote number of each distinct method (segment counts left out), in table order.

    Parameters
    ----------
    fits : Fits
        Fit results.
    """
    out: dict[str, int] = {}
    for row in coefficient_rows(fits):
        if row.method:
            out.setdefault(method_key(row.method), len(out) + 1)
    return out


def coefficient_table_html(fits: Fits, added_mass: Mapping[str, float] | None = None) -> str:
    """The coefficient table (same content as ``tab:coefficients``), lettered notes, numbered methods.

    Each method is written once, as a footnote; a row shows its short name and number.

    Parameters
    ----------
    fits : Fits
        Fit results.
    added_mass : Mapping[str, float], optional
        The vessel config's ``[added_mass]`` (a derivative of a DOF without one gets a note).

    Returns
    -------
    str
        HTML fragment.
    """
    check_fits(fits)
    rows = coefficient_rows(fits, added_mass)
    labels = note_labels(rows)
    methods = method_footnotes(fits)
    out = ['<table class="coefficients" id="coefficient-table">',
           f"<caption>Identified hydrodynamic coefficients of {esc(fits.vessel)}, SI units as listed per "
           f"row, with standard errors and 95&nbsp;% confidence intervals. Sign convention: "
           f"{esc(fits.convention)} Letters: notes; numbers: methods, below.</caption>",
           "<thead><tr><th>Coefficient</th><th>Value ± std. error</th><th>95&nbsp;% CI</th><th>Unit</th>"
           "<th>Segments</th><th>Method</th></tr></thead>", "<tbody>"]
    for row in rows:
        marks = "".join(f"<sup>{labels[n]}</sup>" for n in row.notes)
        if row.method:
            k = methods[method_key(row.method)]
            method = f'{esc(method_label(row.method))}&nbsp;<a href="#method-{k}">[{k}]</a>'
        else:
            method = "--"
        if row.identified:
            num = render_number(row.number, HTML_MARKUP) + (" ± n/a" if row.number.stderr is None else "")
            cells = f'<td class="num">{num}{marks}</td><td class="num">{render_ci(row.number, HTML_MARKUP)}</td>'
        else:
            cells = f'<td class="na" colspan="2">not identified{marks}</td>'
        out.append(f"<tr><td>{_html_symbol(row.name)}</td>{cells}<td>{render_unit(row.unit, HTML_MARKUP)}</td>"
                   f'<td class="num">{row.n_segments}</td><td>{method}</td></tr>')
    out.append("</tbody></table>")
    if labels:
        out.append('<details class="notes"><summary>Notes a&ndash;' + esc(list(labels.values())[-1])
                   + '</summary><ol type="a">')
        out += [f"<li>{esc(note)}</li>" for note in labels]
        out.append("</ol></details>")
    if methods:
        out.append('<div class="methods"><p><b>Methods</b></p><ol>')
        out += [f'<li id="method-{k}">{esc(text)}</li>' for text, k in methods.items()]
        out.append("</ol></div>")
    return "\n".join(out)


def damping_table_html(fits: Fits) -> str:
    """The 5x5 damping matrix D with standard errors, ``--`` where not identified.

    Parameters
    ----------
    fits : Fits
        Fit results.

    Returns
    -------
    str
        HTML fragment.
    """
    D, D_se = checked_matrices(fits)
    out = ['<table class="damping" id="damping-matrix">',
           f"<caption>Linear damping matrix <i>D</i> of {esc(fits.vessel)} in M&nbsp;ν̇ + D&nbsp;ν = τ; rows "
           f"force/moment, columns velocity, DOF order {esc(', '.join(DOFS))}; D<sub>ij</sub> is minus the "
           f"hydrodynamic derivative (positive diagonal). Units: kg/s (force per speed), kg&nbsp;m/s "
           f"(force per rate, moment per speed), kg&nbsp;m<sup>2</sup>/s (moment per rate). "
           f"-- : not identified; an entry without ± has no standard error.</caption>",
           "<thead><tr><th><i>D</i></th>" + "".join(f"<th>{d}</th>" for d in DOFS) + "</tr></thead>",
           "<tbody>"]
    for i, dof in enumerate(DOFS):
        cells = []
        for j in range(len(DOFS)):
            if finite(D[i, j]):
                cells.append(f'<td class="num">{render_number(format_uncertain(D[i, j], D_se[i, j]), HTML_MARKUP)}</td>')
            else:
                cells.append('<td class="num">--</td>')
        out.append(f"<tr><th>{dof}</th>{''.join(cells)}</tr>")
    out.append("</tbody></table>")
    return "\n".join(out)


def segment_table_html(segments: Sequence[Segment]) -> str:
    """Table of segments: number, kind, DOF, start, end, duration, input, quality, origin, label.

    Parameters
    ----------
    segments : sequence of Segment
        Segments in display order; times [s, trial clock].

    Returns
    -------
    str
        HTML fragment.
    """
    if not segments:
        return "<p>No segments.</p>"
    out = ['<table class="segments" id="segment-table">',
           "<caption>Segments (numbers as in the trial overview figure); times on the trial clock.</caption>",
           "<thead><tr><th>#</th><th>Kind</th><th>DOF</th><th>Start [s]</th><th>End [s]</th>"
           "<th>Duration [s]</th><th>Input</th><th>Quality</th><th>Origin</th><th>Label</th></tr></thead>",
           "<tbody>"]
    for k, s in enumerate(segments):
        inp = "--" if s.input_channel is None else (
            f"{s.input_channel}: {s.input_before:.4g} → {s.input_after:.4g}")
        quality = f"{s.quality:.2f}" if finite(s.quality) else "n/a"
        out.append(f"<tr><td class=\"num\">{k}</td><td>{esc(s.kind)}</td><td>{esc(s.dof)}</td>"
                   f'<td class="num">{s.t_start:.2f}</td><td class="num">{s.t_end:.2f}</td>'
                   f'<td class="num">{s.duration:.2f}</td><td>{esc(inp)}</td><td class="num">{quality}</td>'
                   f"<td>{esc(s.origin)}</td><td>{esc(s.label)}</td></tr>")
    out.append("</tbody></table>")
    return "\n".join(out)


def _utc_text(unix_s: float) -> str:
    """ISO 8601 UTC of a Unix time [s], to the millisecond."""
    return datetime.datetime.fromtimestamp(unix_s, datetime.timezone.utc).isoformat(timespec="milliseconds")


def _time_of_day_text(seconds: float) -> str:
    """``hh:mm:ss.sss`` UTC of a time of day [s after midnight]."""
    h, rem = divmod(float(seconds), 3600.0)
    m, sec = divmod(rem, 60.0)
    return f"{int(h):02d}:{int(m):02d}:{sec:06.3f} UTC (date unknown)"


def runs_table_html(trial: Trial) -> str:
    """The runs of a trial: files and their clock offsets, span on the trial clock, start, why grouped so.

    Parameters
    ----------
    trial : Trial
        The aligned trial; a Trial built without runs is one run over all its data
        (:meth:`pipeline.records.Trial.run_list`).

    Returns
    -------
    str
        HTML fragment: one row per run, in trial-clock order (its number is ``Segment.run``).
    """
    runs = trial.run_list()
    out = ['<table class="runs" id="runs-table">',
           f"<caption>{len(runs)} run(s): the recordings of the trial, each on its own clock; the runs lie one "
           "after another on the trial clock with a gap between them, and no segment or replay crosses from one "
           "to the next. Clock offset: added to the file's times to put it on the run's clock (± its standard "
           "error).</caption>",
           "<thead><tr><th>#</th><th>Run</th><th>Files (clock offset [s])</th><th>Start [s]</th><th>End [s]</th>"
           "<th>Duration [s]</th><th>Absolute start</th><th>Why grouped so</th></tr></thead>", "<tbody>"]
    for k, run in enumerate(runs):
        files = "<br>".join(
            f"{esc(src)} ({run.offsets.get(src, 0.0):+.3f} ± {run.offset_stderr.get(src, 0.0):.2g})"
            for src in run.sources) or "--"
        if finite(run.start_time):
            when = _utc_text(run.start_time)
        elif finite(run.time_of_day):
            when = _time_of_day_text(run.time_of_day)
        else:
            when = "unknown (no absolute clock)"
        out.append(f'<tr><td class="num">{k}</td><td>{esc(run.name)}</td><td>{files}</td>'
                   f'<td class="num">{run.t_start:.2f}</td><td class="num">{run.t_end:.2f}</td>'
                   f'<td class="num">{run.duration:.2f}</td><td>{esc(when)}</td><td>{esc(run.reason)}</td></tr>')
    out.append("</tbody></table>")
    return "\n".join(out)


def trial_section_html(trial: Trial) -> str:
    """Where the data came from: runs, sources, sample rate, gaps, aligner notes, reader summaries.

    Parameters
    ----------
    trial : Trial
        The aligned trial.

    Returns
    -------
    str
        HTML fragment.
    """
    out = [f"<p>Trial <b>{esc(trial.name)}</b>, {len(trial.data)} samples at {trial.fs:g} Hz.</p>",
           runs_table_html(trial)]
    if trial.sources:
        out.append("<p>Sources:</p><ul>" + "".join(f"<li>{esc(s)}</li>" for s in trial.sources) + "</ul>")
    if trial.gaps:
        out.append("<p>Data gaps:</p><ul>" + "".join(
            f"<li>{esc(g.channel)}: {g.t_start:.2f}-{g.t_end:.2f} s</li>" for g in trial.gaps) + "</ul>")
    if trial.notes:
        out.append("<p>Alignment notes:</p><ul>" + "".join(f"<li>{esc(n)}</li>" for n in trial.notes) + "</ul>")
    if trial.summaries:
        out.append("<pre>" + esc("\n".join(s.text() for s in trial.summaries)) + "</pre>")
    return "\n".join(out)


def check_extra_sections(extra_sections) -> tuple[tuple[str, str], ...]:
    """Validate the sections other stages append to the report.

    Parameters
    ----------
    extra_sections : sequence of (str, str)
        ``(title, html_fragment)`` pairs; None means none.

    Returns
    -------
    tuple[tuple[str, str], ...]
        The pairs as tuples.

    Raises
    ------
    ReportError
        When an item is not a pair of strings, naming its position and what it was.
    """
    if isinstance(extra_sections, (str, bytes)):
        raise ReportError("extra_sections: expected a sequence of (title, html_fragment) pairs, found a string")
    out = []
    for k, item in enumerate(extra_sections or ()):
        if not (isinstance(item, (tuple, list)) and len(item) == 2
                and isinstance(item[0], str) and isinstance(item[1], str)):
            raise ReportError(f"extra_sections[{k}]: expected a (title, html_fragment) pair of strings, "
                              f"found {type(item).__name__} {item!r:.80}")
        out.append((item[0], item[1]))
    return tuple(out)


def summary_html(rows: Sequence[SummaryRow], headline: str = "", n_warnings: int = 0) -> str:
    """The summary block (``id="summary"``): key numbers with CI and flags, and the diagnosis headline.

    Parameters
    ----------
    rows : Sequence[SummaryRow]
        From :func:`pipeline.report.summary.summary_rows`.
    headline : str
        The diagnosis in one sentence (empty: no diagnosis).
    n_warnings : int
        Warnings listed further down (linked).
    """
    out = ['<section id="summary"><h2>Summary</h2>',
           '<table class="summary"><thead><tr><th>Quantity</th><th>Value ± std. error</th><th>95&nbsp;% CI</th>'
           "<th>Unit</th><th>Flags</th></tr></thead><tbody>"]
    for r in rows:
        flags = "; ".join(esc(f) for f in r.flags)
        if r.name:
            out.append(f"<tr><td>{esc(r.label)}</td><td class=\"num\">{esc(r.value)}</td>"
                       f"<td class=\"num\">{esc(r.ci)}</td><td>{render_unit(r.unit, HTML_MARKUP)}</td>"
                       f'<td class="flag">{flags}</td></tr>')
        else:
            out.append(f'<tr><td>{esc(r.label)}</td><td colspan="4">{esc(r.value)}</td></tr>')
    out.append("</tbody></table>")
    if headline:
        out.append(f'<p class="headline"><b>Sim-to-real gap:</b> {esc(headline)} '
                   f'<a href="#sec-sim-to-real-gap">details</a></p>')
    if n_warnings:
        out.append(f'<p class="headline flag"><a href="#warnings">{n_warnings} warning'
                   f'{"s" if n_warnings != 1 else ""}</a> need attention.</p>')
    out.append("</section>")
    return "\n".join(out)


def quality_table_html(fits: Fits, qualities: Sequence) -> str:
    """Per-segment fit quality: MATLAB ``compare`` fit %, RMSE, whiteness and input independence.

    Parameters
    ----------
    fits : Fits
        Fit results.
    qualities : Sequence[SegmentQuality]
        One per segment fit.
    """
    out = ['<table class="quality" id="quality-table"><caption>Fit quality per segment: fit % = 100 (1 - '
           '||y - y<sub>fit</sub>|| / ||y - mean y||) as MATLAB <i>compare</i>; residual tests as MATLAB '
           '<i>resid</i> (Ljung-Box whiteness, prewhitened input cross-correlation, significance 1&nbsp;%).'
           '</caption><thead><tr><th>Fit</th><th>Segment</th><th>Model</th><th>Channel</th><th>Fit %</th>'
           "<th>RMSE</th><th>White (p)</th><th>Input-independent (p)</th></tr></thead><tbody>"]
    for i, (sf, q) in enumerate(zip(fits.segment_fits, qualities)):
        seg = sf.segment
        pct = f"{q.fit_percent:.1f}" if finite(q.fit_percent) else "n/a"
        rmse = f"{sf.rmse:.3g}" if finite(sf.rmse) else "n/a"
        if q.resid is None:
            white = indep = f"not tested: {esc(q.message)}"
        else:
            white = ("yes" if q.resid.white else '<span class="flag">no</span>') + \
                f" ({q.resid.ljung_box_p:.2g})"
            if q.resid.cross_p:
                p = min(q.resid.cross_p.values())
                indep = ("yes" if q.resid.independent else '<span class="flag">no</span>') + f" ({p:.2g})"
            else:
                indep = "constant input"
        status = "" if sf.success else ' <span class="flag">failed</span>'
        out.append(f'<tr><td class="num"><a href="#fit-{i}">{i}</a></td><td>{esc(seg.kind)}/{esc(seg.dof)} '
                   f"{seg.t_start:.1f}-{seg.t_end:.1f}&nbsp;s{status}</td><td>{esc(sf.model)}</td>"
                   f'<td>{esc(sf.channel)}</td><td class="num">{pct}</td><td class="num">{rmse}</td>'
                   f"<td>{white}</td><td>{indep}</td></tr>")
    out.append("</tbody></table>")
    return "\n".join(out)


def correlation_table_html(names: Sequence[str], corr: np.ndarray, caption: str) -> str:
    """A parameter correlation matrix; ``|rho| > 0.9`` marked (nearly unidentifiable apart).

    Parameters
    ----------
    names : Sequence[str]
        Parameter names, in matrix order.
    corr : numpy.ndarray
        Correlation matrix [-].
    caption : str
        Table caption (plain text).
    """
    if corr.size == 0 or corr.shape[0] != len(names):
        return f"<p>{esc(caption)}: no covariance available.</p>"
    head = "".join(f"<th>{esc(n)}</th>" for n in names)
    rows = []
    for i, n in enumerate(names):
        cells = []
        for j in range(len(names)):
            x = corr[i, j]
            txt = f"{x:.2f}" if finite(x) else "n/a"
            cls = ' class="num flag"' if (i != j and finite(x) and abs(x) > 0.9) else ' class="num"'
            cells.append(f"<td{cls}>{txt}</td>")
        rows.append(f"<tr><th>{esc(n)}</th>{''.join(cells)}</tr>")
    return (f'<table class="correlation"><caption>{esc(caption)} (|&rho;| &gt; 0.9 marked).</caption>'
            f"<thead><tr><th></th>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>")


def footer_html(provenance: Provenance | None) -> str:
    """Footer: version, date, command and the SHA-256 of every input file.

    Parameters
    ----------
    provenance : Provenance or None
        None: the version alone.
    """
    from .. import __version__

    if provenance is None:
        return f"<footer><p>vesselid {esc(__version__)}</p></footer>"
    files = "".join(f"<li><code>{esc(h[:16]) or 'unreadable'}</code>&hellip; {esc(p)}</li>"
                    for p, h in provenance.inputs)
    return (f"<footer><p>{esc(provenance.version)} &middot; created {esc(provenance.created)} &middot; "
            f"command: <code>{esc(provenance.command)}</code></p>"
            + (f"<p>Inputs (SHA-256, first 16 hex digits):</p><ul>{files}</ul>" if files else "") + "</footer>")


def slug(title: str) -> str:
    """Anchor id of a section title: ``Sim-to-real gap`` -> ``sec-sim-to-real-gap``.

    Parameters
    ----------
    title : str
        Section title.
    """
    return "sec-" + (re.sub(r"[^a-z0-9]+", "-", title.lower()).strip("-") or "x")


def render_html(fits: Fits, figures: Sequence[tuple[str, str]] = (), segments: Sequence[Segment] = (),
                warnings: Sequence[str] = (), trial: Trial | None = None,
                extra_sections: Sequence[tuple[str, str]] = (), *, summary: Sequence[SummaryRow] = (),
                headline: str = "", notes: Sequence[str] = (), qualities: Sequence = (),
                fit_figures: Sequence[tuple[str, str | None]] = (), overview: str | None = None,
                added_mass: Mapping[str, float] | None = None, provenance: Provenance | None = None) -> str:
    """The whole report page (figures as relative links; :func:`embed_images` inlines them).

    Parameters
    ----------
    fits : Fits
        Fit results.
    figures : sequence of (str, str)
        Further ``(file name relative to the page, caption)`` figures, shown in a Figures section.
    segments : sequence of Segment
        Segments for the segment table.
    warnings : sequence of str
        Plain-text warnings: things a user must act on (escaped here).
    trial : Trial, optional
        Adds a data-provenance section.
    extra_sections : sequence of (str, str)
        ``(title, html_fragment)`` from the later stages, in flow order; the title is escaped, the
        fragment is not.
    summary : sequence of SummaryRow
        Rows of the summary block.
    headline : str
        Diagnosis headline for the summary.
    notes : sequence of str
        Plain-text notes (information).
    qualities : sequence of SegmentQuality
        One per segment fit (fit %, residual test, parameter correlation).
    fit_figures : sequence of (str, str or None)
        Per segment fit: fit figure and residual-analysis figure file names (None: none).
    overview : str, optional
        Trial overview figure file name.
    added_mass : Mapping[str, float], optional
        The vessel config's ``[added_mass]``, for the table notes.
    provenance : Provenance, optional
        Footer content.

    Returns
    -------
    str
        A complete HTML5 document.
    """
    extra = check_extra_sections(extra_sections)
    title = f"vesselid report: {fits.vessel}"
    sections: list[tuple[str, str]] = []
    warn = ('<ul class="warnings">' + "".join(f"<li>{esc(w)}</li>" for w in warnings) + "</ul>") if warnings \
        else "<p>No warnings: every coefficient was identified with an error bar and white residuals.</p>"
    if notes:
        warn += (f"<details><summary>{len(notes)} notes (information, nothing to act on)</summary><ul>"
                 + "".join(f"<li>{esc(n)}</li>" for n in notes) + "</ul></details>")
    sections.append(("Warnings", warn))
    if trial is not None:
        sections.append(("Data", trial_section_html(trial)))
    seg_html = ""
    if overview:
        seg_html += (f'<figure><img src="{esc(overview)}" alt="trial overview with segments">'
                     f"<figcaption>The trial's main channels with the {len(segments)} segments shaded and numbered "
                     f"as in the table; angles in degrees.</figcaption></figure>")
    sections.append(("Segments", seg_html + segment_table_html(segments)))
    sections.append(("Coefficients", coefficient_table_html(fits, added_mass)
                     + "<h3>Damping matrix</h3>" + damping_table_html(fits)))
    q_parts = [quality_table_html(fits, qualities)] if qualities else []
    n_drawn = sum(1 for fig, _ in fit_figures if fig)
    if fit_figures and n_drawn < len(fits.segment_fits):
        q_parts.append(f"<p>Figures for {n_drawn} of the {len(fits.segment_fits)} segment fits: the failed fits, "
                       "then the worst and the best fit % of each segment kind, DOF and channel in turn; every "
                       "fit is in the table above.</p>")
    for i, sf in enumerate(fits.segment_fits):
        fig, res = fit_figures[i] if i < len(fit_figures) else (None, None)
        q = qualities[i] if i < len(qualities) else None
        inner = []
        if fig:
            inner.append(f'<img src="{esc(fig)}" alt="fit {i}: data, fit and residual">')
        if res:
            inner.append(f'<img src="{esc(res)}" alt="fit {i}: residual autocorrelation and input '
                         f'cross-correlation with 95 % bands">')
        if q is not None and len(sf.param_names) > 1:
            inner.append(correlation_table_html(sf.param_names, q.correlation,
                                                f"fit {i}: parameter correlation"))
        pct = f", fit {q.fit_percent:.1f} %" if q is not None and finite(q.fit_percent) else ""
        seg = sf.segment
        q_parts.append(f'<details id="fit-{i}"><summary>fit {i}: {esc(seg.kind)}/{esc(seg.dof)}, '
                       f"{seg.t_start:.1f}-{seg.t_end:.1f} s, {esc(sf.model)} on {esc(sf.channel)}{pct}"
                       f"</summary>{''.join(inner)}</details>")
    cov = getattr(fits, "covariance", None)
    names = getattr(fits, "covariance_names", None)
    if cov is not None and names:
        q_parts.append(correlation_table_html(list(names), _corr(cov), "Correlation of the coefficients"))
    sections.append(("Fit quality", "\n".join(q_parts) or "<p>No segment fits.</p>"))
    sections.extend(extra)
    if figures:
        sections.append(("Figures", "\n".join(
            f'<figure><img src="{esc(src)}" alt="{esc(cap)}"><figcaption>{esc(cap)}</figcaption></figure>'
            for src, cap in figures)))
    toc = '<nav class="toc"><b>Contents</b><ol>' + "".join(
        f'<li><a href="#{slug(t)}">{esc(t)}</a></li>' for t, _ in sections) + "</ol></nav>"
    body = [f"<h1>{esc(title)}</h1>", summary_html(summary, headline, len(warnings)), toc]
    for k, (sec_title, fragment) in enumerate(sections):
        anchor = "warnings" if sec_title == "Warnings" else slug(sec_title)
        body.append(f'<section id="{anchor}"><h2 id="{slug(sec_title)}">{esc(sec_title)}</h2>\n{fragment}\n</section>'
                    if anchor != slug(sec_title) else
                    f'<section id="{anchor}"><h2>{esc(sec_title)}</h2>\n{fragment}\n</section>')
    body.append(f'<p class="convention"><b>Convention.</b> {esc(fits.convention)}</p>')
    body.append(footer_html(provenance))
    page = "\n".join(body)
    page = re.sub(r"(<table\b.*?</table>)", r'<div class="tw">\1</div>', page, flags=re.S)
    return ("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
            f"<title>{esc(title)}</title>\n<style>{_CSS}</style>\n</head>\n<body>\n"
            + page + "\n</body>\n</html>\n")


def _corr(cov) -> np.ndarray:
    from .quality import correlation_matrix

    return correlation_matrix(np.asarray(cov, float))


_SRC = re.compile(r'(<img\b[^>]*?\bsrc=")([^"]+)(")')


def embed_images(page: str, folder: str | Path) -> str:
    """Replace every ``<img src="file.png">`` that names a PNG in ``folder`` by a base64 data URI.

    Parameters
    ----------
    page : str
        HTML text.
    folder : str or Path
        The folder the relative names refer to.

    Returns
    -------
    str
        The page, self-contained; a name with no file beside it is left as it is (and a browser
        test finds it broken).
    """
    folder = Path(folder)

    def repl(m: re.Match) -> str:
        src = html.unescape(m.group(2))
        if src.startswith("data:") or "/" in src or "\\" in src:
            return m.group(0)
        path = folder / src
        if not (src.lower().endswith(".png") and path.is_file()):
            return m.group(0)
        data = base64.b64encode(path.read_bytes()).decode("ascii")
        return f"{m.group(1)}data:image/png;base64,{data}{m.group(3)}"

    return _SRC.sub(repl, page)
