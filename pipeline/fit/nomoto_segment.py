"""Fit-stage adapter: a zig-zag or sinusoid segment of a trial -> whole-record Nomoto fit -> SegmentFit."""

from __future__ import annotations

import math

import numpy as np

from ..errors import FitError
from ..records import Segment, SegmentFit, Trial
from .data import pick_channel, segment_label
from .nomoto_oe import fit_nomoto
from .nomoto_problem import MIN_SAMPLES, unwrap_heading
from .nomoto_records import NomotoRecord
from .segment_fit import MAX_RELATIVE_STDERR


#: Segment kinds the whole-record fit serves in :func:`pipeline.fit.fit_trial`.
WHOLE_RECORD_KINDS = ("zigzag", "sinusoid")
#: Parameters whose relative standard error decides ``success``.
KEY_PARAMS = ("K", "T")


def fit_nomoto_segment(trial: Trial, segment: Segment) -> SegmentFit:
    """Whole-record Nomoto fit (:func:`fit_nomoto`, ``noise="auto"``) of a zig-zag or sinusoid segment.

    The compass heading ``psi`` and, when logged, the yaw rate ``r`` are fitted against the
    logged rudder ``delta`` (zero-order hold on the trial clock). K, T and the rudder bias b are
    reported; the OE result is kept when its compass residuals are white, the wave PEM otherwise.

    Parameters
    ----------
    trial : Trial
        Trial with ``delta`` and ``psi`` and/or ``r``.
    segment : Segment
        A ``zigzag`` or ``sinusoid`` segment in yaw.

    Returns
    -------
    SegmentFit
        Model ``nomoto_oe`` or ``nomoto_pem``, channel ``psi`` (``r`` without a compass), with
        parameters ``K`` [1/s], ``T`` [s], ``b`` [rad], ``psi0`` [rad], ``r0`` [rad/s] and for the
        PEM ``omega0`` [rad/s], ``lambda`` [-], ``kw_ratio`` [s^-1/2]; ``y_fit`` is the simulated
        heading.

    Raises
    ------
    FitError
        Wrong DOF, missing channels, gaps in the rudder, too few samples.
    """
    where = segment_label(segment)
    if segment.dof != "yaw":
        raise FitError(f"{where}: expected a {segment.kind} in yaw, found DOF {segment.dof!r}")
    u_ch = segment.input_channel or "delta"
    if u_ch != "delta":
        raise FitError(f"{where}: expected the rudder (delta) as input, found {u_ch!r}")
    pick_channel(trial, segment, ["delta"])
    channels = tuple(ch for ch in ("psi", "r") if trial.has(ch))
    if not channels:
        pick_channel(trial, segment, ["psi", "r"])
    rows = trial.window(segment.t_start, segment.t_end)
    t = rows["t"].to_numpy(dtype=float)
    delta = rows["delta"].to_numpy(dtype=float)
    if t.size < MIN_SAMPLES:
        raise FitError(f"{where}: expected at least {MIN_SAMPLES} samples, found {t.size}")
    if not np.all(np.isfinite(delta)):
        raise FitError(f"{where}: expected a logged rudder on every sample, found {int((~np.isfinite(delta)).sum())} gaps")
    rec = NomotoRecord(t=t, delta=delta, psi=rows["psi"].to_numpy(dtype=float) if "psi" in channels else None,
                       r=rows["r"].to_numpy(dtype=float) if "r" in channels else None, name=where)
    fit = fit_nomoto(rec, noise="auto", channels=channels)
    main = channels[0]
    model = "nomoto_oe" if fit.noise_model == "white" else "nomoto_pem"
    fail = []
    if not fit.converged:
        fail.append("solver did not converge")
    if fit.at_bound:
        fail.append(f"parameter(s) {', '.join(fit.at_bound)} outside the plausible range")
    if not np.all(np.isfinite(fit.stderr)):
        fail.append("covariance not computed")
    for name in KEY_PARAMS:
        v, se = fit.value(name), fit.error(name)
        if math.isfinite(se) and abs(se) > MAX_RELATIVE_STDERR * abs(v):
            fail.append(f"{name} = {v:.4g} +- {se:.2g} has a relative standard error above "
                        f"{MAX_RELATIVE_STDERR:.0%}: not identified")
    notes = [fit.message]
    if segment.kind == "zigzag" and not all(t.independent for t in fit.residual_tests):
        notes.append("a zig-zag switches the rudder on the heading, so residuals that lead the rudder "
                     "(negative lags) are the expected feedback, not a model error")
    y = rec.psi if main == "psi" else rec.r
    y = unwrap_heading(y) if main == "psi" else np.asarray(y, float)
    e = fit.residuals[0][main]
    rmse = float(np.sqrt(np.nanmean(e**2)))
    return SegmentFit(segment=segment, model=model, channel=main, param_names=fit.names,
                      params={n: float(v) for n, v in zip(fit.names, fit.values)},
                      stderr={n: float(s) for n, s in zip(fit.names, fit.stderr)},
                      covariance=fit.covariance, t=t - segment.t_start, y=y, y_fit=fit.y_fit[0][main], rmse=rmse,
                      aic=fit.aic, bic=fit.bic, success=not fail, message="; ".join(fail + notes))
