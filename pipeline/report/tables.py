"""Coefficient and damping-matrix tables in LaTeX (booktabs, as the AAUSHIP seed) and Markdown.

Every coefficient the contract knows is listed; one that was not identified reads "not identified"
with a lettered note giving the fit stage's reason, and a value without an error bar says why
(lmfit's rule: when error bars cannot be computed, the report says so instead of printing nothing).
Values are printed to the precision of their standard error, which gets two significant digits.
"""

from __future__ import annotations

import os
import re
from pathlib import Path


from ..records import DOFS, Fits
from ._common import (Formatted, Row, check_fits, checked_matrices, coefficient_rows, finite,
                      format_uncertain, note_labels)
from .atomic import atomic_write_text

GREEK = frozenset({"alpha", "beta", "gamma", "delta", "epsilon", "zeta", "eta", "theta", "kappa",
                   "lambda", "mu", "nu", "xi", "pi", "rho", "sigma", "tau", "phi", "chi", "psi",
                   "omega", "Delta", "Phi", "Psi", "Omega"})

#: Names with a conventional symbol that the generic ``head_sub`` rule would get wrong.
_LATEX_SYMBOLS = {"K_nomoto": r"$K$ (Nomoto)", "T_nomoto": r"$T$ (Nomoto)"}


# --------------------------------------------------------------------------- LaTeX helpers
_LATEX_ESCAPES = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#",
                  "_": r"\_", "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}",
                  "^": r"\textasciicircum{}", "<": r"\textless{}", ">": r"\textgreater{}"}


def latex_escape(text: str) -> str:
    """Text with LaTeX's special characters escaped, safe inside a table cell or caption.

    Parameters
    ----------
    text : str
        Plain text (messages, method names, the convention); newlines become spaces.

    Returns
    -------
    str
        LaTeX text-mode source.
    """
    return "".join(_LATEX_ESCAPES.get(c, c) for c in str(text).replace("\n", " "))


def latex_symbol(name: str) -> str:
    """LaTeX symbol of a coefficient name: ``X_u`` -> ``$X_{u}$``, ``N_delta`` -> ``$N_{\\delta}$``.

    Parameters
    ----------
    name : str
        Coefficient name; ``K_nomoto`` and ``T_nomoto`` read ``$K$ (Nomoto)``, ``$T$ (Nomoto)``, and
        names that are not ``letter_subscript`` are escaped as text.

    Returns
    -------
    str
        LaTeX source.
    """
    if name in _LATEX_SYMBOLS:
        return _LATEX_SYMBOLS[name]
    head, sep, sub = name.partition("_")
    head_ok = head in GREEK or re.fullmatch(r"[A-Za-z]", head)
    sub_ok = not sep or sub in GREEK or re.fullmatch(r"[A-Za-z0-9]+", sub)
    if not (head_ok and sub_ok):
        return latex_escape(name)
    h = "\\" + head if head in GREEK else head
    s = "\\" + sub if sub in GREEK else sub
    return f"${h}_{{{s}}}$" if sep else f"${h}$"


def _latex_unit(unit: str) -> str:
    """Unit in text mode with powers raised and thin spaces: ``kg m^2/s`` -> ``kg\\,m$^{2}$/s``."""
    pieces = re.split(r"\^(-?\d+)", str(unit))
    out = []
    for k, piece in enumerate(pieces):
        out.append(f"$^{{{piece}}}$" if k % 2 else latex_escape(piece).replace(" ", r"\,"))
    return "".join(out)


def _latex_number(f: Formatted) -> str:
    """``$-2.860 \\pm 0.030$``, ``$(1.23 \\pm 0.05)\\times 10^{5}$``; no error bar: value alone."""
    core = f"{f.value} \\pm {f.stderr}" if f.stderr is not None else f.value
    if f.exponent:
        core = f"({core})" if f.stderr is not None else core
        return f"${core}\\times 10^{{{f.exponent}}}$"
    return f"${core}$"


def _latex_ci(f: Formatted | None) -> str:
    """``$[lo, hi]$`` or ``n/a``."""
    if f is None or f.ci is None:
        return "n/a"
    lo, hi = f.ci
    tail = f"\\times 10^{{{f.exponent}}}" if f.exponent else ""
    return f"$[{lo}, {hi}]{tail}$"


def _marks(row: Row, labels: dict[str, str], fmt) -> str:
    return "".join(fmt(labels[n]) for n in row.notes)


