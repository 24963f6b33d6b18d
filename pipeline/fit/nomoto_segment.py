"""Fit-stage adapter: a rudder step, zig-zag or sinusoid of a trial -> whole-record Nomoto fit -> SegmentFit.

What the log holds decides the model, by the data:

- The rudder signal: a piecewise-constant record is a *command* (:func:`pipeline.segment.rudder.is_command_like`),
  and the servo between command and rudder is estimated with K and T: a first-order lag
  ``t_servo`` and, kept when the BIC says so, a rate limit ``rate_servo``
  (:func:`pipeline.model.nomoto.servo_response`). A *measured* rudder angle drives the model
  directly, interpolated like any measured state (its mean over each sample interval).
- The channels: compass and gyro, or the compass alone when a first-order fit leaves its residuals
  coloured (wave-induced yaw, which the gyro sees too but the wave noise model covers only on the
  compass; :func:`_choose_channels`).
- The structure: first-order Nomoto against second order (T1, T2, T3), by held-out error. A trial
  with two or more whole-record segments chooses it once across them, leaving whole segments out
  (:mod:`pipeline.fit.nomoto_structure`; :func:`prepare_window` and :func:`fit_window` here are its
  per-segment parts). A lone segment chooses on its own held-out end: both
  are fitted on the first ``1 - HOLDOUT_FRACTION`` of the record (with the wave PEM when the
  compass needs it) and run on through the rest; the held-out errors are whitened by the same
  wave innovations filter and compared by the shared rule of :mod:`pipeline.fit.heldout_test`.
  The second order starts from the first-order fit and stops after a few evaluations when its
  in-sample gain is below noise (:class:`pipeline.fit.nomoto_oe.GainFloor`); the order note says so. With the second order, ``T`` is its first-order equivalent ``T1 + T2 - T3``
  (error from the covariance).
- Unsure: a near-tie between the structures whose K or T differ materially
  (:func:`structure_ambiguity`), or a second order called for whose fit failed, marks the
  segment fit failed with a message starting ``unsure:``. A wave noise model whose fitted peak
  lies below the ship's corner frequency (:func:`slow_noise_note`) leaves K and T undecided for
  the combined estimates (:func:`pipeline.fit.nomoto_quality.judge_nomoto`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
from scipy import stats
from scipy.ndimage import uniform_filter1d

from ..errors import FitError
from ..records import Segment, SegmentFit, Trial
from ..segment.rudder import is_servo_command
from .data import noise_sigma, pick_channel, segment_label
from .heldout_test import ALPHA, ALPHA_ROBUST, MIN_EXPLAINED, MIN_SHRINK, channel_score, is_significant
from ..model.nomoto import ORDER2_SUM_PRODUCT, distance_time, pole_time_constants
from .nomoto_oe import GainFloor, SecondOrderNoGain, fit_nomoto
from .nomoto_problem import MIN_SAMPLES, SERVO_PARAMS, Problem, prepare, unwrap_heading
from .nomoto_quality import RETIME_TERM, SPEED_RANGE, STRUCTURE_UNDECIDED
from .nomoto_records import NomotoFit, NomotoRecord
from .nomoto_retime import retime_record
from .segment_fit import MAX_RELATIVE_STDERR


#: Segment kinds the whole-record fit serves in :func:`pipeline.fit.fit_trial`.
WHOLE_RECORD_KINDS = ("zigzag", "sinusoid")
#: Parameters whose relative standard error decides ``success``.
KEY_PARAMS = ("K", "T")
#: Share of a record held out (its end) for the model-structure choice.
HOLDOUT_FRACTION = 0.35
#: BIC drop a rate limit must bring to be kept beside the servo lag.
RATE_LIMIT_BIC = 10.0


def fit_nomoto_segment(trial: Trial, segment: Segment) -> SegmentFit:
    """Whole-record Nomoto fit of a zig-zag or sinusoid segment (see the module doc).

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
        parameters ``K`` [1/s], ``T`` [s] (``T1``, ``T2``, ``T3`` [s] too for the second order),
        ``b`` [rad], the initial states, ``t_servo`` [s] / ``rate_servo`` [rad/s] for a logged
        command, and for the PEM ``omega0`` [rad/s], ``lambda`` [-], ``kw_ratio`` [s^-1/2];
        ``y_fit`` is the simulated heading.

    Raises
    ------
    FitError
        Wrong DOF, missing channels, gaps in the rudder, too few samples.
    """
    return fit_nomoto_window(trial, segment, segment.t_start, segment.t_end)


def fit_nomoto_window(trial: Trial, segment: Segment, t0: float, t1: float) -> SegmentFit:
    """Whole-record Nomoto fit of the trial between ``t0`` and ``t1`` for ``segment``.

    The structure (first or second order) is chosen on this record alone, by its held-out end
    (:func:`choose_order`); a trial with several whole-record segments chooses it once across
    them instead (:func:`pipeline.fit.nomoto_structure.fit_nomoto_trial`).

    Parameters
    ----------
    trial : Trial
        Trial with ``delta`` and ``psi`` and/or ``r``.
    segment : Segment
        The segment the result belongs to (a yaw segment driven by ``delta``).
    t0, t1 : float
        Window [s, trial clock]; may start before the segment (a rudder step's steady lead-in).

    Returns
    -------
    SegmentFit
        See :func:`fit_nomoto_segment`; ``t`` is relative to ``segment.t_start``.

    Raises
    ------
    FitError
        Wrong DOF, missing channels, gaps in the rudder, too few samples.
    """
    win = prepare_window(trial, segment, t0, t1)
    choice = choose_order(win.rec, win.channels, win.servo)
    return fit_window(win, choice.order, choice.note, choice.unsure)


@dataclass(frozen=True)
class NomotoWindow:
    """One segment's record prepared for the whole-record fit (channels and servo chosen).

    Attributes
    ----------
    segment : Segment
        The segment the fit belongs to.
    rec : NomotoRecord
        The record (rudder as it drives the model).
    channels : tuple of str
        Outputs fitted (``psi``, ``r``).
    servo : tuple of str
        Servo parameters estimated (a logged command), or empty.
    notes : tuple of str
        What was decided preparing it, for the fit's message.
    t_rel : numpy.ndarray
        Sample times relative to ``segment.t_start`` [s].
    """

    segment: Segment
    rec: NomotoRecord
    channels: tuple[str, ...]
    servo: tuple[str, ...]
    notes: tuple[str, ...]
    t_rel: np.ndarray


def prepare_window(trial: Trial, segment: Segment, t0: float, t1: float) -> NomotoWindow:
    """The record of ``segment`` between ``t0`` and ``t1``, its output channels and its servo model.

    Parameters
    ----------
    trial : Trial
        Trial with ``delta`` and ``psi`` and/or ``r``.
    segment : Segment
        A yaw segment driven by ``delta``.
    t0, t1 : float
        Window [s, trial clock].

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
    rows = trial.window(t0, t1)
    t = rows["t"].to_numpy(dtype=float)
    delta = rows["delta"].to_numpy(dtype=float)
    if t.size < MIN_SAMPLES:
        raise FitError(f"{where}: expected at least {MIN_SAMPLES} samples, found {t.size}")
    if not np.all(np.isfinite(delta)):
        raise FitError(f"{where}: expected a logged rudder on every sample, found {int((~np.isfinite(delta)).sum())} gaps")
    command = is_servo_command(delta, 1.0 / float(np.median(np.diff(t))))
    notes = []
    if command:
        notes.append("rudder logged as a command (piecewise constant or free of sensor noise): servo estimated "
                     "with K and T")
        drive = delta
    else:
        notes.append(f"{MEASURED_RUDDER}: used directly (mean over each sample interval)")
        drive = np.concatenate([0.5 * (delta[:-1] + delta[1:]), delta[-1:]])
    rec = NomotoRecord(t=t, delta=drive, psi=rows["psi"].to_numpy(dtype=float) if "psi" in channels else None,
                       r=rows["r"].to_numpy(dtype=float) if "r" in channels else None, name=where)
    rec, t, retime_note = retime_window(trial, rec, rows, segment, ("t_servo",) if command else ())
    if retime_note:
        notes.append(retime_note)
    if len(channels) > 1:
        channels, channel_note = _choose_channels(rec, channels, ("t_servo",) if command else ())
        if channel_note:
            notes.append(channel_note)
    servo: tuple[str, ...] = ()
    if command:
        servo, servo_note = _choose_servo(rec, channels)
        notes.append(servo_note)
    # The segment itself, not the lead-in before it (which may hold an earlier throttle change).
    lead = None
    if segment.kind == "zigzag":
        # Both ends of a zig-zag turn: its straight-run speed is the straight run's before it.
        lead = trial.window(segment.t_start - LEAD_SPEED_SECONDS, segment.t_start)
        lead = lead[lead["t"] < segment.t_start]
    speed = speed_range_note(rows[rows["t"] >= segment.t_start], lead=lead)
    if speed:
        notes.append(speed)
    return NomotoWindow(segment, rec, tuple(channels), servo, tuple(notes), t - segment.t_start)


#: Departure of the logged speed from the straight-run speed, relative to it, above which a window is
#: re-timed on the distance sailed [-] (the speed noise averaged over ``RETIME_SMOOTH_SECONDS`` is 0.1 %
#: of it on the benchmark's logs; the speed term of :func:`pipeline.fit.nomoto_quality.add_speed_term`
#: covers half the loss below this).
SPEED_RETIME = 0.01
#: Length of the moving mean that smooths the logged speed for the re-timing [s].
RETIME_SMOOTH_SECONDS = 10.0
#: Shortest straight run at the trial's start whose median speed is the reference speed [s].
RETIME_LEAD_SECONDS = 30.0
#: Share of the trial's largest rudder excursion that ends its opening straight run [-].
RETIME_RUDDER_SHARE = 0.25
#: Largest departure of a window's straight-run speed (rudder at the trial's opening level) from ``U0``,
#: relative to it, for the window to be re-timed [-] (Clarke83's holds after a 10 deg turn average +1.8 %:
#: its surge has not settled in 81 s; a throttle set otherwise moves it more).
RETIME_REST = 0.025
#: Largest rise of the speed over ``U0`` a turn is taken to cause [-]: beyond it the throttle moved or the
#: ship started from rest (the project's own simulator opens at rest, U0 = 0.017 m/s, +5900 %).
RETIME_MAX = 0.10
#: Note head of a re-timed window.
RETIMED = "re-timed on the distance sailed"


def straight_run_speed(trial: Trial) -> tuple[str, float, float] | None:
    """The speed channel, the median speed [m/s] of the straight run the trial begins with, and its length [s].

    The run lasts until the rudder first departs from its opening level (the median of the first 10 s) by
    more than ``RETIME_RUDDER_SHARE`` of its largest departure (and 0.5 deg); None when no surge speed ``u``
    is logged (the speed over ground adds the sway velocity of a turn's drift: the project's own simulator, GNSS
    only, re-timed on ``sog``, had K and T unsure), the rudder never moves, or the run is shorter than ``RETIME_LEAD_SECONDS``
    by more than half a sample period (the moment the rudder moved is known only to within one sample interval, so
    a run of 29.99 s and one of 30 s are the same run; a median over ~150 samples at 5 Hz does not hinge on one).

    Parameters
    ----------
    trial : Trial
        The trial (``delta`` and ``u`` or ``sog``).
    """
    # The surge speed only: the speed over ground adds the drift's sway velocity in a turn (and the current).
    ch = "u" if trial.has("u") else None
    if ch is None or not trial.has("delta"):
        return None
    t = np.asarray(trial.t, float)
    d = trial.data["delta"].to_numpy(dtype=float)
    u = np.abs(trial.data[ch].to_numpy(dtype=float))
    first = t < t[0] + 10.0
    d0 = float(np.nanmedian(d[first])) if np.isfinite(d[first]).any() else math.nan
    dev = np.abs(d - d0)
    span = float(np.nanmax(dev)) if np.isfinite(dev).any() else math.nan
    if not (math.isfinite(d0) and span > 0):
        return None
    moved = np.flatnonzero(dev > max(RETIME_RUDDER_SHARE * span, math.radians(0.5)))
    if not moved.size:
        return None
    end = float(t[moved[0]])
    lead = (t < end) & np.isfinite(u)
    # The rudder left its level somewhere in the sample interval before ``end``: the run's length is known to
    # within one interval, so it is too short only when it falls short by more than half of one (a clock
    # rebuilt as t0 + i h puts a move at 30.0 s a float hair under it: the benchmark's commanded zig-zags).
    h = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    if end - t[0] < RETIME_LEAD_SECONDS - 0.5 * h or lead.sum() < MIN_SAMPLES:
        return None
    return ch, float(np.median(u[lead])), end - float(t[0])


def retime_window(trial: Trial, rec: NomotoRecord, rows, segment: Segment,
                  servo: tuple[str, ...] = ()) -> tuple[NomotoRecord, np.ndarray, str]:
    """``rec`` re-timed on the distance sailed where the data choose it (:func:`retime_candidate`,
    :func:`choose_retiming`).

    A rudder step whose logged surge speed departs from the trial's straight-run speed (either way) is fitted
    both plain and re-timed on its first ``1 - HOLDOUT_FRACTION``; the one whose yaw rate predicts the held-out
    end better, by the rule of :func:`choose_retiming`, is kept. When neither wins, the plain record is kept
    and the two fits' difference in K and T is carried as a model term (a ``RETIME_TERM`` note, added to the
    combined K and T by :func:`pipeline.fit.nomoto_quality.judge_nomoto`).

    Parameters
    ----------
    trial : Trial
        The trial.
    rec : NomotoRecord
        The window's record.
    rows : pandas.DataFrame
        The window's rows of the trial (``t`` and the speed channel).
    segment : Segment
        The segment (its start maps to the new time).
    servo : tuple of str
        Servo parameters the comparison's fits estimate (a logged command: ``("t_servo",)``).

    Returns
    -------
    (NomotoRecord, numpy.ndarray, str)
        The record, its times [s, trial clock or the distance-sailed time from the window's start] and a
        note ('' when no re-timing was considered).
    """
    t = np.asarray(rec.t, float)
    cand = retime_candidate(trial, rec, rows, segment)
    if cand is None:
        return rec, t, ""
    new, u, u0, note = cand
    choice = choose_retiming(rec, new, u, u0, servo)
    if choice.retime:
        tau = distance_time(t, u, u0)
        start = float(np.interp(segment.t_start, t, tau))
        # Times from the segment's start in tau, on the trial clock's origin.
        return new, np.asarray(new.t, float) - start + float(segment.t_start), f"{RETIMED}: {note}; {choice.note}"
    return rec, t, f"{NOT_RETIMED}: {note}; {choice.note}"


def retime_candidate(trial: Trial, rec: NomotoRecord, rows, segment: Segment
                     ) -> tuple[NomotoRecord, np.ndarray, float, str] | None:
    """The re-timed record of a rudder step whose logged speed departs from the straight-run speed, or None.

    The speed-scaled Nomoto model (:func:`pipeline.model.nomoto.distance_time`: ``K = K0 u / U0``,
    ``T = T0 U0 / u``) is the constant model at ``U0`` in the distance-sailed time. A window whose speed
    (a ``RETIME_SMOOTH_SECONDS`` moving mean of the surge speed ``u``) departs from ``U0``, the median speed
    of the straight run the trial begins with (:func:`straight_run_speed`), by more than ``SPEED_RETIME``
    and at most ``RETIME_MAX`` of it, either way, is a candidate, provided its own straight-run samples
    (rudder at the trial's opening level) sail within ``RETIME_REST`` of ``U0`` (a trial whose throttle
    changes between its manoeuvres, as the project's own simulator's, is not re-timed). Whether the
    speed-scaled model describes the ship is left to the data (:func:`choose_retiming`): a ship that slows
    in its turns at constant propeller speed may keep its rudder force (the rudder in the propeller race)
    while its damping falls, so its K need not scale with ``u`` (PythonVehicleSimulator's tanker, ident32,
    ident38); Clarke83 speeds up 2.9 % in its 10 deg turns, and its steps' T into a turn are +15 to +34 % at
    constant speed against +0.7 to +1.7 % re-timed (benchmarks/RESULTS.md, "Speed and rudder amplitude").

    Rudder steps only: zig-zags and sinusoids have one amplitude, and re-timed their K carries the rudder
    force's own nonlinearity, which only steps of different amplitudes resolve
    (:mod:`pipeline.fit.nomoto_amplitude`; ident36: Clarke83's measured-rudder sinusoids re-timed, K -0.9
    to -1.0 % with intervals missing on 3 of 3 seeds).

    Parameters
    ----------
    trial : Trial
        The trial (``delta`` and the surge speed ``u``).
    rec : NomotoRecord
        The window's record.
    rows : pandas.DataFrame
        The window's rows of the trial (``t`` and ``delta``).
    segment : Segment
        The segment (a ``rudder_step`` is a candidate; other kinds are not).

    Returns
    -------
    (NomotoRecord, numpy.ndarray, float, str) or None
        The re-timed record, the smoothed speed at ``rec.t`` [m/s], ``U0`` [m/s] and a note on the speed.
    """
    t = np.asarray(rec.t, float)
    if segment.kind != "rudder_step":
        return None
    ref = straight_run_speed(trial)
    if ref is None or ref[1] <= 0:
        return None
    ch, u0, lead = ref
    u_all = np.abs(trial.data[ch].to_numpy(dtype=float))
    t_all = np.asarray(trial.t, float)
    ok = np.isfinite(u_all)
    if ok.sum() < MIN_SAMPLES:
        return None
    h = float(np.median(np.diff(t_all)))
    n = max(1, int(round(RETIME_SMOOTH_SECONDS / h)))
    smooth = uniform_filter1d(u_all[ok], n, mode="nearest")
    u = np.interp(t, t_all[ok], smooth)
    if not np.all(np.isfinite(u)) or not np.all(u > 0.5 * u0):
        return None
    rise, fall = float(np.max(u - u0)) / u0, float(np.max(u0 - u)) / u0
    dev = max(rise, fall)
    if not SPEED_RETIME < dev <= RETIME_MAX:
        return None
    # The window's straight-run samples (rudder at the trial's opening level) must sail at about U0: a speed
    # set elsewhere by the throttle is no turn's speed change.
    d0 = float(np.nanmedian(trial.data["delta"].to_numpy(dtype=float)[t_all < t_all[0] + 10.0]))
    rest = np.abs(np.asarray(rows["delta"].to_numpy(dtype=float)) - d0) <= math.radians(0.5)
    if rest.sum() < MIN_SAMPLES or not abs(float(np.median(u[rest])) / u0 - 1.0) <= RETIME_REST:
        return None
    try:
        new = retime_record(rec, u, u0)
    except FitError:
        return None
    signed = rise if rise >= fall else -fall
    note = (f"the logged speed ({ch}, {RETIME_SMOOTH_SECONDS:g} s mean) departs from the straight-run speed U0 = "
            f"{u0:.4g} m/s (median of the trial's first {lead:.0f} s, rudder steady) by up to {signed:+.2%}")
    return new, u, u0, note


#: Note head of a window whose speed departed but was fitted at constant speed.
NOT_RETIMED = "not re-timed on the distance sailed"


@dataclass(frozen=True)
class RetimeChoice:
    """The held-out choice between a window fitted at constant speed and re-timed on the distance sailed.

    Attributes
    ----------
    retime : bool
        The re-timed record is kept.
    note : str
        The comparison, the rule and, when neither wins, the ``RETIME_TERM`` notes.
    """

    retime: bool
    note: str


def choose_retiming(rec: NomotoRecord, new: NomotoRecord, u: np.ndarray, u0: float,
                    servo: tuple[str, ...] = ()) -> RetimeChoice:
    """Plain or re-timed by the held-out yaw-rate error of the window's end.

    Both records are fitted by the first-order output-error model (compass and gyro, the servo lag for a
    logged command) on the samples before the real time at ``1 - HOLDOUT_FRACTION`` of the window, and run
    on through the rest. They are compared on the logged yaw rate of the held-out samples: the re-timed fit's
    simulated rate (per distance-sailed second) is read at the logged samples' distance-sailed times and scaled
    back by ``u / U0`` (its record is interpolated, which averages the sensor noise: its own errors would flatter
    it). The yaw rate, not the heading: a heading predicted on from a training fit drifts with the fit's K error
    (the drift's autocorrelation outlasts the held-out part), and on PythonVehicleSimulator's tanker (20 m,
    measured rudder, seed 1) the heading chose each way on different steps of one trial at p ~ 1e-8 while the
    yaw rate chose neither (p 0.25-0.86). Without a gyro the heading is used. The two candidates have the same
    parameters (the speed is logged, not fitted): the one with the smaller held-out sum of squares wins when
    :func:`pipeline.fit.heldout_test.channel_score`'s F test of it against the other (one degree of freedom, the
    effective sample size under its lag-1 autocorrelation) gives a p-value below the shared rule's ``ALPHA``
    (1e-4). The shared rule's shrink and explained-error parts are not applied: they guard a larger model's
    extra parameters, which neither candidate has, and read the total held-out error, which the gyro noise
    dominates (tests/test_nomoto_retime_choice.py's ship: a speed-scaled ship whose speed changes 9 % is
    re-timed at p 5e-10 to 3e-5 with shrinks of 2-4 %; at 3 % nothing is decided). The
    constant-speed record is the default: when neither wins it is kept, and the two training fits' difference
    in K and in T is carried as a model term (``RETIME_TERM`` notes, added in quadrature to the combined K and
    T by :func:`pipeline.fit.nomoto_quality.judge_nomoto`): the data cannot tell which model of the speed
    change holds, so the difference is part of the error.

    Parameters
    ----------
    rec, new : NomotoRecord
        The window's record and the same re-timed (:func:`pipeline.fit.nomoto_retime.retime_record`).
    u : numpy.ndarray
        Smoothed speed at ``rec.t`` [m/s].
    u0 : float
        Straight-run speed [m/s].
    servo : tuple of str
        Servo parameters estimated in both fits.
    """
    t = np.asarray(rec.t, float)
    if rec.psi is None or t.size < 2 * MIN_SAMPLES:
        return RetimeChoice(False, "not compared (no compass or too short a record): fitted at constant speed")
    tau = distance_time(t, u, u0)
    nf = int(round((1.0 - HOLDOUT_FRACTION) * t.size))
    t_split = float(t[nf])
    grid = np.asarray(new.t, float)
    t_of = np.interp(grid, tau, t)
    nf_new = int(np.searchsorted(t_of, t_split))
    fits = []
    fit_ch = ("psi", "r") if rec.r is not None else ("psi",)
    for r, k in ((rec, nf), (new, nf_new)):
        part = NomotoRecord(t=r.t[:k], delta=r.delta[:k], psi=r.psi[:k], r=None if r.r is None else r.r[:k],
                            name=r.name)
        try:
            f = fit_nomoto(part, order=1, noise="white", channels=fit_ch, servo=servo)
        except FitError:
            f = None
        if f is None or not _usable(f):
            return RetimeChoice(False, "not compared (a training fit failed): fitted at constant speed")
        fits.append(f)
    if "r" in fit_ch:
        e_plain = _heldout_errors(fits[0], [rec], fit_ch, servo, [nf], None)[0]["r"]
        e_grid = _heldout_errors(fits[1], [new], fit_ch, servo, [nf_new], None)[0]["r"]
        sim_grid = np.asarray(new.r, float) - e_grid
        ok_grid = np.isfinite(sim_grid)
        e_new = np.full(t.size, np.nan)
        if ok_grid.sum() >= 2:
            inside = (tau >= grid[ok_grid][0]) & (tau <= grid[ok_grid][-1])
            e_new[inside] = np.asarray(rec.r, float)[inside] - np.interp(tau[inside], grid[ok_grid],
                                                                         sim_grid[ok_grid]) * u[inside] / u0
    else:
        e_plain = _heldout_errors(fits[0], [rec], ("psi",), servo, [nf], None)[0]["psi"]
        e_grid = _heldout_errors(fits[1], [new], ("psi",), servo, [nf_new], None)[0]["psi"]
        # The re-timed fit's simulated heading, read at the logged samples' distance-sailed times (the re-timed
        # record's heading is interpolated, which would average the compass noise out of its own errors).
        sim_grid = np.asarray(new.psi, float) - e_grid
        ok_grid = np.isfinite(sim_grid)
        e_new = np.full(t.size, np.nan)
        if ok_grid.sum() >= 2:
            inside = (tau >= grid[ok_grid][0]) & (tau <= grid[ok_grid][-1])
            e_new[inside] = unwrap_heading(np.asarray(rec.psi, float))[inside] - np.interp(tau[inside], grid[ok_grid],
                                                                                            sim_grid[ok_grid])
    both = np.isfinite(e_plain) & np.isfinite(e_new)
    both[:nf] = False
    if both.sum() < 10:
        return RetimeChoice(False, "not compared (too few held-out samples): fitted at constant speed")
    ch = fit_ch[-1]
    y = np.asarray(rec.r if ch == "r" else unwrap_heading(np.asarray(rec.psi, float)), float)
    scale = max(float(np.nanstd(y)), 1e-12)
    a, b = e_plain[both][None, :] / scale, e_new[both][None, :] / scale
    sse_a, sse_b = float(np.sum(a**2)), float(np.sum(b**2))
    retimed_better = sse_b < sse_a
    cs = channel_score(ch, *((a, b) if retimed_better else (b, a)), 1, 1, math.nan)
    pv = cs.p_value if math.isfinite(cs.p_value) else 1.0
    shrink = 100.0 * (1.0 - cs.gap_after / cs.gap_before) if cs.gap_before > 0 else 0.0
    # The shared rule's p-value threshold; its shrink and explained-error parts guard a larger model's extra
    # parameters (these two have the same) and read the total error, which the gyro noise dominates here.
    wins = pv < ALPHA
    k_p, k_r = fits[0].value("K"), fits[1].value("K")
    t_p, t_r = fits[0].T, fits[1].T
    sk = math.hypot(fits[0].error("K"), fits[1].error("K"))
    st = math.hypot(equivalent_t_stderr(fits[0]), equivalent_t_stderr(fits[1]))
    unit = "rad/s" if ch == "r" else "rad"
    text = (f"held-out {'yaw rate' if ch == 'r' else 'heading'} ({HOLDOUT_FRACTION:.0%} of the window, first-order "
            f"output error): RMS {math.sqrt(sse_a / a.size) * scale:.4g} {unit} at constant speed, "
            f"{math.sqrt(sse_b / b.size) * scale:.4g} {unit} re-timed ({shrink:.1f} % shrink for the better, "
            f"p = {pv:.2g}, rule p < {ALPHA:g}, training K {k_p:.4g} vs "
            f"{k_r:.4g} 1/s (errors in quadrature {sk:.2g}), T {t_p:.4g} vs {t_r:.4g} s ({st:.2g}))")
    if wins:
        if retimed_better:
            return RetimeChoice(True, f"re-timed chosen: {text}; K and T are the speed-scaled model's at U0 "
                                      f"(K = K0 u / U0, T = T0 U0 / u)")
        return RetimeChoice(False, f"constant speed chosen: {text}")
    return RetimeChoice(False, f"neither wins: {text}, constant speed kept with the training fits' difference as "
                               f"a model term; {RETIME_TERM} K: +-{abs(k_r - k_p):.6g} 1/s; "
                               f"{RETIME_TERM} T: +-{abs(t_r - t_p):.6g} s")


def fit_window_order(win: NomotoWindow, order: int, noise: str = "auto", **kwargs) -> tuple[NomotoFit, str]:
    """Fit one structure to a prepared window; the servo is dropped when its parameters leave their range.

    Parameters
    ----------
    win : NomotoWindow
        The prepared record.
    order : int
        1 or ``ORDER2_SUM_PRODUCT``.
    noise : str
        Noise model (see :func:`pipeline.fit.nomoto_oe.fit_nomoto`).
    **kwargs
        Passed to :func:`pipeline.fit.nomoto_oe.fit_nomoto` (``gain_floor``, ``start``).

    Returns
    -------
    fit : NomotoFit
    note : str
        Why the servo was dropped ('' when it was not).
    """
    fit = fit_nomoto(win.rec, order=order, noise=noise, channels=win.channels, servo=win.servo, **kwargs)
    if win.servo and any(n in SERVO_PARAMS for n in fit.at_bound):
        fit = fit_nomoto(win.rec, order=order, noise=noise, channels=win.channels, **kwargs)
        return fit, "the servo parameters left their range with the chosen structure: rudder taken as the command"
    return fit, ""


def fit_window(win: NomotoWindow, order: int, order_note: str, unsure: str = "",
               fits: dict[int, NomotoFit] | None = None) -> SegmentFit:
    """The segment fit of a prepared window with the structure chosen (first order kept, marked
    unsure, when a chosen second order fails on the whole record).

    Parameters
    ----------
    win : NomotoWindow
        The prepared record.
    order : int
        1 or ``ORDER2_SUM_PRODUCT``.
    order_note : str
        How the structure was chosen.
    unsure : str
        Why the structure leaves K or T undecided ('' when it does not).
    fits : dict, optional
        Whole-record fits already made, by order (reused instead of refitting).
    """
    notes = list(win.notes) + [order_note]
    fits = dict(fits or {})
    if order in fits:
        fit = fits[order]
    else:
        fit, servo_note = fit_window_order(win, order)
        if servo_note:
            notes.append(servo_note)
    if order != 1 and not fit.success:
        first = fits.get(1)
        if first is None:
            first, _ = fit_window_order(win, 1)
        if first.success:
            notes.append("the second-order fit of the whole record failed: first order kept")
            unsure = ("unsure: the held-out data call for the second-order structure, whose fit of the whole "
                      "record failed; the first-order K and T kept are biased by the missing pole-zero pair")
            fit = first
    lost = servo_lost_note(win, fit)
    if lost:
        notes.append(lost)
    return segment_fit_of(win.segment, fit, win.rec, win.channels, win.t_rel, notes, unsure)


def servo_lost_note(win: NomotoWindow, fit: NomotoFit) -> str:
    """Why T is unsure when a logged command's servo was dropped from a second-order fit ('' otherwise).

    A commanded rudder has a servo behind it (:func:`_choose_servo`). When its lag leaves the range
    with the second-order structure (it runs to zero) the fit is made without it, but the lag does
    not go away: to first order in ``s`` a lag ``tau`` turns the zero ``T3 s + 1`` into
    ``(T3 - tau) s + 1``, so the pole-zero pair takes it up and ``T = T1 + T2 - T3`` holds the ship's
    T plus the servo lag, with an error that does not show it (measured: PythonVehicleSimulator's
    Clarke83, 1 s servo lag, commanded steps logged at 2 Hz, seed 0: five steps kept their lag,
    0.65-1.2 s, T 2.4-3.3 s; the sixth's ran to zero, T 3.64 +- 0.19 s against the linearisation's
    2.66 s, and pulled the pooled T to +25.9 % marked success). The note starts with
    ``STRUCTURE_UNDECIDED`` and names T only (the lag leaves the gain alone); K is kept.
    :func:`pipeline.fit.nomoto_quality.judge_nomoto` marks the combined T unsure unless the
    segments carrying it are a minority that agrees with the others.

    Parameters
    ----------
    win : NomotoWindow
        The prepared record (``servo`` non-empty for a logged command).
    fit : NomotoFit
        The fit kept for the segment.
    """
    if not win.servo or fit.order == 1 or any(n in SERVO_PARAMS for n in fit.names):
        return ""
    return (f"{STRUCTURE_UNDECIDED} T: the rudder is logged as a command but its servo lag left the range with "
            f"the second-order structure and was dropped: a lag tau moves the zero T3 to T3 - tau, so T = T1 + T2 "
            f"- T3 = {fit.T:.4g} s holds the ship's T and the servo lag, which this segment cannot tell apart")


def _choose_channels(rec: NomotoRecord, channels: tuple[str, ...], servo: tuple[str, ...]) -> tuple[tuple[str, ...], str]:
    """The compass alone when its first-order residuals are coloured; compass and gyro otherwise.

    Coloured compass residuals come from wave-induced yaw (or from dynamics a first-order model
    lacks). Wave-induced yaw is motion of the ship, so a gyro sees it as the compass does, but the
    wave noise model of the PEM acts on the compass only: a gyro channel fitted beside it carries
    the unmodelled wave yaw rate, which colours its residuals and pulls the noise model onto the
    ship's dynamics (measured on a Clarke83 zig-zag with waves: compass and gyro gave T +93 %, the
    compass alone T -0.4 % with the second order). So the yaw rate is left out then; with white
    compass residuals both channels are fitted.
    """
    if "psi" not in channels:
        return channels, ""
    try:
        probe = fit_nomoto(rec, order=1, noise="white", channels=("psi",), servo=servo)
    except FitError:
        return channels, ""
    if not all(t.white for t in probe.residual_tests):
        return ("psi",), ("first-order compass residuals coloured (wave-induced yaw, which a gyro sees too, or "
                          "unmodelled dynamics): the compass alone is fitted, the wave noise model covering it")
    return channels, ""


def _choose_servo(rec: NomotoRecord, channels: tuple[str, ...]) -> tuple[tuple[str, ...], str]:
    """Servo lag always (a commanded rudder never moves instantly); the rate limit when the BIC says so.

    The rate limit is not tried when the lag's upper bound (value + 2 standard errors) is below the
    sample interval: a rate-limited ramp shows in a lag fit as a lag of about half its duration, so
    such a servo's ramps last less than about two samples and a rate limit cannot be told from the lag
    at this sampling. This skips the rate-limit fit, the costly one (its nonlinear servo recursion
    runs on every sensitivity), where it cannot be supported (measured on the 30-minute scaling
    trial of the project's own simulator, which has no servo: lags of 0.002-0.003 +- 0.001-0.005 s at
    50 Hz on 5 of 24 windows, each followed by a 1.5-7 s rate-limit fit that the BIC then rejected).
    """
    lag = fit_nomoto(rec, noise="white", channels=channels, servo=("t_servo",))
    if not lag.success:
        plain = fit_nomoto(rec, noise="white", channels=channels)
        if plain.success:
            return (), "servo lag not identified (no converged fit with it): rudder taken as the command"
        return ("t_servo",), "servo lag fit did not succeed"
    h = float(np.median(np.diff(rec.t)))
    upper = lag.value("t_servo") + 2.0 * lag.error("t_servo")
    if upper < h:
        return ("t_servo",), (f"servo lag estimated ({lag.value('t_servo'):.3g} +- {lag.error('t_servo'):.2g} s); a "
                              f"rate limit not tried: the lag's upper bound {upper:.2g} s is below the sample "
                              f"interval {h:.3g} s, so no rudder ramp is resolved")
    both = fit_nomoto(rec, noise="white", channels=channels, servo=("t_servo", "rate_servo"),
                      start={"t_servo": lag.value("t_servo")})
    if both.success and both.bic < lag.bic - RATE_LIMIT_BIC:
        return ("t_servo", "rate_servo"), (f"servo lag and rate limit estimated (BIC {both.bic:.1f} vs "
                                           f"{lag.bic:.1f} for the lag alone)")
    return ("t_servo",), (f"servo lag estimated; a rate limit not supported by the data (BIC "
                          f"{both.bic:.1f} vs {lag.bic:.1f} for the lag alone)")


@dataclass(frozen=True)
class OrderChoice:
    """Result of the held-out model-structure comparison of one record.

    Attributes
    ----------
    order : int
        1 or ``ORDER2_SUM_PRODUCT``.
    note : str
        What was compared and why this order (for the fit's message).
    unsure : str
        Why the structure, and so K or T, is not decided by the data ('' when it is).
    first_white : bool
        The first-order training fit's residuals passed the whiteness test.
    """

    order: int
    note: str
    unsure: str = ""
    first_white: bool = False


def choose_order(rec: NomotoRecord | Sequence[NomotoRecord], channels: tuple[str, ...],
                  servo: tuple[str, ...]) -> OrderChoice:
    """First or second order by the held-out one-step prediction errors of the record's end.

    Both orders are fitted on the first ``1 - HOLDOUT_FRACTION`` of the record with the noise model
    the first order's fit chose (white OE, or the wave PEM when the compass residuals are coloured)
    and run on through the rest; the held-out output errors of both are passed through the same
    noise filter (the first order's wave innovations filter, or none), so the wave motion on the
    compass is whitened away before the comparison. The second order is chosen when it passes the
    shared held-out significance rule (:func:`pipeline.fit.heldout_test.is_significant`, ``p`` = 3
    added parameters: T12, T1T2, T3 for T, and the initial yaw acceleration). When it does not pass
    but is not clearly worse either (a near-tie: held-out gap shrink above ``-MIN_SHRINK``) while
    the two structures' K or T differ materially (:func:`structure_ambiguity`), the choice is
    marked unsure.

    Several records (sinusoids at different frequencies, :func:`pipeline.fit.nomoto_structure.joint_sinusoids`)
    are fitted jointly (one ship, per-record initial states): the end of each is held out, each
    record's errors scaled by its own spread, and the robustness p-value leaves the most favourable
    record out. There the second order is also chosen when it passes the rule's p-value and explained
    error but not its shrink or robustness, if the records' own first-order T differ materially
    across their frequencies (:func:`frequency_spread`, which says why the shrink and the robustness
    fail such records by construction).

    Parameters
    ----------
    rec : NomotoRecord or sequence of NomotoRecord
        The record, or several records of one ship fitted jointly.
    channels : tuple of str
        Outputs fitted (``psi``, ``r``).
    servo : tuple of str
        Servo parameters estimated (a logged command), or empty.
    """
    recs = [rec] if isinstance(rec, NomotoRecord) else list(rec)
    n_fits = [int(round((1.0 - HOLDOUT_FRACTION) * r.t.size)) for r in recs]
    if any(nf < MIN_SAMPLES or r.t.size - nf < 10 for r, nf in zip(recs, n_fits)):
        return OrderChoice(1, "first-order Nomoto (record too short to hold out a part for the second-order check)")
    parts = [NomotoRecord(t=r.t[:nf], delta=r.delta[:nf], psi=None if r.psi is None else r.psi[:nf],
                          r=None if r.r is None else r.r[:nf], name=r.name) for r, nf in zip(recs, n_fits)]
    part = parts[0] if len(parts) == 1 else parts
    try:
        first = fit_nomoto(part, order=1, noise="auto", channels=channels, servo=servo)
    except FitError as exc:
        return OrderChoice(1, f"first-order Nomoto (the held-out check could not fit the first order: {exc})")
    if not _usable(first):
        return OrderChoice(1, "first-order Nomoto (its fit on the training part left the plausible range: "
                              "no held-out check)")
    first_peak = first.value("omega0") if "omega0" in first.names else math.nan
    slow = ""
    if len(recs) > 1 and first.noise_model == "waves" and slow_noise_note(first):
        # Joint sinusoids are open loop (output error is consistent): a wave noise model peaking below the
        # first order's corner frequency takes up its misfit of the other frequency, and its filter would
        # whiten away the very error the structures are compared on.
        try:
            oe = fit_nomoto(part, order=1, noise="white", channels=channels, servo=servo)
        except FitError:
            oe = None
        if oe is not None and _usable(oe):
            first = oe
            slow = (f"; the first order's wave noise model peaked below its corner frequency (omega0 = "
                    f"{first_peak:.3g} rad/s), taking up its misfit: output errors compared")
    white = all(t.white for t in first.residual_tests)
    noise = first.noise_model
    floor = GainFloor.from_first_order(first, part)
    try:
        second = fit_nomoto(part, order=ORDER2_SUM_PRODUCT, noise=noise, channels=channels, servo=servo,
                            start=first_order_start_values(first), gain_floor=floor)
    except SecondOrderNoGain as exc:
        return OrderChoice(1, f"first-order Nomoto: {exc} (training part)", first_white=white)
    except FitError:
        second = None
    if noise == "waves" and (second is None or not _usable(second)):
        try:
            second = fit_nomoto(part, order=ORDER2_SUM_PRODUCT, noise="white", channels=channels, servo=servo)
        except FitError:
            second = None
    white_note = "first-order training residuals white" if white else "first-order training residuals coloured"
    if second is None or not _usable(second):
        # A fit that ends out of range (the second order collapsing onto the first: T2 -> 0) is no candidate.
        collapsed = second is not None and "second order collapsing onto the first" in second.message
        how = (" (collapsing onto the first order: its zero cancels a pole, so it was not re-solved)"
               if collapsed else "")
        return OrderChoice(1, f"first-order Nomoto: the second order did not converge in range on the training "
                              f"part{how} ({white_note})", first_white=white)
    filt = first if noise == "waves" else None
    e0 = _heldout_errors(first, recs, channels, servo, n_fits, filt)
    e1 = _heldout_errors(second, recs, channels, servo, n_fits, filt)
    scores = []
    for ch in channels:
        rows0, rows1 = [], []
        for i, r in enumerate(recs):
            a, b = e0[i][ch], e1[i][ch]
            if (np.isfinite(a) & np.isfinite(b)).sum() < 10:
                continue
            y = rec_channel(r, ch)
            scale = max(float(np.std(y[np.isfinite(y)])), 1e-12)
            rows0.append(a / scale)
            rows1.append(b / scale)
        if not rows0:
            continue
        a, b = stack_rows(rows0), stack_rows(rows1)
        cs = channel_score(ch, a, b, ORDER2_EXTRA_PARAMS, a.shape[0], math.nan)
        shrink = 100.0 * (1.0 - cs.gap_after / cs.gap_before) if cs.gap_before > 0 else 0.0
        robust = math.nan
        if a.shape[0] > 1:
            gain = np.nansum(a**2, axis=1) - np.nansum(b**2, axis=1)
            keep = np.arange(a.shape[0]) != int(np.argmax(gain))
            robust = channel_score(ch, a[keep], b[keep], ORDER2_EXTRA_PARAMS, int(keep.sum()), math.nan).p_value
        scores.append((cs, shrink, robust))
    if not scores:
        return OrderChoice(1, "first-order Nomoto (no held-out samples to compare)", first_white=white)
    cs, shrink, robust = min(scores, key=lambda s: s[0].p_value if math.isfinite(s[0].p_value) else 1.0)
    pv = min(1.0, (cs.p_value if math.isfinite(cs.p_value) else 1.0) * len(scores))
    p_rob = min(1.0, robust * len(scores)) if math.isfinite(robust) else math.nan
    sig = is_significant(pv, p_rob, shrink, cs.explained)
    kind = "wave-whitened one-step prediction errors" if filt is not None else "output errors"
    where = (f"{HOLDOUT_FRACTION:.0%} of the record" if len(recs) == 1 else
             f"the last {HOLDOUT_FRACTION:.0%} of each of {len(recs)} records fitted jointly, with the most "
             f"favourable record left out p = {p_rob:.2g}")
    text = (f"held-out {kind} ({where}, channel {cs.channel}): RMS first order "
            f"{cs.gap_before:.4g}, second order {cs.gap_after:.4g} ({shrink:+.1f} % shrink, p = {pv:.2g}, "
            f"shared rule p < {ALPHA:g} and shrink >= {MIN_SHRINK:g} %){slow}; {white_note}")
    if sig:
        return OrderChoice(ORDER2_SUM_PRODUCT, f"second-order Nomoto (T1, T2, T3) selected: {text}", first_white=white)
    if len(recs) > 1 and pv < ALPHA and cs.explained >= MIN_EXPLAINED:
        spread = frequency_spread(parts, channels, servo)
        if spread.material:
            return OrderChoice(ORDER2_SUM_PRODUCT, f"second-order Nomoto (T1, T2, T3) selected: {text}; below the "
                                                   f"shrink or robustness the shared rule asks, but {spread.note}",
                               first_white=white)
    unsure = ""
    if shrink > -MIN_SHRINK:
        unsure = structure_ambiguity(first, second)
    return OrderChoice(1, f"first-order Nomoto selected: {text}", unsure, first_white=white)


@dataclass(frozen=True)
class FrequencySpread:
    """The first-order T of each of several jointly fitted records, fitted alone (:func:`frequency_spread`).

    Attributes
    ----------
    material : bool
        The records' own T disagree beyond their errors and by more than ``STRUCTURE_MATERIAL``.
    note : str
        The values and the test, for the order note.
    """

    material: bool
    note: str


def frequency_spread(parts: Sequence[NomotoRecord], channels: tuple[str, ...], servo: tuple[str, ...]) -> FrequencySpread:
    """Whether records of one ship at different frequencies each call for a different first-order T.

    A sinusoid shows a gain and a phase at one frequency, and a first-order model matches any ship
    there: each record fitted alone leaves white residuals whatever the ship's structure. A ship
    beyond the first order (a pole-zero pair, an unmodelled servo) shows only across frequencies, as
    a first-order T that changes with the frequency. This is the evidence :func:`choose_order` asks
    of jointly fitted records in place of the shared rule's shrink and robustness
    (:func:`pipeline.fit.heldout_test.is_significant`), which fail such records by construction: the
    jointly fitted first order is a compromise weighted by the records' signal, so its misfit sits
    on the record with the smaller heading swing (leaving that record out leaves no gain: with two
    records the robustness p-value was 0.34 and 1 on two of three seeds), where sensor noise
    dominates the held-out error and dilutes the shrink (measured: PythonVehicleSimulator's tanker
    at 20 m, complex poles, measured-rudder sinusoids at 0.066 and 0.017 rad/s without waves: held-out
    shrink 5.1-5.9 % at p = 1e-52 to 1e-65, the records' own first-order T 13.1-13.9 s and 10.0-10.1 s,
    chi-square 108-171 on 1 dof; the first order kept, K and T were combined from the two frequencies'
    first-order matches, K +8.3 % and T +27 % off over 13 seeds).

    The records' first-order output-error fits (each alone: consistent for open-loop sinusoids,
    Newey-West errors where their residuals are coloured) disagree materially when their T spread,
    max - min, exceeds ``STRUCTURE_MATERIAL`` of their weighted mean and the chi-square of their
    differences from it has ``p < ALPHA_ROBUST``. A first-order ship's T does not depend on the
    frequency (measured: the frigate's measured-rudder sinusoids, seeds 1-2: 24.72 and 24.68 s, 24.58 and 24.66 s, p = 0.61 and 0.36), nor on
    which record is left out.

    Parameters
    ----------
    parts : sequence of NomotoRecord
        The training parts of the records.
    channels : tuple of str
        Outputs fitted.
    servo : tuple of str
        Servo parameters estimated (a logged command), or empty.
    """
    values, errors = [], []
    for part in parts:
        try:
            fit = fit_nomoto(part, order=1, noise="white", channels=channels, servo=servo)
        except FitError:
            return FrequencySpread(False, "")
        se = fit.reported_error("T")
        if not (_usable(fit) and math.isfinite(se) and se > 0):
            return FrequencySpread(False, "")
        values.append(fit.T)
        errors.append(se)
    v, s = np.array(values), np.array(errors)
    w = 1.0 / s**2
    mean = float(np.sum(w * v) / np.sum(w))
    chi2 = float(np.sum(w * (v - mean) ** 2))
    p = float(stats.chi2.sf(chi2, v.size - 1))
    spread = float(np.ptp(v)) / abs(mean) if mean != 0 else math.inf
    material = bool(p < ALPHA_ROBUST and spread > STRUCTURE_MATERIAL)
    note = (f"the records' own first-order T {', '.join(f'{x:.4g} +- {e:.2g}' for x, e in zip(v, s))} s "
            f"{'differ' if material else 'do not differ materially'} across their frequencies (spread "
            f"{100 * spread:.0f} % of {mean:.4g} s, chi-square {chi2:.3g} on {v.size - 1} dof, p = {p:.2g}; "
            f"material: > {100 * STRUCTURE_MATERIAL:.0f} % and p < {ALPHA_ROBUST:g}): a first-order ship's T does not "
            f"depend on the frequency")
    return FrequencySpread(material, note)


def stack_rows(rows: list[np.ndarray]) -> np.ndarray:
    """Rows of unequal length stacked, NaN-padded (one row per record or segment).

    Parameters
    ----------
    rows : list of numpy.ndarray
        1-D arrays.
    """
    width = max(r.size for r in rows)
    out = np.full((len(rows), width), np.nan)
    for i, r in enumerate(rows):
        out[i, : r.size] = r
    return out


#: Parameters the second-order model adds on the held-out test (T12, T1T2, T3 for T; rdot0).
ORDER2_EXTRA_PARAMS = 3
#: Relative difference of K or T between the structures that makes a near-tie matter [-].
STRUCTURE_MATERIAL = 0.10
#: Start of the window note of a rudder logged as a measured angle (read by
#: :func:`pipeline.fit.nomoto_structure.with_rudder_timing_note`).
MEASURED_RUDDER = "rudder logged as a measured angle"


def first_order_start_values(first: NomotoFit) -> dict[str, float]:
    """Start values for a second-order fit from a first-order one: K, T, b, the servo and the initial
    heading and yaw rate of every record (the second order's first start then reproduces the first-order
    fit, :func:`pipeline.fit.nomoto_oe.fit_nomoto`).

    Parameters
    ----------
    first : NomotoFit
        First-order fit of the same record(s).
    """
    return {n: float(v) for n, v in zip(first.names, first.values)
            if (n in ("K", "T", "b") + SERVO_PARAMS or n.split("[")[0] in ("psi0", "r0")) and math.isfinite(v)}


def structure_ambiguity(first: NomotoFit, second: NomotoFit) -> str:
    """Why a near-tie between the structures leaves K or T undecided ('' when it does not).

    K or T is undecided when the first- and second-order fits (first-order equivalent
    ``T = T1 + T2 - T3``, error from the covariance) differ by more than ``STRUCTURE_MATERIAL``
    of the first-order value and by more than twice their combined standard error.

    Parameters
    ----------
    first, second : NomotoFit
        First-order and second-order fits of the same data.
    """
    out = []
    for name in KEY_PARAMS:
        v1, s1 = first.value(name), first.error(name)
        v2, s2 = (second.K, second.error("K")) if name == "K" else (second.T, equivalent_t_stderr(second))
        diff = abs(v2 - v1)
        se = math.sqrt(s1**2 + s2**2) if math.isfinite(s1) and math.isfinite(s2) else 0.0
        if diff > STRUCTURE_MATERIAL * abs(v1) and diff > 2.0 * se:
            out.append(f"{name} {v1:.4g} (first order) vs {v2:.4g} (second order)")
    if not out:
        return ""
    return ("unsure: the held-out data do not decide between first- and second-order Nomoto (near-tie), and "
            f"their estimates differ materially: {', '.join(out)}")


def equivalent_t_stderr(fit: NomotoFit) -> float:
    """Standard error of the first-order equivalent ``T = T1 + T2 - T3`` [s] from the covariance.

    Parameters
    ----------
    fit : NomotoFit
        A first- or second-order fit.
    """
    if fit.order == 1:
        return fit.error("T")
    g = np.array([1.0 if n in ("T1", "T2", "T12") else -1.0 if n == "T3" else 0.0 for n in fit.names])
    if not np.all(np.isfinite(fit.covariance)):
        return math.nan
    return float(math.sqrt(max(g @ fit.covariance @ g, 0.0)))


def rec_channel(rec: NomotoRecord, ch: str) -> np.ndarray:
    """One output channel of a record (heading unwrapped) [rad or rad/s].

    Parameters
    ----------
    rec : NomotoRecord
        The record.
    ch : str
        ``psi`` or ``r``.
    """
    return unwrap_heading(rec.psi) if ch == "psi" else np.asarray(rec.r, float)


def _usable(fit: NomotoFit) -> bool:
    """Converged with the ship's parameters in range (a servo lag collapsing to zero is allowed:
    the other structure may not need it)."""
    return fit.converged and all(n in SERVO_PARAMS for n in fit.at_bound) and bool(np.all(np.isfinite(fit.values)))


def _heldout_errors(fit: NomotoFit, recs: Sequence[NomotoRecord], channels: tuple[str, ...],
                    servo: tuple[str, ...], n_fits: Sequence[int], noise: NomotoFit | None) -> list[dict[str, np.ndarray]]:
    """Held-out errors per record and channel (NaN outside each record's held-out part): the fit
    simulated over the whole records from their training starts; the compass error whitened by
    ``noise``'s wave filter if given."""
    waves = noise.waves if noise is not None else None
    var = noise.noise_var.get("psi") if noise is not None else None
    kind = "waves" if waves is not None and var is not None and var > 0 else "white"
    prob = Problem([prepare(r, i, channels) for i, r in enumerate(recs)], fit.order, "b" in fit.names, channels,
                   kind, waves if kind == "waves" else None, var if kind == "waves" else None, servo)
    z = prob.solver_vector(np.array([fit.value(nm) for nm in prob.names]))
    out = []
    for i, per in enumerate(prob.channel_residuals(z)):
        rec_out = {}
        for ch in channels:
            m = prob.recs[i].mask[ch]
            e = np.full(m.size, np.nan)
            e[m] = per[ch]
            e[: n_fits[i]] = np.nan
            rec_out[ch] = e
        out.append(rec_out)
    return out


def segment_fit_of(segment: Segment, fit: NomotoFit, rec: NomotoRecord, channels: tuple[str, ...], t_rel: np.ndarray,
                 notes: list[str], unsure: str = "", record: int = 0, slow_noise_checked: str = "") -> SegmentFit:
    """The SegmentFit of ``segment`` from ``fit``, whose record ``record`` is ``rec`` (a joint fit of
    several records gives each of its segments its own record's heading and simulation).

    Parameters
    ----------
    segment : Segment
        The segment the fit belongs to.
    fit : NomotoFit
        The whole-record fit (first order, or the second order as K, T12, T1T2, T3).
    rec : NomotoRecord
        The segment's record (its heading is the fit's ``y``).
    channels : tuple of str
        Outputs fitted; the first is the fit's channel.
    t_rel : numpy.ndarray
        Sample times relative to ``segment.t_start`` [s].
    notes : list of str
        What was decided, for the message.
    unsure : str
        Why K or T is undecided ('' when they are not): marks the fit failed.
    record : int
        Index of ``rec`` among the fit's records.
    slow_noise_checked : str
        Why a wave noise model below the corner frequency does not bias K and T here (it then
        replaces :func:`slow_noise_note`, measured by the caller); '' to apply that note.
    """
    main = channels[0]
    if fit.robust_covariance is not None:
        # Coloured residuals: the Newey-West errors are the ones to report (nomoto_oe).
        fit = replace(fit, stderr=fit.robust_stderr, covariance=fit.robust_covariance)
    model = "nomoto_oe" if fit.noise_model == "white" else "nomoto_pem"
    params = {n: float(v) for n, v in zip(fit.names, fit.values)}
    stderr = {n: float(s) for n, s in zip(fit.names, fit.stderr)}
    if fit.order != 1:
        # First-order equivalent T = T1 + T2 - T3 (Fossen 2021, eq. 7.41), its error from the covariance.
        g = np.array([1.0 if n in ("T1", "T2", "T12") else -1.0 if n == "T3" else 0.0 for n in fit.names])
        params["T"] = fit.T
        stderr["T"] = float(math.sqrt(max(g @ fit.covariance @ g, 0.0))) if np.all(np.isfinite(fit.covariance)) \
            else math.nan
        if fit.order == ORDER2_SUM_PRODUCT:
            poles = pole_time_constants(params["T12"], params["T1T2"])
            if poles is None:
                notes = notes + [f"complex pole pair: T1 + T2 = {params['T12']:.4g} s, T1 T2 = {params['T1T2']:.4g} s^2 "
                                 f"(T1, T2 not real)"]
            else:
                params["T1"], params["T2"] = poles
                # Delta method: T1,2 = (S +- D)/2 with D = sqrt(S^2 - 4P), S = T1 + T2, P = T1 T2.
                i, j = fit.names.index("T12"), fit.names.index("T1T2")
                cov = fit.covariance[np.ix_([i, j], [i, j])]
                d = poles[0] - poles[1]
                for name, sign in (("T1", 1.0), ("T2", -1.0)):
                    g = np.array([0.5 * (1.0 + sign * params["T12"] / d), -sign / d]) if d > 0 else np.full(2, np.nan)
                    stderr[name] = float(math.sqrt(max(g @ cov @ g, 0.0))) if np.all(np.isfinite(g)) else math.nan
    fail = [unsure] if unsure else []
    if not fit.converged:
        fail.append("solver did not converge")
    if fit.at_bound:
        fail.append(f"parameter(s) {', '.join(fit.at_bound)} outside the plausible range")
    if not np.all(np.isfinite(fit.stderr)):
        fail.append("covariance not computed")
    for name in KEY_PARAMS:
        v, se = params[name], stderr[name]
        if math.isfinite(se) and abs(se) > MAX_RELATIVE_STDERR * abs(v):
            fail.append(f"{name} = {v:.4g} +- {se:.2g} has a relative standard error above "
                        f"{MAX_RELATIVE_STDERR:.0%}: not identified")
    notes = [fit.message] + notes
    slow = slow_noise_note(fit)
    if slow:
        notes.append(slow_noise_checked or slow)
    if segment.kind == "zigzag" and not all(t.independent for t in fit.residual_tests):
        notes.append("a zig-zag switches the rudder on the heading, so residuals that lead the rudder "
                     "(negative lags) are the expected feedback, not a model error")
    y = rec.psi if main == "psi" else rec.r
    y = unwrap_heading(y) if main == "psi" else np.asarray(y, float)
    e = fit.residuals[record][main]
    rmse = float(np.sqrt(np.nanmean(e**2)))
    return SegmentFit(segment=segment, model=model, channel=main, param_names=fit.names, params=params,
                      stderr=stderr, covariance=fit.covariance, t=t_rel, y=y, y_fit=fit.y_fit[record][main], rmse=rmse,
                      aic=fit.aic, bic=fit.bic, success=not fail, message="; ".join(fail + notes))


#: Samples per chunk whose median is one speed level in :func:`speed_range_note` (at least).
SPEED_CHUNK_SAMPLES = 25
#: Chunks a window's speed is read in (fewer when the window is short).
SPEED_CHUNKS = 10


#: Longest stretch before a zig-zag read as its straight run in :func:`speed_range_note` [s].
LEAD_SPEED_SECONDS = 120.0
#: Largest offset of the rudder in that stretch from the zig-zag's centre, as a share of its amplitude,
#: for the stretch to count as the straight run before it (a rudder held near midships).
LEAD_RUDDER_SHARE = 0.25
#: Largest spread of the lead's chunk medians, relative to their median, for a steady straight run [-]
#: (a coast-down, a throttle change or a start from rest before the manoeuvre is no straight-run speed).
LEAD_STEADY_SHARE = 0.05


def speed_range_note(rows, lead=None) -> str:
    """The speed a ship lost in the turns of a Nomoto window, as a note (``SPEED_RANGE``; '' when none).

    Nomoto's K and T scale with the speed (``K = K' U / L``, ``T = T' L / U``; Fossen 2021, sec.
    7.2), and a ship slows in a turn: a K or T fitted over a record whose turns ran slower than its
    straight runs is the ship's at some speed between the two, not at the straight-run speed of its
    linearisation (measured: PythonVehicleSimulator's tanker at 25 m slows from 7.19 to 6.64 m/s in
    its 10 deg rudder steps, and every step's K is 4-6 % below the straight-run linearisation).
    The speed is read as the medians of up to ``SPEED_CHUNKS`` consecutive chunks of at least
    ``SPEED_CHUNK_SAMPLES`` samples (sensor noise averaged out), of ``sog`` when logged, else of the
    surge speed ``u``, and so is the squared yaw rate; the note gives the speed of the window's
    straighter end (first or last chunk, the one with the smaller yaw rate: the steady hold before a
    step into a turn, or the straight run after a step out of it) less that of its turning end,
    relative to the former, or 0 when the turning end is the faster one (a throttle opened with the
    rudder, as in a manoeuvre started from rest, is no speed lost to the turn; the steady ends, not
    a line through the chunks, because the speed lags the yaw rate by the surge time constant and
    a throttle cut inside the window would tilt a line). :func:`pipeline.fit.nomoto_quality.add_speed_term` turns the largest loss
    behind a combined K or T into an error term.

    Both ends of a zig-zag turn (measured: PythonVehicleSimulator's tanker at 25 m, 10/10 zig-zag,
    7.14 m/s in its first tenth, 6.77 m/s in its last, 7.19 m/s in the straight run before it: the
    ends gave 0 loss where the ship lost 5.9 %). With ``lead``, the rows before such a manoeuvre, the
    straight-run speed is the median speed of ``lead`` when at least ``SPEED_CHUNK_SAMPLES`` of them
    have a speed and their median rudder lies within ``LEAD_RUDDER_SHARE`` of the manoeuvre's rudder
    amplitude from its centre (the midpoint of its 5th and 95th percentiles: a rudder held near
    midships, the straight run before the manoeuvre; the yaw rate cannot tell, waves of 0.3 deg/s
    drown a slow ship's turn rate) and its chunk medians spread by at most ``LEAD_STEADY_SHARE`` of
    their median (a steady speed: the bundled sample's zig-zag follows a coast-down to rest and
    starts from rest, whose lead read as a 48.7 % "loss"), and the turning speed is the slowest
    chunk's; otherwise the window's ends are compared as above.

    Parameters
    ----------
    rows : pandas.DataFrame
        The window's rows of the trial (``r``, or ``psi`` and ``t``, for the yaw rate; ``delta`` for
        the rudder when ``lead`` is given).
    lead : pandas.DataFrame, optional
        The trial's rows just before a manoeuvre whose ends both turn (a zig-zag) [same columns].
    """
    if "r" in rows and np.isfinite(rows["r"].to_numpy(dtype=float)).any():
        r = rows["r"].to_numpy(dtype=float)
    elif "psi" in rows and "t" in rows:
        r = np.gradient(np.unwrap(rows["psi"].to_numpy(dtype=float)), rows["t"].to_numpy(dtype=float))
    else:
        return ""
    for ch in ("sog", "u"):
        if ch not in rows:
            continue
        u = rows[ch].to_numpy(dtype=float)
        ok = np.isfinite(u) & np.isfinite(r)
        n = min(SPEED_CHUNKS, int(ok.sum()) // SPEED_CHUNK_SAMPLES)
        if n < 3:
            return ""
        speed = np.array([np.median(c) for c in np.array_split(np.abs(u[ok]), n)])
        r2 = np.array([np.median(c) for c in np.array_split(r[ok] ** 2, n)])
        if not np.ptp(r2) > 0:
            return ""
        before = lead_speed(lead, rows, ch)
        if before is not None:
            straight, turning = before, float(speed.min())
            where = "in the straight run before the manoeuvre", "in its slowest tenth"
        else:
            # The straighter end (smaller yaw rate) against the end that turns harder.
            straight, turning = (speed[0], speed[-1]) if r2[0] <= r2[-1] else (speed[-1], speed[0])
            where = "at the straighter end", "at the turning end"
        if not straight > 0:
            return ""
        loss = max(0.0, (straight - turning) / straight)
        return (f"{SPEED_RANGE} {loss:.4g} of the straight-run speed ({ch} {straight:.4g} m/s {where[0]}, "
                f"{turning:.4g} m/s {where[1]})")
    return ""


def lead_speed(lead, rows, ch: str) -> float | None:
    """Median speed ``ch`` of ``lead`` when it is the straight run before the manoeuvre in ``rows`` [m/s]
    (None otherwise; see :func:`speed_range_note`).

    Parameters
    ----------
    lead : pandas.DataFrame or None
        The rows before the manoeuvre (``delta`` and ``ch``).
    rows : pandas.DataFrame
        The manoeuvre's rows (``delta``).
    ch : str
        The speed column, ``sog`` or ``u``.
    """
    if lead is None or ch not in lead or "delta" not in lead or "delta" not in rows:
        return None
    u = np.abs(lead[ch].to_numpy(dtype=float))
    d_lead = lead["delta"].to_numpy(dtype=float)
    d = rows["delta"].to_numpy(dtype=float)
    ok = np.isfinite(u) & np.isfinite(d_lead)
    d = d[np.isfinite(d)]
    if ok.sum() < SPEED_CHUNK_SAMPLES or d.size < SPEED_CHUNK_SAMPLES:
        return None
    lo, hi = np.percentile(d, [5.0, 95.0])
    if not hi > lo or abs(float(np.median(d_lead[ok])) - 0.5 * (lo + hi)) > LEAD_RUDDER_SHARE * 0.5 * (hi - lo):
        return None
    n = min(SPEED_CHUNKS, int(ok.sum()) // SPEED_CHUNK_SAMPLES)
    chunks = np.array([np.median(c) for c in np.array_split(u[ok], n)])
    straight = float(np.median(u[ok]))
    if not straight > 0 or np.ptp(chunks) > LEAD_STEADY_SHARE * straight:
        return None
    return straight


def slow_noise_note(fit: NomotoFit) -> str:
    """Why K and T are undecided when the wave noise model sits on the ship's own time scale ('' otherwise).

    The wave PEM's coloured noise stands for wave-induced yaw, which is separable from the ship's
    response to its rudder only at frequencies above the ship's corner frequency ``1/T`` (waves are
    fast, the manoeuvre is slow). A fitted peak ``omega0 < 1/T`` is the first-order model's own
    misfit of the manoeuvre (a servo, a pole-zero pair, nonlinearity) taken up as "noise": K and T
    are then biased by what the noise absorbs and their errors do not show it (measured on
    PythonVehicleSimulator's tanker at 20 m, zig-zag with the command logged and no waves:
    ``omega0`` = 0.0085 rad/s against ``1/T`` = 0.13 rad/s, K -5.5 % +- 0.35 %). The note starts with
    ``STRUCTURE_UNDECIDED`` and names K and T.

    Parameters
    ----------
    fit : NomotoFit
        A whole-record fit.
    """
    if fit.noise_model != "waves" or "omega0" not in fit.names:
        return ""
    omega0, T = fit.value("omega0"), fit.T
    if not (math.isfinite(omega0) and math.isfinite(T) and T > 0 and omega0 < 1.0 / T):
        return ""
    return (f"{STRUCTURE_UNDECIDED} K T: the wave noise model's peak, omega0 = {omega0:.3g} rad/s, lies below the "
            f"ship's corner frequency 1/T = {1.0 / T:.3g} rad/s, where the rudder drives the heading: the 'noise' "
            f"is the model's misfit of the manoeuvre (servo, pole-zero pair or nonlinear dynamics the structure "
            f"lacks), and K and T carry a bias their errors do not show")


def rudder_step_lead_in(trial: Trial, segment: Segment) -> float:
    """Start [s] of the steady rudder hold before a rudder step (at most the step's own length back).

    The whole-record fit of a step needs the rudder level before the change and the yaw rate it
    held there: together they separate K from the rudder bias.

    Parameters
    ----------
    trial : Trial
        The trial.
    segment : Segment
        A ``rudder_step`` (``input_before`` is the hold's level [rad]).
    """
    t = trial.t
    delta = trial.data["delta"].to_numpy(dtype=float)
    i0 = int(np.searchsorted(t, segment.t_start))
    lo = int(np.searchsorted(t, segment.t_start - segment.duration))
    noise = noise_sigma(delta[lo:i0]) if i0 - lo > 4 else 0.0
    tol = max(4 * (noise if math.isfinite(noise) else 0.0),
              0.05 * abs(segment.input_after - segment.input_before), 1e-9)
    k = i0 - 1
    while k >= lo and np.isfinite(delta[k]) and abs(delta[k] - segment.input_before) <= tol and \
            not any(g.t_start <= t[k] <= g.t_end for g in trial.gaps):
        k -= 1
    return float(t[min(k + 1, i0)]) if i0 > 0 else float(segment.t_start)


#: Extra Nomoto coefficients a segment fit may carry: parameter -> (estimate name, unit).
EXTRA_COEFFICIENTS = {"T1": ("T1_nomoto", "s"), "T2": ("T2_nomoto", "s"), "T3": ("T3_nomoto", "s"),
                      "T12": ("T12_nomoto", "s"), "T1T2": ("T1T2_nomoto", "s^2"),
                      "t_servo": ("T_servo", "s"), "rate_servo": ("rate_servo", "rad/s")}


def structure_note(fits: Sequence[SegmentFit]) -> str:
    """What the model structures chosen per segment say, when they differ ('' when they agree).

    Parameters
    ----------
    fits : sequence of SegmentFit
        Successful Nomoto segment fits.
    """
    second = [segment_label(f.segment) for f in fits if "T3" in f.params]
    first = [segment_label(f.segment) for f in fits if "T3" not in f.params]
    if second and first:
        return (f"model structure differs between segments: second-order Nomoto chosen by held-out error on "
                f"{len(second)} ({', '.join(second[:3])}{', ...' if len(second) > 3 else ''}), first order on "
                f"{len(first)}; K and T combine the first-order equivalents, and a disagreement between the "
                f"segments points at the unmodelled pole-zero pair")
    return ""
