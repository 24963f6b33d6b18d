"""Damping structure chosen by the data: linear or linear + quadratic, per DOF, by held-out error.

Both structures are fitted jointly to every segment of the DOF (:mod:`pipeline.fit.quadratic`).
Held-out error: with three or more segments each fold leaves whole segments out (at most
``MAX_FOLDS`` folds); with fewer, each fold leaves one time quarter of every segment out. The
shared parameters are refitted on the training data; a left-out segment's initial state is
fitted on its own samples with the shared parameters held (equal for both structures). The
quadratic structure is selected only when it passes the significance rule the gap diagnosis
uses (:func:`pipeline.fit.heldout_test.is_significant`: held-out F test with an effective sample
size, robust to the most favourable fold, a minimum gap shrink and a minimum error explained);
otherwise the linear one, which is also what ``--model linear`` forces.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Mapping, Sequence

import numpy as np

from ..errors import FitError
from ..parallel import ordered_map
from ..records import DOF_NAMES, DOFS, DampingFit, DecayAnalysis, Estimate, Fits, Segment, StructureChoice, Trial
from ..vessel import Vessel
from .coupling import coupling_note
from .current import check_current
from .start_transient import start_transient_note
from .decay_analysis import analyse_decays
from .heldout_test import heldout_gain, is_significant
from .least_squares import confidence_interval
from .segment_fit import MAX_RELATIVE_STDERR
from .steady_map import steady_points
from .quadratic import (TERM_NAMES, SteadyPoint, decimate_records, dof_records, expand_linear, fit_dof, problem, solve,
                        start_vector)

#: Most folds of the leave-segments-out split.
MAX_FOLDS = 5
#: Time blocks per segment when there are too few segments to leave whole ones out.
TIME_BLOCKS = 4
#: Blocks of each segment in one fold.
BLOCKS_PER_FOLD = 4
#: Structures a user may force.
MODELS = ("auto", "linear", "quadratic")
#: DOFs whose damping structure is chosen (one unit of work each: :func:`select_dof`).
STRUCTURE_DOFS = ("surge", "sway", "roll", "pitch", "yaw")


def _folds(mask: np.ndarray) -> tuple[list[np.ndarray], str]:
    """Held-out masks (records x samples), and how they were made."""
    k, n = mask.shape
    if k >= 3:
        nf = min(k, MAX_FOLDS)
        out = []
        for f in range(nf):
            m = np.zeros_like(mask)
            m[f::nf] = mask[f::nf]
            out.append(m)
        return out, f"{nf}-fold leave-segments-out over {k} segments"
    out = []
    for j in range(TIME_BLOCKS):
        m = np.zeros_like(mask)
        for i in range(k):
            idx = np.flatnonzero(mask[i])
            # Short blocks interleaved over the whole record, so that training covers the whole
            # amplitude range and the test is interpolation, not extrapolation, for both structures.
            for block in np.array_split(idx, BLOCKS_PER_FOLD * TIME_BLOCKS)[j::TIME_BLOCKS]:
                m[i, block] = True
        out.append(m)
    return out, (f"{TIME_BLOCKS} folds of interleaved time blocks ({BLOCKS_PER_FOLD} per segment and fold) "
                 f"over {k} segment(s)")


def _heldout(records, dof, dt, mass, steady, lin_full: DampingFit, folds, quad_full: DampingFit | None = None,
             drift: bool = False):
    """Held-out simulation residuals (records x samples, NaN off the test set) per structure; each
    structure's folds start from its own fit to all data."""
    res = {}
    for structure in ("linear", "quadratic"):
        p = problem(records, dof, dt, mass, structure, steady, drift)
        full = quad_full if (structure == "quadratic" and quad_full is not None) else lin_full
        theta_full = expand_linear(np.concatenate([full.values, full.initial_states]), p) if full is lin_full else \
            np.concatenate([full.values, full.initial_states])
        out = np.full(p.Y.shape, np.nan)
        for test in folds:
            train = p.mask & ~test
            th = solve(p, theta_full, train, max_nfev=40)
            # Segments left out entirely get their initial state from their own samples, shared held.
            lone = ~train.any(axis=1) & test.any(axis=1)
            if lone.any():
                th = solve(p, th, test & lone[:, None], fixed_shared=True, max_nfev=40)
            yhat = p.simulate(th)
            out[test] = (p.Y - yhat)[test]
        res[structure] = out
    return res, p


