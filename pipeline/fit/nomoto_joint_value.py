"""T read from the joint second-order fit of a trial's rudder steps, in place of the fits' combination.

The fit is made by :func:`pipeline.fit.nomoto_joint.joint_step_fit`, which hands its T on as the segment
fits' ``joint_t`` field (:class:`pipeline.records.JointNomotoT`, with the user-facing ``JOINT_T`` note in their
messages); this module is kept free of the fitters' imports, so that :mod:`pipeline.fit.nomoto_quality` can
read it without an import cycle.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Sequence

from ..records import Estimate, JointNomotoT, SegmentFit
from .least_squares import confidence_interval

#: Start of the note with T from the joint second-order fit of the rudder steps
#: (``JOINT_T <n> rudder steps (...): T = <v> +- <se> s (...)``).
JOINT_T = "T from the joint second-order fit of"


def joint_t_value(est: Estimate, fits: Sequence[SegmentFit]) -> Estimate | None:
    """T from the joint second-order fit of the rudder steps, in place of the fits' combination (None when
    the segment fits carry none).

    Where the first-order Nomoto model is kept with the structure undecided, the per-step first-order
    T is biased by the pole-zero pair it lacks (PythonVehicleSimulator's tanker at 20 m, noise-free: -9
    to -35 % per step), and a second order fitted step by step is not identified under noise (3 of 30
    per-step fits did not converge). The first-order equivalent ``T1 + T2 - T3`` of a second-order
    model fitted to every step at once is the low-frequency lag of the response whatever the ship's
    structure (a first-order ship gives ``T3 = T2``), so it holds for either structure. Where the second
    order is chosen, the vector pooled from the per-step fits carries each step's nonlinear-estimator
    bias (the same tanker, measured rudder without waves, seeds 0-2: T +3.7, +8.0, +10.2 % with errors of
    3.4-4.2 %, marked success), which one fit of all the steps does not.
    :func:`pipeline.fit.nomoto_joint.joint_step_fit` gives it with its error (Newey-West where the
    residuals are coloured). That error assumes one linear model for every step; the ship's own misfit
    (the tanker's speed loss in its turns: the best linear fit to the noise-free record is +2.7 % off) is a
    bias common to the steps, so the fits' combined error (with the between-step spread of the pooled
    vector, or the first order's) is kept where it is larger (measured: the tanker, measured rudder without
    waves, seeds 0-9: the joint fit's own error 1.2-1.6 %, its interval holding the truth on 4 of 9 seeds
    marked success). The fits' combination stays in the message.

    Parameters
    ----------
    est : Estimate
        The combined T.
    fits : sequence of SegmentFit
        The segment fits behind it (their ``joint_t`` field carries the joint fit's T).
    """
    joint = joint_of(fits)
    if joint is None:
        return None
    note, value, se = joint.note, joint.value, joint.stderr
    if not (math.isfinite(est.value) and value > 0 and se > 0 and math.isfinite(value + se)):
        return None
    own = se
    if math.isfinite(est.stderr) and est.stderr > se:
        # One linear model fitted to every step: its error counts no misfit common to the steps (a speed
        # change in the turns), which the fits' spread does.
        se = est.stderr
    head = (f"{note}; the fits' combination gave {est.value:.4g} +- {est.stderr:.2g} {est.unit}"
            + (f", whose error is kept (the joint fit's own {own:.3g} {est.unit} counts no misfit common to the "
               f"steps)" if se > own else ""))
    return replace(est, value=value, stderr=se, ci95=confidence_interval(value, se, math.inf),
                   message=f"{head}; {est.message}" if est.message else head)


def joint_of(fits: Sequence[SegmentFit]) -> JointNomotoT | None:
    """The joint fit's T carried by the fits (the first ``joint_t`` field set; None when none is).

    Parameters
    ----------
    fits : sequence of SegmentFit
        Segment fits of one trial.
    """
    return next((j for j in (getattr(f, "joint_t", None) for f in fits) if j is not None), None)
