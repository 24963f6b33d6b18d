"""Nomoto model structure chosen once per trial, across its segments, by leave-one-segment-out error.

A trial with several whole-record Nomoto segments (rudder steps, zig-zags, sinusoids) is one
ship: first-order Nomoto (K, T) or second order (K, T1, T2, T3) holds for all of them. Choosing per
segment by the held-out end of each record (:func:`pipeline.fit.nomoto_segment.fit_nomoto_window`)
compares a step's steady turn, where the two structures differ least, and lets segments of one
ship choose differently. Here the choice is made once:

1. Each segment's record is prepared (channels, servo; :func:`prepare_window`) and fitted whole with
   both structures (the second order stops early, :class:`pipeline.fit.nomoto_oe.GainFloor`, when
   its in-sample gain over the first order is below noise: it cannot then win on held-out data).
2. Leave one segment out: for each segment ``j``, the dynamics of each structure are pooled from the
   *other* segments' fits (generalised least squares with their covariances) and simulated over
   ``j``; only ``j``'s nuisances are re-estimated on it (initial heading, yaw rate and yaw
   acceleration, the rudder bias, and the gain K, which a nonlinear ship shifts with the rudder
   amplitude: the structure is the shape of the response, its time constants), with ``j``'s own first-order
   noise filter for both structures (the same whitening for both) and each structure's own servo fit. The transients of
   every segment are held out, not only the records' ends.
3. The held-out errors of all segments (each channel scaled by its spread in that segment) are
   compared by the project's shared rule (:func:`pipeline.fit.heldout_test.is_significant`):
   Bartlett-corrected F test, Bonferroni over channels, the most favourable segment left out for
   the robustness p-value, the held-out shrink and the explained error. The second order wins
   when it passes, or when it passes all but the shrink and was fitted on at least half the
   segments (:func:`significant_small_gain`: wave-whitened held-out errors shrink little even for a
   pole-zero pair beyond doubt); a near-tie whose structures differ materially marks the segments
   unsure (:func:`pipeline.fit.nomoto_segment.structure_ambiguity`). When every segment ends
   second order, K and T are read from the pooled vector of their constants
   (:mod:`pipeline.fit.nomoto_pool`).

   Sinusoids only: a sinusoid cannot identify the second order on its own, so their records are
   fitted jointly and the structure chosen on their jointly fitted held-out ends
   (:func:`joint_sinusoids`).

When the first order is chosen, the records are also fitted together with one rudder bias
(:func:`shared_bias_note`): one ship has one rudder offset, and a combined K or T that differs from that
fit materially and beyond its errors is marked unsure
(:func:`pipeline.fit.nomoto_quality.shared_bias_reason`).

4. Where the held-out errors do not decide the structure clearly (the first order kept on a near-tie,
   including a second order significantly better by less than ``MIN_SHRINK``; or a lone zig-zag or
   sinusoid, which only its own record's end can test), the difference between the two structures'
   K and T is a model-structure term added to the combined error (:func:`structure_term_notes`,
   applied by :func:`pipeline.fit.nomoto_quality.judge_nomoto`); when the structure is undecided
   and the two values also differ beyond their errors, the coefficient is marked unsure with both
   values. Measured on PythonVehicleSimulator's tanker at 20 m (steps, measured rudder, waves): the
   first order was kept at +0.1 % shrink (p = 5e-6) with T +14.5 % marked success, 0 % coverage.

A lone zig-zag whose record's held-out end leaves the structures on a near-tie, their K or T differing
materially, keeps the first order with the difference as that term (:func:`near_tie_zigzag_fit`) rather than
failing; one whose speed rises in its turns is first fitted on the distance sailed, second order, where its
held-out end chooses that (:mod:`pipeline.fit.nomoto_zigzag`). Where every segment is a rudder step, T comes from one second-order fit of all of them
(:mod:`pipeline.fit.nomoto_joint`), made only for the fits that are kept (:func:`with_joint_fit`).

The losing structure's held-out error is reported beside the winner's in every segment fit's
message (and so in ``K_nomoto``/``T_nomoto``), prefixed ``STRUCTURE_PREFIX``. When the segments'
K or T then disagree beyond their errors, :func:`disagreement_note` says what the spread points to:
a trend with the rudder amplitude (a nonlinearity: Norrbin's cubic yaw-rate term, a speed change
in turns) or a difference between manoeuvre kinds (the structure), else neither.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
from scipy import stats

from ..errors import FitError
from ..model.nomoto import ORDER2_SUM_PRODUCT
from ..parallel import ordered_map
from ..records import Segment, SegmentFit, Trial
from .combine import CONSISTENCY_ALPHA
from .nomoto_quality import (EXACT_FIT, RUDDER_TIMING, SHARED_BIAS, SPEED_RANGE, STRUCTURE_TERM, STRUCTURE_UNDECIDED,
                             weighted_slope_t)
from .data import segment_label
from .heldout_test import ALPHA, ALPHA_ROBUST, MIN_EXPLAINED, MIN_SHRINK, channel_score, is_significant
from .nomoto import whole_record_window
from .nomoto_oe import GainFloor, SecondOrderNoGain
from .nomoto_problem import SERVO_PARAMS, Problem, prepare
from .nomoto_records import NomotoFit, NomotoRecord
from .nomoto_oe import fit_nomoto
from .nomoto_pool import JOINT_FOLLOWER
from .nomoto_steady import steady_level_note
from .nomoto_zigzag import retimed_zigzag_fit, retimed_zigzag_window, speed_loss_terms
from .nomoto_rudder_delay import RUDDER_DELAY_TERM, with_rudder_delay
from .nomoto_joint import joint_step_fit, shared_noise
from .nomoto_segment import (LEAD_SPEED_SECONDS, MEASURED_RUDDER, ORDER2_EXTRA_PARAMS, NomotoWindow, choose_order,
                             equivalent_t_stderr, fit_nomoto_window, fit_window, fit_window_order, first_order_start_values, prepare_window,
                             rec_channel, segment_fit_of, slow_noise_note, speed_range_note, stack_rows,
                             structure_ambiguity)
from .nomoto_segment import RETIMED
from .nomoto_segment import structure_note as per_segment_structure_note
from .segment_fit import failed_segment_fit

#: Start of the trial-level structure note in segment-fit messages (read by ``structure_note``).
STRUCTURE_PREFIX = "model structure chosen once across"
#: Start of the disagreement note in segment-fit messages.
DISAGREEMENT_PREFIX = "segments disagree beyond their errors"
#: |t| of an amplitude trend (or a between-kind difference) that explains a disagreement.
TREND_T = 3.0
#: Start of the note on the joint fit of sinusoids (:func:`joint_sinusoids`).
JOINT_PREFIX = "sinusoids fitted jointly"


@dataclass(frozen=True)
class _Candidate:
    """One segment's prepared window and its fits of both structures (local)."""

    index: int
    win: NomotoWindow
    first: NomotoFit | None
    second: NomotoFit | None
    why_no_second: str
    no_gain: bool = False


@dataclass(frozen=True)
class StructureChoice:
    """The trial-level structure decision.

    Attributes
    ----------
    order : int
        1 or ``ORDER2_SUM_PRODUCT``.
    note : str
        Winner and loser with their held-out errors (starts with ``STRUCTURE_PREFIX``).
    near_tie : bool
        Not significant, but the second order not clearly worse either (shrink above ``-MIN_SHRINK``).
    """

    order: int
    note: str
    near_tie: bool = False
    shrink: float = math.nan
    p_value: float = math.nan


@dataclass(frozen=True)
class PendingJoint:
    """The joint second-order fit of a trial's rudder steps (:func:`pipeline.fit.nomoto_joint.joint_step_fit`),
    not yet made: it is made only for the fits that are kept (:func:`with_joint_fit`).

    Attributes
    ----------
    indices : tuple of int
        The segment fits that get its note and its T (keys of the fits' dict).
    bases : tuple of str
        Each fit's message up to where the note goes (notes added later follow it).
    recs, firsts, channels, servo, why
        The arguments of :func:`pipeline.fit.nomoto_joint.joint_step_fit`.
    """

    indices: tuple[int, ...]
    bases: tuple[str, ...]
    recs: tuple[NomotoRecord, ...]
    firsts: tuple[NomotoFit, ...]
    channels: tuple[str, ...]
    servo: tuple[str, ...]
    why: str

    def keyed(self, keys: Sequence[int]) -> "PendingJoint":
        """The same fit with its indices mapped through ``keys`` (index ``j`` becomes ``keys[j]``).

        Parameters
        ----------
        keys : sequence of int
            New key of each old index.
        """
        return replace(self, indices=tuple(keys[i] for i in self.indices))


def with_joint_fit(fits: dict[int, SegmentFit], pending: PendingJoint | None) -> dict[int, SegmentFit]:
    """``fits`` with the pending joint second-order fit made: its note in the messages of the fits it
    concerns (where the notes of :func:`fit_nomoto_trial` put it) and its T in their ``joint_t`` field.

    A trial whose records the end of its data cut is fitted in several passes
    (:func:`pipeline.fit.trial._nomoto_without_unsettled_cuts`), of which one is kept: the joint fit (0.7-3 s
    of CPU on PythonVehicleSimulator's six steps, one BLAS thread) is made for that one only.

    Parameters
    ----------
    fits : dict
        Segment index -> fit, as :func:`fit_nomoto_trial_deferred` returned them (later notes allowed).
    pending : PendingJoint or None
        The fit to make (None: ``fits`` unchanged).
    """
    if pending is None:
        return fits
    note, value = joint_step_fit(pending.recs, pending.firsts, pending.channels, pending.servo, pending.why)
    if not note:
        return fits
    out = dict(fits)
    for i, base in zip(pending.indices, pending.bases):
        sf = out.get(i)
        if sf is not None and sf.message.startswith(base):
            out[i] = replace(sf, message=f"{base}; {note}{sf.message[len(base):]}", joint_t=value)
    return out


