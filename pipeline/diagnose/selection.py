"""Forward selection of several effects, sensor-or-actuator naming, and what stays unexplained.

Ranking (:data:`pipeline.records.RANKING_RULE`): candidates are ranked by their held-out shrink of
the RMS gap over the channels of the DOF they act on; only significant ones can be selected.

Forward selection: the best significant candidate is the verdict. Its correction (its
cross-validated prediction minus the baseline fitted on every window, so the candidate's side
stays held out and the baseline's side is one parameter set, :func:`corrected`) is taken off the
measurements of its DOF, and every other candidate of that DOF is
cross-validated and significance-tested again on top of it; the candidates of other DOFs are
scored on separate problems and keep their scores. The next best significant candidate is
selected, and so on, until none is significant (at most :data:`MAX_EFFECTS`). Working on the
corrected measurements (backfitting; Hastie and Tibshirani 1990) lets any two effects of the
library be stacked without writing every pair as one model. An effect that is a set of linear
regressors (a constant moment or current, a thrust's astern part, an actuator's share, another DOF's
velocity, a sensor bias: :meth:`pipeline.diagnose.candidates.Candidate.carried`) or an input transform
(a delay, a rate limit, at its value fitted on every window) or waves (refitted on top of every
model's training residuals) is not taken off but joins the baseline instead, so the next step fits every candidate jointly with it on the same measurements
(:func:`taken_off`): the first effect, fitted alone, has absorbed part of the second, and backfitting
its correction leaves the second distorted (randomised seeds 41 r015 and 37 r018). One pair does not stack that way: a
delay behind a rate limit of the same input (the rudder slews, then acts late) does not add to it, so
once a rate limit is selected a delay applied to its output is also scored on the original
measurements against the rate limit alone (:func:`pipeline.diagnose.candidates.composed_candidates`;
its correction is taken from the rate limit's fit, ``DofState.result_base``). Two strong effects
can hide each other: each alone leaves the other's slow error in its residual, which leaves the F
test few effective samples. Where no candidate is significant and a DOF's gap fails the "only what a correct model
leaves" test, :func:`pair_step` takes each of the best two candidates off in turn and selects a
pair only when each is significant on top of the other.

Sensor or actuator: an input delay and an output (sensor) delay look the same in one channel of a
linear model. When another DOF, driven by inputs that change at the same instants and measured by a
different sensor group, shows no such delay, the delay is in the first channel's sensor group, not
in the actuators: :func:`sensor_or_actuator` renames it ``sensor_delay``. Each witness DOF's delay
estimates (first round, on top of its other effect, its own selected delay) are read as "none", "the
delay" or "cannot tell", the most precise that tells decides, and a delay that no estimate tells about is
reported unsure (:func:`witness_reading`).

Unexplained (:func:`unexplained`): a channel whose held-out gap ``g`` (noise units) after the
selected effects fails the test "only what a correct model leaves is left",
``n_eff (g / f)^2 ~ chi^2(n_eff)``, at ``ALPHA_UNEXPLAINED``, exceeds ``UNEXPLAINED_GAP f`` (a model
error of at least ``sqrt(UNEXPLAINED_GAP^2 - 1) f`` noise units RMS), and whose model error
``sqrt(g^2 - f^2)`` is at least ``MIN_UNEXPLAINED_SCALE`` of the channel's scale, is reported with
where its gap lives, the frequency band holding its power and its correlation with speed, inputs and
heading. ``f`` is the channel's held-out floor (:mod:`pipeline.diagnose.floor`): the gap a correct
model leaves once its parameters carry the noise of their training windows (1 for a rate; several
noise units for the heading of a slow ship, which integrates a gain error over a whole window).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Callable, Mapping

import numpy as np
import scipy.stats

from ..records import CandidateResult, EffectParam, Place, SelectedEffect, Trial, Unexplained
from . import significance as sig
from .gridfit import GridData
from .problem import DofProblem, block_average
from .replay import band_split, default_band, pooled_psd

#: Most effects selected one after the other.
MAX_EFFECTS = 4
#: Significance level of the "only noise is left" test of a channel's final gap.
ALPHA_UNEXPLAINED = 1e-4
#: Smallest final gap [noise units] called unexplained: below it the model error is under one
#: noise unit RMS, which the noise estimate itself cannot tell apart from 1 reliably.
UNEXPLAINED_GAP = 1.5
#: Smallest model error called unexplained, relative to the channel's scale (its standard deviation
#: over the DOF's own manoeuvres) [-]: ``sqrt(g^2 - 1)`` noise units must be at least this share of
#: the signal, so that a first-order baseline's slight misfit of a large, clean heading record
#: (statistically visible at low noise) is not called a gap.
MIN_UNEXPLAINED_SCALE = 0.01
#: Candidates tried as the first of a pair that hide each other (:func:`pair_step`).
PAIR_TRIES = 2
#: Sensor groups by channel: a delay in one group that another group does not show is the sensor's.
SENSOR_GROUPS: Mapping[str, str] = {
    "sog": "gnss", "cog": "gnss", "x_n": "gnss", "y_e": "gnss", "lat": "gnss", "lon": "gnss",
    "u": "velocity", "v": "velocity", "w": "velocity",
    "p": "imu", "q": "imu", "r": "imu", "phi": "imu", "theta": "imu", "ax": "imu", "ay": "imu", "az": "imu",
    "psi": "compass",
}
#: Share of one DOF's input changes that must coincide with the other's for "the same input".
SAME_INPUT_SHARE = 0.8
#: The other DOF "shows no delay" when its delay plus two standard errors stays under this
#: fraction of the first DOF's delay.
NO_DELAY_FRACTION = 0.5


def rank_key(c: CandidateResult) -> float:
    """Sort key of the ranking rule: larger held-out shrink first.

    Parameters
    ----------
    c : CandidateResult
        A scored candidate.
    """
    return -c.shrink if math.isfinite(c.shrink) else math.inf


def channel_shrink(c: CandidateResult) -> float:
    """The largest held-out shrink of one of a candidate's channels [%] (the per-channel
    significance rule's shrink, :func:`pipeline.diagnose.significance.channel_significant`).

    Parameters
    ----------
    c : CandidateResult
        A scored candidate.
    """
    out = [100.0 * (1.0 - g.gap_after / g.gap_before) for g in c.channels
           if math.isfinite(g.gap_before) and g.gap_before > 0 and math.isfinite(g.gap_after)]
    return max(out) if out else (c.shrink if math.isfinite(c.shrink) else -math.inf)


@dataclass
class DofState:
    """Where the forward selection stands in one DOF (mutable working state, never returned).

    Attributes
    ----------
    problem : DofProblem
        The DOF problem.
    data : GridData
        Measurements with the selected effects' corrections taken off.
    results : list
        ``(CandidateResult, CandidateRun)`` of the candidates on top of the current selection.
    base_heldout : Mapping[str, numpy.ndarray]
        Held-out outputs of the current baseline.
    channel_gaps : dict[str, float]
        Current held-out gap per channel [noise units].
    channel_neff : dict[str, float]
        Effective number of independent samples per channel.
    selected : list[str]
        Labels selected in this DOF.
    base_full : Mapping[str, numpy.ndarray] or None
        Outputs of the current baseline fitted on every window (one parameter set); the reference
        the next correction is taken from (None: ``base_heldout`` stands in).
    channel_floor : dict[str, float]
        Held-out gap per channel that a correct model leaves (:mod:`pipeline.diagnose.floor`);
        missing channels: 1.
    result_base : dict[str, Mapping[str, numpy.ndarray]]
        Per result label, the reference its correction is taken from when it is not ``base_full``
        (a composed input transform is scored against the first transform alone, on the original
        measurements).
    first_results : list
        ``results`` of the first round (on the original measurements); default: ``results`` as given.
    reference : Mapping[str, numpy.ndarray] or None
        Once an effect is selected: outputs whose difference from ``data`` is the held-out residual the
        selection so far leaves (the reference its last correction was taken from), against which a
        candidate on top must also be significant (:func:`beats_previous`); None before.
    """

    problem: DofProblem
    data: GridData
    results: list
    base_heldout: Mapping[str, np.ndarray]
    channel_gaps: dict
    channel_neff: dict
    selected: list
    base_full: Mapping[str, np.ndarray] | None = None
    channel_floor: dict = field(default_factory=dict)
    result_base: dict = field(default_factory=dict)
    first_results: list = field(default_factory=list)
    reference: Mapping[str, np.ndarray] | None = None

    def __post_init__(self) -> None:
        # The first round's scores stay the witnesses of the sensor-or-actuator naming: once an
        # effect is selected, ``results`` hold the candidates on top of it, whose delay is the
        # delay left over (none, when this DOF's own delay was selected).
        if not self.first_results:
            self.first_results = list(self.results)


def heldout_or_full(run, n_windows: int) -> Mapping[str, np.ndarray]:
    """A candidate's held-out outputs, and where a window has none (no training set of its fold saw
    its inputs, :func:`pipeline.diagnose.crossval.supported`) the outputs of the candidate fitted on
    every window.

    Without them such a window kept its measurements uncorrected while the others were corrected:
    both astern windows of AAUSHIP's reverse step in one fold kept the selected current's offset,
    and the next round's thrust asymmetry "explained" that offset (randomised seed 20, r006: a
    ``thrust_asymmetry[tau_x]`` at 58.6 % on top of the true current).

    Parameters
    ----------
    run : pipeline.diagnose.crossval.CandidateRun
        The selected candidate's run.
    n_windows : int
        Windows of its DOF problem.
    """
    held = run.heldout
    if all(np.isfinite(v).any(axis=1).all() for v in held.values()):
        return held
    try:
        full = run.candidate.simulate(run.full, np.arange(n_windows))
    except (ValueError, ArithmeticError, np.linalg.LinAlgError):
        return held
    out = dict(held)
    for k, v in held.items():
        if k in full:
            # Whole windows only: a window the held-out prediction covers keeps it.
            none = ~np.isfinite(v).any(axis=1)
            out[k] = np.where(none[:, None], full[k], v)
    return out


def corrected(data: GridData, base: Mapping[str, np.ndarray], cand: Mapping[str, np.ndarray]) -> GridData:
    """The measurements minus a candidate's correction ``cand - base``: the candidate's held-out
    residual on top of the baseline's outputs, ``base + (y - cand)``.

    ``base`` should be the baseline fitted on every window (one parameter set), not its held-out
    outputs: those come from a different fold fit in every window, and where a gain is pinned by a
    few windows (a slow ship's two rudder steps, one ahead, one astern) the folds' gains differ by
    more than the effect; the corrected data would then carry that fold-to-fold spread as a gap of
    its own, which the next baseline cannot fit (a rudder bias selected first left a heading gap of
    10.9 noise units, instead of its own 1.9). The candidate's side stays held out, so nothing of a
    window's remaining effect is fitted away before the next step scores it.

    The measured start value of each window (the prior of its initial state, ``GridData.y0``)
    is corrected too: left as measured, it pulls the next baseline's initial states back toward
    the uncorrected data, and a correction that moves a window's level (a rudder bias, a current)
    would come back as a gap.

    Parameters
    ----------
    data : GridData
        Current measurements.
    base, cand : Mapping[str, numpy.ndarray]
        Held-out outputs of the baseline and of the selected candidate.
    """
    dy = np.where(np.isfinite(cand["y"]), np.nan_to_num(cand["y"] - base["y"]), 0.0)
    out = {"y": data.y - dy, "y0": data.y0 - start_value(dy, data.mask)}
    if data.angle is not None and "angle" in cand and "angle" in base:
        out["angle"] = data.angle - np.nan_to_num(cand["angle"] - base["angle"])
    new = replace(data, **out)
    return new


def taken_off(s: DofState, res: CandidateResult, run, ref: Mapping[str, np.ndarray] | None = None
              ) -> tuple[GridData, Mapping[str, np.ndarray] | None]:
    """A DOF's data once a selected effect is in the model, and the reference of its residual.

    An effect that is a set of linear regressors (:meth:`pipeline.diagnose.candidates.Candidate.carried`:
    a constant moment, a current, a thrust's astern part, an actuator's share, another DOF's velocity,
    a sensor bias) or an input transform (a delay or rate limit, at its value fitted on every window:
    every model then takes its inputs through it) joins the baseline: the next step fits every
    candidate with it, jointly, on the same measurements (:func:`pipeline.diagnose.gridfit.carry`,
    :func:`pipeline.diagnose.candidates.carry_transform`), and the baseline of that step is the effect
    itself, cross-validated; no reference is needed (None). Selected waves join too: every model of the
    next step refits them on its own training residuals (:class:`pipeline.diagnose.candidates.WavesOnTop`).
    Any other effect's correction (a quadratic damping, a delay composed behind a rate limit) is taken
    off the measurements (:func:`corrected`, backfitting), and the reference it was taken from is returned.

    Backfitting a correction fitted without the second effect leaves that effect distorted: the
    first effect, fitted alone, has absorbed part of it, and the baseline refitted on the corrected
    data predicts held-out windows worse than the first effect did. Randomised seed 41 r015 (a
    Nomoto ship, a rudder bias and a quadratic yaw damping): on the corrected data the damping took r
    from 4.28 to 3.26 and psi from 7.04 to 5.03 noise units (p = 2e-4, not significant) and both were
    reported unexplained; fitted jointly with the bias it takes the bias's residual from r 3.52 and
    psi 5.68 to 1.44 and 1.51 (floors 1.38 and 1.46), p = 6e-32. Seed 37 r018 (AAUSHIP, a delay of
    every input and an N_v coupling in yaw): on the corrected data the coupling gave 15.7 %, p = 1.9e-4;
    with the inputs late by the delay's 0.43 s, 23.8 %, p = 3e-6.

    Parameters
    ----------
    s : DofState
        The DOF's state.
    res : CandidateResult
        The selected candidate.
    run : pipeline.diagnose.crossval.CandidateRun
        Its run.
    ref : Mapping[str, numpy.ndarray], optional
        Outputs the correction is taken from; default the candidate's own (``result_base``), else
        ``base_full``, else ``base_heldout``.
    """
    carried = None if res.label in s.result_base else carried_regressors(run)
    if carried is not None:
        return carried.apply(s.data), None
    if ref is None:
        ref = s.result_base.get(res.label, s.base_full if s.base_full is not None else s.base_heldout)
    return corrected(s.data, ref, heldout_or_full(run, s.data.y.shape[0])), ref


def carried_regressors(run):
    """The selected candidate's regressors to carry (None: backfitting; roll and pitch candidates have none).

    Parameters
    ----------
    run : CandidateRun
        The selected candidate's cross-validated run; its ``candidate.carried`` (when it has one) is
        applied to the fit on every window, ``run.full``.
    """
    how = getattr(getattr(run, "candidate", None), "carried", None)
    return how(run.full) if how is not None else None


def start_value(x: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Each row's value at its window start, extrapolated from its first two block means (W,).

    A block mean refers to the middle of its block, so the start is ``1.5 b_0 - 0.5 b_1`` for a
    signal that is straight over the first two blocks; ``b_0`` alone for a one-block row.

    Parameters
    ----------
    x : numpy.ndarray, shape (W, n)
        Block means (zero or NaN off-window).
    mask : numpy.ndarray, shape (W, n)
        Samples inside each window.
    """
    b0 = np.where(mask[:, 0], x[:, 0], 0.0)
    if x.shape[1] < 2:
        return b0
    return np.where(mask[:, 1], 1.5 * b0 - 0.5 * np.where(mask[:, 1], x[:, 1], 0.0), b0)


def trial_gap(states: Mapping[str, DofState]) -> float:
    """RMS over every channel of every DOF of the current held-out gaps [noise units].

    Parameters
    ----------
    states : Mapping[str, DofState]
        Per-DOF state.
    """
    g = np.array([v for s in states.values() for v in s.channel_gaps.values()], float)
    g = g[np.isfinite(g)]
    return float(np.sqrt(np.mean(g**2))) if len(g) else math.nan


def forward_select(states: dict[str, DofState], rescore: Callable[[DofState], None],
                   max_effects: int = MAX_EFFECTS) -> list[tuple[CandidateResult, object]]:
    """Select effects one after the other (see module docstring).

    Parameters
    ----------
    states : dict[str, DofState]
        Per-DOF state after the first round; updated in place as effects are selected.
    rescore : callable
        ``rescore(state)`` re-runs the cross-validation of a DOF on its corrected data and
        replaces ``state.results``, ``state.base_heldout``, ``channel_gaps`` and ``channel_neff``.
    max_effects : int
        Most effects.

    Returns
    -------
    list of (CandidateResult, SelectedEffect-without-name-decision)
        The selected candidates in order, each with the trial gap after it.
    """
    chosen: list[tuple[CandidateResult, object, float]] = []
    first_on_top_tried = False
    while len(chosen) < max_effects:
        pool = [(res, run, s) for s in states.values() for res, run in s.results
                if res.significant and res.label not in s.selected]
        if not pool and not chosen and not first_on_top_tried:
            # No candidate passes the calibrated rule: judge the first effect by the on-top shrink
            # too, where the gap is above its floor. Randomised seed 40 r014 (a twin's quadratic yaw
            # damping, 4.5 Hz, high noise): p = 1e-37 but a shrink of 5.3 / 7.7 % of the gaps, under
            # 10 %; found this way. Null on clean unchanged: 83/83 (seeds 43, 36, 28 clean sets; the
            # clean trials of seeds 40, 45, 26), right first 25/25 on seeds 40, 45, 26.
            first_on_top_tried = True
            for st in states.values():
                on_top_scores(st)
            continue
        if not pool:
            if len(chosen) + 2 <= max_effects and pair_step(states, rescore, chosen):
                continue
            break
        res, run, s = min(pool, key=lambda x: rank_key(x[0]))
        res, run, why = prefer_shared_delay(res, run, s, chosen)
        for cg in res.channels:
            s.channel_gaps[cg.channel] = cg.gap_after
        chosen.append((res, run, trial_gap(states), *([why] if why else [])))
        s.selected.append(res.label)
        if len(chosen) >= max_effects:
            break
        if len(chosen) == 1:
            for other in states.values():
                if other is not s:
                    on_top_scores(other)
        s.data, s.reference = taken_off(s, res, run)
        rescore(s)
        on_top_scores(s)
        beats_previous(s)
    return chosen


def _names(s: DofState) -> dict:
    return {"y": s.problem.channel, "angle": getattr(s.problem, "angle", None)}


def on_top_scores(s: DofState) -> None:
    """Once an effect is selected in the trial, the candidates of a DOF are judged by the rule's
    ``on_top`` shrink (:func:`pipeline.diagnose.significance.channel_significant`): the larger of the
    gap's shrink and the shrink of the model error above the sensor noise. The first effect is
    chosen by the calibrated rule; the ones after it act on gaps it left near one noise unit.
    A candidate scored against another reference (``result_base``) and roll or pitch (one candidate,
    scored by :mod:`pipeline.diagnose.oscillatory`) keep their scores.

    Parameters
    ----------
    s : DofState
        A DOF's state; ``s.results`` is updated in place.
    """
    if s.problem is None or not s.results:
        return
    out = []
    for res, run in s.results:
        if res.label not in s.result_base and not res.significant:
            try:
                sc = sig.score(s.data, s.base_heldout, run.heldout, run.candidate.n_extra, _names(s),
                               folds=run.fold_of, on_top=True, floors=s.channel_floor)
            except (AttributeError, KeyError, ValueError):
                sc = None
            if sc is not None and sc.significant:
                res = replace(res, significant=True)
        out.append((res, run))
    s.results = out


def beats_previous(s: DofState) -> None:
    """Keep a candidate on top of the selection significant only when, with it, the DOF's held-out
    gap is no larger than the gap the selection so far leaves (``s.reference`` on the corrected data):
    the pair must not predict worse than the first effect alone.

    The candidate is tested against the baseline refitted on the corrected data, which is meant to
    leave what the selected effect left. Where the refit misses by more than the effect did, a
    candidate on top can be significant by repairing the refit alone, and was selected although the
    pair predicted worse than the first effect (randomised seed 33 r010: a current in sway took v's
    gap from 63.5 to 1.04 noise units; the baseline refitted on the corrected data left 4.99, and a
    quadratic sway damping took that to 3.21, p = 2e-22, selected outside the truth). Asking it to be
    significant against the first effect's residual instead lost a true pair whose refit costs both
    alike (seed 33 r016: a delay left r 2.68 and psi 11.4; the refit 3.33 and 14.6; the true yaw
    damping on top 2.80 and 11.0, DOF gap 3 % under the delay's, p = 0.13 against it), so only the
    DOF gap's growth is refused, as in the significance rule. A candidate scored against another
    reference (a delay composed behind a rate limit, ``result_base``) keeps its score. Where the
    selection's residual is smaller than the refitted baseline's, its gaps (and residual) stand for
    the DOF's current gap, so the refit's miss is not reported as unexplained either (seed 33 r010:
    v at 4.99 noise units, against 1.04 left by the current).

    Parameters
    ----------
    s : DofState
        The DOF's state just rescored on its corrected data; ``s.results``, and where the selection
        leaves less, ``channel_gaps``, ``channel_neff`` and ``base_heldout`` are updated in place.
    """
    if s.reference is None or s.problem is None:
        return
    names = _names(s)
    try:
        own = sig.score(s.data, s.reference, s.reference, 1, names)
    except (KeyError, ValueError):
        return
    gaps, neff = channel_gaps_of(own)
    base = sig.score(s.data, s.base_heldout, s.base_heldout, 1, names)
    if own.gap_before < base.gap_before:
        s.base_heldout = s.reference
    for ch, g in gaps.items():
        if math.isfinite(g) and g < s.channel_gaps.get(ch, math.inf):
            s.channel_gaps[ch], s.channel_neff[ch] = g, neff.get(ch, s.channel_neff.get(ch, math.nan))
    out = []
    for res, run in s.results:
        if res.significant and res.label not in s.result_base and getattr(run, "heldout", None) is not None:
            try:
                sc = sig.score(s.data, s.reference, run.heldout, run.candidate.n_extra, names)
            except (KeyError, ValueError):
                sc = None
            if sc is not None and sc.shrink < 0:
                res = replace(res, significant=False)
        out.append((res, run))
    s.results = out


def _every_input_delay(res: CandidateResult) -> bool:
    return res.effect == "actuator_delay" and res.input_channel is None and " after " not in res.label


def prefer_shared_delay(res: CandidateResult, run, s: DofState, chosen: list) -> tuple[CandidateResult, object, str]:
    """A rate limit that ranks first in a DOF by less than ``MIN_SHRINK`` points over the delay of
    every input, once that delay is selected in another DOF: the delay is taken instead.

    A delay and a rate limit both make a step's response late; on a first-order baseline that is not
    quite the vessel's dynamics the two explain about the same share of one DOF (randomised seed 18,
    r010: sway rate limit 56.6 %, sway delay 54.9 %, a true delay of every input). The delay selected
    in another DOF already states that every input, this DOF's too, acts late; the rate limit is
    then tested on top of it (and reported unsure, :func:`confused_with`).

    Parameters
    ----------
    res : CandidateResult
        The best significant candidate of the step.
    run : CandidateRun
        Its run.
    s : DofState
        Its DOF's state.
    chosen : list
        The selection so far.

    Returns
    -------
    (CandidateResult, run, why)
        The candidate to select, its run, and the reason when it was swapped ("" otherwise).
    """
    if res.effect != "actuator_rate_limit" or not any(_every_input_delay(c[0]) and c[0].dof != res.dof
                                                      for c in chosen):
        return res, run, ""
    alt = next(((r, u) for r, u in s.results if _every_input_delay(r) and r.significant
                and r.label not in s.selected), None)
    if alt is None or not alt[0].shrink >= res.shrink - sig.MIN_SHRINK:
        return res, run, ""
    where = next(c[0].dof for c in chosen if _every_input_delay(c[0]) and c[0].dof != res.dof)
    return alt[0], alt[1], (f"taken before {res.label} ({res.shrink:.1f} % against {alt[0].shrink:.1f} %, less than "
                            f"{sig.MIN_SHRINK:g} points apart): the delay of every input is selected in {where}")


def confused_with(res: CandidateResult, earlier: list[CandidateResult]) -> str:
    """Why a delay and a rate limit of the same input selected in one DOF are unsure ("" if not).

    Each alone explains a late response; selected one on top of the other by backfitting, the
    second also takes up what a first-order baseline misses of the vessel's dynamics once the first
    has made the response late (randomised seed 20, r005: a true delay of every input, then a
    ``actuator_rate_limit[tau_x]`` at 35.5 % on top of the surge delay). The held-out data cannot tell
    that from a true second effect, so the second is reported as unsure. A delay composed behind a
    rate limit (``actuator_delay after ...``, fitted jointly and tested against the rate limit alone)
    is not concerned.

    Parameters
    ----------
    res : CandidateResult
        A selected candidate.
    earlier : list[CandidateResult]
        The candidates selected before it.
    """
    kinds = {"actuator_delay", "actuator_rate_limit"}
    if res.effect not in kinds or " after " in res.label:
        return ""
    for e in earlier:
        if e.dof != res.dof or e.effect not in kinds - {res.effect} or " after " in e.label:
            continue
        delay, limit = (e, res) if e.effect == "actuator_delay" else (res, e)
        if delay.input_channel is None or delay.input_channel == limit.input_channel:
            return (f"unsure: {res.label} on top of {e.label} in {res.dof}: a delay and a rate limit of the same "
                    f"input each make the response late, and the second also takes up what the first-order "
                    f"baseline misses once the first is in; the held-out data do not tell the two apart")
    return ""


def close_rival(res: CandidateResult, first_round: list) -> str:
    """Why the first effect selected in a DOF, a delay or a rate limit, is unsure ("" if not): the
    other of the two, of the same input, explains nearly as much of the same DOF.

    Within ``MIN_SHRINK`` points of each other (and the rival explaining at least ``MIN_SHRINK``
    itself), the two are not told apart by the held-out data (randomised seed 22, r016: a Nomoto
    ship's rudder delay, rate limit 15.3 % against delay 12.2 %).

    Parameters
    ----------
    res : CandidateResult
        The selected candidate.
    first_round : list
        ``(CandidateResult, run)`` of its DOF's first round (``DofState.first_results``).
    """
    kinds = {"actuator_delay", "actuator_rate_limit"}
    if res.effect not in kinds or " after " in res.label:
        return ""
    for r, _ in first_round:
        if r.effect not in kinds - {res.effect} or " after " in r.label:
            continue
        delay, limit = (r, res) if r.effect == "actuator_delay" else (res, r)
        if not (delay.input_channel is None or delay.input_channel == limit.input_channel):
            continue
        if math.isfinite(r.shrink) and r.shrink >= sig.MIN_SHRINK and r.shrink >= res.shrink - sig.MIN_SHRINK:
            return (f"unsure: {r.label} explains nearly as much of {res.dof} ({r.shrink:.1f} % against "
                    f"{res.shrink:.1f} %); a delay and a rate limit of the same input both make the response "
                    f"late, and the held-out data do not tell them apart here")
    return ""


def excess_gap(s: DofState) -> bool:
    """True when a channel of the DOF fails the "only what a correct model leaves is left" test
    (the test of :func:`unexplained`, without describing the residual).

    Parameters
    ----------
    s : DofState
        The DOF's current state.
    """
    units = sig.noise_units(s.data)
    names = _names(s)
    return any(gap_above_floor(s, key, ch, units) is not None for key, ch in names.items())


def gap_above_floor(s: DofState, key: str, ch: str | None, units: Mapping[str, float]
                    ) -> tuple[float, float, float] | None:
    """The test of :data:`UNEXPLAINED_TEST` on one channel of a DOF.

    Parameters
    ----------
    s : DofState
        The DOF's current state.
    key : str
        Output key of the channel (``y`` or ``angle``).
    ch : str or None
        Channel name (None: the DOF has no such output).
    units : Mapping[str, float]
        Noise unit of each output key (:func:`pipeline.diagnose.significance.noise_units`).

    Returns
    -------
    tuple of float or None
        ``(gap g, floor f, p-value)`` [noise units, noise units, -] when the channel's gap stays
        well above its floor; None when it does not or cannot be tested.
    """
    if ch is None or ch not in s.channel_gaps:
        return None
    g = s.channel_gaps[ch]
    n_eff = s.channel_neff.get(ch, math.nan)
    if not (math.isfinite(g) and math.isfinite(n_eff) and n_eff > 1):
        return None
    f = max(float(s.channel_floor.get(ch, 1.0)), 1.0)
    pv = float(scipy.stats.chi2.sf(n_eff * (g / f) ** 2, n_eff))
    rel = math.sqrt(max(g * g - f * f, 0.0)) * units.get(key, math.nan)
    if pv < ALPHA_UNEXPLAINED and g >= UNEXPLAINED_GAP * f and not rel < MIN_UNEXPLAINED_SCALE:
        return g, f, pv
    return None


def _tentative(s: DofState, res: CandidateResult, run, ref, rescore: Callable[[DofState], None]) -> DofState:
    """A copy of ``s`` with a candidate in the model (:func:`taken_off`, its correction taken from
    ``ref``) and cross-validated again (``s`` unchanged)."""
    t = replace(s, data=taken_off(s, res, run, ref)[0], results=list(s.results), channel_gaps=dict(s.channel_gaps),
                channel_neff=dict(s.channel_neff), selected=list(s.selected))
    rescore(t)
    return t


def pair_step(states: dict[str, DofState], rescore: Callable[[DofState], None], chosen: list) -> bool:
    """Two effects that hide each other: a joint step when no candidate is significant alone.

    Each of two strong effects, tested alone, leaves the other's slow error in its residual; the
    F test's effective sample size then falls to about the number of windows and neither is
    significant, though each removes a large share of the gap. In a DOF whose gap fails the
    "only what a correct model leaves" test (:func:`excess_gap`; on a clean trial the gap sits at
    its floor and nothing is tried), the :data:`PAIR_TRIES` candidates with the largest shrink
    (at least ``MIN_SHRINK`` in one channel, the DOF's gap not growing) are each taken off in turn (backfitting, as a selection step does);
    the best candidate significant on top of it (``B``) is taken off the original data instead,
    and the first (``A``) is tested again on top of ``B``. Both are selected, ``A`` first (it ranks
    higher alone), only when each is significant on top of the other.

    Parameters
    ----------
    states : dict[str, DofState]
        Per-DOF state; the DOF of a selected pair is updated in place.
    rescore : callable
        As in :func:`forward_select`.
    chosen : list
        The selection so far; the pair is appended.

    Returns
    -------
    bool
        True when a pair was selected.
    """
    for s in states.values():
        if s.base_full is None or not s.results or not excess_gap(s):
            continue
        tries = sorted((x for x in s.results if x[0].label not in s.selected and math.isfinite(x[0].shrink)
                        and x[0].shrink >= 0 and channel_shrink(x[0]) >= sig.MIN_SHRINK),
                       key=lambda x: rank_key(x[0]))[:PAIR_TRIES]
        for res_a, run_a in tries:
            t = _tentative(s, res_a, run_a, s.base_full, rescore)
            ontop = [(r, u) for r, u in t.results if r.significant and r.label != res_a.label]
            if not ontop:
                continue
            res_b, run_b = min(ontop, key=lambda x: rank_key(x[0]))
            ref = t.base_full if t.base_full is not None else t.base_heldout
            t2 = _tentative(s, res_b, run_b, ref, rescore)
            again = next((r for r, _ in t2.results if r.label == res_a.label), None)
            if again is None or not again.significant:
                continue
            why = (f"significant only jointly with {res_b.label}: alone p = {res_a.p_value:.2g}; on top of "
                   f"{res_b.label} p = {again.p_value:.2g} (shrink {again.shrink:.1f}%), {res_b.label} on top of "
                   f"it p = {res_b.p_value:.2g}")
            a_sel = replace(res_a, significant=True, p_value=again.p_value)
            for cg in res_a.channels:
                s.channel_gaps[cg.channel] = cg.gap_after
            chosen.append((a_sel, run_a, trial_gap(states), why))
            s.selected.append(res_a.label)
            s.data, s.results, s.base_heldout, s.base_full = t.data, t.results, t.base_heldout, t.base_full
            s.channel_neff = t.channel_neff
            for cg in res_b.channels:
                s.channel_gaps[cg.channel] = cg.gap_after
            chosen.append((res_b, run_b, trial_gap(states)))
            s.selected.append(res_b.label)
            if len(chosen) < MAX_EFFECTS:
                s.data = taken_off(s, res_b, run_b, ref)[0]
                rescore(s)
            return True
    return False


# --------------------------------------------------------------------------- sensor or actuator
def input_change_times(p: DofProblem) -> np.ndarray:
    """Trial sample indices where any input of a DOF changes (inside its windows).

    Parameters
    ----------
    p : DofProblem
        The DOF problem.
    """
    idx = []
    for c in p.inputs:
        u = np.nan_to_num(p.raw[c])
        scale = max(float(np.max(np.abs(u))), 1e-12)
        idx.append(np.flatnonzero(np.abs(np.diff(u)) > 1e-6 * scale) + 1)
    out = np.unique(np.concatenate(idx)) if idx else np.zeros(0, int)
    inside = np.zeros(len(out), bool)
    for w in p.windows:
        inside |= (out >= w.i0) & (out < w.i1)
    return out[inside]


def same_input(a: DofProblem, b: DofProblem) -> bool:
    """True when DOF ``b`` is driven by the same input as ``a``: a shared input channel, or
    input changes of ``a`` that coincide (within two samples) with changes of ``b``.

    Parameters
    ----------
    a, b : DofProblem
        Two DOF problems of one trial.
    """
    if set(a.inputs) & set(b.inputs):
        return True
    ta, tb = input_change_times(a), input_change_times(b)
    if len(ta) < 2 or len(tb) < 2:
        return False
    near = np.min(np.abs(ta[:, None] - tb[None, :]), axis=1) <= 2
    return bool(near.mean() >= SAME_INPUT_SHARE)


def _param(res: CandidateResult, name: str) -> EffectParam | None:
    return next((q for q in res.params if q.name == name), None)


def _witness_delay(results: list, label: str) -> CandidateResult | None:
    """The delay of ``label`` (the same actuator in actuator space) among ``results``, else the delay of
    every input."""
    return next((r for r, _ in results if r.label == label), None) or \
        next((r for r, _ in results if r.effect == "actuator_delay" and r.input_channel is None), None)


#: Where a witness estimate comes from when it is the witness DOF's own selected delay.
OWN_DELAY = "its own selected delay"
#: Standard errors by which a witness must stand apart from a hypothesis to rule it out
#: (:func:`witness_reading`).
WITNESS_Z = 2.0


def witness_reading(tau: float, tau_se: float, tb: float, tb_se: float, selected: bool = False) -> str:
    """What one witness estimate says of a delay ``tau`` selected in another DOF: ``"none"`` (the
    witness shows no such delay: a sensor delay), ``"delay"`` (it shows the delay too: the inputs act
    late) or ``""`` (it cannot tell).

    ``"none"`` when the witness' delay plus ``WITNESS_Z`` errors stays under ``NO_DELAY_FRACTION``
    of ``tau``, or when it is within ``WITNESS_Z`` of its own errors of zero and more than
    ``WITNESS_Z`` combined errors under ``tau`` (a witness that sees no delay and rules the full one
    out; randomised seed 50 r014, a GNSS lag of 0.15 s in surge: surge 0.128 +- 0.013 s, yaw
    0.022 +- 0.034 s in the first round). ``"delay"`` when the witness' delay less ``WITNESS_Z``
    errors is at least ``NO_DELAY_FRACTION`` of ``tau``, or (``selected``: the witness DOF's own
    delay, significant there) when it is more than ``WITNESS_Z`` errors above zero.

    Parameters
    ----------
    tau, tau_se : float
        The selected delay and its jackknife error [s].
    tb, tb_se : float
        The witness' delay and its jackknife error [s] (0: none stated).
    selected : bool
        The witness estimate is a delay selected in the witness DOF.
    """
    se = math.hypot(tau_se if math.isfinite(tau_se) else 0.0, tb_se)
    if tb + WITNESS_Z * tb_se < NO_DELAY_FRACTION * tau or (
            tb <= WITNESS_Z * tb_se and tau - tb > WITNESS_Z * se):
        return "none"
    if tb - WITNESS_Z * tb_se >= NO_DELAY_FRACTION * tau or (selected and tb > WITNESS_Z * tb_se):
        return "delay"
    return ""


def witness_estimates(s: DofState, label: str, selected: list[CandidateResult] = ()) -> list[tuple[str, float, float]]:
    """Every delay of a witness DOF that speaks to another DOF's delay ``label``, most precise first:
    ``(where, tau_d, stderr)`` [s].

    Its first round's delay. Its last round's when another effect (not a delay or rate limit) was
    selected in it: fitted on top of that effect, it can be the sharper one (randomised seed 30
    r012, a GNSS lag of 0.15 s in surge: yaw's delay 0.024 +- 0.032 s in the first round, beside the
    quadratic damping's large error; 0.012 +- 0.015 s on top of the damping); once its own delay or
    rate limit is selected, its last round's delay is what is left over and does not speak. And its
    own selected delay of the same actuator or of every input, from the round in which it was
    selected (randomised seed 50 r015, both thrusters late: yaw's delay selected on top of its
    damping, 0.066 +- 0.009 s against surge's 0.098 s, while its first round's was 0.078 +- 0.068 s).

    Parameters
    ----------
    s : DofState
        The witness DOF's state after the selection.
    label : str
        Label of the delay to witness.
    selected : list[CandidateResult]
        Every selected effect (the witness DOF's own delays among them).
    """
    found = []
    first = _witness_delay(s.first_results or s.results, label)
    found.append(("first round", first))
    timing = any(lab.split("[")[0].split(" ")[0] in ("actuator_delay", "actuator_rate_limit", "sensor_delay")
                 for lab in s.selected)
    if not timing and s.selected and s.results:
        found.append(("on top of " + " + ".join(s.selected), _witness_delay(s.results, label)))
    dof = s.problem.dof
    own = [r for r in selected if r.dof == dof and r.effect == "actuator_delay" and " after " not in r.label]
    pick = next((r for r in own if r.label == label), None) or next((r for r in own if r.input_channel is None), None)
    if pick is not None:
        found.append((OWN_DELAY, pick))
    out = []
    for where, r in found:
        tb = _param(r, "tau_d") if r is not None else None
        if tb is None or not math.isfinite(tb.value):
            continue
        out.append((where, float(tb.value), float(tb.stderr) if math.isfinite(tb.stderr) else 0.0))
    return sorted(out, key=lambda w: w[2])


def sensor_or_actuator(res: CandidateResult, states: Mapping[str, DofState],
                       selected: list[CandidateResult] = ()) -> tuple[str, str | None, str]:
    """Name a selected delay: ``actuator_delay`` or ``sensor_delay`` (with the sensor group), or
    ``actuator_delay`` reported unsure when the witnesses cannot tell.

    Witnesses are the other DOFs driven by the same inputs through another sensor group; each gives
    its delay estimates (:func:`witness_estimates`) and the most precise estimate that tells
    (:func:`witness_reading`) decides: no delay there -> the first channel's sensor lags; the delay
    there too -> the inputs act late. When no estimate tells, the delay keeps its name and is
    reported unsure, with the witness' figures (randomised seed 50 r014 before: yaw's delay on top of
    its damping, 0.066 +- 0.027 s against surge's 0.128 s, neither none nor the delay, was read as
    "a delay too").

    Parameters
    ----------
    res : CandidateResult
        A selected candidate.
    states : Mapping[str, DofState]
        Every analysed DOF (their delay candidates are the witnesses).
    selected : list[CandidateResult]
        Every selected effect (a witness DOF's own selected delay is one of its estimates).

    Returns
    -------
    (effect, input_channel, why)
        The effect name to report, the input or sensor group, and the reason ("unsure: ..." when the
        witnesses cannot tell).
    """
    if res.effect != "actuator_delay":
        return res.effect, res.input_channel, ""
    tau = _param(res, "tau_d")
    if tau is None or not tau.value > 0:
        return res.effect, res.input_channel, ""
    pa = states[res.dof].problem
    group_a = SENSOR_GROUPS.get(pa.channel, pa.channel)
    told, unclear = [], []
    for dof, s in states.items():
        pb = s.problem
        if dof == res.dof or not pb.inputs or SENSOR_GROUPS.get(pb.channel, pb.channel) == group_a:
            continue
        if not same_input(pa, pb):
            continue
        # The same actuator's delay (actuator space) when the other DOF has it, else every input's.
        for where, v, se in witness_estimates(s, res.label, selected):
            reading = witness_reading(tau.value, tau.stderr, v, se, where == OWN_DELAY)
            (told if reading else unclear).append((se, reading, dof, pb.channel, where, v))
    if not told and not unclear:
        return res.effect, res.input_channel, (
            f"no other channel driven by the same inputs through another sensor, so a delay of the "
            f"{group_a} sensor cannot be told from an actuator delay")
    ts = f"{tau.value:.3g} +- {tau.stderr:.2g} s" if math.isfinite(tau.stderr) else f"{tau.value:.3g} s"
    if told:
        se, reading, dof, ch, where, v = min(told, key=lambda w: w[0])
        if reading == "none":
            return "sensor_delay", group_a, (
                f"{dof} ({ch}, another sensor) is driven by the same inputs and shows no such delay "
                f"({where}: {v:.3g} +- {se:.2g} s against {ts}): the {group_a} measurement lags")
        return res.effect, res.input_channel, (
            f"{dof} ({ch}), driven by the same inputs through another sensor, shows a delay too "
            f"({where}: {v:.3g} +- {se:.2g} s): the inputs act late")
    se, _, dof, ch, where, v = min(unclear, key=lambda w: w[0])
    return res.effect, res.input_channel, (
        f"unsure: actuator_delay or sensor_delay[{group_a}]: {dof} ({ch}), driven by the same inputs through "
        f"another sensor, shows {v:.3g} +- {se:.2g} s ({where}) against {ts}, neither clearly none nor "
        f"clearly the delay, so a late {group_a} measurement cannot be told from late inputs")


def by_channel(res: CandidateResult) -> str:
    """Where an effect whose DOF gap shrinks by less than ``MIN_SHRINK`` passed the per-channel rule
    ("" otherwise): the channel that carries it and the one that dominates the DOF gap.

    Parameters
    ----------
    res : CandidateResult
        A selected candidate.
    """
    if not res.shrink < sig.MIN_SHRINK or len(res.channels) < 2:
        return ""
    ok = [g for g in res.channels if math.isfinite(g.gap_before) and g.gap_before > 0 and math.isfinite(g.gap_after)]
    if not ok:
        return ""
    best = max(ok, key=lambda g: 1.0 - g.gap_after / g.gap_before)
    big = max(ok, key=lambda g: g.gap_before)
    return (f"significant in {best.channel}: its gap {best.gap_before:.3g} -> {best.gap_after:.3g} noise units "
            f"({100 * (1 - best.gap_after / best.gap_before):.1f} %, p = {best.p_value:.2g}); the DOF's gap, "
            f"dominated by {big.channel} ({big.gap_before:.3g}), shrinks by {res.shrink:.1f} % only")


def selected_effects(chosen, states: Mapping[str, DofState],
                     params_of: Callable[[CandidateResult], tuple[EffectParam, ...]] | None = None,
                     ) -> tuple[SelectedEffect, ...]:
    """The selection as records, delays named sensor or actuator.

    Parameters
    ----------
    chosen : list
        :func:`forward_select`'s output.
    states : Mapping[str, DofState]
        Per-DOF state.
    params_of : callable, optional
        Parameters to report for a candidate (default its own).
    """
    out = []
    for i, (res, _run, tg, *joint) in enumerate(chosen):
        effect, inp, why = sensor_or_actuator(res, states, [c[0] for c in chosen])
        unsure = confused_with(res, [c[0] for c in chosen[:i]])
        if not unsure and res.dof in states and not any(c[0].dof == res.dof for c in chosen[:i]):
            unsure = close_rival(res, getattr(states[res.dof], "first_results", None) or [])
        why = "; ".join(w for w in (unsure, why, *joint, by_channel(res)) if w)
        label = res.label if effect == res.effect else f"{effect}[{inp}]"
        out.append(SelectedEffect(step=i + 1, effect=effect, dof=res.dof, label=label, input_channel=inp,
                                  gap_before=res.gap_before, gap_after=res.gap_after, shrink=res.shrink,
                                  trial_gap_after=tg, p_value=res.p_value,
                                  params=params_of(res) if params_of else res.params, why=why,
                                  candidate=res.label))
    return tuple(out)


# --------------------------------------------------------------------------- unexplained
def _corr(a: np.ndarray, b: np.ndarray) -> float:
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 8:
        return math.nan
    x, y = a[ok] - a[ok].mean(), b[ok] - b[ok].mean()
    den = math.sqrt(float(np.sum(x**2) * np.sum(y**2)))
    return float(np.sum(x * y) / den) if den > 0 else math.nan


def _looks_like(band: str, corr: Mapping[str, float], mean_share: float) -> str:
    parts = []
    if mean_share > 0.5:
        parts.append("mostly a steady offset within each window")
    parts.append({"below wave band": "slow (below the wave band): a model or force error more than noise",
                  "in wave band": "oscillation in the wave band: waves or an unmodelled resonance",
                  "above wave band": "fast (above the wave band): vibration, sensor or timing"}.get(band, band))
    strong = sorted(((abs(v), k, v) for k, v in corr.items() if math.isfinite(v) and abs(v) >= 0.3), reverse=True)
    if strong:
        parts.append("correlates with " + ", ".join(f"{k} ({v:+.2f})" for _, k, v in strong[:3]))
    else:
        parts.append("no correlation of 0.3 or more with speed, inputs or heading")
    return "; ".join(parts)


def residual_character(p: DofProblem, resid: np.ndarray, trial: Trial) -> tuple[str, float, dict, str]:
    """Frequency band, spectral peak and correlations of one channel's residual rows.

    Parameters
    ----------
    p : DofProblem
        The DOF problem (windows, analysis step).
    resid : numpy.ndarray
        Residual rows (W, n), NaN off-window.
    trial : Trial
        The trial (speed, inputs, heading).

    Returns
    -------
    (band, peak_omega, correlations, looks_like)
    """
    band_edges = default_band(p)
    split = band_split(resid, p.dt, band_edges)
    band = max(split, key=split.get) if sum(split.values()) > 0 else ""
    om, psd = pooled_psd(resid, p.dt)
    peak = float(om[1:][np.argmax(psd[1:])]) if len(psd) > 2 else math.nan
    total = float(np.nansum(resid**2))
    cnt = np.isfinite(resid).sum(axis=1, keepdims=True)
    means = np.where(cnt > 0, np.nansum(resid, axis=1, keepdims=True) / np.maximum(cnt, 1), 0.0)
    mean_share = float(np.nansum(means**2 * cnt) / total) if total > 0 else 0.0
    corr: dict[str, float] = {}
    speed = "sog" if trial.has("sog") else ("u" if trial.has("u") else None)
    series = {}
    if speed:
        series[f"speed ({speed})"] = trial.data[speed].to_numpy(float)
    for c in p.inputs:
        series[c] = np.nan_to_num(p.raw[c])
    head = "psi" if trial.has("psi") else ("cog" if trial.has("cog") else None)
    if head:
        h = trial.data[head].to_numpy(float)
        series[f"cos {head}"] = np.cos(h)
        series[f"sin {head}"] = np.sin(h)
    for name, x in series.items():
        xb = block_average(x, p.windows, p.m, p.n, trapezoid=True)
        corr[name] = _corr(resid.ravel(), xb.ravel())
    return band, peak, corr, _looks_like(band, corr, mean_share)


def unexplained(states: Mapping[str, DofState], places: tuple[Place, ...], trial: Trial,
                names_of: Callable[[DofProblem], Mapping[str, str]],
                heading_waves: bool = False) -> tuple[Unexplained, ...]:
    """Channels whose gap stays above the noise after the selected effects (see module docstring).

    Parameters
    ----------
    states : Mapping[str, DofState]
        Per-DOF state after the selection.
    places : tuple[Place, ...]
        Where the baseline's gap lives (the top non-channel place of the DOF is reported).
    trial : Trial
        The trial.
    names_of : callable
        Output key -> channel name of a DOF problem.
    heading_waves : bool
        Waves were selected on the heading: the wave-band residual of a body velocity derived from
        the heading (``DofProblem.derived_from``) is those waves times the speed, explained.
    """
    rows = []
    for dof, s in states.items():
        names = names_of(s.problem)
        resid = sig.heldout_residuals(s.data, s.base_heldout)
        units = sig.noise_units(s.data)
        for key, ch in names.items():
            test = gap_above_floor(s, key, ch, units)
            if test is None:
                continue
            g, f, pv = test
            r = resid.get(key)
            r = r / units[key] if r is not None and math.isfinite(units.get(key, math.nan)) else r
            band, peak, corr, looks = residual_character(s.problem, r, trial) if r is not None else ("", math.nan, {}, "")
            if heading_waves and getattr(s.problem, "derived_from", None) and band == "in wave band":
                continue
            place = next((f"{pl.category} {pl.name}" for pl in places
                          if pl.dof == dof and pl.category not in ("channel", "frequency band") and pl.share > 0), "")
            rows.append([dof, ch, g, pv, place, band, peak, corr, looks, f])
    excess = np.array([max(r[2] ** 2 - r[9] ** 2, 0.0) for r in rows])
    tot = float(excess.sum())
    out = [Unexplained(dof=r[0], channel=r[1], gap=float(r[2]), share=float(e / tot) if tot > 0 else math.nan,
                       p_value=float(r[3]), place=r[4], band=r[5], peak_omega=float(r[6]), correlations=r[7],
                       looks_like=r[8]) for r, e in zip(rows, excess)]
    return tuple(sorted(out, key=lambda u: -u.share if math.isfinite(u.share) else 0.0))


UNEXPLAINED_TEST = (
    f"a channel is unexplained when its held-out gap g after the selected effects fails the test 'only "
    f"what a correct model leaves is left' (n_eff (g/f)^2 against chi^2(n_eff), p < {ALPHA_UNEXPLAINED:g}, "
    f"n_eff corrected for the residual's lag-1 autocorrelation), g >= {UNEXPLAINED_GAP:g} f, and the model "
    f"error sqrt(g^2 - f^2) noise units is at least {100 * MIN_UNEXPLAINED_SCALE:g}% of the channel's scale; "
    f"f (>= 1) is the channel's held-out floor: the gap of the baseline cross-validated on synthetic "
    f"data made from its own fit plus white noise at the measured floor (sensor noise plus the noise "
    f"of fitted parameters)")


def channel_gaps_of(base_score: sig.Score) -> tuple[dict, dict]:
    """Per-channel gap and effective sample count of the current baseline.

    Parameters
    ----------
    base_score : Score
        The baseline scored against itself.
    """
    return ({c.channel: c.gap_before for c in base_score.channels},
            {c.channel: c.n_eff for c in base_score.channels})


__all__ = ["DofState", "carried_regressors", "channel_gaps_of", "forward_select", "rank_key", "selected_effects", "sensor_or_actuator",
           "unexplained", "UNEXPLAINED_TEST"]