def select_structure(records, dof: str, dt: float, mass: float, model: str = "auto",
                     steady: Sequence[SteadyPoint] = (), drift: bool = False) -> StructureChoice:
    """Fit both damping structures to the records of one DOF and choose one by held-out error.

    Parameters
    ----------
    records : Sequence[DofRecord]
        From :func:`pipeline.fit.quadratic.dof_records` (decimated inside).
    dof : str
        DOF name.
    dt : float
        Sample interval of the records [s].
    mass : float
        ``M_ii`` from the vessel config [kg or kg m^2] (NaN: no Fossen derivatives).
    model : str
        ``auto`` (held-out choice), ``linear`` (only the linear structure is fitted) or
        ``quadratic`` (forced; both are fitted and scored so the report shows the other).
    steady : Sequence[SteadyPoint]
        Steady force-speed points fitted with the transients.
    drift : bool
        Both structures get a constant velocity offset per segment (speed over ground against speed
        through the water: a current along the track).

    Returns
    -------
    StructureChoice

    Raises
    ------
    FitError
        Unknown ``model`` or no usable record.
    """
    if model not in MODELS:
        raise FitError(f"--model: expected one of {list(MODELS)}, found {model!r}")
    records, dt, _ = decimate_records(records, dt, dof)
    lin = fit_dof(records, dof, dt, mass, "linear", steady, drift=drift)
    if model == "linear":
        return StructureChoice(dof, "linear", {"linear": lin}, {"linear": math.nan}, math.nan, math.nan, math.nan,
                               math.nan, False, "not scored", requested="linear",
                               message="linear structure forced (--model linear)")
    quad = fit_dof(records, dof, dt, mass, "quadratic", steady,
                   start=np.concatenate([lin.values, lin.initial_states]), drift=drift)
    fits = {"linear": lin, "quadratic": quad}
    p0 = problem(records, dof, dt, mass, "linear", steady, drift)
    folds, how = _folds(p0.mask)
    resid, p = _heldout(records, dof, dt, mass, steady, lin, folds, quad, drift)
    e0, e1 = resid["linear"], resid["quadratic"]
    rms = {s: float(np.sqrt(np.nanmean(r**2))) for s, r in resid.items()}
    vals = p.Y[p.mask]
    scale = max(float(np.std(vals)), 1e-12)
    noise = float(np.median([r.sigma for r in records])) / scale
    # Windows of the F test: each record's held-out part in each fold (rows), fold index per row.
    rows0, rows1, fold_of = [], [], []
    for f, test in enumerate(folds):
        for i in range(test.shape[0]):
            if test[i].any():
                rows0.append(np.where(test[i], e0[i], np.nan) / scale)
                rows1.append(np.where(test[i], e1[i], np.nan) / scale)
                fold_of.append(f)
    r0, r1, fold_of = np.array(rows0), np.array(rows1), np.array(fold_of)
    cs, shrink, p_rob = heldout_gain(records[0].channel, r0, r1, fold_of, len(folds), noise)
    pv = cs.p_value if math.isfinite(cs.p_value) else 1.0
    sig = is_significant(pv, p_rob, shrink, cs.explained) and quad.success
    chosen = "quadratic" if (model == "quadratic" or (model == "auto" and sig)) else "linear"
    why = (f"held-out RMS error linear {rms['linear']:.4g}, quadratic {rms['quadratic']:.4g} "
           f"({shrink:+.1f} % gap shrink, p = {pv:.2g}, robust p = {p_rob:.2g}, explained {cs.explained:.3g} of scale; "
           f"{how})")
    if model == "quadratic":
        why = "quadratic structure forced (--model quadratic); " + why
    elif not sig:
        why = "quadratic term not significant on held-out data: " + why
    else:
        why = "quadratic term significant on held-out data: " + why
    return StructureChoice(dof, chosen, fits, rms, pv, p_rob, float(shrink), float(cs.explained), bool(sig), how,
                           requested=model, message=why)


