"""The fit stage's entry point: every segment of a trial -> per-segment fits -> combined coefficients."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Callable, Mapping, Sequence

import numpy as np

from ..errors import FitError
from ..parallel import ordered_map
from ..records import (CHANNEL_UNITS, DOF_CHANNELS, DOF_NAMES, DOFS, Estimate, Fits, Segment, SegmentFit,
                       Segments, Trial)
from ..vessel import Vessel
from .combine import Contribution, combine, combined_estimate
from .damping import (damping_from_decay, damping_from_gain, damping_from_time_constant,
                      natural_frequency_ratio, step_gain)
from .data import gain_formulation, input_levels, segment_label
from .first_order import fit_coast_down, fit_step, step_steadiness
from .nomoto import fit_rudder_step
from .nomoto_quality import judge_nomoto
from .nomoto_pool import is_joint_follower, samples_window
from .nomoto_segment import EXTRA_COEFFICIENTS, WHOLE_RECORD_KINDS, fit_nomoto_segment
from .nomoto_structure import PendingJoint, fit_nomoto_trial, fit_nomoto_trial_deferred, structure_note, with_joint_fit
from .second_order import MIN_SAMPLES_PER_PERIOD, fit_free_decay
from .segment_fit import (SETTLED_TIME_CONSTANTS, UPPER_BOUND_Z, failed_segment_fit, settled_at_run_end,
                          slowest_time_constant)

#: Segment kind -> (fitter, model name).
FITTERS: Mapping[str, tuple[Callable[[Trial, Segment], SegmentFit], str]] = {
    "coast_down": (fit_coast_down, "first_order_decay"),
    "step": (fit_step, "first_order_step"),
    "free_decay": (fit_free_decay, "damped_oscillation"),
    "rudder_step": (fit_rudder_step, "nomoto_step"),
    "zigzag": (fit_nomoto_segment, "nomoto_oe"),
    "sinusoid": (fit_nomoto_segment, "nomoto_oe"),
}
#: DOF name -> Fossen derivative on the diagonal of -D.
DERIVATIVES: Mapping[str, str] = {"surge": "X_u", "sway": "Y_v", "roll": "K_p", "pitch": "M_q", "yaw": "N_r"}
DAMPING_UNITS: Mapping[str, str] = {"surge": "kg/s", "sway": "kg/s", "roll": "kg m^2/s", "pitch": "kg m^2/s",
                                    "yaw": "kg m^2/s"}
#: Relative mismatch of the fitted and the config's natural frequency that is flagged.
WN_TOLERANCE = 0.10
_KIND_WORDS = {"coast_down": ("coast-down", "coast-downs"), "step": ("step", "steps"),
               "free_decay": ("free decay", "free decays"), "rudder_step": ("rudder step", "rudder steps"),
               "zigzag": ("zig-zag", "zig-zags"), "sinusoid": ("sinusoid", "sinusoids")}
# Estimates first in this order (the report's table order); extras follow in insertion order.
_ORDER = ("X_u", "Y_v", "K_p", "M_q", "N_r", "K_nomoto", "T_nomoto", "b_nomoto")
#: How the whole-record Nomoto fits (zig-zags, sinusoids) are described in an estimate's method.
WHOLE_RECORD_METHOD = ("whole-record Nomoto fit on {kinds}: exact ZOH simulation of heading (and yaw rate) driven "
                       "by the logged rudder (a logged command through an estimated servo lag / rate limit), "
                       "first or second order by held-out error, with rudder bias; output error when the compass "
                       "residuals are white, else prediction error with the wave noise model (steady-state "
                       "Kalman innovations)")


@dataclass
class _Pool:
    """Per-coefficient contributions while the segments are walked (local, never returned)."""

    unit: str
    method: str
    items: list[Contribution] = field(default_factory=list)
    kinds: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    #: Further methods (with the kinds they served) when one coefficient comes from several models.
    more: dict[str, list[str]] = field(default_factory=dict)
    #: Combine on the logarithm of the magnitude (:func:`combine_relative`): a damping from a time
    #: constant, whose standard error grows with its value.
    relative: bool = False

    def method_text(self) -> str:
        """The method, or each method with the segment kinds it was used on."""
        first = [k for k in self.kinds if not any(k in ks for ks in self.more.values())]
        parts = [self.method.format(kinds=_kinds_text(first))]
        parts += [m.format(kinds=_kinds_text(ks)) for m, ks in self.more.items()]
        return "; ".join(parts)


def _kinds_text(kinds: list[str]) -> str:
    parts = []
    for kind in dict.fromkeys(kinds):
        n = kinds.count(kind)
        one, many = _KIND_WORDS.get(kind, (kind, kind + "s"))
        parts.append(f"{n} {one if n == 1 else many}")
    return " and ".join(parts)


def _fit_segment(trial: Trial, segment: Segment) -> SegmentFit:
    fitter, model = FITTERS.get(segment.kind, (None, "none"))
    if fitter is None:
        return failed_segment_fit(segment, model, "", f"{segment_label(segment)}: segment kind {segment.kind!r} "
                                  f"is not fitted by this stage; expected one of {sorted(FITTERS)}")
    try:
        return fitter(trial, segment)
    except FitError as exc:
        return failed_segment_fit(segment, model, "", str(exc))
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        # One pathological segment must not cost the user the other segments' results.
        return failed_segment_fit(segment, model, "", f"{segment_label(segment)}: fit failed with "
                                  f"{type(exc).__name__}: {exc}")


class _Collector:
    """Turns segment fits into per-coefficient contributions."""

    def __init__(self, trial: Trial, vessel: Vessel) -> None:
        self.trial = trial
        self.vessel = vessel
        self.pools: dict[str, _Pool] = {}
        self.nomoto_fits: list[SegmentFit] = []

    def add(self, name: str, unit: str, method: str, kind: str, c: Contribution) -> None:
        pool = self.pools.setdefault(name, _Pool(unit=unit, method=method))
        pool.items.append(c)
        pool.kinds.append(kind)
        if method != pool.method:
            pool.more.setdefault(method, []).append(kind)

    def _param(self, sf: SegmentFit, name: str) -> Contribution:
        label = segment_label(sf.segment)
        value = sf.params.get(name, math.nan)
        se = sf.stderr.get(name, math.nan)
        dof = max(sf.y.size - len(sf.param_names), 1)
        return Contribution(value, se, label, dof, sf.success, sf.message, samples_window(sf))

    def _derived(self, sf: SegmentFit, value_se: Callable[[], tuple[float, float]], sign: float = 1.0,
                 missing: str = "") -> Contribution:
        label = segment_label(sf.segment)
        if missing:
            return Contribution(math.nan, math.nan, label, ok=False, reason=missing)
        if not sf.success:
            return Contribution(math.nan, math.nan, label, ok=False, reason=sf.message)
        value, se = value_se()
        return Contribution(sign * value, se, label, max(sf.y.size - len(sf.param_names), 1))

    def _mass(self, dof: str) -> tuple[float, str]:
        if not self.vessel.has_rigid_body:
            return math.nan, (f"vessel config {self.vessel.name!r} has no rigid_body mass and inertia: "
                              f"the damping needs M[i, i]; the mass-free parameters (T, wn, zeta) are still reported")
        return self.vessel.effective_mass(dof), ""

    def collect(self, sf: SegmentFit) -> None:
        seg = sf.segment
        kind, dof = seg.kind, seg.dof
        if kind in ("coast_down", "step") and dof in ("surge", "sway", "yaw"):
            self._first_order(sf)
        elif kind == "free_decay" and dof in ("roll", "pitch"):
            self._free_decay(sf)
        elif kind == "rudder_step" and dof == "yaw":
            method = ("first-order Nomoto step response on {kinds}: K from the rudder change where the yaw "
                      "rate was steady before the step, else K = r_ss/delta_after")
            k = self._param(sf, "K")
            if sf.success and "K" not in sf.params:
                k = replace(k, ok=False, reason=sf.message)
            if sf.model.startswith("nomoto_oe") or sf.model.startswith("nomoto_pem"):
                method = WHOLE_RECORD_METHOD
            self.add("K_nomoto", "1/s", method, kind, k)
            self.add("T_nomoto", "s", method, kind, self._param(sf, "T"))
            self._nomoto_extras(sf, method)
        elif kind in WHOLE_RECORD_KINDS and dof == "yaw":
            if is_joint_follower(sf):
                # Its coefficients are a joint fit's, counted once on that fit's first segment.
                if sf.success:
                    self.nomoto_fits.append(sf)
                return
            for name, unit in (("K", "1/s"), ("T", "s"), ("b", "rad")):
                if name == "b" and "b" not in sf.params and sf.success:
                    continue
                self.add(f"{name}_nomoto", unit, WHOLE_RECORD_METHOD, kind, self._param(sf, name))
            self._nomoto_extras(sf, WHOLE_RECORD_METHOD)

    def _nomoto_extras(self, sf: SegmentFit, method: str) -> None:
        """Second-order time constants and the rudder servo, where a segment's fit estimated them."""
        if sf.success:
            self.nomoto_fits.append(sf)
        for param, (name, unit) in EXTRA_COEFFICIENTS.items():
            if param in sf.params:
                self.add(name, unit, method, sf.segment.kind, self._param(sf, param))

    def _first_order(self, sf: SegmentFit) -> None:
        seg = sf.segment
        dof, kind = seg.dof, seg.kind
        self.add(f"T_{dof}", "s", "first-order exponential on {kinds}", kind, self._param(sf, "T"))
        m, missing = self._mass(dof)
        T, se_T = sf.params.get("T", math.nan), sf.stderr.get("T", math.nan)
        m_text = f"{m:.4g} {'kg' if dof != 'yaw' else 'kg m^2'} from config (M_RB + M_A)" if not missing else \
            "unknown (no rigid_body in config)"
        self.add(DERIVATIVES[dof], DAMPING_UNITS[dof],
                 f"first-order exponential on {{kinds}}; {DERIVATIVES[dof]} = -m_eff/T with m_eff = {m_text}",
                 kind, self._derived(sf, lambda: damping_from_time_constant(m, T, se_T), -1.0, missing))
        self.pools[DERIVATIVES[dof]].relative = True
        if kind != "step":
            return
        before, after, _ = input_levels(self.trial, seg)
        steady, steady_note = step_steadiness(self.trial, sf)
        form = gain_formulation(steady, after)
        missing = ""
        if after == before:
            missing = (f"no input change given (input_before = input_after = {after}): "
                       f"the gain needs delta_input")
        elif form == "none":
            missing = f"gain not identified: {steady_note} and the input returns to zero"
        y_unit = CHANNEL_UNITS.get(sf.channel or DOF_CHANNELS[dof][0], "")
        in_unit = CHANNEL_UNITS.get(seg.input_channel or "", "input unit")
        force = seg.input_channel == DOF_CHANNELS[dof][1]
        gain_unit = {"surge": "s/kg", "sway": "s/kg", "yaw": "s/(kg m^2)"}[dof] if force else f"({y_unit})/({in_unit})"
        rule = ("(y_ss - y0)/(input_after - input_before) where the response was steady before the step, "
                "else y_ss/input_after")
        names = [f"gain_{dof}"]
        self.add(names[0], gain_unit, f"first-order step gain {rule}, on {{kinds}}", kind,
                 self._derived(sf, lambda: step_gain(sf, before, after, form), 1.0, missing))
        if force:
            names.append(f"D_gain_{dof}")
            self.add(names[1], DAMPING_UNITS[dof],
                     f"gain-based D = 1/gain, gain {rule}, on {{kinds}}; a consistency check only: the "
                     f"damping matrix uses the T-based {DERIVATIVES[dof]}",
                     kind, self._derived(sf, lambda: damping_from_gain(sf, before, after, form), 1.0, missing))
        if form == "level" and sf.success and not missing:
            for name in names:
                self.pools[name].notes.append(f"{segment_label(seg)}: {steady_note}: gain read as "
                                              f"y_ss/input_after (assumes no offset)")

    def _free_decay(self, sf: SegmentFit) -> None:
        seg = sf.segment
        dof, kind = seg.dof, seg.kind
        method = "damped oscillation A exp(-zeta wn t) cos(wd t + phase) + offset on {kinds}"
        self.add(f"wn_{dof}", "rad/s", method, kind, self._param(sf, "wn"))
        self.add(f"zeta_{dof}", "1", method, kind, self._param(sf, "zeta"))
        inertia, missing = self._mass(dof)
        name = DERIVATIVES[dof]
        i_text = (f"{inertia:.4g} kg m^2 from config (M_RB + M_A)" if not missing
                  else "unknown (no rigid_body in config)")
        self.add(name, DAMPING_UNITS[dof], f"{method}; {name} = -2 zeta wn I_eff with I_eff = {i_text}",
                 kind, self._derived(sf, lambda: damping_from_decay(inertia, sf), -1.0, missing))
        restoring = self.vessel.restoring.get(dof)
        if missing:
            return
        if sf.success and restoring is not None and restoring > 0 and sf.t.size > 1:
            self._check_resolution(sf, math.sqrt(restoring / inertia))
        if restoring is None or restoring <= 0:
            note = f"restoring.{dof} not in vessel config: wn not checked against sqrt(C/I_eff)"
            if note not in self.pools[name].notes:
                self.pools[name].notes.append(note)
            return
        self.add(f"wn_ratio_{dof}", "1",
                 f"fitted wn over config sqrt(C/I_eff) with C = {restoring:.4g} N m/rad, "
                 f"I_eff = {inertia:.4g} kg m^2, on {{kinds}}", kind,
                 self._derived(sf, lambda: natural_frequency_ratio(sf, restoring, inertia)))

    def _check_resolution(self, sf: SegmentFit, wn_config: float) -> None:
        """Refuse a decay whose log rate cannot resolve the frequency the config predicts.

        Sampled at ``fs``, an oscillation at ``f`` above ``fs / 2`` shows in the samples at the alias
        ``|f - k fs|``, a clean damped cosine at the wrong frequency that the fit alone cannot tell
        from the true one. When the config's ``sqrt(C / I_eff)`` has fewer than
        ``MIN_SAMPLES_PER_PERIOD`` samples per period, the fitted wn, zeta and the damping are
        not used (they are replaced by a refusal that names the rates).
        """
        dt = float(np.median(np.diff(sf.t)))
        per_period = 2 * math.pi / wn_config / dt
        if per_period >= MIN_SAMPLES_PER_PERIOD:
            return
        dof = sf.segment.dof
        reason = (f"{segment_label(sf.segment)}: the config's natural frequency sqrt(C/I_eff) = "
                  f"{wn_config / (2 * math.pi):.3g} Hz has {per_period:.2g} samples per period at the log's "
                  f"{1 / dt:.3g} Hz, expected at least {MIN_SAMPLES_PER_PERIOD:g}: the fitted "
                  f"{sf.params['wn'] / (2 * math.pi):.3g} Hz may be an alias; log {dof} faster to identify it")
        for name in (f"wn_{dof}", f"zeta_{dof}", DERIVATIVES[dof]):
            items = self.pools[name].items
            items[-1] = replace(items[-1], value=math.nan, stderr=math.nan, ok=False, reason=reason)

    def estimates(self) -> dict[str, Estimate]:
        # The wn check is flagged on the damping estimate it qualifies, so it is read first.
        for dof in ("roll", "pitch"):
            ratio_pool = self.pools.get(f"wn_ratio_{dof}")
            if ratio_pool is None:
                continue
            ratio = combine(f"wn_ratio_{dof}", ratio_pool.unit, "", ratio_pool.items)
            if ratio.success and abs(ratio.value - 1.0) > WN_TOLERANCE:
                flag = (f"fitted wn is {ratio.value:.3g} x sqrt(C/I_eff) of the config (mismatch > "
                        f"{WN_TOLERANCE:.0%}): check restoring.{dof}, the inertia and the added mass")
                ratio_pool.notes.append(flag)
                self.pools[DERIVATIVES[dof]].notes.append(flag)
        note = structure_note(self.nomoto_fits)
        for name in ("K_nomoto", "T_nomoto"):
            if note and name in self.pools:
                self.pools[name].notes.append(note)
        out = {name: (combine_relative if pool.relative else combine)(
                   name, pool.unit, pool.method_text(), pool.items, pool.notes,
                   prediction=name in ("K_nomoto", "T_nomoto"))
               for name, pool in self.pools.items()}
        if "b_nomoto" in out:
            out["b_nomoto"] = _bias_estimate(out["b_nomoto"])
        out = judge_nomoto(out, self.nomoto_fits)
        first = {k: out[k] for k in _ORDER if k in out}
        return {**first, **{k: v for k, v in out.items() if k not in first}}


