"""Every fitter's result in one shape: :func:`as_fit_result` -> :class:`pipeline.records.FitResult`.

The pipeline's fitters keep the result types their algorithms need (a prediction-error fit has
innovations, the grey-box fit a Fisher matrix, a Welch fit its spectrum); this module is the one
place that reads each of them as lmfit's shape: parameters with value, standard error and unit,
covariance, AIC/BIC, success, message and provenance. The records of ``pipeline.records``
(:class:`~pipeline.records.SegmentFit`, :class:`~pipeline.records.DampingFit`,
:class:`~pipeline.records.Fits`, :class:`~pipeline.records.Estimate`) and
:class:`~pipeline.fit.least_squares.LeastSquaresResult` convert themselves
(``to_fit_result``); this module adds the fit, autopilot and diagnosis types and dispatches on
all of them. It lives in the report stage because that is the stage allowed to import every
earlier one.

Why not lmfit itself: lmfit's ``Parameters`` and ``MinimizerResult`` hold the same numbers, but
none of the pipeline's fitters is an lmfit problem (exact-ZOH output-error and Kalman
prediction-error criteria, casadi multiple shooting, a Welch-spectrum fit), so lmfit would be a
dependency (and its asteval/uncertainties imports) used only as a container. The field names
follow lmfit's (``params[name].value``, ``.stderr``, ``covariance``, ``aic``, ``bic``,
``success``, ``message``, ``ndata``, ``nvarys``) so a reader who knows lmfit reads these.
"""

from __future__ import annotations

import math
from functools import singledispatch

import numpy as np

from ..diagnose.candidates import Fitted
from ..fit.greybox import UNITS as GREYBOX_UNITS
from ..fit.greybox import GreyBoxFit
from ..fit.least_squares import LeastSquaresResult
from ..fit.nomoto_records import NomotoFit
from ..records import (AutopilotConfig, DampingFit, Estimate, Extinction, FitParameter, FitResult, Fits,
                       NomotoCoefficients, SegmentFit, fit_result_from_arrays, parameter_unit)

__all__ = ["as_fit_result"]


@singledispatch
def as_fit_result(result) -> FitResult:
    """``result`` (any fitter's output) as a :class:`~pipeline.records.FitResult`.

    Parameters
    ----------
    result : object
        A :class:`~pipeline.records.SegmentFit`, :class:`~pipeline.records.DampingFit`,
        :class:`~pipeline.records.Fits`, :class:`~pipeline.records.Estimate`,
        :class:`~pipeline.records.Extinction`, ``LeastSquaresResult``, ``NomotoFit``,
        ``GreyBoxFit``, diagnosis ``Fitted``, ``NomotoCoefficients``, ``AutopilotConfig``, or a
        ``FitResult`` already (such as the wave-spectrum fit's ``WaveFit``), returned as it is.

    Returns
    -------
    FitResult

    Raises
    ------
    TypeError
        For a type no converter is registered for (names what was expected and found).
    """
    known = ", ".join(sorted(t.__name__ for t in as_fit_result.registry if t is not object))
    raise TypeError(f"as_fit_result: expected one of {known}, found {type(result).__name__}")


@as_fit_result.register
def _(result: SegmentFit) -> FitResult:
    return result.to_fit_result()


@as_fit_result.register
def _(result: DampingFit) -> FitResult:
    return result.to_fit_result()


@as_fit_result.register
def _(result: Fits) -> FitResult:
    return result.to_fit_result()


@as_fit_result.register
def _(result: LeastSquaresResult) -> FitResult:
    return result.to_fit_result()


@as_fit_result.register
def _(result: Estimate) -> FitResult:
    par = result.to_parameter()
    return FitResult(model=result.method or "estimate", params={par.name: par},
                     covariance=np.array([[par.stderr ** 2]]), success=par.success, message=par.message,
                     provenance={"fitter": "pipeline.fit (combined estimate)",
                                 "data": f"{result.n_segments} segment(s)"})


@as_fit_result.register
def _(result: NomotoFit) -> FitResult:
    units = {n: parameter_unit(n) for n in result.names}
    model = f"nomoto{result.order}_{'pem' if result.noise_model == 'waves' else 'oe'}"
    ok = bool(result.converged) and not result.at_bound and bool(np.all(np.isfinite(result.values)))
    msg = result.message
    if result.at_bound:
        msg = (msg + "; " if msg else "") + f"outside the plausible range: {', '.join(result.at_bound)}"
    return fit_result_from_arrays(
        model, result.names, result.values, result.stderr, result.covariance, units, dof=max(result.n - len(result.names), 1),
        aic=float(result.aic), bic=float(result.bic), success=ok, message=msg, ndata=int(result.n),
        provenance={"fitter": "pipeline.fit.nomoto_oe.fit_nomoto",
                    "data": f"{len(result.y_fit)} record(s), channels {', '.join(result.channels)}",
                    "covariance": "inverse Fisher information of the "
                                  + ("whitened (innovations) residuals" if result.noise_model == "waves"
                                     else "output-error residuals")},
        statistics={"neg2loglik": float(result.neg2loglik)})


@as_fit_result.register
def _(result: GreyBoxFit) -> FitResult:
    units = {n: GREYBOX_UNITS.get(n, "") for n in result.names}
    dof = max(result.n - len(result.names), 1)
    ok = bool(result.converged) and bool(np.all(np.isfinite(result.values)))
    msg = result.message
    if result.fixed:
        msg = (msg + "; " if msg else "") + "held fixed: " + ", ".join(f"{k} ({v})" for k, v in result.fixed.items())
    return fit_result_from_arrays(
        "greybox_coupled_damping", result.names, result.values, result.stderr, result.covariance, units, dof=dof,
        success=ok, message=msg, ndata=int(result.n),
        provenance={"fitter": "pipeline.fit.greybox.fit_coupled_damping", "method": result.method,
                    "data": f"{len(result.records)} record(s), outputs {', '.join(result.outputs)}",
                    "covariance": "s^2 F^-1 (pseudo-inverse on the determined subspace), long-run variance "
                                  "of the residuals"},
        statistics={"s2": float(result.s2), "max_defect": float(result.max_defect), "elapsed_s": float(result.elapsed)})


@as_fit_result.register
def _(result: FitResult) -> FitResult:
    return result  # already the shape (the wave-spectrum fit's WaveFit is one)


@as_fit_result.register
def _(result: Fitted) -> FitResult:
    names = tuple(result.params)
    units = {n: ("s" if n == "T" else parameter_unit(n)) for n in names}
    values = [float(result.params[n]) for n in names]
    ok = bool(np.all(np.isfinite(values)))
    params = {n: FitParameter(n, v, math.nan, units[n], method="diagnosis candidate",
                              message="no standard error: the candidate is judged by held-out error")
              for n, v in zip(names, values)}
    return FitResult(model="diagnosis_candidate", params=params,
                     covariance=np.full((len(names), len(names)), math.nan), success=ok,
                     message=("" if ok else "non-finite parameter values; ")
                     + "values only: the candidate is judged by held-out cross-validation, not by its errors",
                     provenance={"fitter": "pipeline.diagnose.candidates",
                                 "effect parameters": ", ".join(result.effect_params)},
                     statistics={"sse": float(result.sse)})


@as_fit_result.register
def _(result: AutopilotConfig) -> FitResult:
    return result.to_fit_result()


@as_fit_result.register
def _(result: NomotoCoefficients) -> FitResult:
    return result.to_fit_result()


@as_fit_result.register
def _(result: Extinction) -> FitResult:
    return result.to_fit_result()