# --------------------------------------------------------------------------- LaTeX tables
def latex_coefficient_table(fits: Fits) -> str:
    """Booktabs table of every coefficient, label ``tab:coefficients``.

    Parameters
    ----------
    fits : Fits
        Fit results.

    Returns
    -------
    str
        A ``table`` environment (needs ``\\usepackage{booktabs}``); the caption states the units
        and the sign convention (``Fits.convention``), and lettered notes say why a coefficient or
        an error bar is missing.
    """
    check_fits(fits)
    rows = coefficient_rows(fits)
    labels = note_labels(rows)
    sup = lambda a: f"\\textsuperscript{{{a}}}"  # noqa: E731
    lines = [
        r"\begin{table}[htbp]",
        r"\centering",
        r"\begin{tabular}{llllrp{0.28\linewidth}}",
        r"\toprule",
        r"Coefficient & Value $\pm$ std.\ error & 95\,\% CI & Unit & Segments & Method \\",
        r"\midrule",
    ]
    for row in rows:
        marks = _marks(row, labels, sup)
        sym = latex_symbol(row.name)
        unit = _latex_unit(row.unit)
        method = latex_escape(row.method) if row.method else "--"
        if row.identified:
            num = _latex_number(row.number)
            if row.number.stderr is None:
                num += r" $\pm$ n/a"
            lines.append(f"{sym} & {num}{marks} & {_latex_ci(row.number)} & {unit} & {row.n_segments} "
                         f"& {method} \\\\")
        else:
            lines.append(f"{sym} & \\multicolumn{{2}}{{l}}{{not identified{marks}}} & {unit} & "
                         f"{row.n_segments} & {method} \\\\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    if labels:
        lines.append(r"\par\smallskip")
        lines.append(r"{\footnotesize")
        for note, a in labels.items():
            end = "" if note.endswith(".") else "."
            lines.append(f"\\textsuperscript{{{a}}}\\,{latex_escape(note)}{end}\\par")
        lines.append("}")
    lines += [
        r"\caption{Identified hydrodynamic coefficients of " + latex_escape(fits.vessel) +
        r", in SI units as listed per row, with standard errors and 95\,\% confidence intervals."
        r" Sign convention: " + latex_escape(fits.convention) + "}",
        r"\label{tab:coefficients}",
        r"\end{table}",
    ]
    return "\n".join(lines) + "\n"


def _damping_cell(d: float, se: float) -> Formatted | None:
    return format_uncertain(d, se) if finite(d) else None


def latex_damping_table(fits: Fits) -> str:
    """Booktabs table of the 5x5 damping matrix D, ``--`` where not identified.

    Parameters
    ----------
    fits : Fits
        Fit results.

    Returns
    -------
    str
        A ``table`` environment, label ``tab:damping``.
    """
    D, D_se = checked_matrices(fits)
    lines = [
        r"\begin{table}[htbp]",
        r"\centering",
        r"\begin{tabular}{l" + "c" * len(DOFS) + "}",
        r"\toprule",
        "$D$ & " + " & ".join(f"${d}$" for d in DOFS) + r" \\",
        r"\midrule",
    ]
    for i, dof in enumerate(DOFS):
        cells = []
        for j in range(len(DOFS)):
            f = _damping_cell(D[i, j], D_se[i, j])
            cells.append("--" if f is None else _latex_number(f))
        lines.append(f"${dof}$ & " + " & ".join(cells) + r" \\")
    lines += [
        r"\bottomrule",
        r"\end{tabular}",
        r"\caption{Linear damping matrix $D$ of " + latex_escape(fits.vessel) +
        r" in $M\dot{\nu} + D\nu = \tau$, rows force/moment and columns velocity in DOF order "
        + ", ".join(DOFS) + r"; $D_{ij}$ is minus the hydrodynamic derivative, so the diagonal is positive."
        r" Units: kg/s (force per speed), kg\,m/s (force per rate, moment per speed),"
        r" kg\,m$^{2}$/s (moment per rate). -- : not identified."
        r" Sign convention: " + latex_escape(fits.convention) + "}",
        r"\label{tab:damping}",
        r"\end{table}",
    ]
    return "\n".join(lines) + "\n"


def latex_tables(fits: Fits) -> str:
    """``coefficients.tex``: both tables, ready for ``\\input`` (needs booktabs).

    Parameters
    ----------
    fits : Fits
        Fit results.

    Returns
    -------
    str
        A comment header, then :func:`latex_coefficient_table` and :func:`latex_damping_table`.
    """
    header = ("% Generated by vesselid report. Requires \\usepackage{booktabs}.\n"
              "% Tables: tab:coefficients, tab:damping.\n\n")
    return header + latex_coefficient_table(fits) + "\n" + latex_damping_table(fits)


# --------------------------------------------------------------------------- Markdown
def _md_escape(text: str) -> str:
    """Text safe inside a GitHub pipe-table cell (pipes, HTML and emphasis characters escaped)."""
    text = str(text).replace("\r", " ").replace("\n", " ")
    for c in "\\|*`<>":
        text = text.replace(c, "\\" + c)
    return text


def _plain_number(f: Formatted) -> str:
    """``-2.860 ± 0.030`` or ``(1.23 ± 0.05)×10^5`` (Markdown and plain text)."""
    core = f"{f.value} ± {f.stderr}" if f.stderr is not None else f.value
    if f.exponent:
        return (f"({core})" if f.stderr is not None else core) + f"×10^{f.exponent}"
    return core


def _plain_ci(f: Formatted | None) -> str:
    """``[lo, hi]`` or ``n/a``."""
    if f is None or f.ci is None:
        return "n/a"
    tail = f"×10^{f.exponent}" if f.exponent else ""
    return f"[{f.ci[0]}, {f.ci[1]}]{tail}"


def markdown_coefficient_table(fits: Fits) -> str:
    """GitHub pipe table of every coefficient, with caption line and lettered notes.

    Parameters
    ----------
    fits : Fits
        Fit results.

    Returns
    -------
    str
        Markdown text.
    """
    check_fits(fits)
    rows = coefficient_rows(fits)
    labels = note_labels(rows)
    lines = [
        f"**Table: identified hydrodynamic coefficients of {_md_escape(fits.vessel)}** "
        f"(SI units as listed per row; standard errors and 95 % confidence intervals). "
        f"Sign convention: {_md_escape(fits.convention)}",
        "",
        "| Coefficient | Value ± std. error | 95 % CI | Unit | Segments | Method |",
        "|---|---:|---|---|---:|---|",
    ]
    for row in rows:
        marks = _marks(row, labels, lambda a: f" [{a}]")
        method = _md_escape(row.method) if row.method else "--"
        if row.identified:
            num = _plain_number(row.number) + (" ± n/a" if row.number.stderr is None else "")
            ci = _plain_ci(row.number)
        else:
            num, ci = "not identified", "--"
        lines.append(f"| `{row.name}` | {num}{marks} | {ci} | {_md_escape(row.unit)} | {row.n_segments} "
                     f"| {method} |")
    if labels:
        lines += ["", "Notes:", ""]
        lines += [f"- [{a}] {_md_escape(note)}" for note, a in labels.items()]
    return "\n".join(lines) + "\n"


def markdown_damping_table(fits: Fits) -> str:
    """GitHub pipe table of the 5x5 damping matrix D, ``--`` where not identified.

    Parameters
    ----------
    fits : Fits
        Fit results.

    Returns
    -------
    str
        Caption line and table; entries ``value ± stderr`` in SI units.
    """
    D, D_se = checked_matrices(fits)
    lines = [
        f"**Table: linear damping matrix D of {_md_escape(fits.vessel)}** in M nu_dot + D nu = tau; "
        f"rows force/moment, columns velocity, DOF order {', '.join(DOFS)}; D_ij is minus the "
        f"hydrodynamic derivative (positive diagonal). Units: kg/s (force per speed), kg m/s (force per "
        f"rate, moment per speed), kg m^2/s (moment per rate). -- : not identified; an entry without ± has "
        f"no standard error.",
        "",
        "| D | " + " | ".join(DOFS) + " |",
        "|---|" + "---:|" * len(DOFS),
    ]
    for i, dof in enumerate(DOFS):
        cells = []
        for j in range(len(DOFS)):
            f = _damping_cell(D[i, j], D_se[i, j])
            cells.append("--" if f is None else _plain_number(f))
        lines.append(f"| **{dof}** | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def markdown_tables(fits: Fits) -> str:
    """``coefficients.md``: title, coefficient table and damping matrix.

    Parameters
    ----------
    fits : Fits
        Fit results.

    Returns
    -------
    str
        Markdown text.
    """
    return (f"# Hydrodynamic coefficients: {_md_escape(fits.vessel)}\n\n"
            + markdown_coefficient_table(fits) + "\n" + markdown_damping_table(fits))


def write_tables(fits: Fits, tex_path: str | os.PathLike, md_path: str | os.PathLike) -> tuple[Path, Path]:
    """Write ``coefficients.tex`` and ``coefficients.md`` atomically.

    Parameters
    ----------
    fits : Fits
        Fit results.
    tex_path, md_path : str or os.PathLike
        Destination files.

    Returns
    -------
    tuple[pathlib.Path, pathlib.Path]
        The files written.
    """
    return atomic_write_text(tex_path, latex_tables(fits)), atomic_write_text(md_path, markdown_tables(fits))