def _nomoto_without_unsettled_cuts(trial: Trial, items: Sequence[Segment]) -> dict[int, SegmentFit]:
    """:func:`fit_nomoto_trial` on the segments whose window the end of their data did not cut unsettled.

    The whole-record fits of a trial's yaw segments are made together: one structure chosen across
    them, their disagreement and the joint fit with one rudder bias
    (:func:`pipeline.fit.nomoto_structure.shared_bias_note`) read every record handed on. A record cut
    by the end of its data (``Segment.cut_at_run_end``) may hold the start of a transient only, and
    fitted with the others it would take part in choosing the structure by which its own settling
    is judged (measured: a Clarke83 step cut 39.5 s after its change, settled for the first order's
    T = 2.4 s but not for the second order's 9.5 s envelope, tipped the structure to the first order
    and K to +4.1 %). So the records nothing cut are fitted first; a cut record is handed on with
    them only when it holds ``SETTLED_TIME_CONSTANTS`` of their slowest time constant (the largest
    among their successful fits, :func:`pipeline.fit.segment_fit.slowest_time_constant`, at its 95 %
    upper bound), and stays only while its own fit among them is a settled success (else the others
    are fitted again without it: a record whose own time constant is not identified tells nothing of
    its settling and took part in their structure choice; measured on a tanker step cut 90 s after its
    change, T = 6.5 +- 59 s, the model-structure term it brought tripled K's error); else it is fitted
    alone and failed with the reason (:func:`settled_at_run_end`).
    When no uncut record gives a time constant, the cut records are judged by their own fits and the
    records handed on again until every cut record left is a settled success. The joint second-order fit of
    the rudder steps (:func:`pipeline.fit.nomoto_structure.with_joint_fit`) is made for the pass kept only
    (measured, PythonVehicleSimulator's tanker at 20 m, commanded steps, seed 0, one BLAS thread: two joint fits,
    4.8 s of the benchmark's 9.3 s CPU, one of them for a pass that was dropped; now one, 3.0 s).

    Parameters
    ----------
    trial : Trial
        The trial.
    items : sequence of Segment
        All its segments, in order.

    Returns
    -------
    dict
        Segment index (into ``items``) -> its whole-record fit, as :func:`fit_nomoto_trial`.
    """
    return with_joint_fit(*_nomoto_kept_pass(trial, items))


