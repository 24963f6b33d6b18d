"""fit stage: :class:`~pipeline.records.Segments` + vessel -> :class:`~pipeline.records.Fits`.

One module per concern: ``first_order`` (coast-downs and steps), ``second_order`` (roll/pitch free
decays), ``nomoto`` (rudder steps), ``least_squares`` (solver and Jacobian covariance),
``segment_fit`` (success checks), ``data`` (segment samples, noise level, input levels,
steadiness before a step), ``damping`` (derived coefficients with error propagation),
``combine`` (inverse-variance mean over repeated segments) and ``trial`` (:func:`fit_trial`).
Whole-record Nomoto identification: ``nomoto_oe`` (exact-ZOH output-error and wave
prediction-error fits, :func:`fit_nomoto`) built from ``nomoto_records`` (record and result),
``nomoto_zoh`` (exact sampled simulation), ``nomoto_start`` (closed-form starts),
``nomoto_problem`` (criterion, solver, covariance), ``nomoto_pem`` (the Kalman innovations filter
of the wave model) and ``nomoto_segment`` (the fit-stage adapter for zig-zags and sinusoids). The
baselines and bounds the accuracy benchmark compares them with (the seeds' amplitude method, ARX,
Cramer-Rao bounds) live in ``benchmarks/baselines/``, outside the package.
Every model has a closed-form ``guess_*`` that starts the least-squares fit.
"""

from .combine import Contribution, combine
from .first_order import decay, fit_coast_down, fit_step, guess_decay, guess_step, step_response
from .least_squares import LeastSquaresResult, confidence_interval, fit_least_squares
from .nomoto import fit_rudder_step, guess_nomoto_step, nomoto_step, nomoto_step_change
from .nomoto_oe import Nomoto2Params, NomotoFit, NomotoRecord, fit_nomoto, fit_nomoto_oe, fit_nomoto_pem, guess_nomoto, nomoto2_rhs
from .nomoto_segment import fit_nomoto_segment
from .second_order import damped_oscillation, fit_free_decay, guess_damped_oscillation
from .trial import fit_trial

__all__ = [
    "fit_trial",
    "fit_coast_down", "fit_step", "fit_free_decay", "fit_rudder_step",
    "decay", "step_response", "damped_oscillation", "nomoto_step", "nomoto_step_change",
    "guess_decay", "guess_step", "guess_damped_oscillation", "guess_nomoto_step",
    "fit_least_squares", "LeastSquaresResult", "confidence_interval",
    "combine", "Contribution",
    "fit_nomoto", "fit_nomoto_oe", "fit_nomoto_pem", "fit_nomoto_segment", "guess_nomoto", "NomotoRecord",
    "NomotoFit", "Nomoto2Params", "nomoto2_rhs",
]