def select_structures(trial: Trial, segments: Sequence[Segment], vessel: Vessel, model: str = "auto",
                      steady: dict | None = None) -> dict[str, StructureChoice]:
    """:func:`select_structure` for every DOF that has segments the joint fit can use.

    Parameters
    ----------
    trial : Trial
        The trial.
    segments : Sequence[Segment]
        Its segments.
    vessel : Vessel
        Config (``M_ii`` per DOF; without rigid-body data the fits are normalised by it).
    model : str
        ``auto``, ``linear`` or ``quadratic``.
    steady : dict, optional
        DOF -> steady force-speed points.

    Returns
    -------
    dict[str, StructureChoice]
        DOF -> choice; a DOF whose joint fit fails is left out (the single-DOF fits still stand).
    """
    # The DOFs are independent: worker processes choose them side by side when the cores allow.
    chosen = ordered_map(select_dof, STRUCTURE_DOFS, context=(trial, segments, vessel, model, steady or {}))
    return choices_of(chosen)


def structure_inputs(trial: Trial, segments: Sequence[Segment], vessel: Vessel, model: str = "auto") -> tuple:
    """What :func:`select_dof` reads: ``(trial, segments, vessel, model, steady points by DOF)``, the
    steady points from the vessel config's ``[steady_state]`` (:func:`pipeline.fit.steady_map.steady_points`).

    Parameters
    ----------
    trial : Trial
        The aligned trial.
    segments : Sequence[Segment]
        All of its segments (each DOF picks its own).
    vessel : Vessel
        Config: ``M_ii`` per DOF and the optional ``[steady_state]`` table.
    model : str
        One of ``MODELS``.

    Raises
    ------
    FitError
        ``model`` is not one of ``MODELS``.
    """
    if model not in MODELS:
        raise FitError(f"--model: expected one of {list(MODELS)}, found {model!r}")
    steady = steady_points(vessel.extra["steady_state"]) if "steady_state" in dict(vessel.extra or {}) else None
    return trial, segments, vessel, model, steady or {}


def choices_of(chosen: Sequence[StructureChoice | None]) -> dict[str, StructureChoice]:
    """DOF -> choice from :func:`select_dof`'s results in ``STRUCTURE_DOFS`` order (failed DOFs left out).

    Parameters
    ----------
    chosen : Sequence[StructureChoice or None]
        One result per DOF of ``STRUCTURE_DOFS``, in that order.
    """
    return {dof: c for dof, c in zip(STRUCTURE_DOFS, chosen) if c is not None}


def select_dof(inputs: tuple, dof: str) -> StructureChoice | None:
    """:func:`select_structure` of one DOF with its notes; None when it has no records or its joint fit fails.

    Parameters
    ----------
    inputs : tuple
        From :func:`structure_inputs`.
    dof : str
        One of ``STRUCTURE_DOFS``.
    """
    trial, segments, vessel, model, steady = inputs
    dt = 1.0 / trial.fs
    recs = dof_records(trial, segments, dof)
    if not recs:
        return None
    mass = vessel.effective_mass(dof) if vessel.has_rigid_body else math.nan
    try:
        choice = select_structure(recs, dof, dt, mass, model, steady.get(dof, ()))
    except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError):
        return None
    notes = [coupling_note(vessel, dof, choice.fits[choice.selected])]
    try:
        notes.append(check_current(trial, recs, dof, dt, mass, choice, select_structure, steady.get(dof, ())))
    except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError):
        pass
    notes.append(start_transient_note(choice, recs, dt))
    if any(notes):
        choice = replace(choice, message="; ".join([choice.message] + [n for n in notes if n]))
    return choice