def fit_nomoto_trial(trial: Trial, segments: Sequence[Segment]) -> dict[int, SegmentFit]:
    """:func:`fit_nomoto_trial_deferred` with its joint fit made (:func:`with_joint_fit`).

    Parameters
    ----------
    trial : Trial
        The trial.
    segments : sequence of Segment
        All its segments.
    """
    return with_joint_fit(*fit_nomoto_trial_deferred(trial, segments))


def fit_nomoto_trial_deferred(trial: Trial, segments: Sequence[Segment]
                              ) -> tuple[dict[int, SegmentFit], PendingJoint | None]:
    """Whole-record Nomoto fits of a trial's yaw segments with one structure chosen across them, and the
    joint second-order fit of its rudder steps still to be made (:func:`with_joint_fit`).

    Parameters
    ----------
    trial : Trial
        The trial.
    segments : sequence of Segment
        All its segments (the rudder steps, zig-zags and sinusoids in yaw that the whole-record fit
        serves are picked out).

    Returns
    -------
    dict
        Segment index -> :class:`SegmentFit` for those segments. A lone zig-zag or sinusoid chooses on
        its own held-out end (:func:`lone_segment_fit`, with the model-structure term); sinusoids only
        are fitted jointly when their joint held-out ends choose the second order (:func:`joint_sinusoids`);
        empty when fewer than two can be fitted whole otherwise (the per-segment fitter then serves them).
    PendingJoint or None
        The joint second-order fit of the rudder steps (:mod:`pipeline.fit.nomoto_joint`) where one is due.
    """
    spans = []
    for i, seg in enumerate(segments):
        if seg.dof != "yaw" or seg.kind not in ("rudder_step", "zigzag", "sinusoid"):
            continue
        span = whole_record_window(trial, seg)
        if span is not None:
            spans.append((i, seg, span))
    # Each window is prepared and fitted with both structures on its own (worker processes when the
    # cores allow: pipeline.parallel); the structure is then chosen across them here.
    # A lone window is only prepared: it gets its own structure choice (lone_segment_fit).
    job = _prepare_and_fit if len(spans) > 1 else _prepare
    prepared = [p for p in ordered_map(job, spans, context=trial) if p is not None]
    # A sinusoid's two ends both turn: its speed loss is read against the straight run before it.
    span_of = {i: span for i, _, span in spans}
    prepared = [_straight_run_speed(trial, p, span_of[p[0]]) for p in prepared]
    out, pending = _fit_prepared(trial, segments, prepared)
    # A rudder that jumps within a sample interval leaves its jumps' times unknown to within it, as does a
    # sinusoid's servo path between samples.
    wins = {i: w for i, w, _ in prepared}
    return {i: with_rudder_timing_note(sf, wins[i]) if i in wins else sf for i, sf in out.items()}, pending


def _fit_prepared(trial: Trial, segments: Sequence[Segment], prepared: Sequence[tuple]
                  ) -> tuple[dict[int, SegmentFit], PendingJoint | None]:
    """The fits of :func:`fit_nomoto_trial_deferred` from its prepared windows ((index, window, candidate or
    None)), and the joint fit still to be made."""
    wins = [(i, w) for i, w, _ in prepared]
    if len(wins) == 1:
        return lone_segment_fit(trial, segments[wins[0][0]], wins[0][0], wins[0][1]), None
    if len(wins) < 2:
        return {}, None
    cands = [c for _, _, c in prepared]
    usable = [c for c in cands if c.first is not None]
    if len(usable) < 2:
        return {}, None
    joint_note = ""
    if all(c.win.segment.kind == "sinusoid" for c in usable):
        joint, joint_note = joint_sinusoids(usable)
        if joint:
            return joint, None
    choice = choose_structure(usable)
    undecided = undecided_note(usable) if choice.near_tie and choice.order == 1 else ""
    clear, why = choice_is_clear(choice)
    decided = "clear" if clear else "undecided"
    n_both, n_no_gain = sum(c.second is not None for c in usable), sum(c.no_gain for c in usable)
    if decided == "undecided" and n_no_gain > n_both:
        # Most segments' second order could not gain in-sample above the noise: their data show no
        # pole-zero pair, so the few that did do not leave the structure undecided; their gap stays a term.
        decided = "weak"
        why = (f"{why}; the second order gained above the noise on {n_both} of {len(usable)} segments only (on "
               f"{n_no_gain} its in-sample gain was below the noise: no pole-zero pair in their data)")
    terms = structure_term_notes(
        structure_gaps([pair_values(c.first, c.second) for c in usable if c.second is not None]), decided, why)
    undecided = "; ".join(n for n in [undecided] + terms if n)
    out: dict[int, SegmentFit] = {}
    for c in usable:
        unsure = ""
        fits = {1: c.first}
        if c.second is not None:
            fits[ORDER2_SUM_PRODUCT] = c.second
        note = choice.note if choice.order == 1 or c.second is not None else (
            f"{choice.note}, on this segment the second order was not fitted ({c.why_no_second})")
        try:
            out[c.index] = fit_window(c.win, choice.order, note, unsure, fits)
        except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
            out[c.index] = failed_segment_fit(c.win.segment, "nomoto_oe", "", f"{segment_label(c.win.segment)}: {exc}")
    ok = [out[c.index] for c in usable if out[c.index].success]
    amps = {c.index: float(np.max(np.abs(c.win.rec.delta))) for c in usable}
    extra = disagreement_note(ok, [amps[c.index] for c in usable if out[c.index].success])
    shared = shared_bias_note(usable) if choice.order == 1 else ""
    steady = ""
    pending = None
    if choice.order == 1 and (decided != "clear" or terms):
        steady = steady_level_note([c.win for c in usable], [c.first.T for c in usable],
                                   "the transient's structure is undecided (first order kept, " + (
                                       "second order not resolved)" if decided != "clear" else "structure term present)"))
    steps = all(c.win.segment.kind == "rudder_step" for c in usable) and len({c.win.servo for c in usable}) == 1
    if steps and (choice.order != 1 or decided != "clear" or terms):
        # The first-order T is biased where the structure is undecided, and the second order pooled from
        # per-step fits carries each step's nonlinear-estimator bias: one second order fitted to every
        # step at once reads the first-order equivalent T from all of them (nomoto_joint).
        # Made only for the fits that are kept (with_joint_fit); its note goes after the others.
        channels = tuple(ch for ch in ("psi", "r") if all(ch in c.win.channels for c in usable))
        pending = (tuple(c.win.rec for c in usable), tuple(c.first for c in usable), channels, usable[0].win.servo,
                   (why or "structure term present") if choice.order == 1 else "second order chosen across the steps")
    extra = "; ".join(n for n in (undecided, extra, joint_note, shared, steady) if n)
    if extra:
        out = {i: replace(sf, message=f"{sf.message}; {extra}") for i, sf in out.items()}
    if pending is not None:
        pending = PendingJoint(tuple(out), tuple(sf.message for sf in out.values()), *pending)
    return out, pending


def shared_bias_note(cands: Sequence[_Candidate]) -> str:
    """The first-order fit of all the segments' records at once, with one rudder bias ('' when not made).

    Each segment's own fit estimates its own rudder bias b, and with it the steady turn rates before
    and after its manoeuvre are matched by K and b alone: on a ship whose turn rate is not linear in
    the rudder (or whose response has a pole-zero pair) the per-segment biases then absorb what the
    first order misses, and T takes up the rest (measured: PythonVehicleSimulator's tanker at 20 m,
    six measured-rudder steps with waves, per-step biases -0.51 to -0.78 deg, chi-square 62 on 5 dof,
    per-step T combined +14.6 %, marked success with 0 % coverage). One ship has one rudder offset:
    the records fitted jointly with one bias (K, T and the servo shared, per-record initial states;
    the wave noise model held at the segments' median) give a second estimate of K and T, consistent
    whenever the per-segment ones are (same ship, same structure) and more efficient. Where the two
    differ materially and beyond their errors, :func:`pipeline.fit.nomoto_quality.shared_bias_reason`
    marks the combined value unsure (the same tanker: T +5.2 % with one bias against +14.6 %; the
    PythonVehicleSimulator frigate, a first-order ship: within 0.2 %).

    Parameters
    ----------
    cands : sequence of _Candidate
        Segments with a usable first-order fit (two or more); sinusoids have their own joint fit
        (:func:`joint_sinusoids`).

    Returns
    -------
    str
        ``SHARED_BIAS`` note with the joint K and T and their standard errors (the channels every
        record has are fitted), or '' when the records share no channel or differ in servo, or the
        joint fit fails or leaves its range.
    """
    wins = [c.win for c in cands]
    firsts = [c.first for c in cands]
    channels = tuple(ch for ch in ("psi", "r") if all(ch in w.channels for w in wins))
    if len(cands) < 2 or not channels or len({w.servo for w in wins}) != 1:
        return ""
    if any("b" not in f.names for f in firsts):
        return ""
    noise, kw = shared_noise(firsts)
    kw["start"] = {"K": float(np.median([f.K for f in firsts])), "T": float(np.median([f.T for f in firsts]))}
    try:
        fit = fit_nomoto([w.rec for w in wins], order=1, noise=noise, channels=channels, servo=wins[0].servo, **kw)
    except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError):
        return ""
    if not _usable(fit):
        return ""
    sk, st = fit.reported_error("K"), fit.reported_error("T")
    if not (math.isfinite(sk) and math.isfinite(st)):
        return ""
    bs = np.degrees([f.b for f in firsts])
    return (f"{SHARED_BIAS} {len(cands)} records (first order): K = {fit.K:.6g} +- {sk:.3g} 1/s, T = {fit.T:.6g} "
            f"+- {st:.3g} s, b = {math.degrees(fit.b):.3g} deg (the records' own fits: b from {bs.min():.3g} to "
            f"{bs.max():.3g} deg)")


