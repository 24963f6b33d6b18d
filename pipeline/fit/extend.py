"""Extend the single-DOF fits of a trial: coupled damping, added mass, identifiability, residual checks.

:func:`extend_fits` runs after the single-DOF fits of :func:`pipeline.fit.fit_trial` and returns a
new :class:`~pipeline.records.Fits` (``dataclasses.replace``; nothing is mutated) with

- the coupled lateral derivatives ``Y_r, N_v, K_v, K_r, Y_p, N_p`` of a grey-box fit of the 5-DOF
  model to every sway/roll/yaw record (:mod:`pipeline.fit.greybox`) and their entries of
  ``damping_matrix``/``damping_stderr``; the lateral diagonal re-estimated jointly with them is
  reported beside the single-DOF values as ``Y_v_joint, K_p_joint, N_r_joint`` (the matrix keeps
  the single-DOF diagonal, which needs neither the rudder map nor the coupling model, and takes the
  joint one only where there is no single-DOF value);
- for every coefficient the Fisher information of this trial does not determine:
  ``success=False``, no number, and a message naming the manoeuvre that would determine it
  (:mod:`pipeline.fit.identifiability`);
- ``X_udot``/``Y_vdot``/``N_rdot`` and the thrust-based steady-state damping when the vessel config
  maps thrust (``[thrusters]``, :mod:`pipeline.fit.added_mass`);
- residual whiteness and input cross-correlation tests (:mod:`pipeline.fit.residual_tests`) of
  every segment fit and of the grey-box fit, added to the messages of the estimates they qualify.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Iterable, Mapping

import numpy as np

from ..errors import ConfigError, FitError
from ..records import DOFS, Estimate, Fits, SegmentFit, Segments, Trial
from ..vessel import Vessel
from .added_mass import fit_added_mass
from .combine import failed_estimate
from .data import segment_label
from .greybox import (COEFFICIENTS, COUPLED, DIAGONAL, UNITS, GreyBoxFit, fit_coupled_damping, start_damping,
                      lateral_segments)
from .identifiability import MANOEUVRES, CoefficientStatus, Identifiability, analyse_identifiability
from .least_squares import confidence_interval
from .residual_tests import ResidualTest, segment_fit_residual_test

#: Estimates a segment fit contributes to, by segment kind (``{dof}`` filled in).
_CONTRIBUTES = {
    "coast_down": ("{derivative}", "T_{dof}"),
    "step": ("{derivative}", "T_{dof}", "gain_{dof}", "D_gain_{dof}"),
    "free_decay": ("{derivative}", "wn_{dof}", "zeta_{dof}", "wn_ratio_{dof}"),
    "rudder_step": ("K_nomoto", "T_nomoto"),
}
_DERIVATIVE = {"surge": "X_u", "sway": "Y_v", "roll": "K_p", "pitch": "M_q", "yaw": "N_r"}
#: Suffix of the joint grey-box diagonal estimates (``Y_v_joint``), reported beside the single-DOF ones.
JOINT_SUFFIX = "_joint"
#: Grey-box output channels whose residual tests qualify the lateral coefficients.
LATERAL_CHANNELS = ("v", "p", "r", "phi")
#: Joint and single-DOF diagonal values further apart than this many combined sigmas are flagged.
DIAGONAL_DISAGREEMENT = 3.0


def _append(est: Estimate, note: str) -> Estimate:
    if not note or note in est.message:
        return est
    return replace(est, message="; ".join(m for m in (est.message, note) if m))


def residual_checks(fits: Fits, trial: Trial) -> tuple[dict[str, list[str]], tuple[ResidualTest, ...]]:
    """Residual tests of every segment fit with residuals; failed ones as notes per estimate name.

    Parameters
    ----------
    fits : Fits
        The fits.
    trial : Trial
        The trial (input channels for the cross-correlation test).

    Returns
    -------
    notes : dict[str, list[str]]
        Estimate name -> messages of the failed tests of the segments it comes from.
    tests : tuple[ResidualTest, ...]
        One per segment fit with residuals, in segment order.
    """
    notes: dict[str, list[str]] = {}
    tests = []
    for sf in fits.segment_fits:
        if sf.y.size == 0 or not np.isfinite(sf.y_fit).any():
            continue
        res = segment_fit_residual_test(sf, trial)
        tests.append(res)
        if res.passed:
            continue
        for pattern in _CONTRIBUTES.get(sf.segment.kind, ()):
            name = pattern.format(derivative=_DERIVATIVE.get(sf.segment.dof, ""), dof=sf.segment.dof)
            notes.setdefault(name, []).append(res.message)
    return notes, tuple(tests)


def summarise_residual_tests(tests: Iterable[ResidualTest], what: str) -> str:
    """One sentence on the failed residual tests of a multi-record fit.

    Parameters
    ----------
    tests : iterable of ResidualTest
        Tests named ``"<fit> <channel> [<window>]"`` (the channel is the second word).
    what : str
        Name of the fit for the sentence (``grey-box``).

    Returns
    -------
    str
        Empty when every test passed.
    """
    tests = list(tests)
    total: dict[str, int] = {}
    white: dict[str, int] = {}
    indep: dict[str, int] = {}
    for t in tests:
        ch = t.name.split()[1] if len(t.name.split()) > 1 else t.name
        total[ch] = total.get(ch, 0) + 1
        if not t.white:
            white[ch] = white.get(ch, 0) + 1
        if not t.independent:
            indep[ch] = indep.get(ch, 0) + 1
    parts = []
    if white:
        parts.append(f"{what} residuals not white for " + ", ".join(f"{c} ({k} of {total[c]} records)"
                                                                   for c, k in white.items())
                     + " (coloured noise or unmodelled dynamics: error bars optimistic)")
    if indep:
        parts.append(f"{what} residuals correlated with the inputs for " + ", ".join(
            f"{c} ({k} of {total[c]} records)" for c, k in indep.items())
                     + " (part of the response is not in the model)")
    return "; ".join(parts)


def _failed_coupled(reason: str, names: Iterable[str], method: str) -> dict[str, Estimate]:
    return {n: failed_estimate(n, UNITS[n], method,
                               f"{n} not identified by this trial: {reason}; to determine it run {MANOEUVRES[n]}")
            for n in names}


def _scales(names, damping: np.ndarray) -> np.ndarray:
    # Natural sizes: a diagonal term against its value, a coupled one against a tenth of the
    # geometric mean of the diagonal terms it links (pipeline.fit.identifiability).
    d = np.asarray(damping, float)
    return np.array([abs(d[COEFFICIENTS[n]]) if n in DIAGONAL else
                     0.1 * math.sqrt(abs(d[COEFFICIENTS[n][0], COEFFICIENTS[n][0]])
                                     * abs(d[COEFFICIENTS[n][1], COEFFICIENTS[n][1]])) for n in names])


#: Refits with the undetermined coefficients held, at most.
MAX_REFITS = 3
#: Jacobian evaluations per solve of the first fit (with every coefficient free).
FIRST_FIT_NFEV = 20
#: Relative standard error at the start values above which a coefficient is held before the fit
#: (looser than the final test: the start values may sit where the data are less informative).
SCREEN_RELATIVE_STD = 2.0


def joint_fit(trial: Trial, segments: Segments, vessel: Vessel, d_start: np.ndarray
              ) -> tuple[GreyBoxFit, Identifiability, dict[str, CoefficientStatus]]:
    """Grey-box fit, identifiability analysis, and refits with the undetermined coefficients held.

    A coefficient the Fisher information does not determine is held at its start value (the
    single-DOF diagonal, or 0 for a coupling) and the rest refitted, so that a flat direction does
    not drag the determined coefficients with it; repeated until every remaining one is determined.

    Parameters
    ----------
    trial, segments, vessel
        As for :func:`extend_fits`.
    d_start : numpy.ndarray
        5x5 start damping (``Fits.damping_matrix``).

    Returns
    -------
    gb : GreyBoxFit
        The last fit.
    ident : Identifiability
        Its analysis.
    dropped : dict[str, CoefficientStatus]
        The held coefficients with the status that dropped them.

    Raises
    ------
    FitError
        From :func:`pipeline.fit.greybox.fit_coupled_damping`.
    """
    dropped: dict[str, CoefficientStatus] = {}
    start = np.array(d_start, float, copy=True)
    # Screening: what the Fisher information at the start values says the trial cannot possibly
    # determine (no roll motion, no sway motion) is held before the fit, which keeps the solver
    # out of flat valleys it would wander in.
    # The couplings are probed at their natural size rather than at their zero start: at zero, a
    # coefficient that acts only through a coupling (Y_v on an unmeasured v, through N_v) shows no
    # information at all, which is an artefact of the start point, not of the trial.
    probe, _ = start_damping(start, vessel)
    for n in COUPLED:
        i, j = COEFFICIENTS[n]
        if probe[i, j] == 0.0:
            probe[i, j] = 0.1 * math.sqrt(abs(probe[i, i] * probe[j, j]))
    screen = fit_coupled_damping(trial, segments, vessel, probe, tuple(COEFFICIENTS), solve=False)
    sc = analyse_identifiability(screen.names, screen.values, screen.fisher, _scales(screen.names, screen.damping),
                                 max_relative_std=SCREEN_RELATIVE_STD)
    for n in sc.not_identified:
        st = sc.status[n]
        dropped[n] = replace(st, reasons=st.reasons + ("screened out at the start values",))
    estimate = tuple(n for n in screen.names if n not in dropped)
    if not estimate:
        return screen, sc, dropped
    # The first fit gets fewer iterations: a trial that leaves a direction flat makes the solver
    # crawl, and the analysis of where it got to is enough to find what to hold.
    gb = fit_coupled_damping(trial, segments, vessel, start, estimate, max_nfev=FIRST_FIT_NFEV)
    ident = analyse_identifiability(gb.names, gb.values, gb.fisher, _scales(gb.names, gb.damping), gb.s2)
    if not gb.converged and not ident.not_identified:
        # Nothing looks flat: the solver only needs more iterations; carry on from where it stopped.
        gb = fit_coupled_damping(trial, segments, vessel, np.array(gb.damping, float), estimate)
        ident = analyse_identifiability(gb.names, gb.values, gb.fisher, _scales(gb.names, gb.damping), gb.s2)
    for _ in range(MAX_REFITS):
        bad = list(ident.not_identified)
        if not bad and not gb.converged and len(gb.names) > 1:
            # Nothing fails the Fisher tests, yet the solver did not settle: hold the least
            # determined coefficient, whose flat direction is the likeliest cause.
            worst = max(gb.names, key=lambda n: ident.status[n].relative_std)
            st = ident.status[worst]
            dropped[worst] = replace(st, identified=False, reasons=st.reasons + (
                f"the fit did not converge with it free and it is the least determined coefficient "
                f"(relative standard error {st.relative_std:.0%})",))
            bad = [worst]
        if not bad:
            break
        for n in bad:
            dropped.setdefault(n, ident.status[n])
        estimate = tuple(n for n in gb.names if n not in bad)
        # Warm start for the kept coefficients; the held ones go back to their start values.
        warm = np.array(gb.damping, float, copy=True)
        for n in dropped:
            i, j = COEFFICIENTS[n]
            warm[i, j] = d_start[i, j] if i == j else 0.0
        if not estimate:
            break
        gb = fit_coupled_damping(trial, segments, vessel, warm, estimate)
        ident = analyse_identifiability(gb.names, gb.values, gb.fisher, _scales(gb.names, gb.damping), gb.s2)
    return gb, ident, dropped


def _greybox_estimates(fits: Fits, gb: GreyBoxFit, ident: Identifiability, dropped: Mapping[str, CoefficientStatus],
                       n_segments: int) -> tuple[dict[str, Estimate], np.ndarray, np.ndarray]:
    """Estimates, damping matrix and standard errors from a grey-box fit and its identifiability."""
    # Pitch (q, theta) rides along for the kinematics with its damping held: its residuals say
    # nothing about the lateral coefficients, so only the lateral channels are summarised.
    lateral = [t for t in gb.residual_tests if t.name.split()[1:2] and t.name.split()[1] in LATERAL_CHANNELS]
    test_notes = [m for m in (summarise_residual_tests(lateral, "grey-box"),) if m]
    if dropped:
        held_at, its = ("its start value", "its") if len(dropped) == 1 else ("their start values", "their")
        test_notes.append(f"conditional on {', '.join(sorted(dropped))} held at {held_at}: {its} uncertainty is "
                          f"not in this error bar")
    d = np.array(fits.damping_matrix, float, copy=True)
    se = np.array(fits.damping_stderr, float, copy=True)
    out: dict[str, Estimate] = {}
    dof = max(gb.n - len(gb.names), 1)
    held = sorted(dropped)
    method = gb.method + (f"; {', '.join(held)} not determined by this trial and held at their start values "
                          f"(diagonal: single-DOF value; coupling: 0) in the final fit" if held else "")
    statuses = {**dropped, **{n: ident.status[n] for n in gb.names}}
    values = dict(zip(gb.names, gb.values))
    errors = dict(zip(gb.names, gb.stderr))
    for n in COEFFICIENTS:
        ij = COEFFICIENTS[n]
        # The joint diagonal is reported beside the single-DOF one (``Y_v_joint``), which stays
        # the table's and the matrix's value: it needs no rudder map and no coupling model.
        name = f"{n}{JOINT_SUFFIX}" if n in DIAGONAL else n
        st = statuses.get(n)
        notes = [m for m in (gb.message,) if m]
        if st is not None and n in values and not gb.converged:
            st = replace(st, identified=False, reasons=st.reasons + ("the grey-box solver did not converge",))
        if st is None or not st.identified or n not in values:
            if st is None:
                # Held for a reason the fit gave (no roll channel, say), not by the Fisher analysis.
                why = gb.fixed.get(n, "not estimated")
                text = f"{n} not identified by this trial: {why}; to determine it run {MANOEUVRES[n]}"
            else:
                text = st.message
            out[name] = failed_estimate(name, UNITS[n], method, "; ".join([text] + notes))
            if n in COUPLED:
                d[ij], se[ij] = np.nan, np.nan
            continue
        value, err = float(values[n]), float(errors[n])
        if st.reasons:
            notes.insert(0, st.message)
        if n in DIAGONAL:
            old = fits.estimates.get(n)
            if old is not None and old.success and math.isfinite(old.stderr):
                z = (value - old.value) / math.hypot(err, old.stderr)
                notes.append(f"single-DOF {n} = {old.value:.5g} +- {old.stderr:.2g} ({old.method.split(';')[0]})")
                if abs(z) > DIAGONAL_DISAGREEMENT:
                    notes.append(f"joint and single-DOF values differ by {z:+.1f} sigma: coupling the single-DOF "
                                 f"fit ignores, or a wrong rudder map (yaw_moment, sway_force) or mass matrix")
            elif not math.isfinite(d[ij]):
                # No single-DOF value: the joint one is the best the trial gives for the matrix.
                d[ij], se[ij] = -value, err
                notes.append(f"no single-DOF {n}: D[{ij[0]},{ij[1]}] takes the joint value")
        notes += test_notes
        out[name] = Estimate(name=name, value=value, stderr=err, ci95=confidence_interval(value, err, dof),
                             unit=UNITS[n], n_segments=n_segments, method=method, success=True,
                             message="; ".join(notes))
        if n in COUPLED:
            d[ij], se[ij] = -value, err
    return out, d, se


def extend_fits(fits: Fits, trial: Trial, segments: Segments, vessel: Vessel) -> Fits:
    """Add coupled damping, added mass, identifiability and residual-test messages to ``fits``.

    Parameters
    ----------
    fits : Fits
        Output of :func:`pipeline.fit.fit_trial` for this trial (its diagonal damping starts the
        grey-box fit).
    trial : Trial
        The trial.
    segments : Segments
        Its segments.
    vessel : Vessel
        Rigid-body data, restoring, the rudder map and optional ``[thrusters]``.

    Returns
    -------
    Fits
        A new record: estimates ``Y_r, N_v, K_v, K_r, Y_p, N_p`` [Fossen signs, ``Y_r = -D[1, 4]``;
        kg m/s or kg m^2/s] and ``Y_v_joint, K_p_joint, N_r_joint`` (the joint diagonal; the
        single-DOF ``Y_v, K_p, N_r`` are left as they are), ``X_udot`` etc. when thrust is mapped,
        ``damping_matrix``/``damping_stderr`` with the coupled entries of the joint fit (NaN where
        not identified), and residual-test messages. A vessel without rigid-body data gets only the
        residual-test messages; a trial without segments gets nothing added.

    Raises
    ------
    ConfigError
        A malformed ``[thrusters]`` table.
    """
    if not segments.items:
        # Nothing was run, so nothing is claimed either way (fit_trial's empty result stays empty).
        return replace(fits)
    estimates = dict(fits.estimates)
    d, se = np.array(fits.damping_matrix, float), np.array(fits.damping_stderr, float)

    if vessel.has_rigid_body:
        lat = lateral_segments(segments, vessel)
        try:
            gb, ident, dropped = joint_fit(trial, segments, vessel, fits.damping_matrix)
        except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError, RuntimeError) as exc:
            # Whatever stops the joint fit (casadi raises RuntimeError) must not cost the user the
            # single-DOF results: the coupled terms are reported as not identified, with the reason.
            reason = (str(exc) if isinstance(exc, FitError)
                      else f"the grey-box fit failed with {type(exc).__name__}: {exc}")
            method = "grey-box output-error fit of the linear 5-DOF model (pipeline.fit.greybox)"
            estimates.update(_failed_coupled(reason, COUPLED, method))
            for n in COUPLED:
                d[COEFFICIENTS[n]], se[COEFFICIENTS[n]] = np.nan, np.nan
        else:
            new, d, se = _greybox_estimates(fits, gb, ident, dropped, len(lat))
            estimates.update(new)
        try:
            estimates.update(fit_added_mass(fits, trial, vessel))
        except ConfigError:
            raise
        except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
            # A pathological step must not cost the user the coupled terms.
            names = [n for n in ("X_udot", "Y_vdot", "N_rdot") if n in estimates]
            for n in names:
                estimates[n] = _append(estimates[n], f"added mass failed: {exc}")

    notes, _ = residual_checks(fits, trial)
    for name, msgs in notes.items():
        if name in estimates:
            for m in msgs:
                estimates[name] = _append(estimates[name], m)
    return replace(fits, estimates=estimates, damping_matrix=d, damping_stderr=se)


__all__ = ["extend_fits", "joint_fit", "residual_checks", "summarise_residual_tests"]