def _nomoto_kept_pass(trial: Trial, items: Sequence[Segment]) -> tuple[dict[int, SegmentFit], PendingJoint | None]:
    """The fits of :func:`_nomoto_without_unsettled_cuts` and the joint fit of the pass kept, not yet made."""
    cut = [i for i, s in enumerate(items) if s.cut_at_run_end and s.dof == "yaw" and s.input_channel]
    if not cut:
        return fit_nomoto_trial_deferred(trial, items)
    uncut = [i for i in range(len(items)) if i not in cut]
    first, first_joint = _nomoto_subset(trial, items, uncut)
    slowest = _slowest_of(first.values())
    if slowest is None:
        return _nomoto_own_judgement(trial, items)
    upper = slowest[0] + UPPER_BOUND_Z * slowest[1] if math.isfinite(slowest[1]) else slowest[0]
    settled = [i for i in cut if items[i].t_end - items[i].t_start >= SETTLED_TIME_CONSTANTS * upper]
    out, joint = first, first_joint
    failed: dict[int, SegmentFit] = {}
    while settled:
        out, joint = _nomoto_subset(trial, items, sorted(uncut + settled))
        # A cut record whose own fit with the others is not a settled success leaves them too.
        judged = {i: settled_at_run_end(out[i], slowest) for i in settled if i in out}
        bad = {i: sf for i, sf in judged.items() if not sf.success}
        if not bad:
            break
        failed.update(bad)
        settled = [i for i in settled if i not in bad]
        if not settled:
            out, joint = first, first_joint
    for i in cut:
        if i in settled:
            continue
        if i in failed:
            out[i] = failed[i]
            continue
        alone = fit_nomoto_trial(trial, [items[i]]).get(0) or _fit_segment(trial, items[i])
        out[i] = settled_at_run_end(alone, slowest)
    return out, joint