def joint_sinusoids(cands: Sequence[_Candidate]) -> tuple[dict[int, SegmentFit], str]:
    """Sinusoids at several frequencies fitted jointly, when the held-out data choose the second order.

    One sinusoid shows a gain and a phase at one frequency: a first-order model matches any ship
    there, and a second-order one (K, T1 + T2, T1 T2, T3) is not identified by it alone, so each
    sinusoid's own second-order fit fails or stops (:class:`pipeline.fit.nomoto_oe.GainFloor`) and
    the leave-one-segment-out choice has nothing to pool. Fitted together (one ship, per-record
    initial states, one rudder bias and servo), sinusoids at two frequencies give four numbers, which
    determine the second order (measured: PythonVehicleSimulator's Clarke83 ship, sinusoids at 0.037 and
    0.15 rad/s with the measured rudder, K +0.35 %, T1 + T2 - T3 -0.2 %; first order per frequency
    +4 % / +20 %). The structure is chosen on the held-out end of every record, fitted jointly
    (:func:`pipeline.fit.nomoto_segment.choose_order`). When the second order wins, the whole records
    are fitted jointly with it; the first segment carries the fit's K, T and the rest, the others the
    same fit (their own record's simulation) with a ``JOINT_FOLLOWER`` note, counted once
    (:func:`pipeline.fit.nomoto_pool.is_joint_follower`).

    With a logged command the servo lag is fitted too: then ``2 n`` numbers (``n`` frequencies)
    meet ``4 + 1`` unknowns, and with ``2 n < 5`` the lag trades off against the pole-zero pair
    (measured: the Clarke83 commanded sinusoids, noise-free, lag 1.7 s against 1.0, T -40 % with a
    standard error of 1 %): T is then marked unsure (``STRUCTURE_UNDECIDED``), K is not. A logged command
    counts its servo even when the joint fit dropped the lag (it left its range): the servo's phase then
    goes into the ship's constants (measured: PythonVehicleSimulator's tanker at 25 m, rate-limited
    servo, commanded sinusoids with waves, T +8 % with a 10.6 % standard error marked success).
    With ``2 n = 4 + n_servo`` the numbers fix the constants exactly and leave none to test the
    structure: T is marked unsure too, K is not (measured: PythonVehicleSimulator's Clarke83 ship,
    measured-rudder sinusoids at 10 deg, white output-error residuals, T -2.6 to -4.1 % with standard
    errors of 0.7-1.2 % on 3 of 7 seeds, marked success; K within 0.35 %). In both cases K gets a
    model-structure term of its own error's size (:func:`exact_fit_k_term`).

    A wave noise model whose peak lies below the corner frequency (:func:`pipeline.fit.nomoto_segment.slow_noise_note`)
    is checked against the output-error fit of the same records (consistent for sinusoids, which are
    open loop): when their K and T agree within ``DISAGREE_Z`` combined errors the noise model did not
    take up the ship's response and the note does not apply.

    Parameters
    ----------
    cands : sequence of _Candidate
        The sinusoid segments with a usable first-order fit (two or more).

    Returns
    -------
    fits : dict
        Segment index -> SegmentFit (empty when the first order is kept or the joint fit fails).
    note : str
        How the joint structure choice went ('' when it was not made).
    """
    wins = [c.win for c in cands]
    command = {any(n.startswith("rudder logged as a command") for n in w.notes) for w in wins}
    channels = tuple(ch for ch in ("psi", "r") if all(ch in w.channels for w in wins))
    if len(command) != 1 or not channels:
        return {}, ""
    command_logged = command.pop()
    servo: tuple[str, ...] = ("t_servo",) if command_logged else ()
    recs = [w.rec for w in wins]
    head = f"{JOINT_PREFIX} ({len(recs)} records, one ship)"
    try:
        choice = choose_order(recs, channels, servo)
    except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        return {}, f"{head}: the joint structure check failed ({exc})"
    if choice.order == 1:
        return {}, f"{head}: {choice.note}"
    notes = [f"{head}: {choice.note}"]
    try:
        fit = fit_nomoto(recs, order=ORDER2_SUM_PRODUCT, noise="auto", channels=channels, servo=servo)
        if servo and any(n in SERVO_PARAMS for n in fit.at_bound):
            servo = ()
            fit = fit_nomoto(recs, order=ORDER2_SUM_PRODUCT, noise="auto", channels=channels)
            notes.append("the servo lag left its range in the joint fit: rudder taken as the command")
        slow_checked, terms = _slow_noise_check(fit, recs, channels, servo) if slow_noise_note(fit) else ("", [])
    except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        return {}, f"{head}: {choice.note}, but the joint second-order fit failed ({exc})"
    if not _usable(fit):
        return {}, f"{head}: {choice.note}, but the joint second-order fit did not converge in range"
    # A logged command always has a servo behind it, kept in the fit or not (dropped when its lag left
    # the range: the fit then holds the ship's dynamics only, and the servo's phase goes into them).
    n_servo = max(sum(n in SERVO_PARAMS for n in fit.names), 1 if command_logged else 0)
    unsure = ""
    if 2 * len(recs) < 4 + n_servo:
        unsure = (f"{STRUCTURE_UNDECIDED} T: {len(recs)} sinusoids give {2 * len(recs)} numbers (a gain and a phase "
                  f"per frequency) for the second order's 4 and the servo's {n_servo}: the servo lag trades off "
                  f"against the pole-zero pair, so T1 + T2 - T3 is not identified (add a rudder step, a zig-zag or "
                  f"a sinusoid at a third frequency)")
    elif 2 * len(recs) == 4 + n_servo:
        unsure = (f"{STRUCTURE_UNDECIDED} T: {len(recs)} sinusoids give {2 * len(recs)} numbers (a gain and a phase "
                  f"per frequency) for the second order's 4 constants{' and the servo lag' if n_servo else ''}: they "
                  f"fix them exactly and leave none to test the structure, so a response that is not exactly a "
                  f"linear second order (a nonlinearity at this amplitude, a speed change) goes into T1 + T2 - T3 "
                  f"unseen by its error (add a rudder step, a zig-zag or a sinusoid at a third frequency)")
    if unsure:
        trade = servo_trade_k(fit, recs, channels) if 2 * len(recs) < 4 + n_servo else None
        terms = terms + [exact_fit_k_term(fit, len(recs), trade)]
    lead = segment_label(wins[0].segment)
    out = {}
    for i, (c, w) in enumerate(zip(cands, wins)):
        own = [n for n in w.notes if not (n.startswith("servo ") or n.startswith("first-order compass residuals"))]
        seg_notes = ([f"{JOINT_FOLLOWER} {lead}: its K, T and the other coefficients are that joint fit's, "
                      f"counted once"] if i else []) + own + notes + ([unsure] if unsure else []) + terms
        out[c.index] = segment_fit_of(w.segment, fit, w.rec, channels, w.t_rel, seg_notes, record=i,
                                      slow_noise_checked=slow_checked)
    return out, ""


def servo_trade_k(fit: NomotoFit, recs: Sequence[NomotoRecord], channels: tuple[str, ...]) -> float | None:
    """K [1/s] of the same joint second-order fit with the logged command taken as the rudder angle (no servo
    lag), or None where the fit has no lag or that fit fails.

    Sinusoids at ``n`` frequencies with ``2 n < 4 + 1`` fix a one-parameter family of (servo lag, pole-zero pair)
    that matches their gains and phases: the lag is read from the records' transients alone, and K moves with it
    along that family. Measured on PythonVehicleSimulator's Clarke83 ship (1.0 s servo, commanded sinusoids at
    0.037 and 0.15 rad/s, 10 deg, no waves): the lag came out 1.72 s noise-free (1.77 and 1.72 s on seeds 0-1,
    standard errors 0.14 s), K -0.90 % (-0.88 and -0.95 % +- 0.21 % from the fit, the intervals missing); K
    with the lag held at 0, 0.5, 1.0, 1.5, 2.0 s: +1.25, +0.74, +0.11, -0.59, -1.29 %. The transients prefer the
    wrong lag by far (-2 log L 35 units below the true lag's on seed 0): the ship's response is not exactly a
    linear second order behind a first-order servo, and the lag takes up that misfit. The difference between
    the fitted lag's K and this fit's K (the servo's whole effect on K) is a model term of K
    (:func:`exact_fit_k_term`).

    Parameters
    ----------
    fit : NomotoFit
        The joint second-order fit with the servo lag.
    recs : sequence of NomotoRecord
        The sinusoids' records (the logged command as ``delta``).
    channels : tuple of str
        Outputs fitted.
    """
    if "t_servo" not in fit.names:
        return None
    try:
        plain = fit_nomoto(list(recs), order=ORDER2_SUM_PRODUCT, noise=fit.noise_model, channels=channels)
    except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError):
        return None
    if not (_usable(plain) and math.isfinite(plain.K)):
        return None
    return float(plain.K)


