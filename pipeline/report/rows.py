"""What every report format shares: coefficient order, number formatting, notes and warnings.

The renderers (JSON, LaTeX, Markdown, HTML) only differ in syntax; what is printed, and why a
coefficient shows no error bar, is decided here once so the formats cannot disagree. Coefficients
are read in one shape, :class:`~pipeline.records.FitParameter` of the
:class:`~pipeline.records.FitResult` that :meth:`Fits.to_fit_result` gives.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Callable, Iterable, Mapping, Sequence

import numpy as np

from ..errors import ReportError
# One consistency rule: the report flags disagreeing segments at the level at which the fit stage stops
# treating them as one value (random-effects combination below it).
from ..fit.combine import CONSISTENCY_ALPHA
from ..records import DOFS, Estimate, FitParameter, Fits, Segment, Segments, SegmentFit
from ..text_format import number

#: Force/moment symbol of each DOF row of D (Fossen 2021, SNAME 1950 notation).
FORCE_SYMBOLS: tuple[str, ...] = ("X", "Y", "K", "M", "N")
#: Hydrodynamic derivatives of the 5-DOF linear damping matrix, in the AAUSHIP seed's order.
DERIVATIVES: tuple[str, ...] = ("X_u", "Y_v", "Y_p", "Y_r", "K_v", "K_p", "K_r", "M_q", "N_v", "N_p", "N_r")
#: Nomoto yaw-model coefficients.
NOMOTO: tuple[str, ...] = ("K_nomoto", "T_nomoto")
#: Coefficients every report lists, identified or not (the coefficients.json contract).
STANDARD_COEFFICIENTS: tuple[str, ...] = DERIVATIVES + NOMOTO



def derivative_index(name: str) -> tuple[int, int] | None:
    """Row and column of D that derivative ``name`` (``Y_r``) fills, or None for other names.

    Parameters
    ----------
    name : str
        Coefficient name, force symbol ``_`` velocity symbol.

    Returns
    -------
    tuple[int, int] or None
        ``(i, j)`` in DOF order ``DOFS``; ``D[i, j] = -name`` (Fossen's sign convention).
    """
    head, _, sub = name.partition("_")
    if head in FORCE_SYMBOLS and sub in DOFS:
        return FORCE_SYMBOLS.index(head), DOFS.index(sub)
    return None


def damping_unit(i: int, j: int) -> str:
    """SI unit of ``D[i, j]``: generalised force of DOF ``i`` per velocity of DOF ``j``.

    Parameters
    ----------
    i, j : int
        Row (force) and column (velocity) in DOF order ``DOFS``.

    Returns
    -------
    str
        ``kg/s`` (N per m/s), ``kg m/s`` (N per rad/s, or N m per m/s) or ``kg m^2/s``
        (N m per rad/s); radians are dimensionless.
    """
    # Relative to N/(m/s) = kg/s, a moment (rows p, q, r) adds a metre, and so does dividing by
    # a rate in rad/s instead of a speed in m/s (columns p, q, r).
    metres = int(i >= 2) + int(j >= 2)
    return {0: "kg/s", 1: "kg m/s", 2: "kg m^2/s"}[metres]


def default_unit(name: str) -> str:
    """Unit of a standard coefficient that the fit stage did not return (so it has no unit).

    Parameters
    ----------
    name : str
        Coefficient name.
    """
    idx = derivative_index(name)
    if idx is not None:
        return damping_unit(*idx)
    return {"K_nomoto": "1/s", "T_nomoto": "s"}.get(name, "")


# --------------------------------------------------------------------------- numbers
def finite(x) -> bool:
    """True for a real, finite number (bools and None are not numbers here).

    Parameters
    ----------
    x : Any
        Anything.
    """
    if x is None or isinstance(x, (bool, np.bool_)):
        return False
    try:
        return math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


@dataclass(frozen=True)
class Formatted:
    """A value and its error bar as strings with a shared decimal precision.

    Attributes
    ----------
    value : str
        Mantissa of the value.
    stderr : str or None
        Mantissa of the standard error; None when it is not available.
    ci : tuple[str, str] or None
        Mantissas of the 95 % confidence bounds; None when not available.
    exponent : int
        Common power of ten (0: plain fixed-point notation).
    """

    value: str
    stderr: str | None
    ci: tuple[str, str] | None
    exponent: int = 0


def _fixed(x: float, decimals: int) -> str:
    s = f"{x:.{max(decimals, 0)}f}"
    # "-0.000" reads as a sign error in a coefficient table.
    if float(s) == 0.0:
        s = s.lstrip("-")
    return s


def format_uncertain(value: float, stderr: float = math.nan,
                     ci: Sequence[float] | None = None, sig_plain: int = 4) -> Formatted:
    """Format a value to the precision of its standard error (two significant digits of error).

    ``-2.8612 +- 0.0312`` becomes ``-2.861 +- 0.031``. Without a usable error bar the value gets
    ``sig_plain`` significant digits. Magnitudes outside ``[1e-3, 1e5)`` share a power of ten.

    Parameters
    ----------
    value : float
        Estimate [any unit]; must be finite.
    stderr : float
        Standard error [unit of ``value``]; NaN, inf or <= 0 means not available.
    ci : sequence of two floats, optional
        95 % confidence bounds [unit of ``value``]; printed with the value's precision.
    sig_plain : int
        Significant digits when there is no error bar.

    Returns
    -------
    Formatted
        Strings ready for any renderer.
    """
    value = float(value)
    has_err = finite(stderr) and float(stderr) > 0.0
    scale = max(abs(value), float(stderr) if has_err else 0.0)
    exponent = 0
    if scale > 0.0:
        e = math.floor(math.log10(scale))
        if e >= 5 or e <= -4:
            exponent = e
    f = 10.0 ** -exponent
    v = value * f
    if has_err:
        s = float(stderr) * f
        # Exponent of the error after rounding to two digits (0.0996 rounds to 0.10, not 0.100).
        s_exp = int(f"{s:.1e}".split("e")[1])
        decimals = max(1 - s_exp, 0)
        s_txt = _fixed(float(f"{s:.1e}"), decimals)
    else:
        s_txt = None
        if v == 0.0:
            decimals = sig_plain - 1
        else:
            decimals = max(sig_plain - 1 - math.floor(math.log10(abs(v))), 0)
    ci_txt = None
    if ci is not None and len(ci) == 2 and finite(ci[0]) and finite(ci[1]):
        ci_txt = (_fixed(float(ci[0]) * f, decimals), _fixed(float(ci[1]) * f, decimals))
    return Formatted(_fixed(v, decimals), s_txt, ci_txt, exponent)


@dataclass(frozen=True)
class Markup:
    """How one output format (HTML, LaTeX, plain text) writes a :class:`Formatted` number and a unit.

    Attributes
    ----------
    pm : str
        Between a value and its error (`` ± ``, `` \\pm ``).
    power : callable
        ``power(exponent) -> str``: the common power of ten after a number.
    math : callable
        ``math(text) -> str``: wraps a whole number (LaTeX's ``$...$``; identity elsewhere).
    superscript : callable
        ``superscript(digits) -> str``: a unit's power.
    text : callable
        ``text(piece) -> str``: a unit's text between powers, escaped, spaces as the format's
        narrow space.
    """

    pm: str
    power: Callable[[int], str]
    math: Callable[[str], str]
    superscript: Callable[[str], str]
    text: Callable[[str], str]


def render_number(f: Formatted, markup: Markup) -> str:
    """``-2.860 ± 0.030`` or ``(1.23 ± 0.05)×10^5`` in ``markup``; the value alone without an error.

    Parameters
    ----------
    f : Formatted
        The number (:func:`format_uncertain`).
    markup : Markup
        The output format.

    Returns
    -------
    str
        The number in that format (digits, signs and brackets need no escaping in any of them).
    """
    core = f"{f.value}{markup.pm}{f.stderr}" if f.stderr is not None else f.value
    if f.exponent:
        core = f"({core})" if f.stderr is not None else core
        return markup.math(core + markup.power(f.exponent))
    return markup.math(core)


def render_ci(f: Formatted | None, markup: Markup) -> str:
    """``[lo, hi]`` (with the common power of ten) in ``markup``, or ``n/a``.

    Parameters
    ----------
    f, markup : Formatted or None, Markup
        As in :func:`render_number` (None: no number).

    Returns
    -------
    str
        The interval in that format.
    """
    if f is None or f.ci is None:
        return "n/a"
    tail = markup.power(f.exponent) if f.exponent else ""
    return markup.math(f"[{f.ci[0]}, {f.ci[1]}]{tail}")


def render_unit(unit: str, markup: Markup) -> str:
    """A unit with its powers raised: ``kg m^2/s`` -> ``kg&nbsp;m<sup>2</sup>/s`` (HTML).

    Parameters
    ----------
    unit : str
        Unit text, powers written ``^2``, ``^-1``.
    markup : Markup
        The output format.

    Returns
    -------
    str
        The unit in that format.
    """
    pieces = re.split(r"\^(-?\d+)", str(unit))
    return "".join(markup.superscript(p) if k % 2 else markup.text(p) for k, p in enumerate(pieces))


def format_number(x: float, sig: int = 3) -> str:
    """Plain number with ``sig`` significant digits (``nan`` when not finite), for captions.

    Parameters
    ----------
    x : float
        The number.
    sig : int
        Significant digits.
    """
    return number(x, f".{sig}g", missing="nan")


# --------------------------------------------------------------------------- rows
@dataclass(frozen=True)
class Row:
    """One coefficient as every table shows it.

    Attributes
    ----------
    name : str
        Coefficient name (``X_u``).
    identified : bool
        True when the fit succeeded and gave a finite value.
    number : Formatted or None
        Value, error bar and interval when identified.
    unit : str
        SI unit.
    n_segments : int
        Segments combined.
    method : str
        How the value was obtained.
    notes : tuple[str, ...]
        Why the value or its error bar is missing, and doubts about it.
    """

    name: str
    identified: bool
    number: Formatted | None
    unit: str
    n_segments: int
    method: str
    notes: tuple[str, ...]


def ordered_names(estimates: Mapping[str, FitParameter]) -> tuple[str, ...]:
    """Standard coefficients in the seed's order, then any others the fit returned, in its order.

    Parameters
    ----------
    estimates : Mapping[str, FitParameter]
        The fit stage's coefficients by name (``Fits.to_fit_result().params``).
    """
    return STANDARD_COEFFICIENTS + tuple(k for k in estimates if k not in STANDARD_COEFFICIENTS)


def as_parameter(est: FitParameter | Estimate | None) -> FitParameter | None:
    """``est`` in the one shape the report reads (an :class:`Estimate` converted, None kept).

    Parameters
    ----------
    est : FitParameter, Estimate or None
        A coefficient.
    """
    return est.to_parameter() if isinstance(est, Estimate) else est


def is_identified(est: FitParameter | Estimate | None) -> bool:
    """True when a coefficient succeeded and has a finite value.

    Parameters
    ----------
    est : FitParameter, Estimate or None
        The coefficient (an Estimate is read as its FitParameter).
    """
    est = as_parameter(est)
    return est is not None and bool(est.success) and finite(est.value)


MISSING_NOTE = "the fit stage returned no estimate for this coefficient"


def estimate_notes(est: FitParameter | Estimate | None) -> tuple[str, ...]:
    """Why ``est`` is not identified or has no error bar, and any consistency doubt.

    Parameters
    ----------
    est : FitParameter, Estimate or None
        The coefficient (an Estimate is read as its FitParameter); None when the fit stage did
        not return one.

    Returns
    -------
    tuple[str, ...]
        Plain-text notes, empty for a clean estimate.
    """
    est = as_parameter(est)
    if est is None:
        return (MISSING_NOTE,)
    msg = (est.message or "").strip()
    notes: list[str] = []
    if not is_identified(est):
        why = msg or ("the fit reported failure without a reason" if not est.success
                      else "the fit gave no finite value and no reason")
        if finite(est.value):
            # A value the fit itself rejected stays visible in the note, never in the table.
            rejected = f"{format_number(est.value, 4)}"
            if finite(est.stderr):
                rejected += f" +- {format_number(est.stderr, 2)}"
            why += f" (rejected estimate: {rejected} {est.unit})".rstrip()
        notes.append(why)
        return tuple(notes)
    if not (finite(est.stderr) and float(est.stderr) > 0.0):
        notes.append("standard error not available: " + (msg or "the fit stage gave no reason"))
    elif msg:
        notes.append(msg)
    p = est.consistency_p
    if finite(p) and float(p) < CONSISTENCY_ALPHA and "consisten" not in msg.lower():
        notes.append(f"per-segment values disagree beyond their errors (chi-square p = "
                     f"{format_number(p, 2)} < {CONSISTENCY_ALPHA})")
    return tuple(notes)


#: Derivative -> DOF whose added mass its time-constant value uses.
ADDED_MASS_DOF = {"X_u": "surge", "Y_v": "sway", "K_p": "roll", "M_q": "pitch", "N_r": "yaw"}


def added_mass_note(dof: str) -> str:
    """The note on a derivative whose DOF has no added mass in the vessel config.

    Parameters
    ----------
    dof : str
        DOF name (``surge``).
    """
    return (f"added mass in {dof} taken as zero (no [added_mass] {dof} in the vessel config): the value "
            f"from the time constant is then too small by the added-mass share")


def coefficient_rows(fits: Fits, added_mass: Mapping[str, float] | None = None) -> tuple[Row, ...]:
    """One :class:`Row` per coefficient, standard ones first (see :func:`ordered_names`).

    Parameters
    ----------
    fits : Fits
        Fit results.
    added_mass : Mapping[str, float], optional
        The vessel config's ``[added_mass]``; a derivative of a DOF without one gets the note of
        :func:`added_mass_note`. None: not known (no note).
    """
    rows = []
    params = fits.to_fit_result().params
    for name in ordered_names(params):
        est = params.get(name)
        notes = estimate_notes(est)
        if est is None:
            rows.append(Row(name, False, None, default_unit(name), 0, "", notes))
            continue
        ident = is_identified(est)
        dof = ADDED_MASS_DOF.get(name)
        if ident and dof and added_mass is not None and dof not in added_mass:
            notes = notes + (added_mass_note(dof),)
        number = format_uncertain(est.value, est.stderr, est.ci95) if ident else None
        rows.append(Row(name, ident, number, est.unit or default_unit(name), int(est.n_segments),
                        est.method or "", notes))
    return tuple(rows)


def note_labels(rows: Iterable[Row]) -> dict[str, str]:
    """Letter (``a``, ``b``, ...) for each distinct note, in order of first use.

    Parameters
    ----------
    rows : Iterable[Row]
        Table rows, in order.
    """
    labels: dict[str, str] = {}
    for row in rows:
        for note in row.notes:
            if note not in labels:
                labels[note] = _letters(len(labels))
    return labels


def _letters(i: int) -> str:
    out = ""
    i += 1
    while i:
        i, r = divmod(i - 1, 26)
        out = chr(ord("a") + r) + out
    return out


# --------------------------------------------------------------------------- validation
def checked_matrices(fits: Fits) -> tuple[np.ndarray, np.ndarray]:
    """``fits.damping_matrix`` and ``damping_stderr`` as float 5x5 copies, or ReportError.

    Copies, so nothing downstream can write into the caller's arrays.

    Parameters
    ----------
    fits : Fits
        Fit results.
    """
    out = []
    for label in ("damping_matrix", "damping_stderr"):
        raw = getattr(fits, label)
        try:
            arr = np.array(raw, dtype=float, copy=True)
        except (TypeError, ValueError) as exc:
            raise ReportError(f"Fits.{label}: expected a 5x5 numeric array, found {type(raw).__name__} "
                              f"({exc})") from exc
        if arr.shape != (len(DOFS), len(DOFS)):
            raise ReportError(f"Fits.{label}: expected shape (5, 5) in DOF order {', '.join(DOFS)}, "
                              f"found shape {arr.shape}")
        out.append(arr)
    return out[0], out[1]


def check_fits(fits: Fits) -> None:
    """Raise ReportError when ``fits`` is not a usable :class:`~pipeline.records.Fits`.

    Parameters
    ----------
    fits : Fits
        Anything claimed to be fit results.
    """
    if not isinstance(fits, Fits):
        raise ReportError(f"expected a pipeline.records.Fits, found {type(fits).__name__}")
    if not isinstance(fits.estimates, Mapping):
        raise ReportError(f"Fits.estimates: expected a mapping name -> Estimate, found "
                          f"{type(fits.estimates).__name__}")
    for key, est in fits.estimates.items():
        if not isinstance(est, Estimate):
            raise ReportError(f"Fits.estimates[{key!r}]: expected an Estimate, found {type(est).__name__}")
    for i, sf in enumerate(fits.segment_fits):
        if not isinstance(sf, SegmentFit):
            raise ReportError(f"Fits.segment_fits[{i}]: expected a SegmentFit, found {type(sf).__name__}")
    checked_matrices(fits)


def segment_list(fits: Fits, segments: Segments | Sequence[Segment] | None) -> tuple[Segment, ...]:
    """The segments to report: those given, else the distinct segments the fits used.

    Parameters
    ----------
    fits : Fits
        Fit results.
    segments : Segments, sequence of Segment or None
        The segments given, if any.
    """
    if segments is None:
        seen: list[Segment] = []
        for sf in fits.segment_fits:
            if sf.segment not in seen:
                seen.append(sf.segment)
        return tuple(sorted(seen, key=lambda s: (s.t_start, s.t_end)))
    items = segments.items if isinstance(segments, Segments) else tuple(segments)
    for i, s in enumerate(items):
        if not isinstance(s, Segment):
            raise ReportError(f"segments[{i}]: expected a Segment, found {type(s).__name__}")
    return tuple(items)


# --------------------------------------------------------------------------- consistency
def damping_consistency(fits: Fits) -> tuple[str, ...]:
    """Entries of D that contradict the derivatives (``D[i, j]`` should be ``-derivative``).

    Parameters
    ----------
    fits : Fits
        Fit results.
    """
    D, _ = checked_matrices(fits)
    params = fits.to_fit_result().params
    out = []
    for name in DERIVATIVES:
        i, j = derivative_index(name)
        est = params.get(name)
        d = D[i, j]
        cell = f"D[{i},{j}] ({DOFS[i]},{DOFS[j]})"
        if is_identified(est):
            if not np.isfinite(d):
                out.append(f"{name} is identified but {cell} is not set")
            elif not math.isclose(d, -float(est.value), rel_tol=1e-6, abs_tol=1e-12):
                out.append(f"{cell} = {format_number(d, 4)} but -{name} = {format_number(-est.value, 4)}: "
                           f"D and the derivatives disagree (sign convention D = -derivative)")
        elif np.isfinite(d):
            out.append(f"{cell} = {format_number(d, 4)} is set but {name} is not identified")
    return tuple(out)