def _joint_estimate(fit: DampingFit, name: str, choice: StructureChoice, n_segments: int) -> Estimate:
    value, se, unit = fit.terms[name]
    other = "linear" if choice.selected == "quadratic" else "quadratic"
    method = (f"joint output-error fit of M_ii nu_dot + D nu + D2 |nu| nu (+ G eta) = tau over {n_segments} "
              f"{choice.dof} segment(s), {fit.structure} structure; M_ii from the vessel config; "
              f"structure chosen by held-out error ({choice.folds})")
    msg = [f"{choice.selected} structure selected over {other}: {choice.message}"]
    if fit.message:
        msg.append(fit.message)
    ok = fit.success and math.isfinite(se) and se > 0
    if ok and abs(se) > MAX_RELATIVE_STDERR * abs(value):
        ok = False
        msg.insert(0, f"relative standard error {se / abs(value) if value else math.inf:.0%} above "
                      f"{MAX_RELATIVE_STDERR:.0%}: not identified")
    return Estimate(name=name, value=value, stderr=se, ci95=confidence_interval(value, se, fit.dof_resid), unit=unit,
                    n_segments=n_segments, method=method, success=ok, message="; ".join(msg))


def structure_estimates(estimates: Mapping[str, Estimate], choices: Mapping[str, StructureChoice]) -> dict[str, Estimate]:
    """Estimates with each DOF's damping taken from the structure the data chose.

    Where the quadratic structure wins, the linear derivative (``X_u``) and the quadratic one
    (``X_|u|u``) come from the joint quadratic fit (single-DOF exponential fits are biased when the
    damping is quadratic). Where the linear structure wins, the single-DOF estimate stays (or the
    joint linear fit's when no single-DOF fit was made) and its message names the rejected
    quadratic model and both held-out errors; a failed single-DOF estimate stays failed, with the
    joint value in its message only.

    Parameters
    ----------
    estimates : Mapping[str, Estimate]
        The fit stage's estimates.
    choices : Mapping[str, StructureChoice]
        From :func:`select_structures`.

    Returns
    -------
    dict[str, Estimate]
        A new mapping; the input is not modified.
    """
    out = dict(estimates)
    for dof, choice in choices.items():
        lin_name, quad_name = TERM_NAMES[dof]
        fit = choice.fits[choice.selected]
        if lin_name not in fit.terms:
            continue
        n_seg = len(fit.y_fit)
        if choice.selected == "quadratic":
            out[lin_name] = _joint_estimate(fit, lin_name, choice, n_seg)
            out[quad_name] = _joint_estimate(fit, quad_name, choice, n_seg)
            continue
        old = out.get(lin_name)
        if old is None:
            out[lin_name] = _joint_estimate(fit, lin_name, choice, n_seg)
        elif not old.success:
            # The single-segment fits failed on these very segments (too short, no excitation, ...):
            # a joint fit of the same data would hide that reason behind a number, so it is only noted.
            joint = _joint_estimate(fit, lin_name, choice, n_seg)
            note = (f"joint linear fit over the same segments gave {joint.value:.4g} +- {joint.stderr:.2g} "
                    f"{joint.unit}, not used because the single-segment fits failed")
            out[lin_name] = replace(old, message="; ".join(m for m in (old.message, note) if m))
        else:
            note = f"linear structure kept: {choice.message}"
            out[lin_name] = replace(old, message="; ".join(m for m in (old.message, note) if m))
    return out