def exact_fit_k_term(fit: NomotoFit, n_records: int, k_without_servo: float | None = None) -> str:
    """The model-structure term of K from sinusoids that fix the second order's constants exactly.

    ``n`` sinusoids give ``2 n`` numbers (a gain and a phase per frequency); with ``2 n`` at most
    the 4 constants (and the servo lag) none is left to test the structure, so whatever the response
    has beyond a linear second order (a nonlinearity at the manoeuvre's amplitude, a speed change)
    goes into the constants. T is then marked unsure (:func:`joint_sinusoids`); K, the one constant a
    sinusoid pair pins closely, keeps its value, but its misfit share is a bias common to every
    repetition of the manoeuvre, which the error (from the residuals, as if the misfit were noise)
    does not count. Its size is taken as K's own standard error: the Newey-West error
    (:func:`pipeline.fit.nomoto_oe.correlated_residual_errors`) is the spread that residual pattern
    would give K as noise, the same projection of the misfit; added in quadrature by
    :func:`pipeline.fit.nomoto_quality.add_structure_term` (a ``STRUCTURE_TERM_PREFIX`` note; the
    larger of it and any other term counts); the speed the turns lost adds its own term
    (:func:`pipeline.fit.nomoto_quality.exact_fit_trend`: one exact fit cannot rule out a speed
    dependence). Measured: PythonVehicleSimulator's Clarke83 ship,
    measured-rudder sinusoids at 10 deg without waves, seeds 0-11: K +0.06 to +0.40 % (the
    noise-free best linear fit +0.2 %), 95 % coverage 7 of 10 seeds marked success with the error
    alone, 9 of 10 with the term.

    With a servo lag the sinusoids do not fix (``k_without_servo`` given, :func:`servo_trade_k`), the difference
    between K with the lag fitted and K with the command taken as the rudder angle is added in quadrature: the
    lag trades off against the pole-zero pair and carries K with it.

    Parameters
    ----------
    fit : NomotoFit
        The joint second-order fit.
    n_records : int
        Sinusoid records fitted jointly.
    k_without_servo : float, optional
        K of the same fit without the servo lag [1/s] (:func:`servo_trade_k`).
    """
    se = fit.reported_error("K")
    text = (f"{n_records} {EXACT_FIT}, so a response that is not exactly a "
            f"linear second order goes into K as a bias common to every repetition, taken as the size of K's own "
            f"error (the spread that misfit would give K were it noise)")
    term = se
    if k_without_servo is not None and math.isfinite(k_without_servo):
        trade = abs(fit.K - k_without_servo)
        term = math.hypot(se, trade)
        text += (f", and the servo lag, which {n_records} sinusoids do not fix beside the pole-zero pair (its "
                 f"{fit.value('t_servo'):.3g} s read from the transients alone), carries K with it: K "
                 f"{fit.K:.5g} 1/s with the lag fitted, {k_without_servo:.5g} 1/s with the command taken as the "
                 f"rudder angle, the difference {trade:.3g} 1/s in quadrature")
    return f"{STRUCTURE_TERM_PREFIX} K: +-{term:.6g} 1/s added in quadrature to its standard error: {text}"


def _slow_noise_check(fit: NomotoFit, recs: Sequence, channels: tuple[str, ...], servo: tuple[str, ...]
                      ) -> tuple[str, list[str]]:
    """Why a joint fit's slow wave noise model does not bias K and T, and the terms it leaves ('' and
    none when it may bias them: :func:`pipeline.fit.nomoto_segment.slow_noise_note` then applies).

    The output-error fit of the same records and structure is made (consistent for open-loop
    sinusoids, whatever the noise's colour); the noise model took up none of the ship's response when
    its K and T agree with it within ``DISAGREE_Z`` combined standard errors. Their difference is then
    a noise-model term (``STRUCTURE_TERM_PREFIX`` notes, added in quadrature to the combined error by
    :func:`pipeline.fit.nomoto_quality.judge_nomoto`): two consistent estimators whose noise models
    differ, and the PEM's error bars assume its noise model (measured: Clarke83 measured-rudder
    sinusoids, T -2.6 % and -4.1 % with standard errors of 0.7 %)."""
    try:
        oe = fit_nomoto(recs, order=fit.order, noise="white", channels=channels, servo=servo,
                        start=first_order_start_values(fit))
    except FitError:
        return "", []
    if not _usable(oe):
        return "", []
    parts, terms = [], []
    for name, unit, a, sa, b, sb in (("K", "1/s", fit.K, fit.error("K"), oe.K, oe.error("K")),
                                     ("T", "s", fit.T, equivalent_t_stderr(fit), oe.T, equivalent_t_stderr(oe))):
        se = math.hypot(sa, sb)
        if not (math.isfinite(se) and se > 0 and abs(a - b) <= DISAGREE_Z * se):
            return "", []
        parts.append(f"{name} {a:.4g} against {b:.4g} (z = {(a - b) / se:+.2f})")
        terms.append(f"{STRUCTURE_TERM_PREFIX} {name}: +-{abs(a - b):.6g} {unit} added in quadrature to its standard "
                     f"error, the difference between the wave-noise and output-error fits of the same records (both "
                     f"consistent for open-loop sinusoids; the first one's error bars assume its noise model)")
    return (f"the wave noise model's peak, omega0 = {fit.value('omega0'):.3g} rad/s, lies below the corner "
            f"frequency, but the output-error fit of the same records agrees ({', '.join(parts)}, within "
            f"{DISAGREE_Z:g}): the noise model took up none of the ship's response"), terms


def choice_is_clear(choice: StructureChoice) -> tuple[bool, str]:
    """Whether the held-out errors decided the structure clearly, and why not when they did not.

    Clear: the second order passed the shared rule, or it lost by at least ``MIN_SHRINK`` (its
    held-out error clearly larger). Not clear: the first order kept on a near-tie, including a second
    order significantly better whose held-out gain is below ``MIN_SHRINK`` (real but small: at a low
    signal-to-noise ratio the missing pole-zero pair still biases the first-order T).

    Parameters
    ----------
    choice : StructureChoice
        The trial-level decision.
    """
    if choice.order != 1 or not choice.near_tie:
        return True, ""
    sig = math.isfinite(choice.p_value) and choice.p_value < ALPHA
    if sig:
        return False, (f"the second order is significantly better on the held-out segments (p = "
                       f"{choice.p_value:.2g}) but by {choice.shrink:+.1f} % only (the rule asks {MIN_SHRINK:g} %), so "
                       f"the first order was kept although the data show the second order's pole-zero pair")
    return False, (f"the held-out segments do not decide between the structures ({choice.shrink:+.1f} % shrink, "
                   f"p = {choice.p_value:.2g})")


@dataclass(frozen=True)
class StructureGap:
    """How far the second-order value of K or T (first-order equivalent) lies from the first-order one.

    Attributes
    ----------
    name : str
        ``K`` or ``T``.
    unit : str
        Its unit.
    first, second : float
        Inverse-variance means over the segments fitted with both structures.
    diff, diff_se : float
        Inverse-variance mean of the per-segment differences (second minus first) and its standard
        error (per-segment errors combined in quadrature, scaled by the Birge ratio of the
        differences when they scatter more than that).
    n : int
        Segments fitted with both structures.
    """

    name: str
    unit: str
    first: float
    second: float
    diff: float
    diff_se: float
    n: int

    @property
    def term(self) -> float:
        """The model-structure term: the largest of the paired difference, its standard error and the
        difference of the two structures' own means (each weighted by its own errors, so a few precise
        first-order fits do not hide the second order's value) [unit].

        The term stands for the bias of the kept value should the other structure be the ship's. A
        paired difference smaller than its own error (the two structures fitted on one segment only)
        does not show that bias small, only unmeasured: the term is then that error, what the data allow.
        Measured: PythonVehicleSimulator's tanker at 20 m, commanded rudder steps, seed 5 of 0-7: the
        second order fitted on 1 of 6 segments, its T 0.31 +- 2.3 s above the first order's; with the
        difference as the term T -4.3 +- 7.1 % was marked success, the only seed of the eight whose T
        was (the others' terms, from differences above their errors, were 1.0-2.0 s).
        """
        return max(abs(self.diff), self.diff_se, abs(self.second - self.first))

    @property
    def beyond_errors(self) -> bool:
        """The two structures disagree by more than ``DISAGREE_Z`` combined standard errors."""
        return abs(self.diff) > DISAGREE_Z * self.diff_se


#: Combined standard errors beyond which the two structures' values disagree.
DISAGREE_Z = 2.0
#: Start of the note that adds the structure disagreement to a Nomoto coefficient's error
#: (``model-structure term for T: +-<value> <unit> ...``, read by
#: :func:`pipeline.fit.nomoto_quality.judge_nomoto`).
STRUCTURE_TERM_PREFIX = STRUCTURE_TERM


def pair_values(first: NomotoFit, second: NomotoFit) -> dict[str, tuple[float, float, float, float]]:
    """K and T (first-order equivalent) of both structures fitted to one segment: name -> (first,
    its error, second, its error).

    Parameters
    ----------
    first, second : NomotoFit
        First- and second-order whole-record fits of the same segment.
    """
    return {"K": (first.K, first.error("K"), second.K, second.error("K")),
            "T": (first.T, first.error("T"), second.T, equivalent_t_stderr(second))}


def structure_gaps(pairs: Sequence[dict[str, tuple[float, float, float, float]]]) -> list[StructureGap]:
    """First- against second-order K and T over the segments fitted with both (empty without any).

    Parameters
    ----------
    pairs : sequence of dict
        Per segment, :func:`pair_values`.
    """
    out = []
    for name, unit in (("K", "1/s"), ("T", "s")):
        rows = []
        for pv in pairs:
            v1, s1, v2, s2 = pv.get(name, (math.nan,) * 4)
            if all(math.isfinite(x) for x in (v1, s1, v2, s2)) and s1 > 0 and s2 > 0:
                rows.append((v1, s1, v2, s2))
        if not rows:
            continue
        v1, s1, v2, s2 = (np.array(c) for c in zip(*rows))
        d, sd = v2 - v1, np.hypot(s1, s2)
        w = 1.0 / sd**2
        diff = float(w @ d / w.sum())
        birge = math.sqrt(max(1.0, float(w @ (d - diff) ** 2) / (d.size - 1))) if d.size > 1 else 1.0
        out.append(StructureGap(name, unit, float((v1 / s1**2).sum() / (1 / s1**2).sum()),
                                float((v2 / s2**2).sum() / (1 / s2**2).sum()), diff,
                                birge / math.sqrt(float(w.sum())), d.size))
    return out


