"""Coefficient and damping-matrix tables in LaTeX (booktabs, as the AAUSHIP seed) and Markdown.

Every coefficient the contract knows is listed; one that was not identified reads "not identified"
with a lettered note giving the fit stage's reason, and a value without an error bar says why
(lmfit's rule: when error bars cannot be computed, the report says so instead of printing nothing).
Values are printed to the precision of their standard error, which gets two significant digits.
"""

from __future__ import annotations

import re

from ..records import DOFS, Fits
from .rows import (Formatted, Markup, Row, check_fits, checked_matrices, coefficient_rows, finite, format_uncertain,
                   note_labels, render_ci, render_number, render_unit)
from .summary import method_key

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


#: Numbers and units in LaTeX (numbers in math mode, units in text mode with thin spaces).
LATEX_MARKUP = Markup(pm=" \\pm ", power=lambda e: f"\\times 10^{{{e}}}", math=lambda s: f"${s}$",
                      superscript=lambda p: f"$^{{{p}}}$", text=lambda p: latex_escape(p).replace(" ", r"\,"))


def _marks(row: Row, labels: dict[str, str], fmt) -> str:
    return "".join(fmt(labels[n]) for n in row.notes)


# --------------------------------------------------------------------------- LaTeX tables
def is_derivative(name: str) -> bool:
    """True for a hydrodynamic derivative name (``X_u``, ``N_r``, ``Y_v_joint``, ``X_uu``).

    Parameters
    ----------
    name : str
        Coefficient name.
    """
    return bool(re.fullmatch(r"[XYKMN]_[uvpqr|]+(_[a-z]+)?", name))


def latex_coefficient_table(fits: Fits, which: str = "all", added_mass=None) -> str:
    """Booktabs table of coefficients, one page: methods and notes as footnotes under it.

    Parameters
    ----------
    fits : Fits
        Fit results.
    which : str
        ``derivatives`` (label ``tab:derivatives``), ``time_constants`` (time constants, gains,
        Nomoto; label ``tab:time-constants``) or ``all`` (label ``tab:coefficients``).
    added_mass : Mapping[str, float], optional
        The vessel config's ``[added_mass]`` (notes on derivatives of DOFs without one).

    Returns
    -------
    str
        A ``table`` environment (needs ``\\usepackage{booktabs}``); the caption states the units
        and the sign convention (``Fits.convention``), lettered notes say why a coefficient or an
        error bar is missing, numbers name the method.
    """
    check_fits(fits)
    rows = coefficient_rows(fits, added_mass)
    if which == "derivatives":
        rows = tuple(r for r in rows if is_derivative(r.name))
        label, what = "tab:derivatives", "hydrodynamic derivatives"
    elif which == "time_constants":
        rows = tuple(r for r in rows if not is_derivative(r.name))
        label, what = "tab:time-constants", "time constants, gains and Nomoto coefficients"
    else:
        label, what = "tab:coefficients", "hydrodynamic coefficients"
    labels = note_labels(rows)
    methods: dict[str, int] = {}
    for r in rows:
        if r.method:
            methods.setdefault(method_key(r.method), len(methods) + 1)
    sup = lambda a: f"\\textsuperscript{{{a}}}"  # noqa: E731
    lines = [
        r"\begin{table}[htbp]",
        r"\centering",
        r"\footnotesize\setlength{\tabcolsep}{3pt}",
        r"\begin{tabular}{lllll}",
        r"\toprule",
        r"Coefficient & Value $\pm$ std.\ error & 95\,\% CI & Unit & Segs.\ (method) \\",
        r"\midrule",
    ]
    for row in rows:
        marks = _marks(row, labels, sup)
        sym = latex_symbol(row.name)
        unit = render_unit(row.unit, LATEX_MARKUP)
        meth = f" [{methods[method_key(row.method)]}]" if row.method else ""
        if row.identified:
            num = render_number(row.number, LATEX_MARKUP)
            if row.number.stderr is None:
                num += r" $\pm$ n/a"
            lines.append(f"{sym} & {num}{marks} & {render_ci(row.number, LATEX_MARKUP)} & {unit} & {row.n_segments}{meth} \\\\")
        else:
            lines.append(f"{sym} & \\multicolumn{{2}}{{l}}{{not identified{marks}}} & {unit} & "
                         f"{row.n_segments}{meth} \\\\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    if labels or methods:
        lines.append(r"\par\smallskip")
        lines.append(r"\begin{minipage}{\linewidth}\scriptsize")
        for note, a in labels.items():
            end = "" if note.endswith(".") else "."
            lines.append(f"\\textsuperscript{{{a}}}\\,{latex_escape(_short(note, 120))}{end}\\par")
        for text, k in methods.items():
            lines.append(f"[{k}]\\,{latex_escape(_short(text, 160))}.\\par")
        lines.append(r"\end{minipage}")
    lines += [
        r"\caption{Identified " + what + " of " + latex_escape(fits.vessel) +
        r", in SI units as listed per row, with standard errors and 95\,\% confidence intervals."
        r" Sign convention: " + latex_escape(fits.convention) + "}",
        f"\\label{{{label}}}",
        r"\end{table}",
    ]
    return "\n".join(lines) + "\n"


def _short(text: str, limit: int = 200) -> str:
    from .summary import shorten

    return shorten(text, limit)


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
        r"\scriptsize\setlength{\tabcolsep}{2pt}",
        r"\begin{tabular}{l" + "c" * len(DOFS) + "}",
        r"\toprule",
        "$D$ & " + " & ".join(f"${d}$" for d in DOFS) + r" \\",
        r"\midrule",
    ]
    for i, dof in enumerate(DOFS):
        cells = []
        for j in range(len(DOFS)):
            f = _damping_cell(D[i, j], D_se[i, j])
            cells.append("--" if f is None else render_number(f, LATEX_MARKUP))
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