def _nomoto_subset(trial: Trial, items: Sequence[Segment], keep: Sequence[int]
                   ) -> tuple[dict[int, SegmentFit], PendingJoint | None]:
    """:func:`fit_nomoto_trial_deferred` on ``items[keep]``, keyed by the index into ``items``."""
    fits, joint = fit_nomoto_trial_deferred(trial, [items[i] for i in keep])
    return {keep[j]: sf for j, sf in fits.items()}, (joint.keyed(keep) if joint is not None else None)


def _slowest_of(fits) -> tuple[float, float, str] | None:
    """The largest slowest time constant among successful fits (:func:`slowest_time_constant`), or None."""
    found = [slowest_time_constant(sf) for sf in fits if sf.success]
    found = [f for f in found if math.isfinite(f[0]) and f[0] > 0]
    if not found:
        return None
    tau, se, what = max(found, key=lambda f: f[0])
    return tau, se, f"{what} of the trial's slowest uncut record"


def _nomoto_own_judgement(trial: Trial, items: Sequence[Segment]
                          ) -> tuple[dict[int, SegmentFit], PendingJoint | None]:
    """The records handed on to :func:`fit_nomoto_trial` until every cut one left is a settled success by its own fit
    (and the joint fit of that pass, not yet made)."""
    keep = list(range(len(items)))
    out: dict[int, SegmentFit] = {}
    while True:
        fits, joint = _nomoto_subset(trial, items, keep)
        judged = {i: settled_at_run_end(sf) for i, sf in fits.items() if sf.segment.cut_at_run_end}
        unsettled = {i: sf for i, sf in judged.items() if not sf.success}
        if not unsettled:
            return {**fits, **out}, joint
        out.update(unsettled)
        keep = [i for i in keep if i not in unsettled]


