"""What a reader needs in the first minute: the summary rows, the diagnosis headline, and the split
of everything doubtful into warnings (a user must act) and notes (information).

Also the checks of inputs that are wrong but parse: the damping from a step's gain (force over
speed) against the damping from its time constant and the configured mass, which disagree by the
unit factor when ``tau_x`` was logged in kN or the speed in km/h.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Mapping, Sequence

from ..records import Estimate, Fits
from .rows import (CONSISTENCY_ALPHA, STANDARD_COEFFICIENTS, damping_consistency, estimate_notes, finite,
                   format_number, format_uncertain, is_identified)

#: Damping-matrix diagonal in the summary: derivative, the DOF it belongs to.
SUMMARY_DAMPING: tuple[tuple[str, str], ...] = (("X_u", "surge"), ("Y_v", "sway"), ("K_p", "roll"),
                                                ("M_q", "pitch"), ("N_r", "yaw"))
#: Segment kinds whose residuals speak for the Nomoto K and T.
NOMOTO_KINDS = ("rudder_step", "zigzag", "sinusoid")
#: Gain-based over mass-based damping beyond this factor (either way) is an error, not a modelling
#: difference: added mass may make the mass-based value up to about 2x small, a unit slip makes it
#: 3.6x (km/h) or 1000x (kN).
GAIN_MASS_FACTOR = 3.0
#: Longest message shown on one line; the full text is in the JSON.
SHORT = 160


def reason(est: Estimate | None) -> str:
    """Why ``est`` is not identified, without a repeated "not identified:" prefix.

    Parameters
    ----------
    est : Estimate or None
        The estimate.
    """
    why = estimate_notes(est)[0] if est is not None else "not estimated by the fit stage"
    return re.sub(r"^(\s*not identified\s*[:;,-]?\s*)+", "", why, flags=re.I) or why


def shorten(text: str, limit: int = SHORT) -> str:
    """``text`` cut at a word boundary to ``limit`` characters, with ``...`` when cut.

    Parameters
    ----------
    text : str
        Any message.
    limit : int
        Longest result [characters].
    """
    text = " ".join(str(text).split())
    if len(text) <= limit:
        return text
    cut = text[:limit - 3].rsplit(" ", 1)[0]
    return cut.rstrip(",;:") + "..."


@dataclass(frozen=True)
class SummaryRow:
    """One line of the summary table.

    Attributes
    ----------
    label : str
        What it is (``D_uu = -X_u``).
    name : str
        Coefficient name (empty for the model-structure row).
    value, ci, unit : str
        Formatted value ``v ± se``, 95 % interval, unit.
    flags : tuple[str, ...]
        ``not identified``, ``residuals not white``, ...
    """

    label: str
    name: str
    value: str
    ci: str
    unit: str
    flags: tuple[str, ...] = ()


def _plain(est: Estimate, negate: bool = False) -> tuple[str, str]:
    s = -1.0 if negate else 1.0
    ci = est.ci95 if est.ci95 is not None else (math.nan, math.nan)
    lo, hi = sorted((s * float(ci[0]), s * float(ci[1]))) if all(finite(c) for c in ci) else (math.nan, math.nan)
    f = format_uncertain(s * float(est.value), est.stderr, (lo, hi))
    core = f"{f.value} ± {f.stderr}" if f.stderr is not None else f"{f.value} (no error bar)"
    cit = f"[{f.ci[0]}, {f.ci[1]}]" if f.ci else "n/a"
    if f.exponent:
        core, cit = f"({core})e{f.exponent}", f"{cit}e{f.exponent}"
    return core, cit


def not_white_dofs(fits: Fits, qualities: Sequence) -> dict[str, list[int]]:
    """DOF (and ``nomoto``) -> numbers of the segment fits whose residuals are not white.

    Parameters
    ----------
    fits : Fits
        Fit results.
    qualities : Sequence[SegmentQuality]
        One per ``fits.segment_fits`` (:func:`pipeline.report.quality.segment_quality`).
    """
    out: dict[str, list[int]] = {}
    for i, (sf, q) in enumerate(zip(fits.segment_fits, qualities)):
        if q.resid is None or q.resid.white:
            continue
        key = "nomoto" if sf.segment.kind in NOMOTO_KINDS else sf.segment.dof
        out.setdefault(key, []).append(i)
    return out


def model_structure(fits: Fits) -> str:
    """The selected model structure, in words, from which estimates were identified.

    Parameters
    ----------
    fits : Fits
        Fit results (reads optional additive estimates: quadratic damping ``X_uu``-style names,
        second-order Nomoto ``T1_nomoto``/``T2_nomoto``/``T3_nomoto`` or ``T1``/``T2``/``T3``).
    """
    est = fits.to_fit_result().params
    ident = {k for k, e in est.items() if is_identified(e)}
    parts = []
    coupled = [k for k in ("Y_r", "N_v", "Y_p", "K_v", "K_r", "N_p") if k in ident]
    quad = sorted(k for k in ident if re.fullmatch(r"[XYKMN]_(uu|vv|pp|qq|rr)(_abs)?|[XYKMN]_\|[uvpqr]\|[uvpqr]", k))
    diag = [k for k, _ in SUMMARY_DAMPING if k in ident]
    if diag:
        parts.append(f"linear damping ({len(diag)} of 5 diagonal terms"
                     + (f", {len(coupled)} coupled terms from the joint grey-box fit" if coupled else "") + ")")
    if quad:
        parts.append("quadratic damping " + ", ".join(quad))
    if any(k in ident for k in ("T2_nomoto", "T2")):
        parts.append("second-order Nomoto (T1, T2, T3)")
    elif {"K_nomoto", "T_nomoto"} <= ident:
        parts.append("first-order Nomoto (K, T)")
    return "; ".join(parts) or "no model identified"


def summary_rows(fits: Fits, qualities: Sequence, added_mass: Mapping[str, float] | None = None) -> list[SummaryRow]:
    """Rows of the summary: D diagonal, Nomoto K and T, model structure, each with its flags.

    Parameters
    ----------
    fits : Fits
        Fit results.
    qualities : Sequence[SegmentQuality]
        One per segment fit.
    added_mass : Mapping[str, float], optional
        The vessel config's ``[added_mass]`` (DOF -> value); a DOF without one is flagged
        ``added mass taken as 0``. None: not known (no flag).
    """
    bad = not_white_dofs(fits, qualities)
    params = fits.to_fit_result().params
    rows = []
    for name, dof in SUMMARY_DAMPING:
        v = name[-1]
        rows.append(_row(params.get(name), f"D_{v}{v} = -{name}", name, True, bad.get(dof),
                         added_mass is not None and dof not in added_mass))
    for name, label in (("K_nomoto", "Nomoto K"), ("T_nomoto", "Nomoto T")):
        rows.append(_row(params.get(name), label, name, False, bad.get("nomoto"), False))
    rows.append(SummaryRow("model structure", "", model_structure(fits), "", "", ()))
    return rows


def _row(est: Estimate | None, label: str, name: str, negate: bool, bad: list[int] | None,
         no_added_mass: bool) -> SummaryRow:
    if not is_identified(est):
        why = reason(est)
        unit = est.unit if est is not None else ""
        return SummaryRow(label, name, "not identified", "", unit, (f"not identified: {shorten(why, 90)}",))
    value, ci = _plain(est, negate)
    flags = []
    if bad:
        flags.append("residuals not white (fit " + ", ".join(str(i) for i in bad) + ")")
    if finite(est.consistency_p) and est.consistency_p < CONSISTENCY_ALPHA:
        flags.append(f"segments disagree (p = {format_number(est.consistency_p, 2)})")
    if no_added_mass:
        flags.append("added mass taken as 0")
    return SummaryRow(label, name, value, ci, est.unit, tuple(flags))


def gain_mass_consistency(fits: Fits) -> tuple[str, ...]:
    """Warnings where the damping from a step's gain and from its time constant disagree by a unit factor.

    ``D_gain_<dof>`` (force over steady speed) and ``-X_u`` (``m_eff / T``) measure the same
    damping; a ratio beyond ``GAIN_MASS_FACTOR`` means an input or a speed in the wrong unit, or
    a wrong mass.

    Parameters
    ----------
    fits : Fits
        Fit results.
    """
    out = []
    params = fits.to_fit_result().params
    for dof, name, inp, speed in (("surge", "X_u", "tau_x", "u/sog"), ("sway", "Y_v", "tau_y", "v"),
                                  ("yaw", "N_r", "tau_n", "r")):
        g, d = params.get(f"D_gain_{dof}"), params.get(name)
        if not (is_identified(g) and is_identified(d)) or float(g.value) <= 0 or float(d.value) >= 0:
            continue
        ratio = float(g.value) / -float(d.value)
        if ratio > GAIN_MASS_FACTOR or ratio < 1.0 / GAIN_MASS_FACTOR:
            out.append(f"{dof}: damping from the step gain ({format_number(g.value, 4)} {g.unit}) is "
                       f"{format_number(ratio, 3)} x the damping from the time constant and the configured "
                       f"mass ({format_number(-d.value, 4)} {d.unit}); expected about 1 (up to 2 from added "
                       f"mass). Check the unit of {inp} (N, not kN), of the speed {speed} (m/s, not km/h or "
                       f"knots) and the mass in the vessel config")
    return tuple(out)


def disagreement_warning(name: str, est) -> str:
    """The warning for a coefficient whose segments disagree beyond their errors.

    A random-effects combination (``pipeline.fit.combine``) already widens the error bar by the
    between-segment spread, so it is not "too small"; the disagreement itself is the finding: the
    manoeuvres see different values (a nonlinearity, a speed or amplitude dependence, a disturbance
    that differs between runs), so one linear coefficient describes them only on average.

    Parameters
    ----------
    name : str
        Coefficient name.
    est : FitParameter
        The coefficient (reads ``consistency_p`` and ``method``).
    """
    head = (f"{name}: per-segment values disagree beyond their errors (chi-square p = "
            f"{format_number(est.consistency_p, 2)})")
    if "random-effects" in (est.method or ""):
        return (head + "; the error bar includes the spread between segments (random-effects mean): the "
                       "manoeuvres see different values (nonlinearity, speed or amplitude dependence, or a "
                       "disturbance that differs between runs), so the value is an average over them")
    return head + "; the error bar is too small"


@dataclass(frozen=True)
class Findings:
    """Everything doubtful in a report, split by what the reader must do.

    Attributes
    ----------
    warnings : tuple[str, ...]
        Things a user must act on (coefficients not identified, failed fits, non-white
        residuals, disagreeing segments, unit or sign inconsistencies). Short; details in JSON.
    notes : tuple[str, ...]
        Information (what a fit left out, start values, tests that passed with a caveat).
    """

    warnings: tuple[str, ...]
    notes: tuple[str, ...]


def findings(fits: Fits, qualities: Sequence, extra_warnings: Sequence[str] = (),
             added_mass: Mapping[str, float] | None = None) -> Findings:
    """Split what the fit stage said into warnings and notes, each said once and short.

    Parameters
    ----------
    fits : Fits
        Fit results.
    qualities : Sequence[SegmentQuality]
        One per segment fit.
    extra_warnings : Sequence[str]
        Warnings found elsewhere (figures that cannot be drawn).
    added_mass : Mapping[str, float], optional
        The vessel config's ``[added_mass]``; identified derivatives of DOFs without one give one
        warning. None: not known.
    """
    warn: list[str] = []
    notes: list[str] = []
    params = fits.to_fit_result().params
    missing = [n for n in STANDARD_COEFFICIENTS if n not in params]
    if not fits.segment_fits:
        warn.append("no segment was fitted: the segment detector found no coast-down, step, free decay, rudder "
                    "step, zig-zag or sinusoid in this trial (closed-loop or free sailing holds none it can "
                    "recognise); name the manoeuvres by hand with [[segments]] in the trial manifest or "
                    "`vesselid segment LOG --review page.html` (docs/your_own_data.md)")
    if missing:
        warn.append("not estimated by the fit stage: " + ", ".join(missing))
    for name, est in params.items():
        msg = " ".join((est.message or "").split())
        if not is_identified(est):
            text = f"{name} not identified: {shorten(reason(est))}"
            (warn if name in STANDARD_COEFFICIENTS else notes).append(text)
            continue
        if finite(est.consistency_p) and est.consistency_p < CONSISTENCY_ALPHA:
            warn.append(disagreement_warning(name, est))
        if msg:
            notes.append(f"{name}: {shorten(msg)}")
    for i, sf in enumerate(fits.segment_fits):
        if not sf.success:
            warn.append(f"fit {i} ({sf.segment.kind}/{sf.segment.dof}) failed: "
                        f"{shorten(sf.message or 'no reason given')}")
    bad = not_white_dofs(fits, qualities)
    if bad:
        where = "; ".join(f"{k}: fit {', '.join(map(str, v))}" for k, v in bad.items())
        warn.append(f"residuals not white ({where}): unmodelled dynamics or coloured noise; the error bars of "
                    f"these DOFs are optimistic")
    dep = [i for i, q in enumerate(qualities) if q.resid is not None and not q.resid.independent]
    if dep:
        warn.append(f"residuals correlate with the input (fit {', '.join(map(str, dep))}): part of the response "
                    f"is not in the model (gain, delay or coupling)")
    if added_mass is not None:
        zero = [dof for name, dof in SUMMARY_DAMPING
                if is_identified(params.get(name)) and dof not in added_mass]
        if zero:
            warn.append(f"added mass taken as zero in {', '.join(zero)} (no [added_mass] in the vessel config): "
                        f"damping from time constants is low by the added-mass share; give [added_mass] "
                        f"(docs/your_own_data.md)")
    warn.extend(gain_mass_consistency(fits))
    warn.extend(damping_consistency(fits))
    warn.extend(extra_warnings)
    return Findings(tuple(dict.fromkeys(warn)), tuple(dict.fromkeys(notes)))


def diagnosis_headline(report) -> str:
    """One sentence: what the gap diagnosis found, including a gap nothing explains.

    Parameters
    ----------
    report : pipeline.diagnose.records.GapReport or None
        The diagnosis; None gives an empty string.
    """
    if report is None:
        return ""
    before, after = report.gap_before, report.gap_after
    v = report.verdict
    top = next((p for p in report.places if p.share > 0), None)
    where = f"; largest share in {top.dof} {top.category} '{top.name}' ({100 * top.share:.0f} %)" if top else ""
    if v is None:
        if finite(before) and before > 1.5:
            return (f"No candidate effect explains the gap: the model's held-out error is {before:.3g} x the "
                    f"sensor noise, unexplained{where}.")
        return f"No effect found; the model's held-out error is {format_number(before, 3)} x the sensor noise (1 = noise only)."
    text = (f"{v.effect} in {v.dof} explains part of the gap: held-out error {before:.3g} -> {after:.3g} x the "
            f"sensor noise ({report.shrink:.0f} % smaller)")
    if finite(after) and after > 1.5:
        text += f"; {after:.3g} x noise remains unexplained"
    return text + "."


def method_key(method: str) -> str:
    """A method text without its segment counts, so equal methods share one footnote.

    Parameters
    ----------
    method : str
        ``Estimate.method``.
    """
    m = re.sub(r";\s*(inverse-variance mean of \d+ segments|single segment)", "", method)
    m = re.sub(r" on \d+ [a-z-]+(s)?( and \d+ [a-z-]+)?(?=[;:,]|$)", "", m)
    m = re.sub(r" on \d+ record\(s\) of [^;]*", "", m)
    return m.strip()


def method_label(method: str) -> str:
    """A short name of a method for a table cell (the footnote holds the full text).

    Parameters
    ----------
    method : str
        ``Estimate.method``.
    """
    head = re.split(r"[;:(]| on \d", method_key(method), maxsplit=1)[0].strip()
    return shorten(head, 40)
