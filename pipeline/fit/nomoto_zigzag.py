"""A lone zig-zag whose speed rises in its turns, fitted on the distance sailed.

A 10/10 zig-zag sails at full rudder and drift for most of its record. Where the ship *speeds up* in its
turns at constant propeller speed (PythonVehicleSimulator's Clarke83 ship: +3.5 % in its 10 deg zig-zag,
the rudder's drag term ``-X_dd sin^2 delta`` pushing it on), a linear manoeuvring model whose damping scales
with the speed and whose rudder force with its square is, in the distance-sailed time, the model at the
straight-run speed ``U0`` (:mod:`pipeline.model.nomoto`, "Speed-scaled Nomoto";
:func:`pipeline.fit.nomoto_retime.retime_record`). At constant time the record mixes faster and slower
dynamics and neither structure holds: measured on the noise-free 10/10 zig-zag of Clarke83 (second-order
truth K = 0.0869 1/s, T = T1 + T2 - T3 = 2.66 s), second order K -2.6 %, T -20 %; first order K +18 %,
T +89 %; re-timed, second order K -2.3 %, T -2.7 % (its residual 0.1 mrad against 1.0 mrad at constant
time), first order K +15 %, T +95 %.

:func:`retimed_zigzag_fit` chooses the structure and the time base on the record's held-out end by output
error, fits the chosen second order to the whole re-timed record, and states its uncertainty:

- K: one amplitude cannot separate the rudder force's curvature from K (rudder steps of several amplitudes
  do, :mod:`pipeline.fit.nomoto_amplitude`; a sinusoid re-timed read K -0.9 to -1.0 % with its intervals
  missing, ident36). K is read at zero rudder on a lift growing as ``sin(2 delta) / 2`` (Fossen 2021,
  sec. 9.5.1; :func:`rudder_curvature_term`, 2.0 % at 10 deg) and the correction itself is a model term of
  its error, so that a linear rudder force stays inside the interval.
- T = T1 + T2 - T3 is a small difference of large time constants: the measured rudder's own noise moves it
  beyond its standard error (:func:`rudder_noise_terms`, a term), and a servo lag fitted from a logged command
  moves it more (:func:`servo_t_note`: T unsure).

A ship that *slows* in its turns is not re-timed (the rudder in the propeller race keeps its force as
the damping falls: measured, PythonVehicleSimulator's tanker at 20 m: re-timed K -2.2 -> -4.6 %, its
residual 0.40 -> 0.85 mrad; at 25 m K +7.0 -> +9.9 %, T -11 -> -28 %, residual 0.88 -> 3.3 mrad); a
Norrbin cubic yaw-rate term did not help there either (noise-free, second order: tanker at 20 m K -2.2 ->
+0.6 %, T +2.5 -> -6.4 %; at 25 m K +7.0 -> +10 %, T -11 -> -16 %, the residual unchanged). Those zig-zags keep
the per-segment choice (:func:`pipeline.fit.nomoto_structure.lone_segment_fit`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.ndimage import uniform_filter1d

from ..errors import FitError
from ..model.nomoto import ORDER2_SUM_PRODUCT
from ..records import Segment, SegmentFit, Trial
from .heldout_test import MIN_SHRINK
from .nomoto_oe import fit_nomoto
from .nomoto_problem import unwrap_heading
from .nomoto_quality import STRUCTURE_TERM, STRUCTURE_UNDECIDED, largest_noted
from .nomoto_records import NomotoFit
from .nomoto_retime import retime_record
from .nomoto_segment import (LEAD_SPEED_SECONDS, MIN_SAMPLES, RETIME_MAX, RETIME_SMOOTH_SECONDS, RETIMED, SPEED_RETIME,
                             NomotoWindow, fit_window, fit_window_order)

#: Words of the speed-loss term of a zig-zag that slows in its turns (:func:`speed_loss_terms`).
SPEED_LOSS_TERM = "the zig-zag lost"
#: Note head of the rudder-curvature correction of a re-timed zig-zag's K.
CURVATURE_NOTE = "K corrected for the rudder force's curvature"


def zigzag_speed(trial: Trial, win: NomotoWindow) -> tuple[str, float, np.ndarray] | None:
    """The speed channel, the straight-run speed ``U0`` [m/s] and the smoothed speed at the window's samples
    [m/s] (a ``RETIME_SMOOTH_SECONDS`` moving mean), or None when the trial logs no surge speed ``u`` or no
    steady straight run before the zig-zag.

    ``U0`` is the median surge speed of the last ``LEAD_SPEED_SECONDS`` before the zig-zag starts, taken when
    the rudder lay within 0.5 deg of its median there (the straight run the speed-loss note of
    :func:`pipeline.fit.nomoto_segment.prepare_window` reads too).

    Parameters
    ----------
    trial : Trial
        The trial.
    win : NomotoWindow
        The zig-zag's prepared window (its record on the trial clock).
    """
    if not (trial.has("u") and trial.has("delta")):
        return None
    seg = win.segment
    lead = trial.window(seg.t_start - LEAD_SPEED_SECONDS, seg.t_start)
    lead = lead[lead["t"] < seg.t_start]
    if len(lead) < MIN_SAMPLES:
        return None
    d = lead["delta"].to_numpy(dtype=float)
    u_lead = np.abs(lead["u"].to_numpy(dtype=float))
    ok = np.isfinite(d) & np.isfinite(u_lead)
    if ok.sum() < MIN_SAMPLES or float(np.max(np.abs(d[ok] - np.median(d[ok])))) > math.radians(0.5):
        return None
    u0 = float(np.median(u_lead[ok]))
    if not u0 > 0:
        return None
    t_all = np.asarray(trial.t, float)
    u_all = np.abs(trial.data["u"].to_numpy(dtype=float))
    fin = np.isfinite(u_all)
    h = float(np.median(np.diff(t_all)))
    smooth = uniform_filter1d(u_all[fin], max(1, int(round(RETIME_SMOOTH_SECONDS / h))), mode="nearest")
    return "u", u0, np.interp(np.asarray(win.rec.t, float), t_all[fin], smooth)


def retimed_zigzag_window(trial: Trial, win: NomotoWindow) -> NomotoWindow | None:
    """The zig-zag's window re-timed on the distance sailed where its speed rises in the turns, else None.

    The same conditions as a rudder step's re-timing (:func:`pipeline.fit.nomoto_segment.retime_window`):
    the smoothed surge speed rises above ``U0`` by more than ``SPEED_RETIME`` and at most ``RETIME_MAX``,
    by more than it falls below it, ``U0`` being the straight run's just before the zig-zag
    (:func:`zigzag_speed`).

    Parameters
    ----------
    trial : Trial
        The trial (``u`` logged).
    win : NomotoWindow
        The zig-zag's prepared window (not re-timed).
    """
    seg: Segment = win.segment
    if seg.kind != "zigzag":
        return None
    sp = zigzag_speed(trial, win)
    if sp is None:
        return None
    ch, u0, u = sp
    if not (np.all(np.isfinite(u)) and np.all(u > 0.5 * u0)):
        return None
    rise, fall = float(np.max(u - u0)) / u0, float(np.max(u0 - u)) / u0
    if not (SPEED_RETIME < rise <= RETIME_MAX and rise >= fall):
        return None
    try:
        rec = retime_record(win.rec, u, u0)
    except FitError:
        return None
    if rec.t.size < MIN_SAMPLES:
        return None
    note = (f"{RETIMED}: the zig-zag's logged speed ({ch}, {RETIME_SMOOTH_SECONDS:g} s mean) rises above the "
            f"straight-run speed U0 = {u0:.4g} m/s by up to +{rise:.2%} in its turns (above {SPEED_RETIME:.0%}): "
            f"fitted in tau = integral of u / U0 dt, K and T are the speed-scaled model's at U0")
    start = float(win.rec.t[0]) - float(win.t_rel[0])
    t_rel = np.asarray(rec.t, float) - start
    return replace(win, rec=rec, notes=tuple(win.notes) + (note,), t_rel=t_rel)


def rudder_curvature_term(amplitude: float) -> float:
    """Relative shortfall of a rudder's lift ``sin(2 delta) / 2`` against its linear force at ``amplitude`` [-].

    Parameters
    ----------
    amplitude : float
        The zig-zag's rudder amplitude [rad].
    """
    a = abs(float(amplitude))
    if not (math.isfinite(a) and a > 0):
        raise ValueError(f"rudder amplitude: expected a positive finite angle in rad, found {amplitude!r}")
    return 1.0 - math.sin(2 * a) / (2 * a)


#: Share of the record held out at its end for the structure choice [-] (as the per-segment choice).
HOLDOUT_SHARE = 0.35
#: Smallest held-out shrink of the output (simulation) error for the second order to be chosen [%].
ZIGZAG_MIN_SHRINK = 50.0


def heldout_output_errors(win: NomotoWindow, order: int) -> tuple[np.ndarray, NomotoFit]:
    """The output (simulation) error of ``order`` over the record's held-out end [rad], fitted on the rest.

    The end's headings are left out of a white-noise output-error fit of the whole record (missing samples),
    which simulates on through them from the fitted start: the error is the model's, not one-step
    predictions' (the first order's wave filter whitens a structure's misfit into its prediction errors).

    Parameters
    ----------
    win : NomotoWindow
        The prepared window (channel ``psi``).
    order : int
        1 or ``ORDER2_SUM_PRODUCT``.
    """
    psi = np.asarray(win.rec.psi, float)
    n = psi.size
    cut = int(round((1.0 - HOLDOUT_SHARE) * n))
    masked = psi.copy()
    masked[cut:] = np.nan
    rec = replace(win.rec, psi=masked, r=None)
    fit = fit_nomoto(rec, order=order, noise="white", channels=("psi",), servo=win.servo)
    y = np.asarray(fit.y_fit[0]["psi"], float)
    return unwrap_heading(psi)[cut:] - y[cut:], fit


#: Refits with the measured rudder's noise drawn again, for its term (:func:`rudder_noise_terms`).
RUDDER_NOISE_DRAWS = 3


def second_order_kt(fit: NomotoFit) -> tuple[float, float]:
    """K [1/s] and the first-order equivalent T = T1 + T2 - T3 [s] of a second-order fit (sum-product form).

    Parameters
    ----------
    fit : NomotoFit
        A fit of order ``ORDER2_SUM_PRODUCT`` (``K``, ``T12``, ``T1T2``, ``T3``).
    """
    v = dict(zip(fit.names, fit.values))
    return float(v["K"]), float(v["T12"] - v["T3"])


def rudder_noise_terms(trial: Trial, win: NomotoWindow, fit: NomotoFit) -> tuple[float, float, float]:
    """The spread of K [1/s] and T [s] that the measured rudder's own noise puts into a re-timed zig-zag's fit,
    and that noise [rad].

    A measured rudder drives the fit with its sensor noise; the standard errors count the heading's noise only.
    On a second-order ship T = T1 + T2 - T3 is a small difference of large time constants and moves with that
    noise well beyond its standard error (measured, Clarke83's 10/10 zig-zag, rudder noise 0.1 deg and a
    noise-free heading: T -3.9, -11.8, -5.6 % on seeds 0-2 against -2.7 % noise-free, standard errors 0.3-0.4 %).
    The noise is drawn again ``RUDDER_NOISE_DRAWS`` times at the level read from the rudder's sample-to-sample
    differences (median absolute difference) and added to the logged rudder; the root mean square change of the
    refits' K and T estimates the spread the logged noise itself caused (for a small noise the change is linear in
    it, so a second draw of equal variance moves the estimate as much as the first did). Seeded by the record's
    length: the same record gives the same terms.

    Parameters
    ----------
    trial : Trial
        The trial (its logged ``delta``).
    win : NomotoWindow
        The zig-zag's window at constant time (measured rudder, not re-timed).
    fit : NomotoFit
        The re-timed record's white output-error second-order fit.

    Returns
    -------
    (float, float, float)
        K term [1/s], T term [s], rudder noise [rad]; zeros when the refits fail.
    """
    rows = trial.window(float(win.rec.t[0]), float(win.rec.t[-1]))
    raw = rows["delta"].to_numpy(dtype=float)
    if raw.size != np.asarray(win.rec.t).size or not np.all(np.isfinite(raw)):
        return 0.0, 0.0, 0.0
    sigma = 1.4826 * float(np.median(np.abs(np.diff(raw)))) / math.sqrt(2.0)
    if not sigma > 0:
        return 0.0, 0.0, 0.0
    k0, t0 = second_order_kt(fit)
    rng = np.random.default_rng(raw.size)
    dk, dt = [], []
    for _ in range(RUDDER_NOISE_DRAWS):
        d = raw + sigma * rng.standard_normal(raw.size)
        drive = np.concatenate([0.5 * (d[:-1] + d[1:]), d[-1:]])
        try:
            w = retimed_zigzag_window(trial, replace(win, rec=replace(win.rec, delta=drive)))
            if w is None:
                continue
            f = fit_nomoto(w.rec, order=ORDER2_SUM_PRODUCT, noise="white", channels=("psi",), servo=w.servo)
        except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError):
            continue
        k, t = second_order_kt(f)
        if f.converged and math.isfinite(k) and math.isfinite(t):
            dk.append(k - k0)
            dt.append(t - t0)
    if not dk:
        return 0.0, 0.0, sigma
    return float(np.sqrt(np.mean(np.square(dk)))), float(np.sqrt(np.mean(np.square(dt)))), sigma


#: Model term on T of a re-timed zig-zag fitted with a servo lag, as a share of T [-] (:func:`servo_t_note`).
SERVO_T_SHARE = 0.2


def servo_t_note(sf: SegmentFit) -> str:
    """Why T of a re-timed zig-zag fitted with a servo lag (a logged command) is unsure ('' without the lag).

    The lag fitted with the ship trades with ``T = T1 + T2 - T3``, on a ship with a pole-zero pair the small
    difference of two large numbers: measured, Clarke83's noise-free 10/10 zig-zag re-timed, T -12.4 % +- 0.4 %
    with the lag fitted from the command (1.05 s against the servo's 1.0 s) against -2.7 % +- 0.2 % driven by the
    measured rudder angle; on seeds 0-7 of the benchmark's noise -26 to +2 % (mean -14 %), relative standard errors
    8-12 %, the intervals missing on 2 of 8 (on 2 of 8 still, at z = -1.97, with 12 % of T as a term). A shift of
    ``SERVO_T_SHARE`` of T, the largest seen less the standard error, is added as a model term to T's error
    (:func:`retimed_zigzag_fit`).

    Parameters
    ----------
    sf : SegmentFit
        The re-timed zig-zag's second-order segment fit.
    """
    if "t_servo" not in sf.params or "T3" not in sf.params:
        return ""
    t12 = sf.params.get("T12", sf.params.get("T1", math.nan) + sf.params.get("T2", math.nan))
    return (f"{STRUCTURE_UNDECIDED} T: T = T1 + T2 - T3 = {sf.params['T']:.4g} s is the small difference of "
            f"T1 + T2 = {t12:.4g} s and T3 = {sf.params['T3']:.4g} s, and the servo lag fitted with it from the "
            f"logged command ({sf.params['t_servo']:.3g} s) moves it beyond its standard error (measured on a "
            f"simulated ship: T 12 % short with the lag fitted, 2.7 % with the rudder angle logged): log the "
            f"rudder angle")


def retimed_zigzag_fit(trial: Trial, win: NomotoWindow, retimed: NomotoWindow) -> SegmentFit | None:
    """The second-order fit of a zig-zag re-timed on the distance sailed, where its held-out end chooses it.

    Three models of the record compete on the output error of its held-out end (:func:`heldout_output_errors`,
    each fitted on the rest): the first and the second order re-timed, and the second order at constant time
    (``win``). The re-timed second order is kept when its held-out RMS error is below the first order's by at
    least ``ZIGZAG_MIN_SHRINK`` percent (three more parameters; measured, Clarke83's 10/10 zig-zag without waves:
    65 to 72 % on seeds 0-1 of the benchmark's noise, 98.6 % noise-free; with waves 25 to 33 %, left to the
    per-segment choice) and below the constant-time second order's by at least ``MIN_SHRINK`` percent (the
    same parameters; the logged speed adds none). The whole re-timed record is then fitted by output error
    (white noise, Newey-West errors where its residuals are coloured: the wave noise model would take up the
    misfit a structure leaves, and the choice was made on the output error), K read at zero rudder with the
    rudder force's curvature as a model term (:func:`rudder_curvature_term`, at the record's median rudder
    angle), T with the measured rudder's noise as a term (:func:`rudder_noise_terms`) or unsure with a servo
    lag fitted (:func:`servo_t_note`).

    Parameters
    ----------
    trial : Trial
        The trial (its logged rudder, for :func:`rudder_noise_terms`).
    win : NomotoWindow
        The zig-zag's window at constant time.
    retimed : NomotoWindow
        The same re-timed (:func:`retimed_zigzag_window`).

    Returns
    -------
    SegmentFit or None
        None when the re-timed second order is not chosen, cannot be fitted, or leaves its range.
    """
    if "psi" not in retimed.channels or retimed.rec.psi is None:
        return None
    try:
        e_first, _ = heldout_output_errors(retimed, 1)
        e_second, _ = heldout_output_errors(retimed, ORDER2_SUM_PRODUCT)
        e_const, _ = heldout_output_errors(win, ORDER2_SUM_PRODUCT)
    except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError):
        return None
    rms = [float(np.sqrt(np.nanmean(e ** 2))) for e in (e_first, e_second, e_const)]
    if not all(math.isfinite(x) and x > 0 for x in rms):
        return None
    shrink = [100.0 * (1.0 - rms[1] / rms[0]), 100.0 * (1.0 - rms[1] / rms[2])]
    if shrink[0] < ZIGZAG_MIN_SHRINK or shrink[1] < MIN_SHRINK:
        return None
    note = (f"second-order Nomoto (T1, T2, T3) chosen on the re-timed zig-zag's held-out end ({HOLDOUT_SHARE:.0%} "
            f"of the record) by its output error: RMS {rms[1]:.4g} rad against {rms[0]:.4g} rad (first order re-timed, "
            f"{shrink[0]:+.1f} % shrink, at least {ZIGZAG_MIN_SHRINK:g} % asked) and {rms[2]:.4g} rad (second order at "
            f"constant time, {shrink[1]:+.1f} %, at least {MIN_SHRINK:g} % asked)")
    try:
        fit, servo_note = fit_window_order(retimed, ORDER2_SUM_PRODUCT, noise="white", robust=True)
        if not fit.success:
            return None
        sf = fit_window(retimed, ORDER2_SUM_PRODUCT, note, "", {ORDER2_SUM_PRODUCT: fit})
    except (FitError, ValueError, ArithmeticError, np.linalg.LinAlgError):
        return None
    if "T3" not in sf.params or not np.isfinite(sf.params.get("K", math.nan)):
        return None
    amplitude = float(np.median(np.abs(np.asarray(retimed.rec.delta, float) - sf.params.get("b", 0.0))))
    shortfall = rudder_curvature_term(amplitude)
    k_fit = float(sf.params["K"])
    k0 = k_fit / (1.0 - shortfall)
    curv = abs(k0 - k_fit)
    k_noise = t_noise = 0.0
    noise_why = ""
    if not retimed.servo:
        k_noise, t_noise, sigma = rudder_noise_terms(trial, win, fit)
        noise_why = (f"the measured rudder's noise ({math.degrees(sigma):.3g} deg, {RUDDER_NOISE_DRAWS} refits with "
                     f"it drawn again: K +-{k_noise:.3g} 1/s, T +-{t_noise:.3g} s), which the standard errors do not "
                     f"count")
    k_term = math.hypot(curv, k_noise)
    notes = [servo_note] if servo_note else []
    notes.append(f"{CURVATURE_NOTE}: K {k_fit:.5g} -> {k0:.5g} 1/s at zero rudder, the zig-zag's one amplitude "
                 f"({math.degrees(amplitude):.3g} deg) read on a rudder lift growing as sin(2 delta) / 2, "
                 f"{shortfall:.2%} short of the linear force there (Fossen 2021, sec. 9.5.1)")
    notes.append(f"{STRUCTURE_TERM} K: +-{k_term:.6g} 1/s added in quadrature to its standard error: that correction "
                 f"(+-{curv:.3g} 1/s: one amplitude cannot separate the rudder force's curvature from K, so a linear "
                 f"rudder force is as likely)" + (f" and {noise_why}" if noise_why else ""))
    if t_noise > 0:
        notes.append(f"{STRUCTURE_TERM} T: +-{t_noise:.6g} s added in quadrature to its standard error: {noise_why}")
    servo_t = servo_t_note(sf)
    if servo_t:
        term = SERVO_T_SHARE * abs(sf.params["T"])
        notes += [servo_t, f"{STRUCTURE_TERM} T: +-{term:.6g} s added in quadrature to its standard error: the "
                           f"servo lag fitted with it moved T by up to {SERVO_T_SHARE:.0%} of its value, beyond its "
                           f"standard error, on a simulated ship with the rudder logged as a command"]
    sf = replace(sf, params=dict(sf.params, K=k0),
                 stderr=dict(sf.stderr, K=sf.stderr.get("K", math.nan) * k0 / k_fit))
    return replace(sf, message="; ".join([sf.message] + notes) if sf.message else "; ".join(notes))


#: Model term on K and T of a zig-zag that slows in its turns, per unit of its relative speed loss [-].
SPEED_LOSS_FACTOR = 3.0


def speed_loss_terms(trial: Trial, win: NomotoWindow, sf: SegmentFit) -> list[str]:
    """Model terms on K and T of a zig-zag that slows in its turns (not re-timed), as notes ([] otherwise).

    A 10/10 zig-zag sails at its one rudder amplitude and the drift that goes with it; the speed it loses is the
    drag of that drift (quadratic in the sway velocity), and the hull's nonlinear sway and yaw forces grow the
    same way, so K and T read at that amplitude depart from the linearised ones at zero rudder by an amount the
    speed loss measures but one amplitude cannot give (re-timing on the distance sailed moves them the wrong
    way, :mod:`pipeline.fit.nomoto_zigzag`'s docstring; fitting the record's halves, at 3.0 and 5.7 % loss,
    and extrapolating to the straight-run speed left K +7.7 %, T -10 %: the departure is not the speed's). The
    term is ``SPEED_LOSS_FACTOR`` times the loss, of the value; measured on PythonVehicleSimulator's tanker,
    10/10 zig-zags, seeds 0-2 (benchmarks/RESULTS.md, ident41): at 25 m (6.0 % loss) K 7 to 12 % and T 11 to
    18 % off, 1.2 to 3.0 times the loss, intervals missing on 9 of 12 without it; at 20 m (2.7 %) K 2.2 to 7.7 %.
    Combined in quadrature with a model-structure term the fit already carries (the largest such note is the
    one read, :func:`pipeline.fit.nomoto_quality.structure_term`).

    Parameters
    ----------
    trial : Trial
        The trial (``u`` logged).
    win : NomotoWindow
        The zig-zag's window.
    sf : SegmentFit
        Its segment fit (``K``, ``T``).
    """
    if win.segment.kind != "zigzag" or not sf.success:
        return []
    sp = zigzag_speed(trial, win)
    if sp is None:
        return []
    _, u0, u = sp
    if not np.all(np.isfinite(u)):
        return []
    loss = float(np.max(u0 - u)) / u0
    rise = float(np.max(u - u0)) / u0
    if not (loss > SPEED_RETIME and loss > rise):
        return []
    out = []
    for name, unit in (("K", "1/s"), ("T", "s")):
        value = sf.params.get(name, math.nan)
        if not math.isfinite(value):
            continue
        term = SPEED_LOSS_FACTOR * loss * abs(value)
        before = largest_noted([sf], f"{STRUCTURE_TERM} {name}: +-")
        total = math.hypot(term, before)
        out.append(f"{STRUCTURE_TERM} {name}: +-{total:.6g} {unit} added in quadrature to its standard error"
                   + (f" (with the model-structure term {before:.4g} {unit} above)" if before > 0 else "")
                   + f": {SPEED_LOSS_TERM} {loss:.2%} of the straight-run speed U0 = {u0:.4g} m/s in its turns, "
                   f"the drift's drag at its one rudder amplitude, where the hull's nonlinear forces move {name} "
                   f"from its value at zero rudder by an amount one amplitude cannot give: {SPEED_LOSS_FACTOR:g} "
                   f"times the loss, {term:.4g} {unit}")
    return out