def t_variance_factor(dof: float, several: bool) -> float:
    """``sqrt(dof/(dof - 2))``: the standard deviation of Student's t over that of a normal [-].

    A segment's standard error uses its own residual variance, so its error over the standard error
    is Student-t with the fit's ``dof``; a single segment keeps its t interval, a normal
    combination of several (:func:`combine_relative`) takes each at its t variance (a 5 Hz sway step
    has 13 degrees of freedom: factor 1.08; measured z spread 1.10 over 100 seeds before).

    Parameters
    ----------
    dof : float
        Residual degrees of freedom of the segment's fit.
    several : bool
        True when the segment is combined with others (else the factor is 1).
    """
    if not several or not (math.isfinite(dof) and dof > 2):
        return 1.0
    return math.sqrt(dof / (dof - 2.0))


def combine_relative(name: str, unit: str, method: str, contributions: Sequence[Contribution],
                     notes: Sequence[str] = (), prediction: bool = False) -> Estimate:
    """:func:`pipeline.fit.combine.combine` on ``ln|value|`` with the relative errors, back-transformed.

    A damping from a fitted time constant, ``D = m_eff/T``, has a standard error that grows with
    its value (about ``D^1.5`` for an exponential sampled at a fixed rate), so inverse-variance
    weights on ``D`` itself favour the segments whose noise drew a small ``D``: measured on 100
    seeds of the 5 Hz GNSS-only sway step and coast-down (``benchmarks/trial_shapes.py`` manoeuvres),
    the combined ``Y_v`` sat +0.27 +- 0.11 standard errors off the truth while each segment's ``T``
    was unbiased; on synthetic pairs of fits (3000 draws) the weights on relative errors take the
    mean error from +0.18 to +0.00 standard errors. The combination (consistency test, random
    effects) runs on ``ln|value|`` with ``se/|value|``; the value is ``sign * exp(mean)``, its
    error ``|value| * se_ln`` and its 95 % interval the back-transformed one.

    Parameters
    ----------
    name, unit, method : str
        Coefficient name, SI unit and how each segment's value was obtained.
    contributions : sequence of Contribution
        Per-segment values, all of one sign.
    notes : sequence of str
        Further remarks for the message.
    prediction : bool
        Passed to :func:`pipeline.fit.combine.combine`.

    Returns
    -------
    Estimate
        As :func:`pipeline.fit.combine.combine`; values of mixed sign are combined linearly.
    """
    usable = [c for c in contributions if c.ok and math.isfinite(c.value) and math.isfinite(c.stderr)
              and c.stderr > 0 and c.value != 0]
    signs = {math.copysign(1.0, c.value) for c in usable}
    if len(signs) != 1:
        return combine(name, unit, method, contributions, notes, prediction)
    sign = signs.pop()
    several = len(usable) > 1
    logs = [replace(c, value=math.log(abs(c.value)),
                    stderr=c.stderr / abs(c.value) * t_variance_factor(c.dof, several))
            if c in usable else c for c in contributions]
    notes = list(notes)
    if several and any(t_variance_factor(c.dof, True) > 1.01 for c in usable):
        notes.append("segment errors times sqrt(dof/(dof - 2)) before the normal combination (each is Student-t "
                     "with its fit's residual degrees of freedom: " + ", ".join(f"{c.dof:g}" for c in usable) + ")")
    est = combine(name, "(relative, in ln|value|)", method, logs, notes, prediction)
    if not math.isfinite(est.value):
        return est
    value = sign * math.exp(est.value)
    se = abs(value) * est.stderr
    lo, hi = sorted(sign * math.exp(x) for x in est.ci95)
    messages = [m for m in est.message.split("; ") if m and not m.startswith("relative standard error ")]
    rule = est.method[len(method) + 2:] + " on ln|value| (weights from relative errors)"
    return combined_estimate(name, unit, method, rule, value, se, (lo, hi), est.consistency_p,
                             [sign * math.exp(v) for v in est.per_segment], messages)


