"""When a combined Nomoto K or T is unsure: the rules applied after the segments are combined.

A Nomoto estimate is marked ``success = False`` with a message that starts with ``unsure:`` and
gives the reason (the value, its error and the per-segment values stay in the record, so the
report, coefficients.json and the CLI show what was found and why it is not trusted) when:

- the segments disagree beyond their errors (chi-square heterogeneity test of
  :func:`pipeline.fit.combine.combine`, ``p < CONSISTENCY_ALPHA``) *and* the disagreement is
  material: the per-segment values' standard deviation exceeds ``HETEROGENEITY_MATERIAL`` of the
  combined value. A model that fits each manoeuvre but gives different K or T per manoeuvre is a
  wrong structure (an unmodelled pole-zero pair, servo, speed loss, nonlinearity): no single
  value is right then, and the random-effects interval only says how wide the spread is.
- its relative standard error exceeds ``UNSURE_RELATIVE_STDERR``: the 95 % interval spans more
  than about +-20 % of the value, so "success" would not say that the number is good to 20 %.

- every segment behind it is a sinusoid and there is only one: a first-order model matched at
  one frequency reproduces the ship's gain and phase there whatever its structure, so K and T are
  the ship's only if it is first order, which one frequency cannot show (measured: a tanker's
  fast sinusoid gave T +42 % with white residuals). Two or more sinusoids alone are unsure when
  their values spread by more than ``HETEROGENEITY_MATERIAL`` of the combined value, significant
  or not (measured: a Clarke83 pair with waves, T 2.96 +- 0.50 s fast and 4.18 +- 0.008 s slow,
  passed the chi-square test at p = 0.015 and gave T +57 % marked success). Their K is unsure
  too when that T spread is flagged and the K values disagree beyond their errors
  (:func:`sinusoid_k_reason`). Sinusoids fitted one by one of which fewer than two identify T to within
  ``HETEROGENEITY_MATERIAL`` are the one-sinusoid case (:func:`sinusoid_check_reason`).

- the segments' values trend with the rudder amplitude (:func:`nonlinear_reason`): the ship is
  nonlinear, and a linear K or T holds for one amplitude only.

- the structure chosen across the trial's segments is a near-tie whose first- and second-order
  values of this coefficient differ materially on most segments (``STRUCTURE_UNDECIDED`` in the
  segment fits' messages, :func:`pipeline.fit.nomoto_structure.undecided_note`), or the held-out
  errors did not decide the structure clearly and the two structures' values differ beyond their
  errors (:func:`pipeline.fit.nomoto_structure.structure_term_notes`).

First, when every segment behind K and T is a second-order fit, both are read from the pooled
vector of the segments' (K, T1 + T2, T1 T2, T3) (:func:`pooled_estimates`,
:mod:`pipeline.fit.nomoto_pool`); its segments' heterogeneity is in its random-effects error (the
error of the mean under the multivariate DerSimonian-Laird spread), and the per-segment spread rule above
is not applied to it (a segment's own second-order T is biased).

Where the segments disagree, the rules below read K and T with the random-effects *prediction* error
(the mean's error plus the between-segment spread, as :func:`pipeline.fit.combine.combine` and
:func:`pipeline.fit.nomoto_pool.pool_second_order` give it): whether a value is trusted depends on how far
one more manoeuvre could fall from it. A first-order K or T then reports the mean's error, with the same
terms (:func:`without_spread`): the prediction error read the truth as one more segment, and on segments
that scatter about it (a Norrbin ship's steps into and out of turns) it was a bound (benchmarks/RESULTS.md,
"Coverage over 20 seeds (ident37)": PythonVehicleSimulator's frigate, z rms 0.31 with it, 0.61 without, over
37 estimates at 1 and 5 Hz). K and T from the pooled second-order vector keep the prediction error: there
the spread held a bias common to the segments (Clarke83 steps, K z rms 0.92-1.46 with it, 1.34-1.76 without,
one more miss in 4). Values and success flags are those of the prediction error's rules, unchanged.

Before these rules, a model-structure term (``STRUCTURE_TERM`` notes in the segment fits'
messages: the difference between the first- and second-order values where the structure was not
decided clearly or the two disagree) is added in quadrature to the combined standard error and the
95 % interval is widened to match (:func:`add_structure_term`): a structure bias is common to all
segments, so it is added after combining, never averaged down. K and T get a re-timing term the same way
(:func:`retime_term`, ``RETIME_TERM`` notes): the largest difference between a rudder step's fits at constant
speed and re-timed on the distance sailed where its held-out end chose neither
(:func:`pipeline.fit.nomoto_segment.choose_retiming`; a speed change is common to the steps). T gets a rudder-timing term the same way
where a measured rudder angle jumps within a sample interval or drives a sinusoid (:func:`rudder_timing_term`,
``h / sqrt(12)``: the jumps' moments, or the servo's path between the samples, are known only to within the
interval), and is unsure where half that interval exceeds
``UNSURE_RELATIVE_STDERR`` of it (:func:`rudder_timing_reason`). A speed term follows
(:func:`add_speed_term`): half the largest relative speed loss in the turns of the records behind K or T
(``SPEED_RANGE`` notes of :func:`pipeline.fit.nomoto_segment.speed_range_note`) times the value,
because Nomoto's K and T scale with the speed and a ship slows in its turns; it is added only where the
segments' values show a speed dependence (:func:`speed_trend`: a trend with their speed loss, or a
disagreement beyond their errors), not on a ship whose K and T do not change with the speed; where
the largest loss exceeds ``SPEED_MATERIAL``, the straight-run value is instead the intercept at zero
loss of the segments' values against their losses, or, when that line cannot be extrapolated, the
value is unsure (:func:`straight_run_value`), as it is when one segment (a single zig-zag) lost more than
``SPEED_MATERIAL``. K or T is also unsure when rudder steps into a turn and
steps out of one give different values (:func:`superposition_reason`: a linear ship's step response
does not depend on where the step starts) or differ by more than 10 % (the two halves of the steps do not
reproduce the value), and the other of the two is unsure when one of them differs beyond its errors
(:func:`superposition_other_reason`: the ship is nonlinear over the range its steps covered).
A combined first-order K or T is also unsure when it differs materially and beyond its error from
the first-order fit of all the segments' records with one rudder bias (:func:`shared_bias_reason`, the
fit by :func:`pipeline.fit.nomoto_structure.shared_bias_note`): the per-segment biases then took up
dynamics the first order misses.
The per-segment rules (a near-tie between first- and second-order Nomoto whose K or T differ
materially; a second order called for but not fitted) are in :mod:`pipeline.fit.nomoto_segment`.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace

import numpy as np
from scipy import stats

from typing import Sequence

from ..records import Estimate, SegmentFit
from .combine import CONSISTENCY_ALPHA
from .least_squares import confidence_interval
from .nomoto_amplitude import AMPLITUDE_K, AMPLITUDE_NOT_KEPT, amplitude_note, step_line, undecided_reason
from .nomoto_joint_value import JOINT_T, joint_t_value
from .nomoto_pool import POOLED_NOTE, is_joint_follower, pool_second_order
from .segment_fit import MAX_RELATIVE_STDERR

#: Relative between-segment standard deviation that makes a significant disagreement material [-].
HETEROGENEITY_MATERIAL = 0.10
#: Relative standard error above which a Nomoto K or T is not marked success [-] (95 % CI ~ +-20 %).
UNSURE_RELATIVE_STDERR = 0.10
#: Start of the note a trial-level near-tie between the Nomoto structures leaves in segment-fit
#: messages, followed by the coefficients it leaves undecided (``K``, ``T``).
STRUCTURE_UNDECIDED = "unsure: model structure undecided for"
#: Start of the note that carries the difference between a rudder step's fits at constant speed and re-timed on
#: the distance sailed where the held-out data chose neither (``RETIME_TERM <K|T>: +-<value> <unit>``, written by
#: :func:`pipeline.fit.nomoto_segment.choose_retiming`; read by :func:`retime_term`).
RETIME_TERM = "re-timing term for"
#: Start of the note that carries a model-structure term (``STRUCTURE_TERM <K|T>: +-<value> <unit>``);
#: the same text as ``pipeline.fit.nomoto_structure.STRUCTURE_TERM_PREFIX``.
STRUCTURE_TERM = "model-structure term for"
#: Start of the note that gives the speed a Nomoto window's turns lost (relative to the straight-run
#: speed, then the channel and the speeds in m/s), written by
#: :func:`pipeline.fit.nomoto_segment.speed_range_note`.
SPEED_RANGE = "speed lost in the turns:"
#: Start of the note with the first-order fit of all the segments' records with one rudder bias
#: (``SHARED_BIAS <n> records (first order): K = <v> +- <se> 1/s, T = <v> +- <se> s, ...``), written by
#: :func:`pipeline.fit.nomoto_structure.shared_bias_note`.
SHARED_BIAS = "fitted with one rudder bias over all"
#: Start of the note with K from the rudder steps' steady levels (``STEADY_K: <why>: K = <v> +- <se> 1/s (...)``),
#: written by :func:`pipeline.fit.nomoto_steady.steady_level_note` where the structure is undecided; read by
#: :func:`steady_k_value`.
STEADY_K = "K from the steady levels"
#: Joins the ``STEADY_K`` note and the steady levels' superposition break (read by :func:`judge_nomoto`).
STEADY_BROKEN = ", superposition broken: "
#: Words of the model-structure note of K from sinusoids that fix the second order's constants exactly
#: (:func:`pipeline.fit.nomoto_structure.exact_fit_k_term`; read by :func:`straight_run_value`).
EXACT_FIT = "sinusoids fix the second order's constants exactly"
#: Start of the note with the rudder-timing term of T (``RUDDER_TIMING +-<value> s ...``), written by
#: :func:`pipeline.fit.nomoto_structure.with_rudder_timing_note` where the rudder jumps within a sample interval
#: or drives a sinusoid.
RUDDER_TIMING = "rudder-timing term for T:"
#: Start of the note of a lone zig-zag's rudder-delay term (``RUDDER_DELAY_TERM K: +-<value> 1/s ...``), written by
#: :func:`pipeline.fit.nomoto_rudder_delay.with_rudder_delay`: the error of the rudder-to-heading delay fitted with
#: K and T, carried into each.
RUDDER_DELAY_TERM = "rudder-delay term for"
#: Relative difference between the combined and the one-bias K or T that is material [-].
SHARED_BIAS_MATERIAL = 0.02
#: |z| of that difference (Hausman's) beyond which the two disagree.
SHARED_BIAS_Z = 2.0
#: The estimates these rules judge.
NOMOTO_ESTIMATES = ("K_nomoto", "T_nomoto")


def unsure_reasons(est: Estimate, kinds: Sequence[str] = ()) -> list[str]:
    """Why a combined Nomoto estimate is unsure (empty when it is not).

    Parameters
    ----------
    est : Estimate
        A combined ``K_nomoto`` or ``T_nomoto``.
    kinds : sequence of str
        Segment kinds of the successful Nomoto segment fits behind it (``rudder_step``, ``zigzag``,
        ``sinusoid``).
    """
    out = []
    if not (est.success and math.isfinite(est.value) and est.value != 0):
        return out
    if len(kinds) == 1 and kinds[0] == "sinusoid":
        out.append("unsure: one sinusoid only: a first-order model matched at one frequency gives the ship's K "
                   "and T only if the ship is first order, which one frequency cannot show (add a rudder step, a "
                   "zig-zag or a sinusoid at another frequency)")
    x = np.asarray(est.per_segment, float)
    if kinds and all(k == "sinusoid" for k in kinds) and x.size >= 2:
        spread = float(np.std(x, ddof=1)) / abs(est.value)
        if spread > HETEROGENEITY_MATERIAL:
            out.append(f"unsure: sinusoids only, and their values spread by {spread:.0%} of the combined value "
                       f"(> {HETEROGENEITY_MATERIAL:.0%}; from {x.min():.4g} to {x.max():.4g} {est.unit}): sinusoids "
                       f"show the ship's structure only by agreeing across frequencies, and a spread covered by "
                       f"one segment's wide error is not agreement (the combined value is then the other "
                       f"frequency's first-order match)")
            return out + _rel_reason(est)
    p = est.consistency_p
    # K and T from the pooled second-order vector carry the segments' heterogeneity in their
    # random-effects error; a second-order segment's own T is biased, so its spread is not tested.
    pooled = POOLED_NOTE in est.message
    if x.size >= 2 and math.isfinite(p) and p < CONSISTENCY_ALPHA and not pooled:
        spread = float(np.std(x, ddof=1)) / abs(est.value)
        if spread > HETEROGENEITY_MATERIAL:
            out.append(f"unsure: the {x.size} segments disagree beyond their errors (chi-square p = {p:.2g} < "
                       f"{CONSISTENCY_ALPHA}) and their values spread by {spread:.0%} of the combined value "
                       f"(> {HETEROGENEITY_MATERIAL:.0%}; from {x.min():.4g} to {x.max():.4g} {est.unit}): one "
                       f"Nomoto model does not describe every manoeuvre alike (model structure, servo, speed or "
                       f"nonlinear effects)")
    return out + _rel_reason(est)


def _rel_reason(est: Estimate) -> list[str]:
    rel = abs(est.stderr) / abs(est.value) if math.isfinite(est.stderr) else math.inf
    if rel > UNSURE_RELATIVE_STDERR:
        return [f"unsure: relative standard error {rel:.0%} above {UNSURE_RELATIVE_STDERR:.0%} (the 95 % "
                f"interval spans more than about +-{2 * UNSURE_RELATIVE_STDERR:.0%} of the value)"]
    return []


def judge_nomoto(estimates: dict[str, Estimate], fits: Sequence[SegmentFit] = ()) -> dict[str, Estimate]:
    """``estimates`` with the combined Nomoto K and T marked unsure where :func:`unsure_reasons` says so.

    Parameters
    ----------
    estimates : dict[str, Estimate]
        Name -> estimate; not modified.
    fits : sequence of SegmentFit
        The successful Nomoto segment fits behind them (their segment kinds are used).

    Returns
    -------
    dict[str, Estimate]
        A new mapping; an unsure estimate keeps its value and error, gets ``success = False`` and
        the reasons at the start of its message.
    """
    out = pooled_estimates(dict(estimates), fits)
    spreads = {name: spread_in_error(out[name], fits) for name in NOMOTO_ESTIMATES if name in out}
    kinds = [f.segment.kind for f in fits]
    t_est = out.get("T_nomoto")
    # T's reasons first: sinusoids whose T spread marks a structure error make their K suspect too.
    t_why = unsure_reasons(t_est, kinds) if t_est is not None else []
    for name in NOMOTO_ESTIMATES:
        est = out.get(name)
        if est is None:
            continue
        short = name.split("_")[0]
        steady = steady_k_value(est, fits) if short == "K" else joint_t_value(est, fits)
        amp, amp_why = amplitude_k_value(est, fits) if short == "K" else (None, [])
        if amp is not None and AMPLITUDE_NOT_KEPT in amp.message.split("; ")[0]:
            est, amp = amp, None  # the constant model stays; the note says why
        bias_why = shared_bias_reason(est, fits, short) if amp is None else []
        fitted = est
        if amp is not None:
            # K at zero amplitude: the speed each hold settled at is set by its rudder angle, so the speed lost
            # in the turns is in the amplitude line (its cause modelled), and the one-bias fit averages over the
            # amplitudes (another quantity); the steps' superposition still judges it (below).
            est, speed_why = amp, []
            spreads.pop(name, None)  # the line's own error
        else:
            est, speed_why = straight_run_value(est, fits, short)
        if est.value != fitted.value:
            spreads.pop(name, None)  # the straight-run line's own error
        est = add_structure_term(est, structure_term(fits, short))
        if steady is not None:
            # The steady levels' K depends neither on the transient's structure nor on the rudder bias; it is
            # read at the turns' speed (the speed term applies whatever the fits' trend). It replaces the fits'
            # when its error (with the settling and speed terms) is no larger: holds too short to settle leave
            # the fits' value.
            if not (short == "K" and AMPLITUDE_K in steady.message.split("; ")[0]):
                steady = add_speed_term(steady, speed_range(fits), STEADY_K if short == "K" else JOINT_T)
            if steady.stderr <= est.stderr or short == "T":
                # A joint fit's T (its error at least the fits') keeps the speed trend's and the steps'
                # superposition rules (below).
                est, bias_why, speed_why = steady, [], (speed_why if short == "T" else [])
                if short == "K":
                    amp_why = []  # the steady levels' own amplitude line is in their note
                spreads.pop(name, None)  # the steady levels' or the joint fit's own error
            else:
                steady = None
        est = add_structure_term(est, retime_term(fits, short), "re-timing term (the held-out end chose neither the "
                                 "constant-speed nor the re-timed fit)")
        est = add_structure_term(est, rudder_timing_term(fits, short),
                                 "rudder-timing term" + (" (K's slope on T in the fit times T's)" if short == "K" else ""))
        delay, delay_why = rudder_delay_term(fits, short)
        est = add_structure_term(est, delay, f"rudder-delay term ({delay_why})")
        out[name] = est
        why = amp_why + bias_why + speed_why + unsure_reasons(est, kinds)
        if name == "K_nomoto":
            why += sinusoid_k_reason(est, kinds, t_why)
        why += sinusoid_check_reason(est, fits)
        why += nonlinear_reason(est, fits, short) if amp is None or steady is not None else []
        why += rudder_timing_reason(est, fits, short)
        if steady is not None and short == "K":
            # The steady levels' own superposition test (and T's break: a nonlinear ship); the transients' K
            # and the structure left undecided concern the fits' K, not this one.
            note = next((p for p in est.message.split("; ") if p.startswith(STEADY_K)), "")
            broken = note.partition(STEADY_BROKEN)[2] if est.success else ""
            why += ([f"unsure: nonlinear: {broken}"] if broken else []) or superposition_other_reason(est, out, fits, short)
        else:
            why += superposition_reason(est, fits, short) or superposition_other_reason(est, out, fits, short)
        for part in dict.fromkeys(p for f in fits for p in f.message.split("; ") if p.startswith(STRUCTURE_UNDECIDED)):
            if steady is not None:
                continue
            if est.success and f" {short} " in part.split(":")[1] + " ":
                kept = minority_note_kept(fits, part, short)
                if kept:
                    est = replace(est, message="; ".join([kept] + ([est.message] if est.message else [])))
                    out[name] = est
                else:
                    why.insert(0, part)
        if why:
            out[name] = replace(est, success=False, message="; ".join(why + ([est.message] if est.message else [])))
    for name, spread in spreads.items():
        if spread is not None:
            out[name] = without_spread(out[name], *spread)
    return out


#: Words of :func:`pipeline.fit.combine.prediction_stderr`'s note, after ``standard error <mean> -> <prediction>
#: <unit>``.
PREDICTION_NOTE = "with the between-segment spread (random-effects prediction error"


def spread_in_error(est: Estimate, fits: Sequence[SegmentFit]) -> tuple[float, float] | None:
    """The prediction error a combined K or T carries and the random-effects mean's error under it (None when
    its error is no prediction error).

    From :func:`pipeline.fit.combine.combine` (its ``standard error <mean> -> <prediction>`` note; the
    prediction error is the estimate's own error). K and T read from the pooled second-order vector keep theirs
    (None).

    Parameters
    ----------
    est : Estimate
        K or T as combined (before the terms of :func:`judge_nomoto`).
    fits : sequence of SegmentFit
        The segment fits behind it.

    Returns
    -------
    (float, float) or None
        The prediction error and the mean's error [unit of the estimate].
    """
    if not (math.isfinite(est.value) and math.isfinite(est.stderr) and est.stderr > 0):
        return None
    if POOLED_NOTE in est.message:
        # The pooled second-order vector keeps its spread: there it was no bound (Clarke83 steps, K z rms
        # 0.92-1.46 with it, 1.34-1.76 without; module doc).
        return None
    m = re.search(r"standard error (\S+) -> (\S+) \S+ " + re.escape(PREDICTION_NOTE), est.message)
    if not m:
        return None
    try:
        mean = float(m.group(1))
    except ValueError:
        return None
    return (est.stderr, mean) if 0 < mean < est.stderr else None


def without_spread(est: Estimate, prediction: float, mean: float) -> Estimate:
    """``est`` whose error holds the prediction error ``prediction`` with the mean's error ``mean`` in its place
    (the terms added in quadrature since kept) and its 95 % interval to match.

    Parameters
    ----------
    est : Estimate
        K or T after :func:`judge_nomoto`'s terms and rules.
    prediction, mean : float
        The prediction error inside its standard error, and the random-effects mean's error [unit of it].
    """
    var = est.stderr**2 - prediction**2 + mean**2
    if not (math.isfinite(var) and var > 0 and math.isfinite(est.value)):
        return est
    se = math.sqrt(var)
    note = (f"standard error {est.stderr:.4g} -> {se:.4g} {est.unit}: the random-effects mean's error {mean:.4g} in "
            f"place of the prediction error {prediction:.4g} (the between-segment spread, which the rules above "
            f"read, is not in the error: on segments that scatter about the truth it was a bound)")
    parts = est.message.split("; ") if est.message else []
    lead = next((i for i, part in enumerate(parts) if not part.startswith("unsure:")), len(parts))
    # The unsure reasons stay first (what the report shows of a value not marked success).
    return replace(est, stderr=se, ci95=confidence_interval(est.value, se, math.inf),
                   message="; ".join(parts[:lead] + [note] + parts[lead:]))


def amplitude_k_value(est: Estimate, fits: Sequence[SegmentFit]) -> tuple[Estimate | None, list[str]]:
    """K at zero rudder amplitude from the rudder steps' own K, and why K is unsure ((None, []) where the
    amplitude model is not identified).

    :func:`pipeline.fit.nomoto_amplitude.step_line` fits ``K(delta) = K0 (1 + a delta^2)`` across the steps;
    where its slope is significant the estimate is ``K0`` with the extrapolation's error, else ``est`` with
    a note (its first part) that the constant model was kept. A constant model kept whose K lies more than
    ``AMPLITUDE_UNDECIDED`` of it and ``AMPLITUDE_LEAN`` standard errors of the difference from the line's
    ``K0`` is unsure (:func:`pipeline.fit.nomoto_amplitude.undecided_reason`): the test could not decide a difference
    that matters (measured: PythonVehicleSimulator's Clarke83 steps re-timed, seeds 4 and 8 of 0-9, slope
    p = 0.06 and 0.12, the constant K -1.8 % off with an error of 0.3 %, K0 -0.1 and -0.6 %).

    Parameters
    ----------
    est : Estimate
        The combined K (or the pooled second-order vector's).
    fits : sequence of SegmentFit
        The segment fits behind it (all rudder steps, else None).
    """
    if not math.isfinite(est.value):
        return None, []
    line = step_line(fits)
    if line is None:
        return None, []
    note = amplitude_note(line, est.unit)
    if not line.kept:
        reason = undecided_reason(line, est.unit)
        why = [f"unsure: {reason}"] if reason else []
        return replace(est, message="; ".join([note] + ([est.message] if est.message else []))), why
    msg = [note, f"the steps' combination gave {est.value:.4g} +- {est.stderr:.2g} {est.unit}"]
    return replace(est, value=line.k0, stderr=line.se_k0, ci95=confidence_interval(line.k0, line.se_k0, math.inf),
                   message="; ".join(msg + ([est.message] if est.message else []))), []


def steady_k_value(est: Estimate, fits: Sequence[SegmentFit]) -> Estimate | None:
    """K read from the rudder steps' steady levels, in place of the fits' combination (None when not given).

    Where the first-order Nomoto model is kept with the structure undecided, the whole-record fits read
    K from the transients too, where the structure's bias sits; a step's K is a steady-state gain, and
    :func:`pipeline.fit.nomoto_steady.steady_level_note` reads it from the turn rates between steady
    holds (measured: PythonVehicleSimulator's tanker at 20 m, commanded steps noise-free, secants -0.68
    to -1.18 % against the first order's -1.74 % mean). The combination of the fits stays in the message.

    Parameters
    ----------
    est : Estimate
        The combined K (not from the pooled second-order vector).
    fits : sequence of SegmentFit
        The segment fits behind it (their messages carry the ``STEADY_K`` note).
    """
    if not math.isfinite(est.value) or POOLED_NOTE in est.message:
        return None
    note = next((p for f in fits for p in f.message.split("; ") if p.startswith(STEADY_K)), "")
    m = re.search(r": K = (\S+) \+- (\S+) 1/s", note)
    if not m:
        return None
    try:
        value, se = float(m.group(1)), float(m.group(2))
    except ValueError:
        return None
    if not (math.isfinite(value) and math.isfinite(se) and se > 0):
        return None
    msg = [note, f"the fits' combination (transient and levels) gave {est.value:.4g} +- {est.stderr:.2g} {est.unit}"]
    return replace(est, value=value, stderr=se, ci95=confidence_interval(value, se, math.inf),
                   message="; ".join(msg + ([est.message] if est.message else [])))


def shared_bias_reason(est: Estimate, fits: Sequence[SegmentFit], short: str) -> list[str]:
    """Why K or T is unsure when the segments' records fitted with one rudder bias give another value.

    :func:`pipeline.fit.nomoto_structure.shared_bias_note` fits the first order to all the records at
    once with one rudder bias. If the ship were first order with a constant rudder offset, both that
    fit and the combination of the per-segment fits (each with its own bias) would be consistent, the
    joint one the more efficient: their difference ``d`` then has the variance ``se_combined^2 -
    se_joint^2`` (Hausman 1978), taken at least ``se_joint^2``. When ``|d|`` exceeds ``SHARED_BIAS_Z``
    of that and ``SHARED_BIAS_MATERIAL`` of the value, the value depends on how the bias is modelled:
    the per-segment biases took up dynamics the first order misses, and neither value is the ship's
    (measured: PythonVehicleSimulator's tanker at 20 m, measured-rudder steps with waves, T +14.6 %
    combined against +5.2 % with one bias, truth from the linearisation). Empty otherwise, and for
    K and T read from the pooled second-order vector.

    Hausman, J. A. (1978). Specification tests in econometrics. Econometrica 46, 1251-1271.

    Parameters
    ----------
    est : Estimate
        The combined K or T, before the structure and speed terms (both fits share those).
    fits : sequence of SegmentFit
        The segment fits behind it (their messages carry the one-bias fit's note).
    short : str
        ``K`` or ``T``.
    """
    if not (est.success and math.isfinite(est.value) and est.value != 0 and math.isfinite(est.stderr)):
        return []
    if POOLED_NOTE in est.message:
        return []
    note = next((p for f in fits for p in f.message.split("; ") if p.startswith(SHARED_BIAS)), "")
    m = re.search(rf"\b{short} = (\S+) \+- (\S+) ", note)
    if not m:
        return []
    try:
        value, se = float(m.group(1)), float(m.group(2))
    except ValueError:
        return []
    d = est.value - value
    sd = math.sqrt(max(est.stderr**2 - se**2, se**2))
    rel = abs(d) / abs(est.value)
    if not (sd > 0 and abs(d) > SHARED_BIAS_Z * sd and rel > SHARED_BIAS_MATERIAL):
        return []
    unit = est.unit
    return [f"unsure: {short} depends on how the rudder bias is modelled: the segments' own fits (each with its "
            f"own bias) give {est.value:.4g} +- {est.stderr:.2g} {est.unit}, their records fitted together with one "
            f"bias {value:.4g} +- {se:.2g} {est.unit} (difference {d / abs(value):+.1%}, z = {d / sd:+.1f} beyond "
            f"{SHARED_BIAS_Z:g}): the per-segment biases take up dynamics the first-order Nomoto model misses (a "
            f"pole-zero pair, a turn rate not linear in the rudder), so neither value is the ship's with certainty "
            f"({note})"]


def pooled_estimates(estimates: dict[str, Estimate], fits: Sequence[SegmentFit]) -> dict[str, Estimate]:
    """``estimates`` with K and T from the pooled second-order vector when every segment is second order
    (:func:`pipeline.fit.nomoto_pool.pool_second_order`; unchanged otherwise).

    The per-segment values stay in ``per_segment``; ``consistency_p`` becomes the test of them about
    the pooled value, and the per-segment combination is kept in the message.

    Parameters
    ----------
    estimates : dict[str, Estimate]
        Name -> estimate (modified in place and returned).
    fits : sequence of SegmentFit
        The successful Nomoto segment fits behind them.
    """
    pooled = pool_second_order(fits)
    if pooled is None:
        return estimates
    for name in NOMOTO_ESTIMATES:
        est = estimates.get(name)
        short = name.split("_")[0]
        if est is None or not math.isfinite(est.value) or short not in pooled.values:
            continue
        pv = pooled.values[short]
        kept = [m for m in est.message.split("; ") if m and not m.endswith(": not identified")]
        rel = pv.stderr / abs(pv.value) if pv.value != 0 else math.inf
        fail = ([f"relative standard error {rel:.0%} above {MAX_RELATIVE_STDERR:.0%}: not identified"]
                if not rel <= MAX_RELATIVE_STDERR else [])
        msg = fail + [f"{pooled.note}; {short} = {pv.value:.4g} +- {pv.stderr:.2g} {est.unit} (the segments' own "
                      f"values gave {est.value:.4g} +- {est.stderr:.2g})"] + kept
        estimates[name] = replace(est, value=pv.value, stderr=pv.stderr,
                                  ci95=confidence_interval(pv.value, pv.stderr, math.inf), consistency_p=pv.p_value,
                                  success=not fail, message="; ".join(msg))
    return estimates


def minority_note_kept(fits: Sequence[SegmentFit], part: str, short: str) -> str:
    """Why a segment's structure-undecided note does not mark the combined K or T unsure ('' when it does).

    A note carried by fewer than half of the segments (e.g. a zig-zag whose wave noise model took
    up its misfit, :func:`pipeline.fit.nomoto_segment.slow_noise_note`) says that those segments'
    values may carry a bias their errors do not show. The other segments test it: when the carriers'
    inverse-variance mean agrees with the others' within ``MINORITY_Z`` combined standard errors, the
    bias is not there at the others' precision and the combined value stands (measured: the
    PythonVehicleSimulator frigate, a first-order ship, logged at 2 Hz: 1 zig-zag of 5 segments
    flagged, its K 0.07996 +- 0.00026 against the steps' 0.0800, marked unsure). Otherwise, or when
    the carriers are half or more of the segments, the note applies.

    Parameters
    ----------
    fits : sequence of SegmentFit
        The Nomoto segment fits behind the estimate.
    part : str
        The note (starts with ``STRUCTURE_UNDECIDED``).
    short : str
        ``K`` or ``T``.
    """
    carriers = [part in f.message.split("; ") for f in fits]
    n = sum(carriers)
    if not 0 < 2 * n < len(fits):
        return ""
    groups = []
    for flag in (True, False):
        v = np.array([f.params.get(short, math.nan) for f, c in zip(fits, carriers) if c == flag], float)
        s = np.array([f.stderr.get(short, math.nan) for f, c in zip(fits, carriers) if c == flag], float)
        ok = np.isfinite(v) & np.isfinite(s) & (s > 0)
        if not ok.any():
            return ""
        w = 1.0 / s[ok] ** 2
        groups.append((float(w @ v[ok] / w.sum()), float(1.0 / math.sqrt(w.sum()))))
    (m1, s1), (m0, s0) = groups
    z = (m1 - m0) / math.hypot(s1, s0)
    if abs(z) > MINORITY_Z:
        return ""
    return (f"a structure note on {n} of {len(fits)} segments not applied to {short}: their {short} "
            f"{m1:.4g} +- {s1:.2g} agrees with the other segments' {m0:.4g} +- {s0:.2g} (z = {z:+.2f}, within "
            f"{MINORITY_Z:g}): {part.removeprefix('unsure: ')}")


#: Combined standard errors within which a minority of flagged segments agrees with the rest.
MINORITY_Z = 2.0


#: Words of the disagreement note (:func:`pipeline.fit.nomoto_structure.disagreement_note`) that name
#: a trend of a coefficient with the rudder amplitude, after the coefficient's name.
AMPLITUDE_TREND = "changes with the rudder amplitude"
#: Range of the segments' values, relative to the combined value, that makes an amplitude trend
#: material [-] (a trend of 0.1 % on a nearly linear ship is real but harmless).
AMPLITUDE_MATERIAL = 0.02


def nonlinear_reason(est: Estimate, fits: Sequence[SegmentFit], short: str) -> list[str]:
    """Why K or T is unsure when the segments' values trend with the rudder amplitude (empty otherwise).

    A linear Nomoto K or T that changes with the amplitude (and whose segment values range over more
    than ``AMPLITUDE_MATERIAL`` of the combined value) is the ship's at one amplitude only: the
    combined value is an average over the amplitudes tried, and the small-rudder (linearised) value
    lies off it by more than the segments' spread shows (measured: PythonVehicleSimulator's tanker at
    25 m, steps of 5 and 10 deg, every step's K 3-9 % above the linearisation, combined +5 % marked
    success with 0 % coverage).

    Parameters
    ----------
    est : Estimate
        The combined K or T.
    fits : sequence of SegmentFit
        The segment fits behind it (their disagreement notes are read).
    short : str
        ``K`` or ``T``.
    """
    x = np.asarray(est.per_segment, float)
    x = x[np.isfinite(x)]
    if not est.success or x.size < 2 or not np.ptp(x) > AMPLITUDE_MATERIAL * abs(est.value):
        return []
    head = f"{short} {AMPLITUDE_TREND}"
    for f in fits:
        for part in f.message.split("; "):
            if head in part:
                tail = part[part.index(head):].split(", and ")[0]
                return [f"unsure: nonlinear: {tail}"]
    return []


#: |t| of the difference between steps into a turn and steps out of one that breaks superposition.
SUPERPOSITION_T = 3.0
#: Difference between the two groups' means, relative to the combined value, that is material [-].
SUPERPOSITION_MATERIAL = 0.02


def superposition_reason(est: Estimate, fits: Sequence[SegmentFit], short: str) -> list[str]:
    """Why K or T is unsure when rudder steps into a turn and steps out of one give different values.

    A linear ship's response to a rudder step does not depend on the steady level it starts from
    (superposition, whatever the order, servo or rudder bias): a step from straight ahead into a turn
    and the step back out of it give the same K and T. When the two groups' inverse-variance means
    (each group's error scaled by its own Birge ratio, at least 1) differ by ``|t| >= SUPERPOSITION_T``
    and by more than ``SUPERPOSITION_MATERIAL`` of the combined value, the ship is nonlinear (a cubic
    yaw-rate term, a speed change in the turns), each group's value holds for its own direction, and
    the combined one, an average of two values that are not the linearisation's, need not lie near
    it. This needs no range of amplitudes, which equal +-10 deg steps lack (measured:
    PythonVehicleSimulator's frigate at 6 m/s with Norrbin's ``n3 = 150 s^2/rad^2``, measured rudder,
    equal 10 deg steps, 4 seeds: T into turns -4.1 to -5.2 %, out of them -1.8 to -2.8 %, each
    +- 0.2-0.6 %; combined -3.3 to -3.7 % (+- 4.2-7.5 %) marked success before this rule).

    Steps between two turns (a reversal, ``|before| == |after|``) are neither (the groups:
    :func:`superposition_groups`). The two groups are also two halves of the data: when their values
    differ by more than ``SUPERPOSITION_SPREAD`` of the combined value, significant or not, the value is
    ``unsure: not reproduced`` (a difference that wide errors cover is not agreement).

    For K and T read from the pooled second-order vector each group's vectors are pooled, and only
    that reproduction test applies: the pooled groups' t is no linearity test (the project's linear
    second-order ship, six 45 s steps behind a 1 s servo, gave t = -3.8 and 28 % between the groups on
    one seed of three; with 90 s holds 0.5-2.6 %), so it never marks the other coefficient
    (:func:`superposition_other_reason`). Measured: PythonVehicleSimulator's Clarke83 ship,
    measured-rudder steps with waves, seeds 1, 3 and 5 of 0-7 (the others mix first- and second-order
    segments): T +6.6, +5.3, +6.8 % (+- 6.1-6.6 %) marked success before; the groups' T differ by 19,
    12 and 24 % (t 2.95, 1.61, 3.52): unsure now. The tanker at 25 m, measured steps without waves,
    seeds 0-3: 0.6-4.9 % (|t| <= 0.72), its T (-0.5 to +3.2 %) stays success.

    Parameters
    ----------
    est : Estimate
        The combined K or T.
    fits : sequence of SegmentFit
        The segment fits behind it (their ``segment.input_before`` and ``input_after`` are read).
    short : str
        ``K`` or ``T``.
    """
    if not est.success:
        return []
    why = superposition_break(est, fits, short)
    return [why] if why else []


#: Difference between the two groups' values, relative to the combined value, beyond which
#: superposition is not shown even when the difference is within the errors [-] (the
#: ``HETEROGENEITY_MATERIAL`` of a spread "covered by one segment's wide error", :func:`unsure_reasons`).
SUPERPOSITION_SPREAD = HETEROGENEITY_MATERIAL


@dataclass(frozen=True)
class SuperpositionGroups:
    """The value of K or T from the rudder steps into a turn and from those out of one.

    Attributes
    ----------
    m_in, s_in, m_out, s_out : float
        Each group's value and standard error [unit of the estimate].
    n_in, n_out : int
        Steps in each group.
    t : float
        ``(m_in - m_out) / hypot(s_in, s_out)``.
    rel : float
        ``|m_in - m_out|`` over the combined value's magnitude [-].
    pooled : bool
        Whether each group's value is its pooled second-order vector's.
    """

    m_in: float
    s_in: float
    n_in: int
    m_out: float
    s_out: float
    n_out: int
    t: float
    rel: float
    pooled: bool


def superposition_groups(est: Estimate, fits: Sequence[SegmentFit], short: str) -> SuperpositionGroups | None:
    """K or T of the rudder steps into a turn against the steps out of one (None without both groups).

    A step whose level moves away from midships by more than half its size goes into a turn, one
    that moves toward it out of one; reversals (``|before| == |after|``) are neither. For a
    first-order (per-segment) value each group's value is its inverse-variance mean, its error scaled
    by its own Birge ratio (at least 1). For K and T read from the pooled second-order vector each
    group's vectors are pooled the same way (:func:`pipeline.fit.nomoto_pool.pool_second_order`, the error
    of the group's mean: no prediction error, as two means are compared) and
    K or T read from that: a second-order segment's own T, the difference of two correlated
    constants, scatters beyond its error and is not compared.

    Parameters
    ----------
    est : Estimate
        The combined value (its pooled note chooses how the groups are read; its value scales ``rel``).
    fits : sequence of SegmentFit
        Nomoto segment fits; the rudder steps among them are grouped by their levels before and after.
    short : str
        Which coefficient, ``K`` or ``T``.
    """
    if not (math.isfinite(est.value) and est.value != 0):
        return None
    pooled = POOLED_NOTE in est.message
    groups: dict[bool, list[SegmentFit]] = {True: [], False: []}
    for f in fits:
        seg = f.segment
        if seg.kind != "rudder_step" or is_joint_follower(f):
            continue
        lo, hi = getattr(seg, "input_before", math.nan), getattr(seg, "input_after", math.nan)
        before, after, step = abs(lo), abs(hi), abs(hi - lo)
        v, s = f.params.get(short, math.nan), f.stderr.get(short, math.nan)
        if not (step > 0 and math.isfinite(v) and math.isfinite(s) and s > 0):
            continue
        if abs(after - before) > 0.5 * step:
            groups[after > before].append(f)
    if not groups[True] or not groups[False] or len(groups[True]) + len(groups[False]) < 3:
        return None
    means = {}
    for into, members in groups.items():
        if pooled:
            vec = pool_second_order(members, min_segments=1, prediction=False)
            if vec is None or short not in vec.values:
                return None
            means[into] = (vec.values[short].value, vec.values[short].stderr, len(members))
            continue
        x = np.array([f.params[short] for f in members], float)
        w = 1.0 / np.array([f.stderr[short] for f in members], float) ** 2
        mu = float(w @ x / w.sum())
        birge2 = max(1.0, float(w @ (x - mu) ** 2) / (x.size - 1)) if x.size > 1 else 1.0
        means[into] = (mu, math.sqrt(birge2 / w.sum()), x.size)
    (m_in, s_in, n_in), (m_out, s_out, n_out) = means[True], means[False]
    se = math.hypot(s_in, s_out)
    if not (math.isfinite(se) and se > 0):
        return None
    return SuperpositionGroups(m_in, s_in, n_in, m_out, s_out, n_out, (m_in - m_out) / se,
                               abs(m_in - m_out) / abs(est.value), pooled)


def superposition_break(est: Estimate, fits: Sequence[SegmentFit], short: str, significant_only: bool = False) -> str:
    """The superposition test of :func:`superposition_reason` whatever the estimate's success: the reason, or ''.

    Parameters
    ----------
    est : Estimate
        The combined K or T (its value sets the materiality).
    fits : sequence of SegmentFit
        The segment fits behind it.
    short : str
        ``K`` or ``T``.
    significant_only : bool
        Only a difference beyond the errors counts (not one that is merely larger than
        ``SUPERPOSITION_SPREAD``): the evidence that the ship is nonlinear, for the other coefficient.
    """
    g = superposition_groups(est, fits, short)
    if g is None:
        return ""
    # The pooled groups' t is no test of linearity: a linear second-order ship's steps gave t = -3.8.
    significant = abs(g.t) >= SUPERPOSITION_T and g.rel > SUPERPOSITION_MATERIAL and not g.pooled
    if not significant and (significant_only or not g.rel > SUPERPOSITION_SPREAD):
        return ""
    how = " (each group's second-order vectors pooled)" if g.pooled else ""
    head = (f"{g.n_in} rudder steps into a turn give {short} = {g.m_in:.4g} +- {g.s_in:.2g} {est.unit}, {g.n_out} "
            f"steps out of one {g.m_out:.4g} +- {g.s_out:.2g}{how} (difference {g.rel:.1%} of the value, "
            f"t = {g.t:+.2g})")
    cause = speed_change_clause(fits)
    if significant:
        return (f"unsure: nonlinear: {head}: a linear ship's step response does not depend on where the step "
                f"starts, so the ship is nonlinear (a cubic yaw-rate term, a speed change in the turns) and the "
                f"combined {short}, an average of the two, is not its linear value{cause}")
    return (f"unsure: not reproduced: {head}: the two halves of the steps differ by more than "
            f"{SUPERPOSITION_SPREAD:.0%} of the value, so the combined {short} is not known to that (a linear "
            f"ship's steps give the same {short} from either start; the difference is a nonlinearity, or an "
            f"estimator bias that differs between steps from rest and steps from a turn; add steps, or longer "
            f"holds){cause}")


#: Relative change of the logged speed between a step window's straight end and its turning end that
#: is named as the cause of a superposition break [-].
SPEED_CHANGE_MATERIAL = 0.01
_SPEED_ENDS = re.compile(r"\((\w+) (\S+) m/s (?:at the straighter end|in the straight run before the manoeuvre), "
                         r"(\S+) m/s (?:at the turning end|in its slowest tenth)\)")


def speed_change_clause(fits: Sequence[SegmentFit]) -> str:
    """The logged speed change that a superposition break points to, as a clause ('' when not material).

    K and T depend on the speed (Nomoto's ``K = K' U / L``, ``T = T' L / U`` where the rudder force grows
    with ``U^2``; a rudder in the propeller race at constant rpm turns the ship faster per degree as it
    slows: PythonVehicleSimulator's tanker at 20 m, noise-free steps, second-order K -0.7 % with its
    1.0-1.5 % speed loss, +0.1 % with the speed held); a ship whose speed
    changes with the rudder (drag of the deflected rudder and the drift, or a rudder force that grows
    with the speed) and settles at its surge time constant, slower than the yaw, is still speeding up
    or slowing while a step's yaw settles: the step into a turn answers with a slow creep on top of its
    yaw transient, the step out of one at the turn's speed, so the two groups differ although each is
    fitted well. Read from the ``SPEED_RANGE`` notes' two speeds (a gain counts as much as a loss; the
    note's own loss figure is 0 for a gain). Measured: PythonVehicleSimulator's Clarke83 ship speeds
    up from 3.26 to 3.35 m/s (+2.9 %) in its 10 deg turns (surge time constant L = its length in s);
    noise-free commanded steps: T of the steps into a turn +27 / +18 / +3 % (10, 10, 5 deg), out of
    one -2.2 / -1.8 / +0.9 %; with the simulator's surge speed held at the straight-run value the six
    steps give T from -1.5 to +3.2 %.

    Parameters
    ----------
    fits : sequence of SegmentFit
        The segment fits behind the two groups (their messages carry the speed notes).
    """
    best = None
    for f in fits:
        for part in f.message.split("; "):
            if not part.startswith(SPEED_RANGE):
                continue
            m = _SPEED_ENDS.search(part)
            if not m:
                continue
            try:
                straight, turning = float(m.group(2)), float(m.group(3))
            except ValueError:
                continue
            if straight > 0 and math.isfinite(turning):
                change = (turning - straight) / straight
                if best is None or abs(change) > abs(best[1]):
                    best = (m.group(1), change, straight, turning)
    if best is None or not abs(best[1]) > SPEED_CHANGE_MATERIAL:
        return ""
    ch, change, straight, turning = best
    return (f"; the logged speed ({ch}) changed by up to {change:+.1%} between the straight runs and the turns "
            f"({straight:.4g} to {turning:.4g} m/s): K and T depend on the speed, and a speed still "
            f"changing while a step's yaw settles shapes steps into a turn and out of one differently: the "
            f"difference may come from the speed change alone (a linear model scheduled on the logged speed would "
            f"take it up; a constant-speed Nomoto model cannot)")


def superposition_other_reason(est: Estimate, estimates: dict[str, Estimate], fits: Sequence[SegmentFit],
                               short: str) -> list[str]:
    """Why K (T) is unsure when the steps into and out of a turn break superposition for T (K).

    Rudder steps of one amplitude into a turn and back out of it reach the same steady turn rate
    both ways, so a K that is not linear in the rudder (Norrbin's cubic yaw-rate term: the turn rate
    falls short of ``K delta`` the more, the faster the turn) gives the same value from both groups
    and passes :func:`superposition_reason`; the transient, which starts from a turn in one group
    and from straight ahead in the other, shows the nonlinearity in T. A ship shown nonlinear over
    the range its steps covered by either coefficient has both K and T effective at that amplitude,
    not its linear (small-rudder) values (measured: PythonVehicleSimulator's frigate at 6 m/s with
    ``n3 = 150 s^2/rad^2``, measured rudder, equal 10 deg steps, 6 seeds: T into turns 2.1-2.6 %
    below T out of them, t -9 to -14, unsure; K -2.5 % with a standard error of 0.4-0.9 %, its
    interval missing on 6 of 6 seeds (|z| 2.9-5.7), was marked success). Empty when this coefficient's own test
    already fired or the other's did not.

    Parameters
    ----------
    est : Estimate
        The combined K or T being judged.
    estimates : dict[str, Estimate]
        All combined estimates (the other coefficient's is read).
    fits : sequence of SegmentFit
        The segment fits behind them.
    short : str
        ``K`` or ``T`` (of ``est``).
    """
    other = "T" if short == "K" else "K"
    other_est = estimates.get(f"{other}_nomoto")
    if not est.success or other_est is None:
        return []
    why = superposition_break(other_est, fits, other, significant_only=True)
    if not why:
        return []
    return [f"unsure: nonlinear: {short} is an effective value at the steps' amplitude, not the linear one, because "
            f"the steps break superposition in {other} ({why.removeprefix('unsure: nonlinear: ')})"]


def sinusoid_k_reason(est: Estimate, kinds: Sequence[str], t_reasons: Sequence[str]) -> list[str]:
    """Why a K from sinusoids only is unsure when their T spread already shows a structure error.

    A first-order model matched at two frequencies gives the ship's K only if the ship is first
    order; when the T of the same fits spreads beyond ``HETEROGENEITY_MATERIAL`` (``t_reasons``
    holds the sinusoid-spread reason) the ship is not, and a K whose per-frequency values also
    disagree beyond their errors (chi-square ``p < CONSISTENCY_ALPHA``) is the random-effects mean
    of two gains that are not the ship's (measured: PythonVehicleSimulator's tanker at 25 m, K +16.6 %
    fast and +8.0 % slow, combined +12.3 +- 4.3 % marked success, its spread 5 % under the 10 %
    materiality). Empty otherwise.

    Parameters
    ----------
    est : Estimate
        The combined K.
    kinds : sequence of str
        Segment kinds of the fits behind it.
    t_reasons : sequence of str
        The unsure reasons of the combined T (:func:`unsure_reasons`).
    """
    if not (est.success and kinds and all(k == "sinusoid" for k in kinds)):
        return []
    if not any(r.startswith("unsure: sinusoids only, and their values spread") for r in t_reasons):
        return []
    p = est.consistency_p
    if not (math.isfinite(p) and p < CONSISTENCY_ALPHA):
        return []
    x = np.asarray(est.per_segment, float)
    return [f"unsure: sinusoids only, their T spreads beyond {HETEROGENEITY_MATERIAL:.0%} (a first-order model "
            f"matched at each frequency: the ship is not first order) and their K values disagree beyond their "
            f"errors (chi-square p = {p:.2g} < {CONSISTENCY_ALPHA}; from {x.min():.4g} to {x.max():.4g} {est.unit}): "
            f"the combined K is a mean of two frequencies' gains, not the ship's (add a rudder step or a zig-zag)"]


def sinusoid_check_reason(est: Estimate, fits: Sequence[SegmentFit]) -> list[str]:
    """Why K or T from sinusoids fitted one by one is unsure when fewer than two of them identify T to within
    ``HETEROGENEITY_MATERIAL`` (empty otherwise).

    Sinusoids alone show the ship's structure only by agreeing across frequencies (:func:`unsure_reasons`); a
    sinusoid whose own T is known to no better than that share of it agrees with any value, so it checks
    nothing, and the combined K and T are the other frequency's first-order match: the one-sinusoid case
    (measured: PythonVehicleSimulator's tanker at 20 m, commanded-rudder sinusoids, seed 1: the fast one's T
    +- 40 % and 49 % (with waves), the combined K +3.2 / +3.3 % +- 0.11 / 0.26 % marked success). Sinusoids
    fitted jointly (one fit, :func:`pipeline.fit.nomoto_pool.is_joint_follower`) are judged by their own rules.

    Parameters
    ----------
    est : Estimate
        The combined K or T.
    fits : sequence of SegmentFit
        The segment fits behind it.
    """
    fits = [f for f in fits if getattr(f, "success", True)]
    if not (est.success and len(fits) >= 2 and all(f.segment.kind == "sinusoid" for f in fits)
            and not any(is_joint_follower(f) for f in fits)):
        return []
    rel = [abs(f.stderr.get("T", math.nan) / f.params["T"]) if f.params.get("T") else math.inf for f in fits]
    checked = sum(r <= HETEROGENEITY_MATERIAL for r in rel)
    if checked >= 2:
        return []
    shown = ", ".join("not identified" if not math.isfinite(r) else f"{r:.0%}" for r in rel)
    return [f"unsure: sinusoids only, and {checked} of the {len(fits)} identify T to within "
            f"{HETEROGENEITY_MATERIAL:.0%} (their T errors {shown} of it): a sinusoid whose T is that uncertain "
            f"agrees with any value, so the frequencies do not check that the ship is first order, and K and T are "
            f"one frequency's first-order match (add a rudder step or a zig-zag, or a sinusoid that identifies T)"]


def structure_term(fits: Sequence[SegmentFit], short: str) -> float:
    """The largest model-structure term for ``K`` or ``T`` in the fits' messages (0 when none) [unit of it].

    Parameters
    ----------
    fits : sequence of SegmentFit
        Nomoto segment fits.
    short : str
        ``K`` or ``T``.
    """
    return largest_noted(fits, f"{STRUCTURE_TERM} {short}: +-")


def retime_term(fits: Sequence[SegmentFit], short: str) -> float:
    """The largest re-timing term for ``K`` or ``T`` in the fits' messages (0 when none) [unit of it].

    A rudder step whose speed departed and whose held-out end chose neither the constant-speed nor the re-timed
    fit carries their difference (:func:`pipeline.fit.nomoto_segment.choose_retiming`); the speed change is
    common to the steps, so the largest step's difference is added to the combined K or T, not a mean.

    Parameters
    ----------
    fits : sequence of SegmentFit
        Nomoto segment fits.
    short : str
        ``K`` or ``T``.
    """
    return largest_noted(fits, f"{RETIME_TERM} {short}: +-")


def largest_noted(fits: Sequence[SegmentFit], head: str) -> float:
    """The largest magnitude of the number that follows ``head`` in the fits' messages (0 when none).

    Parameters
    ----------
    fits : sequence of SegmentFit
        Nomoto segment fits; their messages are ``"; "``-separated notes.
    head : str
        The start of the note, up to the number.
    """
    out = 0.0
    for f in fits:
        for part in f.message.split("; "):
            if part.startswith(head):
                try:
                    out = max(out, abs(float(part[len(head):].split(" ")[0])))
                except ValueError:
                    continue
    return out


def add_structure_term(est: Estimate, term: float, what: str = "model-structure term") -> Estimate:
    """``est`` with ``term`` added in quadrature to its standard error and its 95 % interval widened.

    Parameters
    ----------
    est : Estimate
        A combined Nomoto K or T.
    term : float
        Model-structure term [unit of the estimate]; 0 leaves ``est`` unchanged.
    what : str
        The term's name in the note.
    """
    if not (term > 0 and math.isfinite(est.value) and math.isfinite(est.stderr)):
        return est
    se = math.hypot(est.stderr, term)
    return replace(est, stderr=se, ci95=confidence_interval(est.value, se, math.inf),
                   message="; ".join([f"standard error {est.stderr:.4g} -> {se:.4g} {est.unit} with the "
                                      f"{what} {term:.4g} {est.unit}"]
                                     + ([est.message] if est.message else [])))


def rudder_timing_reason(est: Estimate, fits: Sequence[SegmentFit], short: str) -> list[str]:
    """Why T is unsure when the moment of the rudder's jumps alone may shift it by more than
    ``UNSURE_RELATIVE_STDERR`` of its value (empty otherwise, and for K).

    A jump within a sample interval ``h`` (:func:`rudder_timing_term`, whose term is ``h / sqrt(12)``)
    happened up to ``h / 2`` before or after the moment the fit gives it, and T moves one for one with it:
    a shift the data do not show (a data-driven choice between the two timings chose wrongly on 4 of 6
    logs). The rule reads the whole half-interval against the value, not the term's standard deviation
    against it: that would let the value the delay inflated pass where the right one fails (measured: the
    project's linear second-order ship, T = 2.7 s, measured rudder jumping within the samples at 1 Hz, six
    steps, seeds 0-5: held from each sample on, T +18.3 to +20.3 % with a relative error of 9.0-9.4 % of its
    value; jumping mid-interval, T -1.5 to +0.6 % with 10.8-11.4 %).

    Parameters
    ----------
    est : Estimate
        The combined K or T (after its terms).
    fits : sequence of SegmentFit
        The segment fits behind it.
    short : str
        ``K`` or ``T``.
    """
    term = rudder_timing_term(fits, short) if short == "T" else 0.0
    if not (est.success and term > 0 and math.isfinite(est.value) and est.value != 0):
        return []
    h = term * math.sqrt(12.0)
    shift = 0.5 * h / abs(est.value)
    if not shift > UNSURE_RELATIVE_STDERR:
        return []
    jumps = any(f"{RUDDER_TIMING} +-" in p and "jumps within" in p for f in fits for p in f.message.split("; "))
    cause = ("the rudder jumps within its sample interval of {h:.3g} s, so each jump's moment is known only to within "
             "it" if jumps else "the rudder's path between its samples, {h:.3g} s apart, is not logged, so its timing "
             "is known only to within a sample interval").format(h=h)
    return [f"unsure: {cause}, and T moves one for one with the rudder's timing: up to h / 2 = {0.5 * h:.3g} s, "
            f"{shift:.0%} of T (> {UNSURE_RELATIVE_STDERR:.0%}), which the data cannot show (log the rudder faster, "
            f"or its servo's ramp)"]


def rudder_delay_term(fits: Sequence[SegmentFit], short: str) -> tuple[float, str]:
    """The largest rudder-delay term of ``K`` or ``T`` in the fits' messages [unit of it] and its note's reason
    ((0, '') when none).

    A lone zig-zag's rudder-to-heading delay is fitted with its K and T
    (:func:`pipeline.fit.nomoto_rudder_delay.with_rudder_delay`); the segment's error is the one at the fitted
    delay, and the delay's own error, carried through the slope of K (T) on it, is this term.

    Parameters
    ----------
    fits : sequence of SegmentFit
        Nomoto segment fits.
    short : str
        ``K`` or ``T``.
    """
    head = f"{RUDDER_DELAY_TERM} {short}: +-"
    term = largest_noted(fits, head)
    if not term > 0:
        return 0.0, ""
    for f in fits:
        for part in f.message.split("; "):
            if part.startswith(head) and ": " in part[len(head):]:
                return term, part[len(head):].split(": ", 1)[1]
    return term, ""


def rudder_timing_term(fits: Sequence[SegmentFit], short: str) -> float:
    """The largest rudder-timing term of T in the fits' messages (``RUDDER_TIMING`` notes of
    :func:`pipeline.fit.nomoto_structure.with_rudder_timing_note`) [s], or for K that term carried by
    K's regression on T in the fit's covariance [1/s]; 0 when none.

    A rudder that jumps within a sample interval jumped at a moment known only to within it (and a
    sinusoid's servo path between samples leads their straight line by up to half an interval), and a
    delay of the rudder moves the first-order equivalent T one for one; the term is common to every
    jump of the log (a logger's convention), so it is added after combining, never averaged down.
    A delay leaves a steady turn's K alone, but where the fit reads K together with T (a sinusoid's gain
    at its frequency is ``K / |1 + j w T|``) K moves with T: by ``cov(K, T) / var(T)`` per second of T,
    the slope of K on T in the segment's own covariance, which is the term of K (measured:
    PythonVehicleSimulator's frigate, measured-rudder sinusoids at 1 Hz, seeds 0-9: T -0.39 to -0.89 %
    and K -0.06 to -0.18 % with errors of 0.04-0.10 %, K's interval missing on 3 of 10).

    Parameters
    ----------
    fits : sequence of SegmentFit
        Nomoto segment fits (their ``RUDDER_TIMING`` notes are read).
    short : str
        The coefficient, ``K`` or ``T``.
    """
    head = f"{RUDDER_TIMING} +-"
    if short == "T":
        return largest_noted(fits, head)
    if short != "K":
        return 0.0
    out = 0.0
    for f in fits:
        term = largest_noted([f], head)
        slope = k_on_t_slope(f) if term > 0 else 0.0
        out = max(out, abs(slope) * term)
    return out


def k_on_t_slope(sf: SegmentFit) -> float:
    """The slope of K on the first-order equivalent T in a segment fit's covariance [1/s^2] (0 when unknown).

    ``cov(K, T) / var(T)`` with ``T`` the first-order ``T`` or the second order's ``T12 - T3``.

    Parameters
    ----------
    sf : SegmentFit
        A Nomoto segment fit with ``param_names`` and ``covariance``.
    """
    names = list(getattr(sf, "param_names", None) or ())
    cov = getattr(sf, "covariance", None)
    if "K" not in names or cov is None:
        return 0.0
    cov = np.asarray(cov, float)
    g = np.zeros(len(names))
    if "T" in names:
        g[names.index("T")] = 1.0
    elif "T12" in names and "T3" in names:
        g[names.index("T12")], g[names.index("T3")] = 1.0, -1.0
    else:
        return 0.0
    if cov.shape != (g.size, g.size):
        return 0.0
    var_t = float(g @ cov @ g)
    c_kt = float(cov[names.index("K")] @ g)
    return c_kt / var_t if var_t > 0 and math.isfinite(c_kt) else 0.0


def speed_range(fits: Sequence[SegmentFit]) -> float:
    """The largest relative speed loss in turns (``SPEED_RANGE`` notes) over the fits' records [-] (0 when none).

    Parameters
    ----------
    fits : sequence of SegmentFit
        Nomoto segment fits.
    """
    return largest_noted(fits, f"{SPEED_RANGE} ")


def weighted_slope_t(a: np.ndarray, x: np.ndarray, w: np.ndarray) -> float:
    """t of the weighted slope of ``x`` on ``a``, its error scaled by the Birge ratio of the line (>= 1).

    Parameters
    ----------
    a, x : numpy.ndarray
        Abscissae and values (at least 3, ``a`` not all equal; NaN otherwise).
    w : numpy.ndarray
        Weights of ``x``, 1 / standard error squared.
    """
    line = weighted_line(a, x, w)
    return line.slope_t if line is not None else math.nan


#: |t| of the per-segment values' slope against their speed loss that shows a speed dependence.
SPEED_TREND_T = 3.0


def speed_rows(fits: Sequence[SegmentFit], short: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each segment's speed loss (``SPEED_RANGE`` note) [-], value and standard error of ``K`` or ``T``.

    Segments without the note, without a finite value or error, and joint followers are left out.

    Parameters
    ----------
    fits : sequence of SegmentFit
        Nomoto segment fits; each one's message carries its record's ``SPEED_RANGE`` note.
    short : str
        The coefficient read from each fit's ``params`` and ``stderr``: ``K`` or ``T``.
    """
    rows = []
    for f in fits:
        if is_joint_follower(f):
            continue
        loss = largest_noted([f], f"{SPEED_RANGE} ")
        has = any(p.startswith(SPEED_RANGE) for p in f.message.split("; "))
        v, s = f.params.get(short, math.nan), f.stderr.get(short, math.nan)
        if has and all(math.isfinite(x) for x in (loss, v, s)) and s > 0:
            rows.append((loss, v, s))
    if not rows:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    a, x, s = (np.array(c, float) for c in zip(*rows))
    return a, x, s


#: p of the chi-square of the segments about their speed-loss line below which the line does not
#: describe them well enough to be extrapolated to zero loss: the conventional 5 % goodness-of-fit level, not
#: the 1 % of the consistency test of :mod:`pipeline.fit.combine` (an extrapolation carries a wrong shape to
#: zero, where no segment checks it, and the Birge ratio scales the error for a misfit, not for a shape).
#: Measured: PythonVehicleSimulator's tanker at 25 m, rudder steps of 10 and 5 deg, seeds 0-1 (8 lines,
#: commanded and measured rudder, with and without waves): chi-square about the line 8.6-86 on 3 dof, p < 0.05
#: on all 8, p < 0.01 on 6; the two between (commanded, seed 0: 9.9 and 8.6) gave K -3.7 / -4.0 % +- 0.24 /
#: 0.18 % marked success (z 16, 21): the dependence is steepest near zero amplitude, where no segment is.
LINE_FIT_ALPHA = 0.05
#: Largest speed loss in the turns [-] up to which the speed term of :func:`add_speed_term` covers a speed
#: dependence: by Nomoto's scaling (``K = K' U / L``, ``T = T' L / U``) a loss ``l`` shifts K and T by about
#: ``l``, immaterial below this (the same 2 % as ``AMPLITUDE_MATERIAL``).
SPEED_MATERIAL = 0.02
#: The smallest speed loss of the segments must be at most this share of the largest for the line to
#: be extrapolated to zero loss (the extrapolation then reaches no farther than the span it rests on).
EXTRAPOLATION_REACH = 0.5


def straight_run_value(est: Estimate, fits: Sequence[SegmentFit], short: str) -> tuple[Estimate, list[str]]:
    """K or T at zero speed loss where the segments show a speed dependence, or why it is unsure.

    The linearisation a user compares with is the ship's at its straight-run speed and zero rudder
    amplitude; a ship that slows in its turns (and whose K and T change with the amplitude that makes
    it slow) gives each segment the value at its own speed loss. Where the segments show that
    dependence (:func:`speed_trend`), the straight-run value is the intercept at zero loss of the
    weighted straight line of the segments' values against their losses, with the intercept's error
    scaled by the line's Birge ratio (at least 1), when the line can be extrapolated:

    - at least 3 segments, the smallest loss at most ``EXTRAPOLATION_REACH`` of the largest (the
      line then reaches zero from no farther than its own span), and
    - the line describes the segments: the chi-square of their values about it on ``n - 2`` degrees
      of freedom has ``p >= LINE_FIT_ALPHA``. A line that misses its own points beyond their errors
      is the wrong shape (a K that changes with the amplitude, not in proportion to the speed loss,
      or differs between port and starboard turns), and its intercept is no better than its shape
      (measured: PythonVehicleSimulator's tanker at 25 m, 10 and 5 deg steps, losses 0.9-7.8 %,
      chi-square about the line 26-149 on 3-4 dof over seeds 0-7, intercept K still +3.4 to +3.9 %
      with an error of 0.3-0.7 % on seeds 0-3; noise-free step programs of 1 deg give K within 0.1 %
      of the linearisation, of 5 deg +2.9 %: the dependence is steepest near zero amplitude, where
      no segment is).

    Otherwise the estimate keeps its value, gets the speed term of :func:`add_speed_term` and is
    ``unsure`` with the reason (returned, not yet in the message). Where the segments show no
    speed dependence, or the largest loss is at most ``SPEED_MATERIAL`` (the speed term covers what such
    a loss can shift; a speed-held ship loses none), only :func:`add_speed_term` applies (measured:
    PythonVehicleSimulator's tanker at 20 m, losses 0-1 %, K -2.0 to -2.4 % with segments disagreeing
    beyond their errors: extrapolation would have marked a K within 3 % unsure).

    Sinusoids fitted jointly whose second order they fix exactly (:func:`exact_fit`) leave no number to
    show or rule out a speed dependence either (one joint fit, no residual degree of freedom): their
    value gets the speed term whatever their loss (:func:`exact_fit_trend`).

    One segment (a single zig-zag) whose turns lost more than ``SPEED_MATERIAL`` can neither show nor
    rule out that dependence: its value gets the speed term and is ``unsure`` (measured:
    PythonVehicleSimulator's tanker at 25 m, one 10/10 zig-zag that lost 5.9 % of the straight-run
    speed, K +7.0 % and T -11.3 % were marked success before).

    Parameters
    ----------
    est : Estimate
        The combined K or T (``per_segment`` and the segments' errors are in ``fits``).
    fits : sequence of SegmentFit
        The segment fits behind it.
    short : str
        ``K`` or ``T``.

    Returns
    -------
    (Estimate, list of str)
        The estimate (the intercept, or the value with the speed term), and the unsure reasons.
    """
    # The per-segment T of a second-order fit (T1 + T2 - T3, a difference of two correlated constants)
    # scatters beyond its error; in the pooled vector that spread is in the random-effects error, so it
    # is no evidence of a speed dependence (its trend still is).
    spread_counts = not (short == "T" and POOLED_NOTE in est.message)
    trend = speed_trend(fits, short, spread_counts=spread_counts)
    rel_range = speed_range(fits)
    if (not trend and rel_range > SPEED_MATERIAL and speed_rows(fits, short)[0].size < 2
            and math.isfinite(est.value) and math.isfinite(est.stderr)):
        # One segment can neither show nor rule out a speed dependence.
        trend = f"one segment, whose turns lost {rel_range:.1%} of the speed: no trend can be shown or ruled out"
        return add_speed_term(est, rel_range, trend), [
            f"unsure: {short} comes from one segment whose turns lost {rel_range:.1%} of the straight-run speed; "
            f"Nomoto's K and T scale with the speed, and one segment cannot show how its value depends on it, "
            f"so the straight-run value (the linearisation's) is not known (add manoeuvres with a smaller "
            f"rudder, or rudder steps, which lose less speed)"]
    if not trend and rel_range > 0 and exact_fit(fits):
        trend = exact_fit_trend(rel_range)
    if not trend or not rel_range > SPEED_MATERIAL or not (math.isfinite(est.value) and math.isfinite(est.stderr)):
        return add_speed_term(est, rel_range, trend), []
    a, x, s = speed_rows(fits, short)
    why = ""
    if a.size < 3:
        why = f"only {a.size} segments with a speed loss (a line through fewer than 3 cannot be tested)"
    elif not a.min() <= EXTRAPOLATION_REACH * a.max():
        why = (f"their losses span {a.min():.1%} to {a.max():.1%}: zero lies farther from the smallest than "
               f"{EXTRAPOLATION_REACH:.0%} of the largest (add manoeuvres with a smaller rudder, which lose less speed)")
    else:
        line = weighted_line(a, x, 1.0 / s**2)
        if line is None:
            why = "the weighted line is singular"
        elif line.p < LINE_FIT_ALPHA:
            why = (f"a straight line in the speed loss misses their values beyond their errors (chi-square "
                   f"{line.chi2:.3g} on {a.size - 2} dof, p = {line.p:.2g} < {LINE_FIT_ALPHA}): the value changes "
                   f"with the manoeuvre in a way the line does not describe (the rudder amplitude, port against "
                   f"starboard), so its intercept is no better than its shape")
        else:
            value, se = line.intercept, line.intercept_se
            note = (f"straight-run value: {short} at zero speed loss = {value:.4g} +- {se:.2g} {est.unit}, the "
                    f"intercept of the weighted line of the {a.size} segments' {short} against their speed loss "
                    f"({a.min():.1%} to {a.max():.1%}; slope t = {line.slope_t:+.2g}, chi-square about it "
                    f"{line.chi2:.3g} on {a.size - 2} dof, p = {line.p:.2g}; error scaled by the Birge ratio "
                    f"{line.birge:.2g}), in place of the combined {est.value:.4g} +- {est.stderr:.2g} ({trend})")
            return replace(est, value=value, stderr=se, ci95=confidence_interval(value, se, math.inf),
                           message="; ".join([note] + ([est.message] if est.message else []))), []
    out = add_speed_term(est, rel_range, trend)
    return out, [f"unsure: {short} changes with the speed lost in the turns ({trend}), and the straight-run value "
                 f"(zero speed loss, the linearisation's) cannot be read off the segments: {why}"]


def exact_fit(fits: Sequence[SegmentFit]) -> bool:
    """Whether the fits are sinusoids fitted jointly whose second order they fix exactly (``EXACT_FIT``
    in a model-structure note of their messages, :func:`pipeline.fit.nomoto_structure.exact_fit_k_term`).

    Parameters
    ----------
    fits : sequence of SegmentFit
        Nomoto segment fits.
    """
    return any(part.startswith(STRUCTURE_TERM) and EXACT_FIT in part
               for f in fits for part in f.message.split("; "))


def exact_fit_trend(rel_range: float) -> str:
    """Why jointly fitted sinusoids that fix the second order exactly get the speed term of
    :func:`add_speed_term` although their value shows no trend with the speed (the ``trend`` it is given).

    A trend is shown by segments' values against their speed losses; sinusoids fitted jointly are one
    value, and with ``2 n`` numbers for the ``2 n`` constants their fit leaves no residual degree of
    freedom in which a speed change could show: "no trend" is then no evidence that the ship's K does
    not change with the speed, and the straight-run value may lie anywhere across the loss, as for one
    segment (:func:`straight_run_value`). Measured: PythonVehicleSimulator's tanker at 20 m, measured-rudder
    sinusoids without waves, seeds 0-12: K -0.1 to -1.2 % (the noise-free best linear fit -0.9 %, a bias
    common to every seed) with errors of 0.4-0.7 % (its model-structure term included), 95 % coverage 7 of 13;
    losses noted 0-1.0 %.

    Parameters
    ----------
    rel_range : float
        Largest relative speed loss in the turns of the records [-].
    """
    return (f"sinusoids fitted jointly fix the second order's constants exactly, so their one fit can neither "
            f"show nor rule out a dependence on the {rel_range:.1%} of the speed their turns lost")


@dataclass(frozen=True)
class WeightedLine:
    """A weighted straight line ``x = intercept + slope a`` and how well it fits.

    Attributes
    ----------
    intercept, intercept_se : float
        Value at ``a = 0`` and its standard error, scaled by ``birge`` [unit of x].
    slope_t : float
        Slope over its Birge-scaled error [-].
    chi2, p : float
        Weighted residual sum of squares and its chi-square p on ``n - 2`` degrees of freedom.
    birge : float
        ``sqrt(chi2 / (n - 2))``, at least 1.
    """

    intercept: float
    intercept_se: float
    slope_t: float
    chi2: float
    p: float
    birge: float


def weighted_line(a: np.ndarray, x: np.ndarray, w: np.ndarray) -> WeightedLine | None:
    """Weighted least-squares line of ``x`` on ``a`` (at least 3 points, ``a`` not all equal; None otherwise).

    Parameters
    ----------
    a, x : numpy.ndarray
        Abscissae and values.
    w : numpy.ndarray
        Weights of ``x``, 1 / standard error squared.
    """
    if a.size < 3 or np.ptp(a) <= 1e-9 * max(np.max(np.abs(a)), 1e-12):
        return None
    design = np.column_stack([np.ones_like(a), a])
    info = design.T @ (design * w[:, None])
    try:
        cov = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return None
    beta = cov @ (design.T @ (w * x))
    resid = x - design @ beta
    chi2 = float(w @ resid**2)
    birge2 = max(1.0, chi2 / (a.size - 2))
    se_slope = math.sqrt(cov[1, 1] * birge2)
    return WeightedLine(intercept=float(beta[0]), intercept_se=math.sqrt(cov[0, 0] * birge2),
                        slope_t=float(beta[1] / se_slope) if se_slope > 0 else math.nan, chi2=chi2,
                        p=float(stats.chi2.sf(chi2, a.size - 2)), birge=math.sqrt(birge2))


def speed_trend(fits: Sequence[SegmentFit], short: str, spread_counts: bool = True) -> str:
    """Whether the segments' K or T change with the speed their turns lost: the evidence, or ''.

    Each segment fit's ``SPEED_RANGE`` note gives its record's relative speed loss; a weighted straight
    line of the segments' values against those losses (:func:`weighted_slope_t`, its error scaled by
    the line's Birge ratio) with ``|t| >= SPEED_TREND_T`` shows that the value depends on the speed (or
    on the rudder amplitude that set it): the straight-run value then lies off the combined one.
    Segments whose values disagree beyond their errors (chi-square ``p < CONSISTENCY_ALPHA``) while
    their turns lost different speeds count too: something unmodelled changes between them, the speed
    among the candidates, although the line is too noisy to show it (measured: PythonVehicleSimulator's
    tanker at 25 m, six steps, K chi-square 190-360 on 5 dof, slope t 1.9-5.7 over the seeds).
    Otherwise (segments that agree, or one segment) the data show no speed dependence and
    :func:`add_speed_term` adds nothing (measured: the project's own simulator, whose K does not depend
    on the speed, 2.1 % speed loss: the term widened K from +-0.00012 to +-0.018 1/s and the sd of z
    of K fell to 0.36).

    Parameters
    ----------
    fits : sequence of SegmentFit
        Nomoto segment fits (joint followers are skipped).
    short : str
        ``K`` or ``T``.
    spread_counts : bool
        Whether a disagreement beyond the errors counts (not for the per-segment T behind a pooled
        second-order T, whose spread is no evidence: :func:`straight_run_value`).
    """
    a, x, s = speed_rows(fits, short)
    if a.size < 2:
        return ""
    w = 1.0 / s**2
    t = weighted_slope_t(a, x, w)
    if math.isfinite(t) and abs(t) >= SPEED_TREND_T:
        return (f"the {a.size} segments' {short} trends with their speed loss ({a.min():.1%} to {a.max():.1%}, "
                f"slope t = {t:+.2g})")
    if not spread_counts:
        return ""
    chi2 = float(w @ (x - float(w @ x) / w.sum()) ** 2)
    p = float(stats.chi2.sf(chi2, x.size - 1))
    if p < CONSISTENCY_ALPHA:
        return (f"the {a.size} segments' {short} disagree beyond their errors (chi-square p = {p:.2g}) and "
                f"their turns lost {a.min():.1%} to {a.max():.1%} of the speed")
    return ""


def add_speed_term(est: Estimate, rel_range: float, trend: str = "shown") -> Estimate:
    """``est`` with a speed term added in quadrature to its standard error (unchanged when 0, or when
    the data show no speed dependence).

    Nomoto's K and T scale with the speed (``K = K' U / L``, ``T = T' L / U``; Fossen 2021, sec.
    7.2). A K or T fitted over manoeuvres whose turns ran slower than the straight runs by a
    fraction ``rel_range`` is the ship's at some speed inside that range; the straight-run value
    (the linearisation a user compares with, and what a small rudder gives) may lie up to
    ``rel_range`` of the value away, in a direction the fit cannot tell (a ship whose K does not
    scale with U shows no shift at all). The term is ``rel_range |value| / 2``: as a standard
    error its 95 % interval, +-0.98 ``rel_range``, spans a shift across the whole range. It is
    common to every segment (all turn at about the same speed loss), so it is added after the
    combination and never averaged down (measured: PythonVehicleSimulator's tanker at 25 m, 10 deg
    rudder steps, speed 6.64-7.19 m/s (7.7 %), K 5 % below the straight-run linearisation with a
    standard error of 0.5-1 %: 0 % coverage before the term). With a constant speed (a speed-held
    frigate) the term is 0 and nothing changes.

    Parameters
    ----------
    est : Estimate
        A combined Nomoto K or T.
    rel_range : float
        Largest relative speed loss in the turns of the records behind it (:func:`speed_range`) [-].
    trend : str
        The evidence that the segments' values depend on the speed (:func:`speed_trend`); '' when the
        data show none: the term is then not added (a note says so), because a ship whose K and T do
        not scale with the speed shows no shift at all and the term would only widen the interval
        (the project's own simulator: sd of z of K 0.36 with it).
    """
    term = 0.5 * rel_range * abs(est.value) if math.isfinite(est.value) else math.nan
    if not (term > 0 and math.isfinite(est.stderr)):
        return est
    if not trend:
        return replace(est, message="; ".join([f"no speed term: the ship lost {rel_range:.1%} of its speed in the "
                                               f"turns, but the segments' values show no trend with their speed "
                                               f"loss (|t| < {SPEED_TREND_T:g}, or too few segments to tell)"]
                                              + ([est.message] if est.message else [])))
    se = math.hypot(est.stderr, term)
    return replace(est, stderr=se, ci95=confidence_interval(est.value, se, math.inf),
                   message="; ".join([f"standard error {est.stderr:.4g} -> {se:.4g} {est.unit} with the speed term "
                                      f"{term:.4g} {est.unit}: the ship lost {rel_range:.1%} of its speed in the "
                                      f"turns, and Nomoto's K and T scale with the speed (K = K' U / L, "
                                      f"T = T' L / U), so the straight-run values may lie anywhere across that "
                                      f"range ({trend})"]
                                     + ([est.message] if est.message else [])))