def apply_structures(fits: Fits, trial: Trial, segments: Sequence[Segment], vessel: Vessel,
                     model: str = "auto") -> Fits:
    """``fits`` with the damping structure chosen per DOF (:func:`select_structures`; the vessel
    config's ``[steady_state]`` points, :func:`pipeline.fit.steady_map.steady_points`, enter the same
    joint fit as the transients), the damping
    matrix diagonal taken from the chosen structure's linear terms, and the roll/pitch extinction
    analyses (:func:`pipeline.fit.decay_analysis.analyse_decays`) with the effective inertia
    ``I_eff_<dof> = C / wn^2`` beside the config's.

    Parameters
    ----------
    fits : Fits
        Result of the single-DOF (and grey-box) fits.
    trial : Trial
        The trial.
    segments : Sequence[Segment]
        Its segments.
    vessel : Vessel
        Config.
    model : str
        ``auto``, ``linear`` or ``quadratic``.

    Returns
    -------
    Fits
        A new record with ``structures`` filled.
    """
    inputs = structure_inputs(trial, segments, vessel, model)
    return apply_choices(fits, trial, segments, vessel, select_structures(*inputs))


def apply_choices(fits: Fits, trial: Trial, segments: Sequence[Segment], vessel: Vessel,
                  choices: Mapping[str, StructureChoice]) -> Fits:
    """:func:`apply_structures` with the choices already made (:func:`select_structures`, or
    :func:`select_dof` per DOF as units of another ``ordered_map``: :func:`pipeline.fit.trial.fit_trial`).

    Parameters
    ----------
    fits : Fits
        The fits the choices are applied to (single-DOF and grey-box).
    trial : Trial
        The trial (roll and pitch extinction analyses).
    segments : Sequence[Segment]
        The trial's segments.
    vessel : Vessel
        Config (restoring, for the effective inertia).
    choices : Mapping[str, StructureChoice]
        DOF -> choice; a DOF left out keeps its single-DOF fits.

    Returns
    -------
    Fits
        A new record with ``structures`` filled.
    """
    decays = {dof: a for dof in ("roll", "pitch") if (a := analyse_decays(trial, segments, vessel, dof)) is not None}
    if decays:
        fits = replace(fits, estimates={**fits.estimates, **inertia_estimates(decays)}, decay_analyses=decays)
    if not choices:
        return fits
    estimates = structure_estimates(fits.estimates, choices)
    d = np.array(fits.damping_matrix, float, copy=True)
    se = np.array(fits.damping_stderr, float, copy=True)
    for i, vel in enumerate(DOFS):
        est = estimates.get(TERM_NAMES[DOF_NAMES[vel]][0])
        if est is not None and est.success:
            d[i, i], se[i, i] = -est.value, est.stderr
    return replace(fits, estimates=estimates, damping_matrix=d, damping_stderr=se, structures=choices)


def inertia_estimates(decays: Mapping[str, DecayAnalysis]) -> dict[str, Estimate]:
    """``I_eff_<dof> = C / wn^2`` from each pooled extinction analysis, with the config's in the message.

    Parameters
    ----------
    decays : Mapping[str, DecayAnalysis]
        DOF -> analysis.

    Returns
    -------
    dict[str, Estimate]
        Only DOFs whose restoring is known.
    """
    out = {}
    for dof, a in decays.items():
        c = a.curves["combined"]
        if not math.isfinite(c.inertia_fit):
            continue
        ok = math.isfinite(c.inertia_fit_se) and c.inertia_fit_se > 0
        msg = (f"config M_ii = {a.inertia_config:.4g} kg m^2 ({c.inertia_fit / a.inertia_config:.3g} x)"
               if math.isfinite(a.inertia_config) else "config gives no inertia")
        out[f"I_eff_{dof}"] = Estimate(
            f"I_eff_{dof}", c.inertia_fit, c.inertia_fit_se,
            confidence_interval(c.inertia_fit, c.inertia_fit_se, max(c.phi_m.size, 1)), "kg m^2", c.n_decays,
            f"effective inertia C / wn^2 with C = {a.restoring:.4g} N m/rad from the config and wn from the "
            f"extrema times of {c.n_decays} free decay(s)", ok, msg)
    return out