def _bias_estimate(est: Estimate) -> Estimate:
    """The rudder bias is often truly zero: a relative-error test would call a clean zero "not
    identified", so b is judged by its absolute standard error instead."""
    if est.success or est.n_segments == 0 or not (math.isfinite(est.value) and math.isfinite(est.stderr)):
        return est
    kept = [m for m in est.message.split("; ") if not m.startswith("relative standard error")]
    if abs(est.value) < 2 * est.stderr:
        kept.insert(0, "b is within 2 standard errors of zero: no rudder bias detected")
    return replace(est, success=True, message="; ".join(kept))


def _damping_matrix(estimates: Mapping[str, Estimate]) -> tuple[np.ndarray, np.ndarray]:
    d = np.full((5, 5), np.nan)
    se = np.full((5, 5), np.nan)
    for i, vel in enumerate(DOFS):
        est = estimates.get(DERIVATIVES[DOF_NAMES[vel]])
        if est is not None and est.success:
            # Fossen: X_u = -D[0, 0], so the matrix holds the negated derivative.
            d[i, i] = -est.value
            se[i, i] = est.stderr
    return d, se


def fit_trial(trial: Trial, segments: Segments, vessel: Vessel, extend: bool = True, model: str = "auto") -> Fits:
    """Fit every segment of a trial and combine the results into coefficients.

    Per segment kind (Fossen 2021 for the damping; Nomoto et al. 1957 for the ship model):

    - ``coast_down`` (surge/sway/yaw): ``y0 exp(-t/T)`` -> ``T_<dof>``, ``X_u``/``Y_v``/``N_r``
      ``= -m_eff/T``.
    - ``step`` (surge/sway/yaw): ``y_ss + (y0 - y_ss) exp(-t/T)`` -> the same ``T`` and derivative,
      plus ``gain_<dof>`` and, when the input is the DOF's generalised force, ``D_gain_<dof>``.
    - ``free_decay`` (roll/pitch): damped cosine -> ``wn_<dof>``, ``zeta_<dof>``,
      ``K_p``/``M_q`` ``= -2 zeta wn I_eff``, ``wn_ratio_<dof>`` against the config's restoring.
    - ``rudder_step`` (yaw): first-order Nomoto -> ``K_nomoto``, ``T_nomoto``.
    - ``zigzag``, ``sinusoid`` (yaw, rudder input): whole-record Nomoto output-error or wave
      prediction-error fit (:func:`pipeline.fit.nomoto_segment.fit_nomoto_segment`) -> ``K_nomoto``,
      ``T_nomoto`` (combined with the rudder steps) and the rudder bias ``b_nomoto`` [rad].

    Repeated segments are combined by an inverse-variance weighted mean with a chi-square
    consistency test (see :func:`pipeline.fit.combine.combine`). A segment that cannot be fitted is
    recorded as a failed :class:`SegmentFit` (and left out of the estimates, with the reason); it
    never stops the other segments.

    Parameters
    ----------
    trial : Trial
        The trial (SI units, radians, uniform clock).
    segments : Segments
        Its segments.
    vessel : Vessel
        Mass, inertia, added mass and restoring; a vessel with only ``name`` gets time constants and
        Nomoto K and T but no damping matrix.
    extend : bool
        Add the joint grey-box results (coupled damping, added mass, identifiability, residual
        tests) with :func:`pipeline.fit.extend.extend_fits` and the damping structure per DOF; False
        gives the single-DOF fits only.
    model : str
        Damping structure per DOF (:func:`pipeline.fit.structure.apply_structures`, with ``extend``):
        ``auto`` (linear or linear + quadratic, chosen by held-out error), ``linear`` (linear only,
        as before structure selection existed), ``quadratic`` (forced) or ``none`` (no joint
        structure fits).

    Returns
    -------
    Fits
        Estimates by name, per-segment fits in segment order, and the 5x5 damping matrix (diagonal
        only; NaN where not identified, including all coupled terms) with its standard errors.
    """
    collector = _Collector(trial, vessel)
    fits = []
    # Several whole-record Nomoto segments: one model structure chosen across them.
    nomoto = _nomoto_without_unsettled_cuts(trial, segments.items)
    for i, seg in enumerate(segments.items):
        sf = settled_at_run_end(nomoto[i] if i in nomoto else _fit_segment(trial, seg))
        fits.append(sf)
        collector.collect(sf)
    estimates = collector.estimates()
    d, se = _damping_matrix(estimates)
    single_dof = Fits(vessel=vessel.name, estimates=estimates, segment_fits=tuple(fits), damping_matrix=d,
                      damping_stderr=se)
    if not extend:
        return single_dof
    if model == "none":
        from .extend import extend_fits

        return extend_fits(single_dof, trial, segments, vessel)
    from .structure import STRUCTURE_DOFS, apply_choices, choices_of, structure_inputs

    # The joint grey-box fit (it starts from the single-DOF diagonal and adds what the single-DOF
    # models cannot give: coupled terms, added mass, identifiability and residual checks) and the
    # damping structure of each DOF (which reads the trial, not the fits) do not depend on each other:
    # they are the units of one ordered_map, handed out largest first as measured on the 30- and 120-minute
    # trials of benchmarks/scaling.py (120 min: grey-box 7.9 s CPU, surge 6.3, roll 3.2, pitch 2.1, yaw 1.1,
    # sway 0.6). The order does not change any result.
    inputs = structure_inputs(trial, segments.items, vessel, model)
    units = (_GREYBOX,) + tuple(sorted(STRUCTURE_DOFS, key=_UNIT_ORDER.index))
    done = dict(zip(units, ordered_map(_extend_unit, units, context=(single_dof, segments, inputs))))
    return apply_choices(done[_GREYBOX], trial, segments.items, vessel,
                         choices_of([done[dof] for dof in STRUCTURE_DOFS]))


#: The grey-box unit of :func:`fit_trial`'s last ordered_map (the others are DOF names).
_GREYBOX = "grey-box"
#: Hand-out order of the DOF units (largest first, as measured).
_UNIT_ORDER = ("surge", "roll", "pitch", "yaw", "sway")


def _extend_unit(context: tuple, unit: str):
    """One unit of :func:`fit_trial`'s last step: the grey-box fits (:func:`pipeline.fit.extend.extend_fits`)
    or one DOF's damping structure (:func:`pipeline.fit.structure.select_dof`)."""
    single_dof, segments, inputs = context
    if unit == _GREYBOX:
        from .extend import extend_fits

        trial, _, vessel, _, _ = inputs
        return extend_fits(single_dof, trial, segments, vessel)
    from .structure import select_dof

    return select_dof(inputs, unit)
