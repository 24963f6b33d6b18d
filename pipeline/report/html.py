"""``report.html``: one self-contained page (inline CSS, figures as relative links in the same folder).

Every text that comes from data (vessel name, messages, labels, captions) is escaped with
:func:`html.escape`; only the ``extra_sections`` fragments that other stages pass in are inserted
as HTML, since producing HTML is their job.
"""

from __future__ import annotations

import html
import re
from typing import Sequence

from ..errors import ReportError
from ..records import DOFS, Fits, Segment, Trial
from ._common import Formatted, check_fits, checked_matrices, coefficient_rows, finite, format_uncertain, \
    note_labels
from .tables import GREEK

_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; margin: 2em auto;
       max-width: 1100px; padding: 0 1em; color: #222; line-height: 1.45; }
h1 { border-bottom: 2px solid #345; padding-bottom: .2em; }
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
ul.warnings li { color: #8a3b00; }
figure { margin: 1.5em 0; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: .9em; color: #333; }
pre { background: #f7f7f7; padding: .5em; overflow-x: auto; font-size: .85em; }
"""


def _esc(text) -> str:
    """``html.escape`` of ``str(text)``, quotes included."""
    return html.escape(str(text), quote=True)


def _html_symbol(name: str) -> str:
    """``X_u`` -> ``X<sub>u</sub>``; Nomoto K and T named; anything else escaped as is."""
    if name == "K_nomoto":
        return "<i>K</i> (Nomoto)"
    if name == "T_nomoto":
        return "<i>T</i> (Nomoto)"
    head, sep, sub = name.partition("_")
    if sep and re.fullmatch(r"[A-Za-z]", head) and (re.fullmatch(r"[A-Za-z0-9]+", sub) or sub in GREEK):
        sub_txt = f"&{sub};" if sub in GREEK else _esc(sub)
        return f"<i>{_esc(head)}</i><sub>{sub_txt}</sub>"
    return _esc(name)


def _html_unit(unit: str) -> str:
    """``kg m^2/s`` -> ``kg&nbsp;m<sup>2</sup>/s``, escaped."""
    pieces = re.split(r"\^(-?\d+)", str(unit))
    return "".join(f"<sup>{p}</sup>" if k % 2 else _esc(p).replace(" ", "&nbsp;") for k, p in enumerate(pieces))


def _html_number(f: Formatted) -> str:
    """``-2.860 ± 0.030`` or ``(1.23 ± 0.05)×10<sup>5</sup>``, escaped."""
    core = f"{f.value} ± {f.stderr}" if f.stderr is not None else f.value
    if f.exponent:
        core = (f"({core})" if f.stderr is not None else core)
        return _esc(core) + f"×10<sup>{f.exponent}</sup>"
    return _esc(core)


def _html_ci(f: Formatted | None) -> str:
    """``[lo, hi]`` or ``n/a``."""
    if f is None or f.ci is None:
        return "n/a"
    tail = f"×10<sup>{f.exponent}</sup>" if f.exponent else ""
    return _esc(f"[{f.ci[0]}, {f.ci[1]}]") + tail


def coefficient_table_html(fits: Fits) -> str:
    """The coefficient table (same content as ``tab:coefficients``) with its lettered notes.

    Parameters
    ----------
    fits : Fits
        Fit results.

    Returns
    -------
    str
        HTML fragment.
    """
    check_fits(fits)
    rows = coefficient_rows(fits)
    labels = note_labels(rows)
    out = ['<table class="coefficients" id="coefficient-table">',
           f"<caption>Identified hydrodynamic coefficients of {_esc(fits.vessel)}, SI units as listed per "
           f"row, with standard errors and 95&nbsp;% confidence intervals. Sign convention: "
           f"{_esc(fits.convention)}</caption>",
           "<thead><tr><th>Coefficient</th><th>Value ± std. error</th><th>95&nbsp;% CI</th><th>Unit</th>"
           "<th>Segments</th><th>Method</th></tr></thead>", "<tbody>"]
    for row in rows:
        marks = "".join(f"<sup>{labels[n]}</sup>" for n in row.notes)
        method = _esc(row.method) if row.method else "--"
        if row.identified:
            num = _html_number(row.number) + (" ± n/a" if row.number.stderr is None else "")
            cells = f'<td class="num">{num}{marks}</td><td class="num">{_html_ci(row.number)}</td>'
        else:
            cells = f'<td class="na" colspan="2">not identified{marks}</td>'
        out.append(f"<tr><td>{_html_symbol(row.name)}</td>{cells}<td>{_html_unit(row.unit)}</td>"
                   f'<td class="num">{row.n_segments}</td><td>{method}</td></tr>')
    out.append("</tbody></table>")
    if labels:
        out.append('<div class="notes"><ol type="a">')
        out += [f"<li>{_esc(note)}</li>" for note in labels]
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
           f"<caption>Linear damping matrix <i>D</i> of {_esc(fits.vessel)} in M&nbsp;ν̇ + D&nbsp;ν = τ; rows "
           f"force/moment, columns velocity, DOF order {_esc(', '.join(DOFS))}; D<sub>ij</sub> is minus the "
           f"hydrodynamic derivative (positive diagonal). Units: kg/s (force per speed), kg&nbsp;m/s "
           f"(force per rate, moment per speed), kg&nbsp;m<sup>2</sup>/s (moment per rate). "
           f"-- : not identified; an entry without ± has no standard error.</caption>",
           "<thead><tr><th><i>D</i></th>" + "".join(f"<th>{d}</th>" for d in DOFS) + "</tr></thead>",
           "<tbody>"]
    for i, dof in enumerate(DOFS):
        cells = []
        for j in range(len(DOFS)):
            if finite(D[i, j]):
                cells.append(f'<td class="num">{_html_number(format_uncertain(D[i, j], D_se[i, j]))}</td>')
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
        out.append(f"<tr><td class=\"num\">{k}</td><td>{_esc(s.kind)}</td><td>{_esc(s.dof)}</td>"
                   f'<td class="num">{s.t_start:.2f}</td><td class="num">{s.t_end:.2f}</td>'
                   f'<td class="num">{s.duration:.2f}</td><td>{_esc(inp)}</td><td class="num">{quality}</td>'
                   f"<td>{_esc(s.origin)}</td><td>{_esc(s.label)}</td></tr>")
    out.append("</tbody></table>")
    return "\n".join(out)


def trial_section_html(trial: Trial) -> str:
    """Where the data came from: sources, sample rate, gaps, aligner notes, reader summaries.

    Parameters
    ----------
    trial : Trial
        The aligned trial.

    Returns
    -------
    str
        HTML fragment.
    """
    out = [f"<p>Trial <b>{_esc(trial.name)}</b>, {len(trial.data)} samples at {trial.fs:g} Hz.</p>"]
    if trial.sources:
        out.append("<p>Sources:</p><ul>" + "".join(f"<li>{_esc(s)}</li>" for s in trial.sources) + "</ul>")
    if trial.gaps:
        out.append("<p>Data gaps:</p><ul>" + "".join(
            f"<li>{_esc(g.channel)}: {g.t_start:.2f}-{g.t_end:.2f} s</li>" for g in trial.gaps) + "</ul>")
    if trial.notes:
        out.append("<p>Alignment notes:</p><ul>" + "".join(f"<li>{_esc(n)}</li>" for n in trial.notes) + "</ul>")
    if trial.summaries:
        out.append("<pre>" + _esc("\n".join(s.text() for s in trial.summaries)) + "</pre>")
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


def render_html(fits: Fits, figures: Sequence[tuple[str, str]] = (), segments: Sequence[Segment] = (),
                warnings: Sequence[str] = (), trial: Trial | None = None,
                extra_sections: Sequence[tuple[str, str]] = ()) -> str:
    """The whole report page.

    Parameters
    ----------
    fits : Fits
        Fit results.
    figures : sequence of (str, str)
        ``(file name relative to the page, caption)`` per figure, in display order.
    segments : sequence of Segment
        Segments for the segment table.
    warnings : sequence of str
        Plain-text warnings (escaped here).
    trial : Trial, optional
        Adds a data-provenance section.
    extra_sections : sequence of (str, str)
        ``(title, html_fragment)`` from other stages; the title is escaped, the fragment is not.

    Returns
    -------
    str
        A complete HTML5 document.
    """
    extra = check_extra_sections(extra_sections)
    title = f"vesselid report: {fits.vessel}"
    body = [f"<h1>{_esc(title)}</h1>",
            f'<p class="convention"><b>Convention.</b> {_esc(fits.convention)}</p>',
            '<h2 id="coefficients">Coefficients</h2>', coefficient_table_html(fits),
            '<h2 id="damping">Damping matrix</h2>', damping_table_html(fits),
            '<h2 id="warnings">Warnings</h2>']
    if warnings:
        body.append('<ul class="warnings">' + "".join(f"<li>{_esc(w)}</li>" for w in warnings) + "</ul>")
    else:
        body.append("<p>No warnings: every coefficient was identified with an error bar.</p>")
    body += ['<h2 id="segments">Segments</h2>', segment_table_html(segments)]
    if trial is not None:
        body += ['<h2 id="data">Data</h2>', trial_section_html(trial)]
    if figures:
        body.append('<h2 id="figures">Figures</h2>')
        for k, (src, caption) in enumerate(figures, start=1):
            body.append(f'<figure id="figure-{k}"><img src="{_esc(src)}" alt="{_esc(caption)}">'
                        f"<figcaption>Figure {k}: {_esc(caption)}</figcaption></figure>")
    for k, (sec_title, fragment) in enumerate(extra):
        body.append(f'<section id="extra-{k}"><h2>{_esc(sec_title)}</h2>\n{fragment}\n</section>')
    return ("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
            f"<title>{_esc(title)}</title>\n<style>{_CSS}</style>\n</head>\n<body>\n"
            + "\n".join(body) + "\n</body>\n</html>\n")