def structure_term_notes(gaps: Sequence[StructureGap], decided: str, why: str) -> list[str]:
    """Notes that widen (or mark unsure) K and T where the structure was not decided clearly.

    ``decided`` says how the held-out errors decided the structure:

    - ``clear``: leave-one-segment-out across the trial's segments passed the shared rule for the
      winner (or the second order lost clearly): the winner's value stands, no term.
    - ``weak``: the second order won on the held-out end of one record only (a lone zig-zag or
      sinusoid: no other manoeuvre confirms it), or a near-tie across the segments where the second
      order gained in-sample above the noise on fewer segments than it could not (measured on
      PythonVehicleSimulator's frigate, a first-order ship, at 5 Hz: 1 of 5 segments fitted with
      both, K marked unsure): the difference to the first-order value is a
      model-structure term (``STRUCTURE_TERM_PREFIX``), added in quadrature to the combined
      standard error by :func:`pipeline.fit.nomoto_quality.judge_nomoto`.
    - ``undecided``: the first order was kept on a near-tie: the same term, and when the two
      structures' values also differ beyond their combined errors (``StructureGap.beyond_errors``)
      the coefficient is marked unsure (``STRUCTURE_UNDECIDED``) with both values and what the
      disagreement points to.

    Parameters
    ----------
    gaps : sequence of StructureGap
        From :func:`structure_gaps`.
    decided : str
        ``clear``, ``weak`` or ``undecided``.
    why : str
        How the structure was (not) decided, for the note.
    """
    if decided not in ("clear", "weak", "undecided"):
        raise ValueError(f"decided: expected 'clear', 'weak' or 'undecided', found {decided!r}")
    out = []
    if decided == "clear":
        return out
    for g in gaps:
        values = (f"first order {g.first:.4g}, second order {g.second:.4g} {g.unit} (difference {g.diff:+.3g} +- "
                  f"{g.diff_se:.2g} on {g.n} segment(s) fitted with both)")
        if decided == "undecided" and g.beyond_errors:
            out.append(f"{STRUCTURE_UNDECIDED} {g.name}: the first- and second-order Nomoto values differ beyond "
                       f"their errors, {values}, and {why}: the ship's response has a pole-zero pair (or "
                       f"servo, speed or nonlinear dynamics) that a first-order {g.name} does not hold, and the "
                       f"data cannot tell which value is the ship's")
        out.append(f"{STRUCTURE_TERM_PREFIX} {g.name}: +-{g.term:.6g} {g.unit} added in quadrature to its "
                   f"standard error, {values}, because {why}")
    return out


def lone_segment_fit(trial: Trial, seg: Segment, index: int, win: NomotoWindow) -> dict[int, SegmentFit]:
    """A lone whole-record segment: its own structure choice (:func:`pipeline.fit.nomoto_segment.fit_nomoto_window`)
    plus the other structure fitted to the whole record for the model-structure term.

    A zig-zag whose speed rises in its turns is first fitted on the distance sailed
    (:func:`pipeline.fit.nomoto_zigzag.retimed_zigzag_fit`, its rudder-timing note as a step trial's), where its
    held-out end chooses that; one that slows in its turns carries the speed loss as a model term on K and T
    (:func:`pipeline.fit.nomoto_zigzag.speed_loss_terms`). Otherwise see :func:`_lone_segment_fit`. A zig-zag
    not re-timed, fitted first order from a measured rudder angle, has its rudder-to-heading delay fitted with
    K and T, the delay's error a term on both (:func:`pipeline.fit.nomoto_rudder_delay.with_rudder_delay`).

    Parameters
    ----------
    trial : Trial
        The trial.
    seg : Segment
        The segment.
    index : int
        Its index in the trial's segments.
    win : NomotoWindow
        Its prepared window.
    """
    out = _lone_segment_fit(trial, seg, index, win)
    sf = out.get(index)
    if sf is None or seg.kind != "zigzag" or RETIMED in sf.message:
        return out
    if any(n.startswith(MEASURED_RUDDER) for n in win.notes) and not win.servo:
        sf = with_rudder_delay(sf, win.rec, win.channels)
        out = {**out, index: sf}
    notes = speed_loss_terms(trial, win, sf)
    if not notes:
        return out
    return {**out, index: replace(sf, message="; ".join([sf.message] + notes) if sf.message else "; ".join(notes))}


def _lone_segment_fit(trial: Trial, seg: Segment, index: int, win: NomotoWindow) -> dict[int, SegmentFit]:
    """:func:`lone_segment_fit` before the speed-loss terms: the re-timed zig-zag where it is chosen, else the
    segment's own structure choice plus the other structure fitted to the whole record for the model-structure
    term.

    The per-segment choice holds out the record's end: a second order selected there is a ``weak``
    decision, a first order kept an ``undecided`` one (:func:`structure_term_notes`). A zig-zag or a sinusoid
    only (a rudder step keeps its own fitter and fallbacks): empty otherwise.

    Parameters
    ----------
    trial : Trial
        The trial.
    seg : Segment
        The segment.
    index : int
        Its index in the trial's segments.
    win : NomotoWindow
        Its prepared window.
    """
    if seg.kind not in ("zigzag", "sinusoid"):
        return {}
    retimed = retimed_zigzag_window(trial, win) if seg.kind == "zigzag" else None
    if retimed is not None:
        sf = retimed_zigzag_fit(trial, win, retimed)
        if sf is not None:
            return {index: with_rudder_timing_note(sf, retimed)}
    try:
        sf = fit_nomoto_window(trial, seg, seg.t_start, seg.t_end)
    except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError):
        return {}
    if not sf.success:
        if seg.kind == "zigzag" and sf.message.startswith(NEAR_TIE):
            return near_tie_zigzag_fit(index, win, sf)
        return {index: sf}
    chosen_second = "T3" in sf.params
    why = ("the second order won on the held-out end of this one record only (no other manoeuvre confirms the "
           "structure, and one record's end is a weak test of it)" if chosen_second else
           "the record's held-out end kept the first order (one record's end is a weak test of the structure)")
    try:
        if chosen_second:
            # The chosen second order is the segment fit itself; only the first order is added.
            first, _ = fit_window_order(win, 1)
            if not _usable(first):
                return {index: sf}
            pv = {"K": (first.K, first.error("K"), sf.params["K"], sf.stderr.get("K", math.nan)),
                  "T": (first.T, first.error("T"), sf.params["T"], sf.stderr.get("T", math.nan))}
        else:
            cand = _fit_both(index, win)
            if cand.first is None or cand.second is None:
                return {index: sf}
            pv = pair_values(cand.first, cand.second)
    except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError):
        return {index: sf}
    notes = structure_term_notes(structure_gaps([pv]), "weak" if chosen_second else "undecided", why)
    if not notes:
        return {index: sf}
    return {index: replace(sf, message="; ".join([sf.message] + notes) if sf.message else "; ".join(notes))}


#: Start of the message of a record whose held-out end leaves the structure on a near-tie and whose two
#: structures' K or T differ materially (:func:`pipeline.fit.nomoto_segment.structure_ambiguity`).
NEAR_TIE = "unsure: the held-out data do not decide between first- and second-order Nomoto (near-tie)"


def near_tie_zigzag_fit(index: int, win: NomotoWindow, failed: SegmentFit) -> dict[int, SegmentFit]:
    """A lone zig-zag whose held-out end does not decide the structure: the first order kept with both
    structures' K and T as a model-structure term (``undecided``, :func:`structure_term_notes`), in place of
    a failed fit (``failed`` kept where either structure cannot be fitted to the whole record).

    The failed fit left K and T "not identified: no usable segment", although the data give both
    structures' values, the difference between them being the thing not known; a sinusoid's or a step
    trial's undecided structure gives its value with that difference as a term, marked unsure where the two
    differ beyond their errors. Measured (PythonVehicleSimulator, 10 deg zig-zags, no waves, seeds 0-2 of the
    coordinator's baseline of efba945): Clarke83 measured rudder (first order K +19 %, T +90 %; second order
    K -3 %, T -22 %), tanker at 20 m measured (T 11.8 s against 9.6 s, truth 9.32 s); an offline fit of the
    second order to the zig-zag's rudder holds as separate records (each hold a step of
    :mod:`pipeline.fit.nomoto_joint`, its own initial state) did not help: Clarke83 noise-free T -34 % +- 3.6 %
    (-27 % re-timed on the distance sailed), the tankers' fits did not converge in range.

    Parameters
    ----------
    index : int
        The segment's index in the trial's segments.
    win : NomotoWindow
        Its prepared window.
    failed : SegmentFit
        Its failed fit (message starting with ``NEAR_TIE``).
    """
    cand = _fit_both(index, win)
    if cand.first is not None and cand.second is None and cand.first.noise_model == "waves" and not cand.no_gain:
        # As the structure choice does (nomoto_segment.choose_order): a second order that leaves its range
        # under the wave noise model is fitted by output error (Clarke83, seed 0: not converged in range).
        try:
            second, _ = fit_window_order(win, ORDER2_SUM_PRODUCT, noise="white")
        except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError):
            second = None
        if second is not None and _usable(second):
            cand = replace(cand, second=second)
    if cand.first is None or cand.second is None:
        return {index: failed}
    why = ("the record's held-out end left the two structures on a near-tie (one record's end is a weak test of "
           "the structure)")
    try:
        sf = fit_window(win, 1, f"first-order Nomoto kept: {why}", "", {1: cand.first, ORDER2_SUM_PRODUCT: cand.second})
    except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError):
        return {index: failed}
    notes = structure_term_notes(structure_gaps([pair_values(cand.first, cand.second)]), "undecided", why)
    if not (sf.success and notes):
        return {index: failed}
    return {index: replace(sf, message="; ".join([sf.message] + notes))}


