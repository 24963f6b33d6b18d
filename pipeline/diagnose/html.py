"""The diagnosis' section of the HTML report: ``diagnose_html_section(report) -> (title, html)``.

Every text that comes from data is escaped; figures are referenced by the file names
:func:`pipeline.diagnose.figures.write_figures` writes into the same folder.
"""

from __future__ import annotations

import math
from typing import Mapping

from .figures import figure_names
from ..records import CandidateResult, EffectParam, GapReport
from ..text_format import esc as _e, number as _num

TITLE = "Sim-to-real gap"


def _param(p: EffectParam) -> str:
    se = f" &plusmn; {_num(p.stderr, '.2g')}" if math.isfinite(p.stderr) else ""
    unit = f" {_e(p.unit)}" if p.unit and p.unit != "-" else ""
    return f"{_e(p.name)} = {_num(p.value, '.4g')}{se}{unit}"


def _unexplained_html(report: GapReport) -> str:
    """The section's lead when a gap is left: what, where, what it looks like."""
    if not report.unexplained:
        return ""
    head = ("No effect of the library explains the gap: the model is not fine." if not report.effects else
            "A gap is left after the selected effects.")
    rows = "\n".join(
        f"<tr><td>{_e(u.dof)}</td><td>{_e(u.channel)}</td><td class=\"num\">{_num(u.gap)}</td>"
        f"<td class=\"num\">{_num(100 * u.share, '.0f')}</td><td>{_e(u.place or '-')}</td>"
        f"<td>{_e(u.band or '-')} (peak {_num(u.peak_omega)} rad/s)</td><td>{_e(u.looks_like)}</td></tr>"
        for u in report.unexplained)
    return (f"<div class=\"unexplained\" style=\"border-left:4px solid #c33;padding-left:8px\">"
            f"<p><b>Unexplained.</b> {_e(head)} Trial gap {_num(report.gap_before)} &rarr; "
            f"{_num(report.gap_final)} noise units (1 = sensor noise only).</p>"
            "<table><caption>Channels whose held-out gap stays above the noise ("
            f"{_e(report.unexplained_test)}).</caption><thead><tr><th>DOF</th><th>channel</th><th>gap</th>"
            "<th>share [%]</th><th>where</th><th>band</th><th>what it looks like</th></tr></thead>"
            f"<tbody>{rows}</tbody></table></div>")


def _verdict_text(report: GapReport) -> str:
    v = report.verdict
    if not report.effects or v is None:
        if report.unexplained:
            return ("<p><b>Verdict: none of the library's effects is significant.</b> This is not a clean bill: "
                    "the gap above is left unexplained.</p>")
        return (f"<p><b>Verdict: no effect.</b> No candidate improves the held-out gap beyond what noise alone "
                f"produces, and nothing is left above the noise (trial gap {_num(report.gap_before)} in units of the "
                f"sensor noise; 1 means only noise is left).</p>")
    items = []
    for e in report.effects:
        params = "; ".join(_param(p) for p in e.params) or "no parameter"
        items.append(f"<li><b>{_e(e.effect)} in {_e(e.dof)}</b>"
                     + (f" ({_e(e.input_channel)})" if e.input_channel else "")
                     + f": {_e(e.dof)} gap {_num(e.gap_before)} &rarr; {_num(e.gap_after)} "
                     f"({_num(e.shrink, '.1f')}% on top of the effects above), trial gap now "
                     f"{_num(e.trial_gap_after)}; p = {_num(e.p_value, '.2g')}; {params}."
                     + (f" <i>{_e(e.why)}</i>" if e.why else "") + "</li>")
    first = report.effects[0]
    return (f"<p><b>Verdict: {_e(first.effect)} in {_e(first.dof)}</b>. Effects selected in order "
            f"(forward selection, each held out and significance-tested on top of the ones before):</p>"
            f"<ol>{''.join(items)}</ol><p>Trial gap {_num(report.gap_before)} &rarr; {_num(report.gap_after)} with "
            f"the verdict alone, {_num(report.gap_final)} with every selected effect.</p>")


def _candidate_rows(cands: tuple[CandidateResult, ...]) -> str:
    rows = []
    for c in cands:
        cls = ' style="background:#e8f5e9"' if c.significant else ""
        rows.append(f"<tr{cls}><td>{_e(c.dof)}</td><td>{_e(c.label)}</td><td class=\"num\">{_num(c.gap_before)}</td>"
                    f"<td class=\"num\">{_num(c.gap_after)}</td><td class=\"num\">{_num(c.shrink, '.1f')}</td>"
                    f"<td class=\"num\">{_num(c.p_value, '.2g')}</td><td>{'yes' if c.significant else 'no'}</td>"
                    f"<td>{'; '.join(_param(p) for p in c.params)}</td></tr>")
    return "\n".join(rows)