def latex_tables(fits: Fits, added_mass=None) -> str:
    """``coefficients.tex``: three tables, each one page, ready for ``\\input`` (needs booktabs).

    Parameters
    ----------
    fits : Fits
        Fit results.
    added_mass : Mapping[str, float], optional
        The vessel config's ``[added_mass]``.

    Returns
    -------
    str
        A comment header, then the derivatives (``tab:derivatives``), the time constants and gains
        (``tab:time-constants``) and the damping matrix (``tab:damping``).
    """
    header = ("% Generated by vesselid report. Requires \\usepackage{booktabs}.\n"
              "% Tables: tab:derivatives, tab:time-constants, tab:damping.\n\n")
    return (header + latex_coefficient_table(fits, "derivatives", added_mass) + "\n"
            + latex_coefficient_table(fits, "time_constants", added_mass) + "\n" + latex_damping_table(fits))


# --------------------------------------------------------------------------- Markdown
def _md_escape(text: str) -> str:
    """Text safe inside a GitHub pipe-table cell (pipes, HTML and emphasis characters escaped)."""
    text = str(text).replace("\r", " ").replace("\n", " ")
    for c in "\\|*`<>":
        text = text.replace(c, "\\" + c)
    return text


#: Numbers in Markdown and plain text (``×10^5``).
PLAIN_MARKUP = Markup(pm=" ± ", power=lambda e: f"×10^{e}", math=lambda s: s, superscript=lambda p: f"^{p}",
                      text=lambda p: p)


def markdown_coefficient_table(fits: Fits, added_mass=None) -> str:
    """GitHub pipe table of every coefficient, with caption line and lettered notes.

    Parameters
    ----------
    fits : Fits
        Fit results.
    added_mass : Mapping[str, float], optional
        The vessel config's ``[added_mass]``.

    Returns
    -------
    str
        Markdown text.
    """
    check_fits(fits)
    rows = coefficient_rows(fits, added_mass)
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
            num = render_number(row.number, PLAIN_MARKUP) + (" ± n/a" if row.number.stderr is None else "")
            ci = render_ci(row.number, PLAIN_MARKUP)
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
            cells.append("--" if f is None else render_number(f, PLAIN_MARKUP))
        lines.append(f"| **{dof}** | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def markdown_tables(fits: Fits, added_mass=None) -> str:
    """``coefficients.md``: title, coefficient table and damping matrix.

    Parameters
    ----------
    fits : Fits
        Fit results.
    added_mass : Mapping[str, float], optional
        The vessel config's ``[added_mass]``.

    Returns
    -------
    str
        Markdown text.
    """
    return (f"# Hydrodynamic coefficients: {_md_escape(fits.vessel)}\n\n"
            + markdown_coefficient_table(fits, added_mass) + "\n" + markdown_damping_table(fits))