def undecided_note(cands: Sequence[_Candidate]) -> str:
    """Which of K and T the structures leave undecided after a near-tie ('' when neither).

    A coefficient is undecided when, on most segments fitted with both structures, the two fits
    differ materially (:func:`pipeline.fit.nomoto_segment.structure_ambiguity`). The note starts
    with ``STRUCTURE_UNDECIDED`` and names the coefficients; :func:`pipeline.fit.nomoto_quality.judge_nomoto`
    marks only those combined estimates unsure (a K both structures agree on stays).

    Parameters
    ----------
    cands : sequence of _Candidate
        The segments.
    """
    both = [c for c in cands if c.second is not None]
    if not both:
        return ""
    names, example = [], {}
    for name in ("K", "T"):
        flagged = []
        for c in both:
            text = structure_ambiguity(c.first, c.second)
            parts = [p for p in text.split("materially: ")[-1].split(", ") if p.startswith(f"{name} ")] if text else []
            if parts:
                flagged.append(parts[0])
        if 2 * len(flagged) > len(both):
            names.append(name)
            example[name] = flagged[0]
    if not names:
        return ""
    return (f"{STRUCTURE_UNDECIDED} {' and '.join(names)}: the held-out data do not decide between first- and "
            f"second-order Nomoto (near-tie across the segments) and their {' and '.join(names)} differ materially "
            f"on most segments (e.g. {', '.join(example.values())})")


#: Share of the rudder's range (1st to 99th percentile of the window's drive) that its largest change over two
#: sample intervals must reach for the rudder to count as jumping within a sample [-] (a measured angle
#: is driven as each interval's mean, which spreads a jump over two intervals).
RUDDER_JUMP_SHARE = 0.5
#: The rudder's range must exceed this many times its sample-to-sample noise for a jump to be read [-].
RUDDER_JUMP_NOISE = 10.0


def rudder_jumps(rec: NomotoRecord) -> bool:
    """Whether the record's rudder (the drive of the fit) jumps within a sample interval.

    A jump: the largest change over two consecutive sample intervals is at least ``RUDDER_JUMP_SHARE``
    of the rudder's range (its 1st to 99th percentile), and that range is more than
    ``RUDDER_JUMP_NOISE`` times the sample-to-sample noise (the median absolute difference,
    scaled to a standard deviation). A servo that ramps over several samples (PythonVehicleSimulator's
    ships at 5 Hz) does not jump; a held rudder or a command does.

    Parameters
    ----------
    rec : NomotoRecord
        The record (``delta`` as it drives the model) [rad].
    """
    d = np.asarray(rec.delta, float)
    d = d[np.isfinite(d)]
    if d.size < 3:
        return False
    lo, hi = np.percentile(d, [1.0, 99.0])
    noise = 1.4826 * float(np.median(np.abs(np.diff(d)))) / math.sqrt(2.0)
    span = hi - lo
    if not (span > 0 and span > RUDDER_JUMP_NOISE * noise):
        return False
    return float(np.max(np.abs(d[2:] - d[:-2]))) >= RUDDER_JUMP_SHARE * span


#: Words of the rudder-timing note of a measured rudder whose servo's speed the record does not show (a sinusoid).
RUDDER_PATH = "the rudder's path between its samples is not logged"


def with_rudder_timing_note(sf: SegmentFit, win: NomotoWindow) -> SegmentFit:
    """``sf`` with a rudder-timing term for T in its message where its rudder, logged as a measured angle,
    jumps within a sample interval or follows a sinusoid (``sf`` unchanged otherwise).

    A measured rudder that jumps between two samples (a rudder held by a fast servo, logged at a low
    rate) jumped at a moment the log does not show: anywhere in that interval of ``h`` seconds. The fit
    drives the model with the angle's interval mean, the jump half-way through the interval: a jump at
    any other moment is a delay of the rudder of up to ``h / 2`` either way, and a delay of the rudder
    moves the first-order equivalent T one for one (K not at all). The term is the standard deviation of
    a moment uniform over the interval, ``h / sqrt(12)``, common to every jump of a log (a logger's
    convention does not average out over the jumps); it is added in quadrature to T's combined error by
    :func:`pipeline.fit.nomoto_quality.judge_nomoto` (``RUDDER_TIMING`` notes; the largest counts).
    Measured on the project's linear second-order ship (T = 2.7 s), measured rudder held from each
    sample on, six steps, seeds 0-5: T +18.3 to +20.3 % at 1 Hz with errors of 1.9-3.4 %, and +2.6 to
    +5.1 % at 5 Hz with 0.9-1.9 %, marked success, the interval missing the truth on all 12.

    A sinusoid gets the same term whether its samples jump or not: the interval mean assumes a straight
    line between two samples, and a servo driven by a command held over each interval (a digital
    autopilot updated at the log rate) relaxes towards it exponentially, ahead of that line. Its lead
    grows from 0 (a servo much slower than the interval) to ``h / 2`` (one much faster: the held jump
    above): 0.014 h, 0.08 h, 0.15 h and 0.30 h for ``h / tau`` = 0.2, 1, 2 and 5 (a first-order servo
    of lag ``tau``, numerically). A step or a zig-zag shows the servo's speed (a fast one jumps, which
    :func:`rudder_jumps` reads); a sinusoid's smooth rudder does not, so the lead is known only to be within
    the interval (measured: PythonVehicleSimulator's frigate, 1 s servo, measured-rudder sinusoids at 1 Hz,
    seed 0: T -0.62 +- 0.19 % marked success, the interval missing; the best linear fit to the noise-free
    record -0.43 %).

    A logged command gets no term: it is the actuator's input as applied at its sample (a digital
    autopilot's, the project's simulator's and the independent benchmark's), held from there, and a
    servo lag fitted with it takes up what delay there is (the same ship behind a 1 s servo, its command
    switching half a sample before the logged one at 5 Hz: T moved by 0.017 s, +0.6 %, the lag by -0.1 s,
    against the 0.1 s delay). The project's own simulator, whose command drives the ship from each
    sample without a servo, gave T = 4.21 +- 0.0014 s (z 0.42 on seed 1); a term there would have
    widened it 40 times.

    Parameters
    ----------
    sf : SegmentFit
        The segment's fit.
    win : NomotoWindow
        Its prepared window (the rudder as it drives the model, the sample times).
    """
    measured = any(n.startswith(MEASURED_RUDDER) for n in win.notes)
    if not (measured and sf.success and "T" in sf.params and "t_servo" not in sf.params):
        return sf
    if f"{RUDDER_DELAY_TERM} T: +-" in sf.message:
        return sf  # the rudder's delay is fitted with K and T, its error a term already
    jumps = rudder_jumps(win.rec)
    if not (jumps or sf.segment.kind == "sinusoid"):
        return sf
    t = np.asarray(win.rec.t, float)
    if t.size < 2:
        return sf
    h = float(np.median(np.diff(t)))
    term = h / math.sqrt(12.0)
    if jumps:
        why = (f"the rudder jumps within one sample interval ({h:.3g} s), so the moment of each jump is known only "
               f"to within it")
    else:
        why = (f"{RUDDER_PATH} ({h:.3g} s apart) and a sinusoid does not show its servo's speed: a servo driven "
               f"by a command held over each interval leads the straight line between its samples by 0 to h / 2")
    note = (f"{RUDDER_TIMING} +-{term:.4g} s added in quadrature to its standard error: {why}, and a "
            f"delay of the rudder moves T one for one (h / sqrt(12), a moment uniform over the interval)")
    return replace(sf, message=f"{sf.message}; {note}" if sf.message else note)


def _straight_run_speed(trial: Trial, prepared: tuple, span: tuple[float, float]) -> tuple:
    """``prepared`` (index, window, candidate or None) with a sinusoid's window from :func:`sinusoid_speed_window`."""
    index, win, cand = prepared
    new = sinusoid_speed_window(trial, win, span)
    if new is win:
        return prepared
    return index, new, (replace(cand, win=new) if cand is not None else None)