def diagnose_html_section(report: GapReport, figures: Mapping[str, str] | None = None) -> tuple[str, str]:
    """The report section of a diagnosis.

    Parameters
    ----------
    report : GapReport
        The diagnosis.
    figures : Mapping[str, str], optional
        Figure key -> relative path; default the names :func:`pipeline.diagnose.figures.write_figures`
        uses in the report folder. Pass ``{}`` for a section without figures.

    Returns
    -------
    (str, str)
        Section title and HTML fragment.
    """
    figs = figure_names(report) if figures is None else dict(figures)
    parts = [p for p in (_unexplained_html(report), _verdict_text(report)) if p]
    parts.append(f"<p class=\"notes\">Ranking rule: {_e(report.ranking_rule)}.</p>")
    parts.append(
        "<p class=\"notes\">Gaps are held-out RMS errors of the open-loop simulation (every window predicted by a "
        "model fitted without it, re-initialised from the measured state at the window start), in units of each "
        "channel's sensor noise at the analysis step. A candidate is significant when, in at least one channel of "
        f"its DOF, its held-out F test gives p &lt; {_num(report.thresholds.get('alpha', math.nan), '.0e')} "
        f"(Bonferroni over the channels), it shrinks that channel's gap by at least "
        f"{_num(report.thresholds.get('min_shrink_percent', math.nan), '.0f')}% and explains at least "
        f"{_num(100 * report.thresholds.get('min_explained', math.nan), '.2g')}% of the channel's scale, and the "
        "DOF's gap does not grow (thresholds calibrated on clean simulated trials to at most 5% false verdicts).</p>")
    parts.append("<h3>Where</h3>")
    top = [p for p in report.places if p.share > 0][:12]
    if top:
        rows = "\n".join(f"<tr><td>{_e(p.dof)}</td><td>{_e(p.category)}</td><td>{_e(p.name)}</td>"
                         f"<td class=\"num\">{_num(100 * p.share, '.1f')}</td><td class=\"num\">{_num(p.gap)}</td></tr>"
                         for p in top)
        parts.append("<table><caption>Places holding the baseline's held-out gap above the noise, largest share "
                     "first (categories overlap: each splits the same gap another way).</caption><thead><tr>"
                     "<th>DOF</th><th>split</th><th>place</th><th>share [%]</th><th>gap</th></tr></thead><tbody>"
                     f"{rows}</tbody></table>")
    else:
        parts.append("<p>The baseline's held-out error is at the sensor noise everywhere.</p>")
    drows = "\n".join(
        f"<tr><td>{_e(d.dof)}</td><td>{_e(', '.join(d.channels))}</td><td>{_e(', '.join(d.inputs) or '-')}</td>"
        f"<td>{'; '.join(_param(p) for p in d.baseline)}</td><td class=\"num\">{_num(d.gap)}</td>"
        f"<td class=\"num\">{_num(d.replay_gap)}</td><td class=\"num\">{d.n_windows} / {d.n_folds}</td></tr>"
        for d in report.dofs)
    parts.append("<table><caption>Baselines (first-order output-error fits, T y' = -y + &Sigma; k u) with "
                 "jackknife errors over the folds; gap held out, replay gap over the whole trial from its start."
                 "</caption><thead><tr><th>DOF</th><th>channels</th><th>inputs</th><th>baseline</th><th>gap</th>"
                 f"<th>replay gap</th><th>windows / folds</th></tr></thead><tbody>{drows}</tbody></table>")
    parts.append("<h3>Which</h3>")
    parts.append("<table><caption>Candidate effects, refitted on training windows and scored on held-out ones "
                 "(significant rows shaded).</caption><thead><tr><th>DOF</th><th>candidate</th><th>gap before</th>"
                 "<th>gap after</th><th>shrink [%]</th><th>p</th><th>significant</th><th>effect parameters</th>"
                 f"</tr></thead><tbody>{_candidate_rows(report.candidates)}</tbody></table>")
    captions = {
        "where": "Where the baseline's held-out gap lives (shares of the excess over sensor noise).",
        "candidates": "Held-out shrink of each candidate; the dashed line is the smallest shrink that counts.",
        "spectra": "Spectra of the baseline's held-out residuals; the wave band is shaded.",
    }
    for key, path in figs.items():
        if key.startswith("overlay:"):
            captions[key] = f"How far: {key.split(':', 1)[1]}, held-out windows: measured, baseline, and with the effect."
        elif key.startswith("replay:"):
            captions[key] = f"{key.split(':', 1)[1]}: the baseline replayed over the whole trial from its start."
    for key, path in figs.items():
        parts.append(f"<figure><img src=\"{_e(path)}\" alt=\"{_e(captions.get(key, key))}\">"
                     f"<figcaption>{_e(captions.get(key, key))}</figcaption></figure>")
    if report.notes:
        parts.append("<ul class=\"notes\">" + "".join(f"<li>{_e(n)}</li>" for n in report.notes) + "</ul>")
    return TITLE, "\n".join(parts)
