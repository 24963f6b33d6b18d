"""One second-order Nomoto model fitted to all of a trial's rudder steps at once (one ship, one servo).

Where the trial's structure choice keeps the first order without deciding it clearly
(:func:`pipeline.fit.nomoto_structure.choice_is_clear`), the first-order T of each step is biased by
the pole-zero pair it lacks, and a second order fitted step by step is not identified under noise.
Fitted to every step at once (K, T1 + T2, T1 T2, T3, the rudder bias and, with a logged command, the
servo lag shared; per step the initial heading, yaw rate and yaw acceleration), the second order's
first-order equivalent ``T = T1 + T2 - T3`` is the low-frequency lag of the response: the heading's
asymptote in a steady turn lags ``K delta (t - T)`` whatever the structure, so the value holds for a
first-order ship too (``T3 = T2`` cancels). :func:`joint_step_fit` gives it as a
:class:`pipeline.records.JointNomotoT` (with its ``JOINT_T`` note for the user), which
:func:`pipeline.fit.nomoto_joint_value.joint_t_value` uses in place of the fits' combination.

Measured (PythonVehicleSimulator's tanker at 20 m, six 5 and 10 deg steps, measured rudder, no waves,
seeds 0-2): T +1.9, +1.7, +2.5 % with standard errors of 1.1-1.5 % (the best linear fit to the
noise-free record +2.7 %: the ship's speed loss in its turns); the first-order fits' combination was
unsure (a model-structure term of 1.5-2.5 s).

Not used when the servo lag is fitted (a logged command): a first-order servo lag adds to the
response's low-frequency lag exactly as T does (``T1 + T2 - T3 + t_servo``), so only the higher
frequencies of the steps tell them apart, and there the servo's assumed shape (a first-order lag)
decides the split (the same tanker with the logged command, seeds 0-2: correlation of T with the lag
-0.985 to -0.987, T -12.6 +- 7.7 % and +5.5 +- 7.6 %, on seed 0 the lag at its bound;
PythonVehicleSimulator's Clarke83 ship, commanded steps, seed 0: T -8.9 +- 4.1 % with the lag at
1.30 +- 0.09 s; both servos are rate limited, which a first-order lag is not). The note then gives
the sum, which the steps do identify, and T keeps the fits' judgement.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..errors import FitError
from ..model.nomoto import ORDER2_SUM_PRODUCT
from ..model.waves import WaveParams
from ..records import JointNomotoT
from .nomoto_joint_value import JOINT_T
from .nomoto_oe import fit_nomoto
from .nomoto_problem import SERVO_PARAMS
from .nomoto_records import NomotoFit, NomotoRecord

#: Start of the note when the joint fit's T is not used (information only).
JOINT_T_NOT_USED = "joint second-order fit of the rudder steps not used for T:"


def shared_noise(firsts: Sequence[NomotoFit]) -> tuple[str, dict]:
    """The noise model of a joint fit of several records: the wave PEM with the wave model held at the
    records' own fits' medians when most of them chose it, else output error.

    Parameters
    ----------
    firsts : sequence of NomotoFit
        The records' own (first-order) fits.

    Returns
    -------
    noise : str
        ``waves`` or ``white``.
    kw : dict
        ``waves`` and ``noise_var`` for :func:`pipeline.fit.nomoto_oe.fit_nomoto` (empty for ``white``).
    """
    noise = "waves" if 2 * sum(f.noise_model == "waves" for f in firsts) > len(firsts) else "white"
    kw: dict = {}
    wv = [f.waves for f in firsts if f.noise_model == "waves" and f.waves is not None and "psi" in f.noise_var]
    if noise == "waves" and wv:
        kw["waves"] = WaveParams(float(np.median([w.omega0 for w in wv])), float(np.median([w.lam for w in wv])),
                                 float(np.median([w.kw for w in wv])))
        kw["noise_var"] = float(np.median([f.noise_var["psi"] for f in firsts if f.noise_model == "waves"]))
    return noise, kw


def t_gradient(fit: NomotoFit) -> np.ndarray:
    """Gradient of the first-order equivalent T (``T1 + T2 - T3``, or ``T12 - T3``) in the fit's parameters.

    Parameters
    ----------
    fit : NomotoFit
        A second-order fit.
    """
    return np.array([1.0 if n in ("T1", "T2", "T12") else -1.0 if n == "T3" else 0.0 for n in fit.names])


def reported_covariance(fit: NomotoFit) -> np.ndarray:
    """The covariance the fit reports: Newey-West where the residuals stayed coloured, else the plain one.

    Parameters
    ----------
    fit : NomotoFit
        A second-order fit.
    """
    return fit.robust_covariance if fit.robust_covariance is not None else fit.covariance


def t_and_error(fit: NomotoFit) -> tuple[float, float]:
    """First-order equivalent T [s] and its reported standard error [s] (nan when not finite).

    Parameters
    ----------
    fit : NomotoFit
        A second-order fit.
    """
    g, cov = t_gradient(fit), reported_covariance(fit)
    if not np.all(np.isfinite(cov)):
        return fit.T, math.nan
    return fit.T, float(math.sqrt(max(g @ cov @ g, 0.0)))


def usable(fit: NomotoFit) -> bool:
    """Converged, finite, the ship's constants in range (a servo parameter at its bound allowed).

    Parameters
    ----------
    fit : NomotoFit
        A second-order fit.
    """
    return bool(fit.converged and all(n in SERVO_PARAMS for n in fit.at_bound) and np.all(np.isfinite(fit.values))
                and np.all(np.isfinite(fit.stderr[:4])))


def joint_fit(recs: Sequence[NomotoRecord], channels: tuple[str, ...], servo: tuple[str, ...], noise: str,
              kw: dict) -> NomotoFit:
    """The second-order fit of ``recs`` at once (one K, T12, T1T2, T3, rudder bias and servo).

    Output error keeps Newey-West errors where the compass residuals are coloured.

    Parameters
    ----------
    recs : sequence of NomotoRecord
        The rudder steps' records.
    channels : tuple of str
        Channels fitted.
    servo : tuple of str
        Servo parameters fitted (empty for a measured rudder).
    noise : str
        ``white`` or ``waves`` (:func:`shared_noise`).
    kw : dict
        The wave model held for ``waves`` (:func:`shared_noise`).
    """
    return fit_nomoto(list(recs), order=ORDER2_SUM_PRODUCT, noise=noise, channels=channels, servo=servo,
                      robust=noise == "white", **kw)


def joint_step_fit(recs: Sequence[NomotoRecord], firsts: Sequence[NomotoFit], channels: tuple[str, ...],
                   servo: tuple[str, ...], why: str) -> tuple[str, JointNomotoT | None]:
    """The ``JOINT_T`` note of the trial's rudder steps fitted with one second-order model and its T ('' and
    None when the fit is not made; a ``JOINT_T_NOT_USED`` note and None when its T is not to be used).

    The steps into a turn and those out of one were also fitted apart, to add their spread to the
    error; dropped: on a linear ship of the tanker's shape (tests/test_nomoto_joint.py, seed 1) the two
    groups' second-order fits of three records each gave T 11.47 +- 0.38 s and 9.68 +- 0.36 s (z = +3.4,
    truth 9.32 s): three steps do not pin the pole-zero pair, and their errors do not show it.

    Parameters
    ----------
    recs : sequence of NomotoRecord
        The rudder steps' records (two or more).
    firsts : sequence of NomotoFit
        Their own first-order fits (for the noise model, :func:`shared_noise`).
    channels : tuple of str
        Channels every record has.
    servo : tuple of str
        Servo parameters fitted (the same for every record: a logged command).
    why : str
        Why the structure is undecided, for the note.

    Returns
    -------
    note : str
        For the segment fits' messages.
    value : JointNomotoT or None
        T [s] and its standard error where it is to be used.
    """
    if len(recs) < 2 or not channels:
        return "", None
    noise, kw = shared_noise(firsts)
    # The note is one part of a message joined by "; " (read back by splitting on it).
    why = why.replace("; ", ", ")
    head = f"{len(recs)} rudder steps ({why}, one K, T1 + T2, T1 T2, T3, rudder bias{' and servo lag' if servo else ''})"
    try:
        fit = joint_fit(recs, channels, servo, noise, kw)
    except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        return f"{JOINT_T_NOT_USED} the fit of {head} failed ({exc})", None
    if not usable(fit):
        return (f"{JOINT_T_NOT_USED} the fit of {head} did not converge in range "
                f"({', '.join(fit.at_bound) or 'not converged'})"), None
    t, st = t_and_error(fit)
    if not (math.isfinite(st) and st > 0 and t > 0):
        return f"{JOINT_T_NOT_USED} the fit of {head} gave T = {t:.4g} s, not positive or without a finite error", None
    cov = reported_covariance(fit)
    if "t_servo" in fit.names:
        j = fit.names.index("t_servo")
        g = t_gradient(fit)
        lag, slag = fit.value("t_servo"), math.sqrt(max(cov[j, j], 0.0))
        corr = float(g @ cov[:, j] / (st * slag)) if slag > 0 else math.nan
        gs = g.copy()
        gs[j] = 1.0
        s_sum = math.sqrt(max(gs @ cov @ gs, 0.0))
        return (f"{JOINT_T_NOT_USED} the fit of {head} gives T = {t:.4g} +- {st:.2g} s and the servo lag "
                f"{lag:.3g} +- {slag:.2g} s, correlated {corr:+.3f}: a first-order servo lag adds to the response's "
                f"lag as T does, so the steps identify their sum, T + t_servo = {t + lag:.4g} +- {s_sum:.2g} s, and "
                f"the split between them rests on the servo's assumed shape (a rate-limited servo is not a "
                f"first-order lag)"), None
    note = (f"{JOINT_T} {head}: T = {t:.6g} +- {st:.3g} s (T1 + T2 = {fit.value('T12'):.4g} s, T1 T2 = "
            f"{fit.value('T1T2'):.4g} s^2, T3 = {fit.value('T3'):.4g} s, K = {fit.K:.5g} 1/s, "
            f"{fit.noise_model} noise)")
    # The value as the note prints it (T to 6 digits, its error to 3), so that the estimate and the note agree.
    return note, JointNomotoT(float(f"{t:.6g}"), float(f"{st:.3g}"), note)