def sinusoid_speed_window(trial: Trial, win: NomotoWindow, span: tuple[float, float]) -> NomotoWindow:
    """A sinusoid's window with its speed-loss note read against the straight run before it (``win`` unchanged
    for other kinds, or when the note is the same).

    :func:`pipeline.fit.nomoto_segment.prepare_window` compares the two ends of a window, the straighter
    against the one that turns harder (a rudder step holds before it, or straight after it); a
    sinusoid turns at both ends, as a zig-zag does, and that comparison then notes a loss of 0 however much
    speed the ship lost in its turns. Here, as for a zig-zag, the straight-run speed is the median of the
    rows before the sinusoid (:func:`pipeline.fit.nomoto_segment.speed_range_note` with ``lead``, the last
    ``LEAD_SPEED_SECONDS``, taken only when the rudder lay near the sinusoid's centre and the speed was
    steady; otherwise the ends are compared as before), and the turning speed the window's slowest tenth.
    Measured: PythonVehicleSimulator's tanker at 20 m, measured-rudder sinusoids at 10 deg without waves,
    seeds 0-12: the ends noted 0 loss on 3 seeds (1, 7, 12), the straight run 0.99 % on all 13; the
    tanker at 25 m: ends 0 to 4.8 %, the straight run 5.7 % on every seed (its K, +3.9 % off with the
    measured rudder, is then unsure through the one-segment rule of
    :func:`pipeline.fit.nomoto_quality.straight_run_value` on every seed, not on some).

    Parameters
    ----------
    trial : Trial
        The trial (``sog`` or ``u``, ``delta``, ``r`` or ``psi``).
    win : NomotoWindow
        The prepared window.
    span : (float, float)
        The window's bounds [s, trial clock], as prepared.
    """
    seg = win.segment
    if seg.kind != "sinusoid":
        return win
    rows = trial.window(*span)
    lead = trial.window(seg.t_start - LEAD_SPEED_SECONDS, seg.t_start)
    note = speed_range_note(rows[rows["t"] >= seg.t_start], lead=lead[lead["t"] < seg.t_start])
    notes = tuple(n for n in win.notes if not n.startswith(SPEED_RANGE)) + ((note,) if note else ())
    if notes == win.notes:
        return win
    return replace(win, notes=notes)


def _prepare(trial: Trial, job: tuple[int, Segment, tuple[float, float]]
             ) -> tuple[int, NomotoWindow, None] | None:
    """One yaw segment's window prepared (:func:`prepare_window`); None when it cannot be (the
    per-segment fitter then reports it, or falls back to the step response)."""
    index, seg, span = job
    try:
        return index, prepare_window(trial, seg, *span), None
    except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError):
        return None


def _prepare_and_fit(trial: Trial, job: tuple[int, Segment, tuple[float, float]]
                     ) -> tuple[int, NomotoWindow, _Candidate] | None:
    """One yaw segment's window prepared and both structures fitted to it (:func:`_fit_both`), in one
    unit so that the preparation's fits are reused by the same process; None as :func:`_prepare`.
    (When all but one window fail to prepare, that one's candidate is not used: it gets its own
    structure choice, :func:`lone_segment_fit`.)"""
    prepared = _prepare(trial, job)
    return None if prepared is None else (prepared[0], prepared[1], _fit_both(prepared[0], prepared[1]))


def _fit_both(index: int, win: NomotoWindow) -> _Candidate:
    """Both structures fitted to one window; the second stops early when it cannot gain."""
    try:
        first, _ = fit_window_order(win, 1)
    except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError):
        return _Candidate(index, win, None, None, "the first order could not be fitted")
    if not _usable(first):
        return _Candidate(index, win, None, None, "the first-order fit left the plausible range")
    floor = GainFloor.from_first_order(first, win.rec)
    try:
        second, _ = fit_window_order(win, ORDER2_SUM_PRODUCT, noise=first.noise_model,
                                     start=first_order_start_values(first), gain_floor=floor)
    except SecondOrderNoGain as exc:
        return _Candidate(index, win, first, None, str(exc), no_gain=True)
    except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        return _Candidate(index, win, first, None, f"second-order fit failed: {exc}")
    if not _usable(second):
        return _Candidate(index, win, first, None, "the second order did not converge in range")
    return _Candidate(index, win, first, second, "")


def _usable(fit: NomotoFit) -> bool:
    """Converged, finite, the ship's parameters in range (a servo parameter at its bound allowed)."""
    return bool(fit.converged and all(n in SERVO_PARAMS for n in fit.at_bound) and np.all(np.isfinite(fit.values))
                and np.all(np.isfinite(fit.stderr[:_n_dyn(fit)])))


def _n_dyn(fit: NomotoFit) -> int:
    return 2 if fit.order == 1 else 4


def pooled_dynamics(fits: Sequence[NomotoFit]) -> np.ndarray:
    """Generalised-least-squares mean of the fits' dynamic parameters (K, T or K, T12, T1T2, T3).

    ``theta = (sum C_i^-1)^-1 sum C_i^-1 theta_i`` with each fit's covariance block; per-parameter
    inverse-variance weights where a block is singular, or where the generalised mean leaves the range
    of the fits' own values in any parameter: with strongly correlated parameters (K and T of a step)
    the generalised mean extrapolates along the correlation (Peelle's puzzle), and a held-out segment
    scored with such dynamics says nothing about the structure (measured: PythonVehicleSimulator's
    Clarke83 ship, commanded steps with waves, seed 0: pooled first-order T -0.06 to -0.88 s from
    segments whose T are all positive, a held-out error of NaN).

    Parameters
    ----------
    fits : sequence of NomotoFit
        Fits of one structure.
    """
    k = _n_dyn(fits[0])
    info = np.zeros((k, k))
    vec = np.zeros(k)
    vals = np.array([f.values[:k] for f in fits])
    try:
        for f in fits:
            c_inv = np.linalg.inv(f.covariance[:k, :k])
            info += c_inv
            vec += c_inv @ f.values[:k]
        out = np.linalg.solve(info, vec)
        if np.all(np.isfinite(out)) and np.all((out >= vals.min(axis=0)) & (out <= vals.max(axis=0))):
            return out
    except np.linalg.LinAlgError:
        pass
    w = np.array([1.0 / np.maximum(f.stderr[:k], 1e-300) ** 2 for f in fits])
    return (w * vals).sum(axis=0) / w.sum(axis=0)


def heldout_errors(c: _Candidate, order: int, dyn: np.ndarray) -> dict[str, np.ndarray]:
    """Errors of the dynamics ``dyn`` (pooled from the other segments) on segment ``c`` [channel units].

    The segment's own first-order fit gives the nuisances shared by both structures (its wave
    innovations filter and compass noise); the servo (lag, rate limit) is the segment's own fit of
    the structure scored (the first order's when the segment has no usable second-order fit): a
    first-order lag soaks up the second order's pole-zero pair (3-6 s against the second order's
    own 0.9-1.6 s, PythonVehicleSimulator's tanker at 20 m, commanded steps), and the comparison is
    of the two models as fitted. The rudder bias and the initial states are re-estimated on the
    segment by Gauss-Newton (the residual is linear in them), and so is the gain K (the time
    constants are what is held out).

    Parameters
    ----------
    c : _Candidate
        The held-out segment.
    order : int
        Structure of ``dyn``.
    dyn : numpy.ndarray
        K, T (or K, T12, T1T2, T3).
    """
    own = c.first
    servo = tuple(n for n in SERVO_PARAMS if n in own.names)
    var = own.noise_var.get("psi")
    waves = own.waves if own.noise_model == "waves" and var is not None and var > 0 else None
    kind = "waves" if waves is not None else "white"
    prob = Problem([prepare(c.win.rec, 0, c.win.channels)], order, "b" in own.names, c.win.channels, kind,
                   waves, var if waves is not None else None, servo)
    theta = np.zeros(len(prob.names))
    theta[: prob.n_dyn] = dyn
    servo_fit = c.second if order != 1 and c.second is not None else own
    for j, nm in enumerate(prob.names[prob.n_dyn:], start=prob.n_dyn):
        src = servo_fit if nm in SERVO_PARAMS and nm in servo_fit.names else own
        theta[j] = src.value(nm) if nm in src.names else 0.0
    for ch in prob.channels:
        v = own.innovation_var.get(ch, math.nan)
        prob.weights[ch] = 1.0 / math.sqrt(v) if math.isfinite(v) and v > 0 else 1.0
    z = prob.solver_vector(theta)
    # The gain K (index 0) is re-estimated with the nuisances: the structure is the response's
    # shape, and K shifts with the rudder amplitude on a nonlinear ship, which would otherwise
    # dominate the held-out heading error of both structures alike.
    cols = [0] + ([prob.n_dyn] if prob.bias else []) + list(prob.ic_index[0])
    for _ in range(4):
        r = prob.residual(z)
        jac = prob.fd_jacobian(z, cols)
        step, *_ = np.linalg.lstsq(jac, -r, rcond=None)
        if not np.all(np.isfinite(step)):
            break
        z[cols] += step
    per = prob.channel_residuals(z)[0]
    out = {}
    for ch in prob.channels:
        m = prob.recs[0].mask[ch]
        e = np.full(m.size, np.nan)
        e[m] = per[ch]
        out[ch] = e
    return out


