"""``coefficients.json``: the identified coefficients as a contract other stages and scripts read.

Structure (every number in SI; ``null`` wherever a value is not identified, never ``NaN``)::

    {"vessel": str, "convention": str,
     "damping_matrix": {"dofs": ["u", "v", "p", "q", "r"],
                        "values": 5x5 number|null,     # D, positive diagonal
                        "stderr": 5x5 number|null},
     "coefficients": {"X_u": {"value", "stderr", "ci95": [lo, hi], "unit", "n_segments",
                              "method", "success", "message", "consistency_p"},
                      ...,                             # all of DERIVATIVES, then
                      "K_nomoto": {...}, "T_nomoto": {...},
                      ...},                            # any further coefficients the fit returned
     "model_structure": {...}, "quadratic_damping": {...}, "covariance": {...},   # when structures were selected
     "decay_analysis": {...}}                          # roll/pitch extinction curves, when free decays were fitted

Derivatives carry Fossen's signs (``X_u = -D[0, 0] < 0``). A coefficient whose fit did not succeed
has ``value``, ``stderr`` and both ``ci95`` bounds ``null``, ``success`` false and the reason in
``message``. New keys may be added in later versions; existing ones keep their meaning.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..errors import ReportError
from ..records import DOFS, FitParameter, FitResult, Fits
from .rows import (STANDARD_COEFFICIENTS, MISSING_NOTE, check_fits, checked_matrices,
                      as_parameter, default_unit, estimate_notes, finite, is_identified, ordered_names)
from ..atomic import atomic_write_text

#: Keys of one coefficient entry, in the order written.
COEFFICIENT_KEYS: tuple[str, ...] = ("value", "stderr", "ci95", "unit", "n_segments", "method",
                                     "success", "message", "consistency_p")
#: Top-level keys.
TOP_KEYS: tuple[str, ...] = ("vessel", "convention", "damping_matrix", "coefficients")
#: Keys of ``damping_matrix``.
DAMPING_KEYS: tuple[str, ...] = ("dofs", "values", "stderr")


def _num(x) -> float | None:
    """Float for JSON, None for NaN/inf (JSON has no NaN)."""
    return float(x) if finite(x) else None


def _square(a: np.ndarray) -> list[list[float | None]]:
    """A matrix as JSON rows, None for NaN/inf."""
    return [[_num(x) for x in row] for row in np.asarray(a, float)]


def estimate_to_dict(est: FitParameter | None, name: str = "") -> dict[str, Any]:
    """One coefficient entry of the contract.

    Parameters
    ----------
    est : FitParameter or None
        The coefficient (``Fits.to_fit_result().params[name]``; an ``Estimate`` is read as its
        FitParameter); None gives an entry that says the fit stage returned nothing.
    name : str
        Coefficient name, for the default unit of a missing estimate.

    Returns
    -------
    dict
        Keys ``COEFFICIENT_KEYS``; numbers are floats or None.
    """
    if est is None:
        return {"value": None, "stderr": None, "ci95": [None, None], "unit": default_unit(name),
                "n_segments": 0, "method": "", "success": False, "message": MISSING_NOTE,
                "consistency_p": None}
    est = as_parameter(est)
    ident = is_identified(est)
    message = (est.message or "").strip()
    if not ident:
        # The reason, with any value the fit itself rejected moved into the text, so a script that
        # forgets to check "success" cannot pick that value up.
        message = estimate_notes(est)[0]
    ci = tuple(est.ci95) if est.ci95 is not None else (math.nan, math.nan)
    if len(ci) != 2:
        raise ReportError(f"coefficient {est.name or name!r}: ci95 expected 2 bounds, found {len(ci)}")
    return {
        "value": _num(est.value) if ident else None,
        "stderr": _num(est.stderr) if ident else None,
        "ci95": [_num(ci[0]) if ident else None, _num(ci[1]) if ident else None],
        "unit": est.unit or default_unit(name),
        "n_segments": int(est.n_segments),
        "method": est.method or "",
        "success": bool(est.success) and ident,
        "message": message,
        "consistency_p": _num(est.consistency_p),
    }


def fits_to_dict(fits: Fits) -> dict[str, Any]:
    """The ``coefficients.json`` contract for ``fits`` (module docstring), as plain Python.

    Parameters
    ----------
    fits : Fits
        Fit results; not modified.

    Returns
    -------
    dict
        JSON-serialisable with ``allow_nan=False``.

    Raises
    ------
    ReportError
        When ``fits`` is malformed (damping matrix not 5x5, estimates not Estimate records).
    """
    check_fits(fits)
    D, D_se = checked_matrices(fits)
    params = fits.to_fit_result().params
    return {
        "vessel": str(fits.vessel),
        "convention": str(fits.convention),
        "damping_matrix": {"dofs": list(DOFS), "values": _square(D), "stderr": _square(D_se)},
        "coefficients": {name: estimate_to_dict(params.get(name), name) for name in ordered_names(params)},
        **model_structure_to_dict(fits),
        **decay_analysis_to_dict(fits),
    }


def decay_analysis_to_dict(fits: Fits) -> dict[str, Any]:
    """Additive ``decay_analysis`` field: per DOF (roll, pitch) and per release direction plus
    ``combined``, the extinction curve (``phi_m``, ``dphi`` [rad]), coefficients ``a``, ``b`` with
    covariance, ``B1`` [kg m^2/s], ``B2`` [kg m^2], ``B_eq`` at ``amplitude`` [rad], ``wn`` [rad/s], and
    the effective inertia ``C / wn^2`` beside the config's ``inertia_config`` [kg m^2]; the direction
    consistency p-value and message. Empty without free decays.

    Parameters
    ----------
    fits : Fits
        Fit results.
    """
    analyses = getattr(fits, "decay_analyses", None) or {}
    if not analyses:
        return {}
    out = {}
    for dof, a in analyses.items():
        curves = {}
        for k, c in a.curves.items():
            fr = c.to_fit_result()
            p = fr.params
            curves[k] = {"n_decays": c.n_decays, "phi_m": [_num(x) for x in c.phi_m], "dphi": [_num(x) for x in c.dphi],
                         "a": _num(p["a"].value), "b": _num(p["b"].value), "cov_ab": _square(fr.covariance[:2, :2])}
            for n in ("a_linear", "wn", "B1", "B2", "B_eq"):
                curves[k].update({n: _num(p[n].value), f"{n}_stderr": _num(p[n].stderr)})
            curves[k]["amplitude"] = _num(fr.statistics["amplitude"])
            curves[k].update({"inertia_fit": _num(p["inertia_fit"].value),
                              "inertia_fit_stderr": _num(p["inertia_fit"].stderr)})
        out[dof] = {"curves": curves, "inertia_config": _num(a.inertia_config), "restoring": _num(a.restoring),
                    "consistency_p": _num(a.consistency_p), "message": a.message}
    return {"decay_analysis": out}


def _damping_fit_dict(fit) -> dict[str, Any]:
    """One structure's joint fit: its Fossen terms with value, stderr, 95% CI, unit, and covariance.

    Read through :meth:`DampingFit.to_fit_result` (the terms) and ``shared_fit_result`` (the shared
    parameters ``a``, ``b``, ``c``, ``g_<input>``).
    """
    shared = fit.shared_fit_result()
    result: FitResult = fit.to_fit_result() if fit.terms else None
    names = list(result.params) if result is not None else []
    cov = result.covariance if result is not None else np.zeros((0, 0))
    sd = np.sqrt(np.clip(np.diag(cov), 0, None)) if cov.size else np.zeros(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd, sd) if cov.size else cov
    terms = {}
    for n in names:
        par = result.params[n]
        terms[n] = {"value": _num(par.value), "stderr": _num(par.stderr), "ci95": [_num(par.ci95[0]), _num(par.ci95[1])],
                    "unit": par.unit}
    stats = shared.statistics
    return {"terms": terms, "covariance": {"names": names, "matrix": _square(cov)},
            "correlation": {"names": names, "matrix": _square(corr)},
            "parameters": {n: {"value": _num(p.value), "stderr": _num(p.stderr)} for n, p in shared.params.items()},
            "parameter_covariance": {"names": list(shared.names), "matrix": _square(shared.covariance),
                                     "method": "Newey-West (HAC) sandwich, records independent"},
            "rmse_noise_units": _num(stats["rmse_noise_units"]), "residual_lag1": _num(stats["residual_lag1"]),
            "n_residuals": int(shared.ndata), "inertia": _num(stats["inertia"]), "success": bool(shared.success),
            "message": shared.message}


def model_structure_to_dict(fits: Fits) -> dict[str, Any]:
    """Additive ``coefficients.json`` fields of the damping-structure selection (empty without it).

    ``model_structure``: per DOF the selected structure (``linear`` or ``quadratic``), the one
    requested, both structures' joint fits (terms with value, stderr, ci95, unit; covariance and
    correlation of the terms; shared parameters), their held-out RMS errors [SI unit of the output]
    and the held-out test (p-value, robust p-value, gap shrink [%], significant); each fit also gives
    the ``inertia`` M_ii [kg or kg m^2] it used. ``quadratic_damping``:
    D2 per DOF (positive, ``D2 = -X_|u|u``) in DOF order u v p q r, null where the linear structure
    was kept. ``covariance``: the selected damping terms of every DOF with their full covariance and
    correlation matrix; terms of different DOFs come from disjoint segments and independent fits, so
    their covariance is zero.

    Parameters
    ----------
    fits : Fits
        Fit results (``fits.structures`` may be empty).

    Returns
    -------
    dict
        ``{}`` or the three keys above.
    """
    choices = getattr(fits, "structures", None) or {}
    if not choices:
        return {}
    from ..fit.quadratic import TERM_NAMES

    structure, names, blocks = {}, [], []
    d2 = [None] * 5
    d2_se = [None] * 5
    for dof, ch in choices.items():
        structure[dof] = {
            "selected": ch.selected, "requested": ch.requested, "message": ch.message, "folds": ch.folds,
            "heldout_rmse": {k: _num(v) for k, v in ch.heldout_rmse.items()},
            "p_value": _num(ch.p_value), "p_robust": _num(ch.p_robust), "shrink_percent": _num(ch.shrink),
            "explained": _num(ch.explained), "significant": bool(ch.significant),
            "models": {k: _damping_fit_dict(f) for k, f in ch.fits.items()},
        }
        sel = ch.fits[ch.selected]
        terms = sel.to_fit_result() if sel.terms else None  # the Fossen terms, not the shared parameters
        if terms is not None:
            names += list(terms.names)
            blocks.append(terms.covariance)
        quad = TERM_NAMES[dof][1]
        if ch.selected == "quadratic" and terms is not None and quad in terms.params:
            i = list(DOFS).index({"surge": "u", "sway": "v", "roll": "p", "pitch": "q", "yaw": "r"}[dof])
            d2[i] = _num(-terms.params[quad].value)
            d2_se[i] = _num(terms.params[quad].stderr)
    n = len(names)
    cov = np.zeros((n, n))
    k = 0
    for b in blocks:
        cov[k:k + b.shape[0], k:k + b.shape[0]] = b
        k += b.shape[0]
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd, sd)
    return {"model_structure": structure,
            "quadratic_damping": {"dofs": list(DOFS), "values": d2, "stderr": d2_se},
            "covariance": {"names": names, "matrix": _square(cov), "correlation": _square(corr),
                           "note": "selected damping terms of every DOF; terms of different DOFs come from "
                                   "disjoint segments and independent fits (zero covariance)"}}


def dumps(fits: Fits) -> str:
    """``coefficients.json`` text for ``fits``.

    Parameters
    ----------
    fits : Fits
        Fit results.

    Returns
    -------
    str
        Strict JSON (no NaN tokens), two-space indent, final newline.
    """
    return _pretty(fits_to_dict(fits)) + "\n"


def _pretty(obj, level: int = 0) -> str:
    """Indented JSON with flat lists on one line, so each matrix row reads as a row."""
    pad, inner = "  " * level, "  " * (level + 1)
    if isinstance(obj, dict) and obj:
        items = [f"{inner}{json.dumps(str(k))}: {_pretty(v, level + 1)}" for k, v in obj.items()]
        return "{\n" + ",\n".join(items) + f"\n{pad}}}"
    if isinstance(obj, list) and any(isinstance(x, (dict, list)) for x in obj):
        return "[\n" + ",\n".join(inner + _pretty(x, level + 1) for x in obj) + f"\n{pad}]"
    # allow_nan=False: a NaN that slipped past _num fails here instead of writing invalid JSON.
    return json.dumps(obj, allow_nan=False)


def write_coefficients_json(fits: Fits, path: str | os.PathLike) -> Path:
    """Write ``coefficients.json`` atomically.

    Parameters
    ----------
    fits : Fits
        Fit results.
    path : str or os.PathLike
        Destination file.

    Returns
    -------
    pathlib.Path
        The file written.
    """
    return atomic_write_text(path, dumps(fits))


# --------------------------------------------------------------------------- reading back
def _reject_constant(token: str):
    raise ValueError(f"{token} is not valid JSON; expected null for a missing number")


def _type_name(x) -> str:
    return "null" if x is None else type(x).__name__


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _expect(cond: bool, where: str, expected: str, found) -> None:
    if not cond:
        shown = repr(found)
        if len(shown) > 60:
            shown = shown[:57] + "..."
        raise ReportError(f"{where}: expected {expected}, found {_type_name(found)} {shown}")


def _check_matrix(m, where: str) -> None:
    n = len(DOFS)
    _expect(isinstance(m, list) and len(m) == n, where, f"a list of {n} rows", m)
    for i, row in enumerate(m):
        _expect(isinstance(row, list) and len(row) == n, f"{where}[{i}]", f"a list of {n} numbers or null", row)
        for j, x in enumerate(row):
            _expect(x is None or _is_number(x), f"{where}[{i}][{j}]", "a number or null", x)


def validate_coefficients(data: Any, source: str = "coefficients.json") -> None:
    """Check that ``data`` follows the ``coefficients.json`` contract (module docstring).

    Extra keys are allowed (later versions may add some); missing keys and wrong types are not.

    Parameters
    ----------
    data : Any
        Parsed JSON.
    source : str
        File name used in error messages.

    Raises
    ------
    ReportError
        Naming the first key whose value is missing or of the wrong type, what was expected and
        what was found.
    """
    _expect(isinstance(data, dict), source, "a JSON object at top level", data)
    for key in TOP_KEYS:
        if key not in data:
            raise ReportError(f"{source}: missing key {key!r}; expected keys {list(TOP_KEYS)}, "
                              f"found {sorted(data)}")
    _expect(isinstance(data["vessel"], str), f"{source}: vessel", "a string", data["vessel"])
    _expect(isinstance(data["convention"], str), f"{source}: convention", "a string", data["convention"])
    dm = data["damping_matrix"]
    _expect(isinstance(dm, dict), f"{source}: damping_matrix", "an object", dm)
    for key in DAMPING_KEYS:
        if key not in dm:
            raise ReportError(f"{source}: damping_matrix: missing key {key!r}; expected keys "
                              f"{list(DAMPING_KEYS)}, found {sorted(dm)}")
    _expect(dm["dofs"] == list(DOFS), f"{source}: damping_matrix.dofs", f"{list(DOFS)}", dm["dofs"])
    _check_matrix(dm["values"], f"{source}: damping_matrix.values")
    _check_matrix(dm["stderr"], f"{source}: damping_matrix.stderr")
    coefs = data["coefficients"]
    _expect(isinstance(coefs, dict), f"{source}: coefficients", "an object name -> entry", coefs)
    missing = [n for n in STANDARD_COEFFICIENTS if n not in coefs]
    if missing:
        raise ReportError(f"{source}: coefficients: missing {missing}; expected at least "
                          f"{list(STANDARD_COEFFICIENTS)}")
    for name, entry in coefs.items():
        where = f"{source}: coefficients.{name}"
        _expect(isinstance(entry, dict), where, "an object", entry)
        absent = [k for k in COEFFICIENT_KEYS if k not in entry]
        if absent:
            raise ReportError(f"{where}: missing keys {absent}; expected {list(COEFFICIENT_KEYS)}, "
                              f"found {sorted(entry)}")
        for key in ("value", "stderr", "consistency_p"):
            _expect(entry[key] is None or _is_number(entry[key]), f"{where}.{key}", "a number or null",
                    entry[key])
        ci = entry["ci95"]
        _expect(isinstance(ci, list) and len(ci) == 2 and all(x is None or _is_number(x) for x in ci),
                f"{where}.ci95", "[lo, hi] with numbers or null", ci)
        for key in ("unit", "method", "message"):
            _expect(isinstance(entry[key], str), f"{where}.{key}", "a string", entry[key])
        n = entry["n_segments"]
        _expect(isinstance(n, int) and not isinstance(n, bool) and n >= 0, f"{where}.n_segments",
                "an integer >= 0", n)
        _expect(isinstance(entry["success"], bool), f"{where}.success", "true or false", entry["success"])
        if entry["success"]:
            _expect(entry["value"] is not None, f"{where}.value", "a number when success is true",
                    entry["value"])


def load_coefficients(path: str | os.PathLike) -> dict[str, Any]:
    """Read and validate a ``coefficients.json`` written by :func:`write_coefficients_json`.

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    dict
        The parsed contract (module docstring); missing numbers are None.

    Raises
    ------
    ReportError
        When the file is missing, is not strict JSON (``NaN`` tokens included) or does not follow
        the contract; the message names what was expected and what was found.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ReportError(f"{path}: no such file; expected a coefficients.json from 'vesselid report'") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ReportError(f"{path}: cannot read: {exc}") from exc
    if not text.strip():
        raise ReportError(f"{path}: empty file; expected a JSON object")
    try:
        data = json.loads(text, parse_constant=_reject_constant)
    except json.JSONDecodeError as exc:
        raise ReportError(f"{path}: not valid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from exc
    except ValueError as exc:
        raise ReportError(f"{path}: {exc}") from exc
    validate_coefficients(data, source=str(path))
    return data


def damping_from_dict(data: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """D and its standard errors from a loaded contract, NaN where ``null``.

    Parameters
    ----------
    data : Mapping
        The dict :func:`load_coefficients` returns.

    Returns
    -------
    D, D_stderr : numpy.ndarray, shape (5, 5)
        Damping matrix (positive diagonal) [SI, see :func:`~pipeline.report.rows.damping_unit`]
        in DOF order u, v, p, q, r, and its standard errors.
    """
    dm = data["damping_matrix"]
    conv = [[math.nan if x is None else float(x) for x in row] for row in dm["values"]]
    conv_se = [[math.nan if x is None else float(x) for x in row] for row in dm["stderr"]]
    return np.array(conv, dtype=float), np.array(conv_se, dtype=float)
