"""Numbers and text as the reports print them: one formatter for every HTML writer and text table.

The report page, the autopilot and diagnosis sections, the catalogue pages and the catalogue's
terminal tables all print numbers through :func:`number` and :func:`plus_minus` and escape text
through :func:`esc`; :func:`finite_or_none` is the one "a finite number or nothing" rule. It
imports nothing from the package, so every stage can use it. (The coefficient tables, which round
a value to the precision of its error bar, use :func:`pipeline.report.rows.format_uncertain`.)
"""

from __future__ import annotations

import html
import math
from typing import Any


def esc(text: Any) -> str:
    """``html.escape`` of ``str(text)``, quotes included.

    Parameters
    ----------
    text : object
        Anything; converted with ``str``.

    Returns
    -------
    str
        Text safe inside HTML elements and attribute values.
    """
    return html.escape(str(text), quote=True)


def finite_or_none(x: Any) -> float | None:
    """``float(x)`` when it is a finite number, else None (None, NaN, inf, text that is not a number).

    Parameters
    ----------
    x : object
        A number, a numeric string, None, ...

    Returns
    -------
    float or None
        The finite value, or None (what JSON and DuckDB store for "no number").
    """
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def number(x: Any, fmt: str = ".3g", missing: str = "n/a", unit: str = "", zero: float = 0.0) -> str:
    """A number in a format spec, or ``missing`` when there is none.

    Parameters
    ----------
    x : float, int, str or None
        The number [any unit]; None, NaN, inf and text that is not a number are "missing".
    fmt : str
        ``format`` spec, e.g. ``".3g"`` or ``".2f"``.
    missing : str
        What to print for a missing number (``"n/a"``, ``"-"``, ``"&mdash;"``, ...).
    unit : str
        Appended after a space when given (not after ``missing``).
    zero : float
        Magnitudes below this print as 0 (simulation round-off such as 1.5e-268 is not a measurement).

    Returns
    -------
    str
        The formatted number.
    """
    v = finite_or_none(x)
    if v is None:
        return missing
    if abs(v) < zero:
        v = 0.0
    return format(v, fmt) + (f" {unit}" if unit else "")


def plus_minus(value: Any, stderr: Any, fmt: str = ".4g", stderr_fmt: str = ".2g", unit: str = "",
               sign: str = " &plusmn; ", missing: str = "n/a", no_stderr: str = "") -> str:
    """``value ± stderr unit``; the value alone (followed by ``no_stderr``) when there is no error bar.

    Parameters
    ----------
    value, stderr : float
        Estimate and its standard error [same unit]; a missing or non-finite stderr drops the ``±`` part.
    fmt, stderr_fmt : str
        ``format`` specs of the value and of the error.
    unit : str
        Appended after a space when given.
    sign : str
        The separator (``" &plusmn; "`` in HTML, ``" ± "`` or ``" +- "`` in text).
    missing : str
        What to print for a missing value.
    no_stderr : str
        Appended when the error bar is missing (e.g. ``" (no standard error)"``).

    Returns
    -------
    str
        The formatted estimate.
    """
    tail = f" {unit}" if unit else ""
    if finite_or_none(value) is None:
        return missing
    if finite_or_none(stderr) is None:
        return number(value, fmt, missing) + tail + no_stderr
    return f"{number(value, fmt, missing)}{sign}{number(stderr, stderr_fmt, missing)}{tail}"