def choose_structure(cands: Sequence[_Candidate]) -> StructureChoice:
    """First or second order for all segments, by leave-one-segment-out held-out error (module doc).

    Parameters
    ----------
    cands : sequence of _Candidate
        Segments with a usable first-order fit (two or more).
    """
    n = len(cands)
    with_second = [c for c in cands if c.second is not None]
    head = f"{STRUCTURE_PREFIX} the {n} Nomoto segments by leave-one-segment-out error"
    if not with_second:
        whys = sorted({c.why_no_second.split(":")[0] for c in cands})
        return StructureChoice(1, f"{head}: first-order Nomoto, the second order was no candidate on any segment "
                                  f"({', '.join(whys)})")
    rows0: dict[str, list[np.ndarray]] = {}
    rows1: dict[str, list[np.ndarray]] = {}
    for c in cands:
        others1 = [o.first for o in cands if o is not c]
        others2 = [o.second for o in with_second if o is not c]
        if not others2:
            continue
        try:
            e0 = heldout_errors(c, 1, pooled_dynamics(others1))
            e1 = heldout_errors(c, ORDER2_SUM_PRODUCT, pooled_dynamics(others2))
        except (FitError, np.linalg.LinAlgError, ValueError, FloatingPointError):
            continue
        for ch in c.win.channels:
            y = rec_channel(c.win.rec, ch)
            scale = max(float(np.std(y[np.isfinite(y)])), 1e-12)
            rows0.setdefault(ch, []).append(e0[ch] / scale)
            rows1.setdefault(ch, []).append(e1[ch] / scale)
    scored = max((len(v) for v in rows0.values()), default=0)
    if scored < 2:
        return StructureChoice(1, f"{head}: first-order Nomoto, fewer than two segments could be held out against "
                                  f"the second order")
    scores = []
    for ch in rows0:
        e0, e1 = stack_rows(rows0[ch]), stack_rows(rows1[ch])
        cs = channel_score(ch, e0, e1, ORDER2_EXTRA_PARAMS, e0.shape[0], math.nan)
        gain = np.nansum(e0**2, axis=1) - np.nansum(e1**2, axis=1)
        keep = np.arange(e0.shape[0]) != int(np.argmax(gain))
        robust = channel_score(ch, e0[keep], e1[keep], ORDER2_EXTRA_PARAMS, int(keep.sum()), math.nan)
        scores.append((cs, robust))
    m = len(scores)
    pv_of = lambda s: min(1.0, (s.p_value if math.isfinite(s.p_value) else 1.0) * m)  # noqa: E731
    cs, robust = min(scores, key=lambda s: pv_of(s[0]))
    pv, p_rob = pv_of(cs), pv_of(robust)
    shrink = 100.0 * (1.0 - cs.gap_after / cs.gap_before) if cs.gap_before > 0 else 0.0
    sig = is_significant(pv, p_rob, shrink, cs.explained)
    # Below the shrink the shared rule asks but significant, robust and fitted on most segments: chosen
    # (significant_small_gain).
    small = not sig and significant_small_gain(pv, p_rob, cs.explained, len(with_second), n)
    text = (f"held-out RMS error on channel {cs.channel} (each segment's spread = 1) first order {cs.gap_before:.4g}, "
            f"second order {cs.gap_after:.4g} ({shrink:+.1f} % shrink, p = {pv:.2g}, with the most favourable "
            f"segment left out p = {p_rob:.2g}, over {cs.n} samples of {scored} segments, shared rule p < {ALPHA:g}, "
            f"shrink >= {MIN_SHRINK:g} %)")
    if sig or small:
        why = "" if sig else (f"; below the {MIN_SHRINK:g} % shrink but significant with the most favourable segment "
                              f"left out (p < {ALPHA_ROBUST:g}) and fitted on {len(with_second)} of {n} segments")
        return StructureChoice(ORDER2_SUM_PRODUCT, f"{head}: second-order Nomoto (T1, T2, T3) selected, the first "
                                                   f"order loses, {text}{why}", shrink=shrink, p_value=pv)
    return StructureChoice(1, f"{head}: first-order Nomoto selected, the second order loses (not significant), "
                              f"{text}", near_tie=shrink > -MIN_SHRINK, shrink=shrink, p_value=pv)


def significant_small_gain(p_value: float, p_robust: float, explained: float, n_second: int, n: int) -> bool:
    """Whether a second order below the shared rule's shrink is still chosen across the segments.

    The shared rule (:func:`pipeline.fit.heldout_test.is_significant`) also asks the held-out error
    to shrink by ``MIN_SHRINK``. Here the held-out errors are the segments' one-step prediction errors
    (whitened by each segment's wave noise filter): wave-induced yaw and sensor noise dominate them, so
    a pole-zero pair the data show beyond doubt shrinks them by a few percent only (measured:
    PythonVehicleSimulator's Clarke83 ship, six rudder steps with waves, p = 1e-37 and 1e-26 with the
    most favourable segment left out, shrink 1.8-2.1 %; commanded steps without waves, shrink 7.9-9.8 %
    at p = 1e-54 and 1e-81). The first order kept there gave T +44 % (unsure) or K +2.8 %, the second
    order K +0.3-0.5 %. So the second order is chosen when it passes the rest of the rule (``p_value <
    ALPHA``, ``p_robust < ALPHA_ROBUST``, ``explained >= MIN_EXPLAINED``) and was fitted in range on at
    least half the segments (a first-order ship's second order stops early or collapses on most of
    them, :class:`pipeline.fit.nomoto_oe.GainFloor`). Measured on the tanker at 20 m (measured steps,
    waves): p = 5e-6, but 0.008 with the most favourable segment left out: still a near-tie.

    Parameters
    ----------
    p_value, p_robust : float
        Bonferroni-corrected held-out p-value, and the same with the most favourable segment left out.
    explained : float
        Scale-normalised RMS error explained [-].
    n_second, n : int
        Segments with a usable second-order fit, and all segments.
    """
    return bool(p_value < ALPHA and p_robust < ALPHA_ROBUST and explained >= MIN_EXPLAINED and 2 * n_second >= n)


def disagreement_note(fits: Sequence[SegmentFit], amplitudes: Sequence[float]) -> str:
    """What a spread of K or T beyond the segments' errors points to ('' when they agree).

    For K and T (first-order equivalent) in turn: the chi-square consistency test of
    :func:`pipeline.fit.combine.combine`; when it fails, a weighted straight line against the
    rudder amplitude (|t| of the slope, its error inflated by the Birge ratio of the line's own
    misfit) and a weighted difference between manoeuvre kinds are tried. A trend with the amplitude
    points to a nonlinearity (the cubic yaw-rate term of Norrbin's model, or a speed change in
    turns): K and T then hold for one amplitude only. A difference between kinds with no trend
    points to the model structure (steps, zig-zags and sinusoids weight different frequencies).

    Parameters
    ----------
    fits : sequence of SegmentFit
        Successful Nomoto segment fits.
    amplitudes : sequence of float
        Largest |rudder| of each segment's record [rad].
    """
    out = []
    for name in ("K", "T"):
        x = np.array([f.params.get(name, math.nan) for f in fits])
        se = np.array([f.stderr.get(name, math.nan) for f in fits])
        a = np.asarray(amplitudes, float)
        ok = np.isfinite(x) & np.isfinite(se) & (se > 0) & np.isfinite(a)
        if ok.sum() < 2:
            continue
        x, se, a = x[ok], se[ok], a[ok]
        kinds = [f.segment.kind for f, k in zip(fits, ok) if k]
        w = 1.0 / se**2
        mean = float(w @ x / w.sum())
        chi2 = float(w @ (x - mean) ** 2)
        p = float(stats.chi2.sf(chi2, x.size - 1))
        if not p < CONSISTENCY_ALPHA:
            continue
        spread = f"{name} from {x.min():.4g} to {x.max():.4g} (chi2 = {chi2:.3g} on {x.size - 1} dof, p = {p:.2g})"
        why = ""
        t_amp = weighted_slope_t(a, x, w)
        if math.isfinite(t_amp) and abs(t_amp) >= TREND_T:
            why = (f"{name} changes with the rudder amplitude ({math.degrees(a.min()):.3g} to "
                   f"{math.degrees(a.max()):.3g} deg, slope t = {t_amp:.2g}): a nonlinearity (Norrbin's cubic "
                   f"yaw-rate term, or a speed change in turns), so the linear K and T hold for one amplitude; the "
                   f"Norrbin fit is the model to read")
        elif len(set(kinds)) > 1:
            t_kind = _kind_t(kinds, x, w)
            if math.isfinite(t_kind) and abs(t_kind) >= TREND_T:
                why = (f"{name} differs between manoeuvre kinds ({', '.join(sorted(set(kinds)))}; t = {t_kind:.2g}) "
                       f"with no trend in amplitude: the model structure (the manoeuvres weight different "
                       f"frequencies)")
        if not why:
            why = ("neither a trend with the rudder amplitude nor a difference between manoeuvre kinds explains it "
                   "(an unmodelled disturbance, or a structure error common to all)")
        out.append(f"{spread}: {why}")
    if not out:
        return ""
    return f"{DISAGREEMENT_PREFIX}: " + ", and ".join(out)


def _kind_t(kinds: Sequence[str], x: np.ndarray, w: np.ndarray) -> float:
    """t of the difference between the first manoeuvre kind's weighted mean and the others'."""
    first = np.array([k == kinds[0] for k in kinds])
    parts = []
    for m in (first, ~first):
        ww = w[m]
        mu = float(ww @ x[m] / ww.sum())
        birge2 = max(1.0, float(ww @ (x[m] - mu) ** 2) / (m.sum() - 1)) if m.sum() > 1 else 1.0
        parts.append((mu, birge2 / ww.sum()))
    (m1, v1), (m2, v2) = parts
    return float((m1 - m2) / math.sqrt(v1 + v2)) if v1 + v2 > 0 else math.nan


def structure_note(fits: Sequence[SegmentFit]) -> str:
    """The note on K and T about the model structure: the trial-level choice and any disagreement
    (from the segment fits' messages), else the per-segment structures' note
    (:func:`pipeline.fit.nomoto_segment.structure_note`).

    Parameters
    ----------
    fits : sequence of SegmentFit
        Successful Nomoto segment fits.
    """
    notes = structure_note_from_messages(fits)
    return "; ".join(notes) if notes else per_segment_structure_note(fits)


def structure_note_from_messages(fits: Sequence[SegmentFit]) -> list[str]:
    """The trial-level structure and disagreement notes carried in segment-fit messages (deduplicated).

    Parameters
    ----------
    fits : sequence of SegmentFit
        Nomoto segment fits.
    """
    out: list[str] = []
    for f in fits:
        for part in f.message.split("; "):
            if part.startswith((STRUCTURE_PREFIX, DISAGREEMENT_PREFIX, STRUCTURE_UNDECIDED, STRUCTURE_TERM_PREFIX)):
                base = part.split(", on this segment the second order was not fitted")[0]
                if base not in out:
                    out.append(base)
    return out
