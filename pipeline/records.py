"""The records that flow between stages, top to bottom in flow order.

``ingest`` -> :class:`RawLog`; ``align`` -> :class:`Trial`; ``segment`` -> :class:`Segments`;
``fit`` -> :class:`Fits`. Every record is frozen: a stage returns a new record and never mutates
its input. Units are SI and angles radians throughout (see ``CHANNEL_UNITS``); frames are Fossen's
(NED world, body x forward, y starboard, z down).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
import pandas as pd

from . import __version__

# --------------------------------------------------------------------------- channels
#: Canonical state channels and their SI units (DESIGN.md, "Canonical CSV log").
STATE_UNITS: Mapping[str, str] = {
    "u": "m/s", "v": "m/s", "w": "m/s",
    "p": "rad/s", "q": "rad/s", "r": "rad/s",
    "phi": "rad", "theta": "rad", "psi": "rad",
    "x_n": "m", "y_e": "m",
    "lat": "deg", "lon": "deg",
    "sog": "m/s", "cog": "rad",
    "ax": "m/s^2", "ay": "m/s^2", "az": "m/s^2",
}
#: Canonical input channels and their SI units.
INPUT_UNITS: Mapping[str, str] = {
    "delta": "rad",
    "tau_x": "N", "tau_y": "N",
    "tau_k": "N m", "tau_m": "N m", "tau_n": "N m",
}
CHANNEL_UNITS: Mapping[str, str] = {**STATE_UNITS, **INPUT_UNITS}
#: How an input channel was logged: ``command`` (what a controller ordered; the actuator holds it
#: until the next one, so it is resampled by zero-order hold) or ``measured`` (an actuator state
#: from a sensor, a rudder-angle transducer or shaft rpm: a continuous signal, interpolated like
#: the states). An input without a stated kind is a ``command`` (the default of every reader).
INPUT_KINDS = ("command", "measured")
#: Channels that are angles and wrap at +-pi.
ANGLE_CHANNELS = frozenset({"phi", "theta", "psi", "cog"})

#: DOF order of the 5-DOF damping matrix (AAUSHIP seed): velocity symbol -> DOF name.
DOFS: tuple[str, ...] = ("u", "v", "p", "q", "r")
DOF_NAMES: Mapping[str, str] = {"u": "surge", "v": "sway", "p": "roll", "q": "pitch", "r": "yaw"}
#: DOF name -> (velocity channel, generalised-force channel).
DOF_CHANNELS: Mapping[str, tuple[str, str]] = {
    "surge": ("u", "tau_x"), "sway": ("v", "tau_y"), "roll": ("p", "tau_k"),
    "pitch": ("q", "tau_m"), "yaw": ("r", "tau_n"),
}
#: DOF name -> attitude channel, for the DOFs that have restoring.
DOF_ANGLE: Mapping[str, str] = {"roll": "phi", "pitch": "theta", "yaw": "psi"}


# --------------------------------------------------------------------------- ingest
@dataclass(frozen=True)
class Channel:
    """One canonical channel as sampled by one sensor.

    Attributes
    ----------
    name : str
        Canonical name (``CHANNEL_UNITS``).
    t : numpy.ndarray
        Sample times [s] on the source clock, strictly increasing.
    values : numpy.ndarray
        Samples in the canonical SI unit of ``name``.
    source : str
        Where the samples came from (message type, topic or CSV column).
    input_kind : str
        Inputs only: ``command`` (held until the next sample) or ``measured`` (interpolated),
        see ``INPUT_KINDS``; empty means the default, ``command``. Ignored for states.
    """

    name: str
    t: np.ndarray
    values: np.ndarray
    source: str = ""
    input_kind: str = ""

    @property
    def held(self) -> bool:
        """True for an input command, resampled by zero-order hold (False for states and measured inputs)."""
        return self.name.split("@", 1)[0] in INPUT_UNITS and self.input_kind != "measured"

    @property
    def unit(self) -> str:
        """SI unit of the channel."""
        return CHANNEL_UNITS.get(self.name, "")


@dataclass(frozen=True)
class IngestSummary:
    """What a reader did with a file: messages read and skipped per type, and warnings.

    Attributes
    ----------
    path : str
        The file read.
    format : str
        Format name (``csv``, ``tlog``, ...).
    read : Mapping[str, int]
        Messages (or rows) used, per message type.
    skipped : Mapping[str, int]
        Messages seen but not used, per type (unmapped types, bad CRC, out-of-order stamps).
    warnings : tuple[str, ...]
        Human-readable notes on anything unusual, each with counts.
    """

    path: str
    format: str
    read: Mapping[str, int] = field(default_factory=dict)
    skipped: Mapping[str, int] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()

    def text(self) -> str:
        """One-paragraph summary for the terminal and the report."""
        used = ", ".join(f"{k} {v}" for k, v in sorted(self.read.items())) or "none"
        skip = ", ".join(f"{k} {v}" for k, v in sorted(self.skipped.items())) or "none"
        lines = [f"{self.path} [{self.format}]: read {used}; skipped {skip}"]
        lines += [f"  warning: {w}" for w in self.warnings]
        return "\n".join(lines)


@dataclass(frozen=True)
class RawLog:
    """A log file read into canonical channels, each on its own timestamps.

    The simulator produces the same record (``format='sim'``) before a writer puts it in a file,
    so a round trip write -> read can be compared channel by channel.

    Attributes
    ----------
    source : str
        Path of the file, or a description for simulated logs.
    format : str
        Format name.
    channels : Mapping[str, Channel]
        Canonical channels; a second sensor of the same quantity uses ``name@sensor``
        (for example ``sog@gps2``).
    summary : IngestSummary
        Reader summary.
    time_reference : str
        What ``t = 0`` means: ``boot`` (autopilot boot), ``trial`` (trial start), ``gps``, ``unix``.
    start_time : float
        Absolute UTC time of ``t = 0`` [s since the Unix epoch, leap seconds removed as in Unix
        time]; NaN when the source has no absolute clock. Readers set it where the format gives
        it (GPS week and time of week, an NMEA date, MAVLink SYSTEM_TIME, wall-clock ROS stamps),
        so :func:`pipeline.align.clock.estimate_offsets` can put several files on one clock.
    time_of_day : float
        UTC time of day of ``t = 0`` [s after midnight] when the source gives the time but not
        the date (NMEA GGA/VTG without RMC); NaN otherwise. Two such logs of one day are compared
        by it, so recordings that do not overlap are never merged into one run.
    """

    source: str
    format: str
    channels: Mapping[str, Channel]
    summary: IngestSummary
    time_reference: str = "trial"
    start_time: float = math.nan
    time_of_day: float = math.nan

    def channel(self, name: str) -> Channel:
        """Return channel ``name`` or raise ``KeyError`` naming the channels present.

        Parameters
        ----------
        name : str
            Canonical channel name (``psi``, ``r``, ``delta``, ...).
        """
        try:
            return self.channels[name]
        except KeyError:
            raise KeyError(f"channel {name!r} not in {self.source}; found {sorted(self.channels)}") from None


# --------------------------------------------------------------------------- align
@dataclass(frozen=True)
class Gap:
    """A dropout in one channel, longer than the aligner's gap threshold.

    Attributes
    ----------
    channel : str
        Channel with the dropout.
    t_start, t_end : float
        Last sample before and first sample after the gap [s, trial clock].
    """

    channel: str
    t_start: float
    t_end: float


@dataclass(frozen=True)
class Run:
    """One recording of a trial: the sensor logs that share one clock.

    A trial day is many recordings (a new ArduPilot .bin at every arming, a pool roll-decay test
    in its own file). :func:`pipeline.align.align` groups logs into runs: logs that overlap in
    absolute time, or whose clocks a cross-correlation ties together, are sensors of one run;
    logs whose absolute times do not overlap are never merged. In ``Trial.data`` the runs are
    laid one after another on the trial clock, each followed by a NaN gap (a :class:`Gap` with
    channel ``RUN_BOUNDARY``), so no segment spans two runs. Anything that integrates the model
    over time (replay, simulation error, an initial state) must restart at each run's ``t_start``
    and never cross a run boundary.

    Attributes
    ----------
    name : str
        Run name (the manifest's, or the stem of its first file).
    sources : tuple[str, ...]
        Files of the run.
    offsets : Mapping[str, float]
        Clock offset added to each file's times [s] to put it on the run's clock.
    offset_stderr : Mapping[str, float]
        Standard error of each offset [s].
    start_time : float
        Absolute UTC of the run's first sample [s, Unix]; NaN when no file has an absolute clock.
    t_start, t_end : float
        First and last sample of the run [s, trial clock].
    reason : str
        Why these files form one run (and why it is separate from the others).
    input_kinds : Mapping[str, str]
        Input channel -> ``command`` (held) or ``measured`` (interpolated), as resampled.
    time_of_day : float
        UTC time of day of the first sample [s after midnight] when only that is known; NaN otherwise.
    """

    name: str
    sources: tuple[str, ...]
    offsets: Mapping[str, float] = field(default_factory=dict)
    offset_stderr: Mapping[str, float] = field(default_factory=dict)
    start_time: float = math.nan
    t_start: float = 0.0
    t_end: float = 0.0
    reason: str = ""
    input_kinds: Mapping[str, str] = field(default_factory=dict)
    time_of_day: float = math.nan

    @property
    def duration(self) -> float:
        """Run length [s]."""
        return self.t_end - self.t_start


#: ``Gap.channel`` of the NaN stretch that separates two runs in ``Trial.data``.
RUN_BOUNDARY = "(run boundary)"


@dataclass(frozen=True)
class Trial:
    """All logs of one trial on one uniform clock, in SI units and Fossen's body frame.

    Attributes
    ----------
    name : str
        Trial name.
    data : pandas.DataFrame
        Column ``t`` [s] from trial start on a uniform grid of rate ``fs``, and canonical channels.
        Samples inside a :class:`Gap` are NaN.
    fs : float
        Sample rate [Hz].
    gaps : tuple[Gap, ...]
        Dropouts; no segment may span one.
    sources : tuple[str, ...]
        Files the trial came from.
    notes : tuple[str, ...]
        What the aligner derived or estimated (clock offsets, derived body velocities, ...).
    summaries : tuple[IngestSummary, ...]
        Reader summaries of the source files.
    runs : tuple[Run, ...]
        The recordings, in trial-clock order (see :class:`Run`); each is followed in ``data`` by
        a NaN gap. Empty for a Trial built by hand: then the whole of ``data`` is one run
        (:meth:`run_list` says so).
    sample_times : Mapping[str, numpy.ndarray]
        Channels measured slower than the grid (a 5 Hz GNSS on a 10 Hz grid, and ``u``, ``v``
        derived from it) -> the trial-clock times [s] of their real measurements; between them
        ``data`` holds interpolated values, which are not measurements. A channel not named here
        is measured at every grid sample (or the Trial was built by hand). See
        :meth:`measured_rows`.
    """

    name: str
    data: pd.DataFrame
    fs: float
    gaps: tuple[Gap, ...] = ()
    sources: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    summaries: tuple[IngestSummary, ...] = ()
    runs: tuple[Run, ...] = ()
    sample_times: Mapping[str, np.ndarray] = field(default_factory=dict)

    def measured_rows(self, channel: str, t: np.ndarray) -> np.ndarray:
        """Which of the grid times ``t`` hold a real measurement of ``channel``.

        Parameters
        ----------
        channel : str
            Channel name (a column of ``data``).
        t : numpy.ndarray
            Grid times [s, trial clock], increasing.

        Returns
        -------
        numpy.ndarray
            Boolean mask over ``t``: all True when the channel is measured at every grid sample;
            else True at the grid sample nearest to each real measurement within half a grid
            step (a measurement between grid samples marks the nearer one).
        """
        t = np.asarray(t, float)
        times = self.sample_times.get(channel)
        if times is None or not len(t):
            return np.ones(t.shape, bool)
        times = np.asarray(times, float)
        times = times[(times >= t[0] - 0.5 / self.fs) & (times <= t[-1] + 0.5 / self.fs)]
        mask = np.zeros(t.shape, bool)
        if not len(times):
            return mask
        j = np.clip(np.searchsorted(t, times), 1, len(t) - 1) if len(t) > 1 else np.zeros(len(times), int)
        if len(t) > 1:
            j = np.where(np.abs(t[j - 1] - times) <= np.abs(t[j] - times), j - 1, j)
        near = np.abs(t[j] - times) <= 0.5 / self.fs + 1e-9
        mask[j[near]] = True
        return mask

    def run_list(self) -> tuple[Run, ...]:
        """The runs; a Trial without ``runs`` is one run spanning all of ``data``."""
        if self.runs:
            return self.runs
        t = self.t
        return (Run(self.name, tuple(self.sources), t_start=float(t[0]) if len(t) else 0.0,
                    t_end=float(t[-1]) if len(t) else 0.0, reason="one run (no grouping recorded)"),)

    def run_index(self, t: float) -> int:
        """Index of the run whose span holds ``t`` [s, trial clock]; the nearest run before a gap.

        Parameters
        ----------
        t : float
            Time on the trial clock [s].
        """
        runs = self.run_list()
        k = 0
        for i, run in enumerate(runs):
            if t >= run.t_start - 0.5 / max(self.fs, 1e-9):
                k = i
        return k

    def run_data(self, index: int) -> pd.DataFrame:
        """Rows of one run (its own span, without the NaN gap after it).

        Parameters
        ----------
        index : int
            Position in :meth:`run_list`.
        """
        run = self.run_list()[index]
        return self.window(run.t_start, run.t_end)

    @property
    def t(self) -> np.ndarray:
        """Time [s] from trial start."""
        return self.data["t"].to_numpy()

    def has(self, channel: str) -> bool:
        """True when ``channel`` is present and holds at least one finite sample.

        Parameters
        ----------
        channel : str
            Canonical channel name (a column of ``data``).
        """
        return channel in self.data.columns and bool(np.isfinite(self.data[channel].to_numpy()).any())

    def window(self, t_start: float, t_end: float) -> pd.DataFrame:
        """Rows with ``t_start <= t <= t_end`` [s].

        Parameters
        ----------
        t_start, t_end : float
            Window bounds [s, trial clock], both inclusive.
        """
        t = self.t
        return self.data.loc[(t >= t_start) & (t <= t_end)]


# --------------------------------------------------------------------------- segment
#: Segment kinds the detector and the manifest know.
SEGMENT_KINDS = ("coast_down", "step", "free_decay", "rudder_step", "zigzag", "sinusoid")
#: DOF names a segment may refer to.
SEGMENT_DOFS = ("surge", "sway", "heave", "roll", "pitch", "yaw")


@dataclass(frozen=True)
class Segment:
    """A stretch of a trial that one manoeuvre produced.

    Attributes
    ----------
    kind : str
        One of ``SEGMENT_KINDS``.
    dof : str
        DOF excited (``SEGMENT_DOFS``).
    t_start, t_end : float
        Bounds [s, trial clock]. For coast-downs and steps ``t_start`` is the input change.
    input_channel : str or None
        The input that drives the segment (``tau_x``, ``delta``, ...), None for free decays.
    input_before, input_after : float
        Input level before and after ``t_start`` [SI unit of ``input_channel``].
    quality : float
        0 (unusable) to 1 (clean): excitation over noise, length over time constant.
    origin : str
        ``detected`` or ``manifest``.
    label : str
        Free text (manifest name, detector note).
    run : int
        Index of the run (``Trial.run_list()``) the segment lies in; 0 for a single-run trial.
    cut_at_run_end : bool
        True when the end of its data ended the window, not the next input change: the end of its
        run (a file boundary with a gap to the next run, the end of the log or of its last run) or
        a dropout of its response or input. Its response may not have settled (the fit judges it).
    cut_by : str
        What ended the window when ``cut_at_run_end`` (``'the end of the log'``, ``'a dropout of r
        at t = 40.00-45.00 s'``, ...); '' otherwise.
    """

    kind: str
    dof: str
    t_start: float
    t_end: float
    input_channel: str | None = None
    input_before: float = 0.0
    input_after: float = 0.0
    quality: float = 1.0
    origin: str = "detected"
    label: str = ""
    run: int = 0
    cut_at_run_end: bool = False
    cut_by: str = ""

    @property
    def duration(self) -> float:
        """Segment length [s]."""
        return self.t_end - self.t_start


@dataclass(frozen=True)
class Segments:
    """The segments of one trial, in time order, and what the detector left out and why (``notes``)."""

    trial: str
    items: tuple[Segment, ...]
    notes: tuple[str, ...] = ()

    def of(self, kind: str | None = None, dof: str | None = None) -> tuple[Segment, ...]:
        """Segments of one kind and/or DOF.

        Parameters
        ----------
        kind : str, optional
            One of ``SEGMENT_KINDS``; None matches any kind.
        dof : str, optional
            One of ``SEGMENT_DOFS``; None matches any DOF.
        """
        return tuple(s for s in self.items if (kind is None or s.kind == kind) and (dof is None or s.dof == dof))


# --------------------------------------------------------------------------- fit
@dataclass(frozen=True)
class JointNomotoT:
    """The first-order equivalent T of one second-order Nomoto model fitted to several records at once
    (:mod:`pipeline.fit.nomoto_joint`), as :func:`pipeline.fit.nomoto_joint_value.joint_t_value` uses it.

    Attributes
    ----------
    value : float
        ``T1 + T2 - T3`` [s].
    stderr : float
        Its standard error [s] (Newey-West where the residuals stayed coloured).
    note : str
        The user-facing note (also in the segment fits' messages).
    """

    value: float
    stderr: float
    note: str = ""


@dataclass(frozen=True)
class SegmentFit:
    """The least-squares fit of one model to one segment (lmfit-style result).

    Attributes
    ----------
    segment : Segment
        The segment fitted.
    model : str
        Model name (``first_order_decay``, ``first_order_step``, ``damped_oscillation``, ...).
    channel : str
        Channel fitted.
    param_names : tuple[str, ...]
        Parameter names, in covariance order.
    params, stderr : Mapping[str, float]
        Values and standard errors (NaN where they could not be computed; ``message`` says why).
    covariance : numpy.ndarray
        Parameter covariance (Jacobian estimate scaled by the residual variance).
    t, y, y_fit : numpy.ndarray
        Time from segment start [s], data and model, for the figures.
    rmse : float
        Residual RMS [unit of ``channel``].
    aic, bic : float
        Information criteria of the fit.
    success : bool
        False when the fit did not converge or failed a sanity check.
    message : str
        Why a fit failed or what is doubtful about it.
    joint_t : JointNomotoT or None
        T of the joint second-order fit of the trial's records, where one was made and is to be used
        (None otherwise).
    """

    segment: Segment
    model: str
    channel: str
    param_names: tuple[str, ...]
    params: Mapping[str, float]
    stderr: Mapping[str, float]
    covariance: np.ndarray
    t: np.ndarray
    y: np.ndarray
    y_fit: np.ndarray
    rmse: float
    aic: float
    bic: float
    success: bool
    message: str = ""
    joint_t: JointNomotoT | None = None

    def to_fit_result(self) -> "FitResult":
        """This fit as a :class:`FitResult` (units from ``PARAMETER_UNITS`` and the channel)."""
        p = len(self.param_names)
        n = int(np.size(self.y))
        chan_unit = CHANNEL_UNITS.get(self.channel, "")
        units = {k: parameter_unit(k, chan_unit) for k in self.param_names}
        values = [self.params.get(k, math.nan) for k in self.param_names]
        errors = [self.stderr.get(k, math.nan) for k in self.param_names]
        seg = self.segment
        res = fit_result_from_arrays(
            self.model, self.param_names, values, errors, self.covariance, units, dof=max(n - p, 0) or math.inf,
            aic=float(self.aic), bic=float(self.bic), success=bool(self.success), message=self.message, ndata=n,
            provenance={"fitter": f"pipeline.fit segment model {self.model}",
                        "data": f"{seg.kind} {seg.dof} segment {seg.t_start:.2f}-{seg.t_end:.2f} s of run {seg.run}, "
                                f"channel {self.channel}",
                        "covariance": "Jacobian (J^T J)^-1 scaled by the residual variance"},
            statistics={"rmse": float(self.rmse)})
        return res


@dataclass(frozen=True)
class Estimate:
    """One identified coefficient, combined over segments.

    Attributes
    ----------
    name : str
        Coefficient name (``X_u``, ``K_p``, ``K_nomoto``, ...).
    value, stderr : float
        Estimate and standard error [``unit``]; NaN when not identified.
    ci95 : tuple[float, float]
        95% confidence interval.
    unit : str
        SI unit.
    n_segments : int
        Segments combined.
    method : str
        How it was obtained (model, combination rule).
    success : bool
        False when no usable segment was fitted; ``message`` says why.
    message : str
        Reasons for failure, and consistency warnings.
    consistency_p : float
        p-value of the chi-square test that the per-segment values agree within their errors
        (NaN for a single segment).
    per_segment : tuple[float, ...]
        The per-segment values combined.
    """

    name: str
    value: float
    stderr: float
    ci95: tuple[float, float]
    unit: str
    n_segments: int
    method: str
    success: bool = True
    message: str = ""
    consistency_p: float = math.nan
    per_segment: tuple[float, ...] = ()

    def to_parameter(self) -> "FitParameter":
        """This estimate as a :class:`FitParameter`."""
        ci = tuple(self.ci95) if self.ci95 is not None else (math.nan, math.nan)
        return FitParameter(name=self.name, value=float(self.value), stderr=float(self.stderr), unit=self.unit,
                            ci95=ci, success=bool(self.success), message=self.message, method=self.method,
                            n_segments=int(self.n_segments), consistency_p=float(self.consistency_p))


@dataclass(frozen=True)
class DampingFit:
    """The joint fit of one DOF with one damping structure (:mod:`pipeline.fit.quadratic`).

    Attributes
    ----------
    dof, structure : str
        DOF name and ``linear`` or ``quadratic``.
    names : tuple[str, ...]
        Shared parameters (``a``, ``b``, ``c``, ``g_<input>``), in covariance order.
    values, stderr : numpy.ndarray
        Their estimates and standard errors.
    covariance : numpy.ndarray
        Covariance of the shared parameters (the per-segment initial states profiled out).
    terms : dict
        Fossen derivative -> (value, stderr, unit), e.g. ``X_u``, ``X_|u|u`` (empty without a mass).
    term_covariance : numpy.ndarray
        Covariance of ``terms`` in their order [products of their units].
    rmse : float
        RMS of the noise-weighted residuals [-] (1 when only white sensor noise is left).
    lag1 : float
        Lag-1 autocorrelation of the residuals.
    n, dof_resid : int
        Residual rows and degrees of freedom.
    y_fit : tuple[numpy.ndarray, ...]
        Model output per record (for figures).
    success : bool
        Solver converged and the covariance is finite.
    message : str
        Solver status and notes.
    initial_states : numpy.ndarray
        Fitted per-segment initial states, flattened (segment-major).
    inertia : float
        ``M_ii`` the force inputs were divided by (vessel config) [kg or kg m^2]; NaN when unknown.
    """

    dof: str
    structure: str
    names: tuple[str, ...]
    values: np.ndarray
    stderr: np.ndarray
    covariance: np.ndarray
    terms: dict
    term_covariance: np.ndarray
    rmse: float
    lag1: float
    n: int
    dof_resid: int
    y_fit: tuple = ()
    success: bool = True
    message: str = ""
    initial_states: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    inertia: float = math.nan

    def param(self, name: str) -> float:
        """Value of shared parameter ``name`` (NaN when the structure lacks it).

        Parameters
        ----------
        name : str
            ``a``, ``b``, ``c`` or ``g_<input>``.
        """
        return float(self.values[self.names.index(name)]) if name in self.names else math.nan

    def to_fit_result(self) -> "FitResult":
        """The Fossen terms (``terms``, ``term_covariance``) as a :class:`FitResult`.

        Without terms (no mass in the vessel config) the shared parameters instead, as
        :meth:`shared_fit_result`.
        """
        if not self.terms:
            return self.shared_fit_result()
        names = tuple(self.terms)
        return fit_result_from_arrays(
            f"damping_{self.structure}", names, [self.terms[k][0] for k in names],
            [self.terms[k][1] for k in names], self.term_covariance, {k: self.terms[k][2] for k in names},
            dof=self.dof_resid, **self._fit_result_fields())

    def shared_fit_result(self) -> "FitResult":
        """The shared parameters (``a``, ``b``, ``c``, ``g_<input>``) as a :class:`FitResult`."""
        return fit_result_from_arrays(
            f"damping_{self.structure}_shared", self.names, self.values, self.stderr, self.covariance,
            dof=self.dof_resid, **self._fit_result_fields())

    def _fit_result_fields(self) -> dict:
        return dict(success=bool(self.success), message=self.message, ndata=int(self.n),
                    provenance={"fitter": "pipeline.fit.quadratic (joint fit of one DOF's segments)",
                                "data": f"{self.dof} segments, {self.n} residuals",
                                "covariance": "Jacobian, per-segment initial states profiled out"},
                    statistics={"rmse_noise_units": float(self.rmse), "residual_lag1": float(self.lag1),
                                "inertia": float(self.inertia), "dof_resid": float(self.dof_resid)})


@dataclass(frozen=True)
class StructureChoice:
    """Which damping structure the data chose for one DOF, and by how much (:mod:`pipeline.fit.structure`).

    Attributes
    ----------
    dof : str
        DOF name.
    selected : str
        ``linear`` or ``quadratic``.
    fits : Mapping[str, DampingFit]
        Each structure fitted to all of the DOF's segments (the loser is kept for the report).
    heldout_rmse : Mapping[str, float]
        Held-out RMS simulation error per structure [SI unit of the output channel].
    p_value, p_robust : float
        Held-out F test of the quadratic term (Bonferroni-corrected; with the most favourable fold
        left out), :mod:`pipeline.fit.heldout_test`.
    shrink : float
        Held-out gap reduction of the quadratic structure [%].
    explained : float
        Scale-normalised RMS error the quadratic term explains [-].
    significant : bool
        The shared significance rule's verdict.
    folds : str
        How the data were split (leave-one-segment-out or time quarters).
    requested : str
        ``auto`` (held-out choice) or the structure the user forced (``--model linear``).
    message : str
        Why the choice was made, or why no choice was possible.
    """

    dof: str
    selected: str
    fits: Mapping[str, DampingFit]
    heldout_rmse: Mapping[str, float]
    p_value: float
    p_robust: float
    shrink: float
    explained: float
    significant: bool
    folds: str
    requested: str = "auto"
    message: str = ""


@dataclass(frozen=True)
class Extinction:
    """One extinction-curve fit (one direction or pooled), :mod:`pipeline.fit.decay_analysis`.

    Attributes
    ----------
    label : str
        ``port down``, ``starboard down``, ``bow up``, ``bow down`` or ``combined``.
    phi_m, dphi : numpy.ndarray
        Mean amplitudes and decrements per half cycle [rad].
    a, b : float
        Extinction coefficients [-], [1/rad] (``b`` NaN for too few points).
    cov_ab : numpy.ndarray
        Their covariance.
    a_linear, a_linear_se : float
        Linear-only fit ``dphi = a phi_m`` [-].
    wn, wn_se : float
        Natural frequency and standard error [rad/s].
    B1, B1_se, B2, B2_se : float
        Linear [kg m^2/s] and quadratic [kg m^2] damping.
    B_eq, B_eq_se : float
        Equivalent linear damping at ``amplitude`` [kg m^2/s].
    amplitude : float
        Stated amplitude [rad].
    inertia_fit, inertia_fit_se : float
        ``C / wn^2`` [kg m^2] (NaN without restoring).
    n_decays : int
        Decays pooled.
    """

    label: str
    phi_m: np.ndarray
    dphi: np.ndarray
    a: float
    b: float
    cov_ab: np.ndarray
    a_linear: float
    a_linear_se: float
    wn: float
    wn_se: float
    B1: float
    B1_se: float
    B2: float
    B2_se: float
    B_eq: float
    B_eq_se: float
    amplitude: float
    inertia_fit: float
    inertia_fit_se: float
    n_decays: int

    #: Parameters of :meth:`to_fit_result` and their units.
    FIT_UNITS = {"a": "", "b": "1/rad", "a_linear": "", "wn": "rad/s", "B1": "kg m^2/s", "B2": "kg m^2",
                 "B_eq": "kg m^2/s", "inertia_fit": "kg m^2"}

    def to_fit_result(self) -> "FitResult":
        """This curve as a :class:`FitResult`: ``a``, ``b`` with their covariance, and the quantities
        derived from the curve (``a_linear``, ``wn``, ``B1``, ``B2``, ``B_eq`` at ``amplitude``,
        ``inertia_fit``) with their standard errors (covariance NaN outside the ``a``, ``b`` block)."""
        names = tuple(self.FIT_UNITS)
        cov_ab = np.asarray(self.cov_ab, float)
        se_ab = np.sqrt(np.clip(np.diag(cov_ab), 0, None)) if cov_ab.shape == (2, 2) else np.full(2, math.nan)
        cov = np.full((len(names), len(names)), math.nan)
        if cov_ab.shape == (2, 2):
            cov[:2, :2] = cov_ab
        values = [self.a, self.b, self.a_linear, self.wn, self.B1, self.B2, self.B_eq, self.inertia_fit]
        errors = [*se_ab, self.a_linear_se, self.wn_se, self.B1_se, self.B2_se, self.B_eq_se, self.inertia_fit_se]
        return fit_result_from_arrays(
            f"extinction_{self.label.replace(' ', '_')}", names, values, errors, cov, self.FIT_UNITS,
            dof=max(self.phi_m.size - 2, 1), success=math.isfinite(self.a),
            message="" if math.isfinite(self.b) else "b not estimated (too few half cycles)",
            ndata=int(self.phi_m.size),
            provenance={"fitter": "pipeline.fit.decay_analysis", "data": f"{self.n_decays} free decay(s)",
                        "covariance": "least squares on the extinction curve dphi = a phi_m + b phi_m^2; "
                                      "the derived quantities' errors by propagation"},
            statistics={"wn": float(self.wn), "wn_se": float(self.wn_se), "amplitude": float(self.amplitude)})


@dataclass(frozen=True)
class DecayAnalysis:
    """Extinction analysis of one DOF's free decays.

    Attributes
    ----------
    dof : str
        ``roll`` or ``pitch``.
    curves : Mapping[str, Extinction]
        Per direction and ``combined``.
    inertia_config : float
        ``M_ii`` of the vessel config [kg m^2] (NaN when not given).
    restoring : float
        ``C`` [N m/rad] (NaN when not given).
    consistency_p : float
        Wald test p-value that the directions share ``(a, b)`` (NaN with one direction).
    message : str
        Verdict and notes.
    """

    dof: str
    curves: Mapping[str, Extinction] = field(default_factory=dict)
    inertia_config: float = math.nan
    restoring: float = math.nan
    consistency_p: float = math.nan
    message: str = ""


@dataclass(frozen=True)
class Fits:
    """Everything the fit stage identified for one vessel.

    Attributes
    ----------
    vessel : str
        Vessel name.
    estimates : Mapping[str, Estimate]
        Coefficients by name (hydrodynamic derivatives with Fossen's signs, Nomoto K and T, ...).
    segment_fits : tuple[SegmentFit, ...]
        Per-segment fits (for figures and residual checks).
    damping_matrix, damping_stderr : numpy.ndarray
        5x5 D (positive diagonal) in DOF order ``DOFS`` and its standard errors; NaN where not
        identified.
    convention : str
        Sign convention stated in every table.
    structures : Mapping[str, StructureChoice]
        Per DOF, the damping structure the held-out test chose and both fits (empty when the
        structure selection did not run).
    decay_analyses : Mapping[str, DecayAnalysis]
        Roll and pitch extinction analyses (empty when there are no free decays).
    """

    vessel: str
    estimates: Mapping[str, Estimate]
    segment_fits: tuple[SegmentFit, ...]
    damping_matrix: np.ndarray
    damping_stderr: np.ndarray
    convention: str = (
        "M nu_dot + D nu = tau with D positive definite; hydrodynamic derivatives follow Fossen "
        "(X_u = -D[0,0] < 0); DOF order u, v, p, q, r; Nomoto psi/delta = K/(s(Ts+1))."
    )
    structures: Mapping[str, StructureChoice] = field(default_factory=dict)
    decay_analyses: Mapping[str, DecayAnalysis] = field(default_factory=dict)

    def to_fit_result(self) -> "FitResult":
        """Every estimate as one :class:`FitResult` (parameters in ``estimates`` order).

        The coefficients are combined over different segments and fits, so only their variances
        are known: the covariance is diagonal with NaN off the diagonal, and there is no single
        AIC/BIC. ``success`` is True when every estimate succeeded.
        """
        params = {k: e.to_parameter() for k, e in self.estimates.items()}
        cov = np.full((len(params), len(params)), math.nan)
        for i, par in enumerate(params.values()):
            cov[i, i] = par.stderr ** 2
        failed = [k for k, par in params.items() if not par.success]
        message = (f"{len(failed)} of {len(params)} coefficients not identified: {', '.join(failed)}"
                   if failed else "")
        return FitResult(model="vessel coefficients", params=params, covariance=cov, success=not failed,
                         message=message,
                         provenance={"fitter": "pipeline.fit.trial.fit_trial", "vessel": str(self.vessel),
                                     "data": f"{len(self.segment_fits)} segment fits",
                                     "covariance": "per coefficient only (combined over separate fits)"})


# --------------------------------------------------------------------------- one fit result
#: SI unit of the fit parameters that keep one meaning across models (``psi0[2]``: the name before
#: ``[``); amplitudes and offsets (``y0``, ``y_ss``, ``A``, ``offset``) take the fitted channel's unit.
PARAMETER_UNITS: Mapping[str, str] = {
    "T": "s", "T1": "s", "T2": "s", "T3": "s", "T12": "s", "T1T2": "s^2", "t_servo": "s",
    "K": "1/s", "b": "rad", "psi0": "rad", "r0": "rad/s", "rate_servo": "rad/s",
    "omega0": "rad/s", "wn": "rad/s", "lambda": "", "lam": "", "zeta": "", "phase": "rad",
    "kw_ratio": "s^-1/2", "kw": "rad s^-1/2", "sigma": "rad s^1/2",
}
#: Parameters in the unit of the fitted channel.
CHANNEL_PARAMETERS = frozenset({"y0", "y_ss", "A", "offset"})


def parameter_unit(name: str, channel_unit: str = "") -> str:
    """SI unit of fit parameter ``name`` (``""`` when not known).

    Parameters
    ----------
    name : str
        Parameter name; an index suffix (``psi0[1]``) is ignored.
    channel_unit : str
        Unit of the fitted channel, for amplitudes and offsets.
    """
    base = name.split("[", 1)[0]
    if base in CHANNEL_PARAMETERS:
        return channel_unit
    return PARAMETER_UNITS.get(base, "")


def confidence_interval(value: float, stderr: float, dof: float, level: float = 0.95) -> tuple[float, float]:
    """Two-sided confidence interval from Student's t distribution.

    Parameters
    ----------
    value, stderr : float
        Estimate and standard error [any unit].
    dof : float
        Degrees of freedom; ``inf`` gives the normal interval.
    level : float
        Coverage (0.95 for a 95% interval).

    Returns
    -------
    tuple[float, float]
        Lower and upper bound (NaN when ``stderr`` is not finite).
    """
    if not (math.isfinite(value) and math.isfinite(stderr)) or dof <= 0:
        return (math.nan, math.nan)
    from scipy import stats  # scipy.stats costs ~0.5 s to import; only a fit needs it

    q = stats.norm.ppf(0.5 + level / 2) if math.isinf(dof) else stats.t.ppf(0.5 + level / 2, dof)
    return (float(value - q * stderr), float(value + q * stderr))


@dataclass(frozen=True)
class FitParameter:
    """One estimated parameter: lmfit's ``Parameter`` with what a report needs to print it.

    Attributes
    ----------
    name : str
        Parameter name (``K``, ``T``, ``Y_r``, ``omega0``, ...).
    value, stderr : float
        Estimate and standard error [``unit``]; NaN when not estimated (``message`` says why),
        ``inf`` stderr along directions the data do not determine.
    unit : str
        SI unit (``""`` dimensionless or not known).
    ci95 : tuple[float, float]
        95% confidence interval [``unit``] (NaN when not available).
    success : bool
        False when this parameter was not identified (the fit may succeed for others).
    message : str
        Why it failed, or what is doubtful about it.
    method : str
        Model and rule that gave it (e.g. ``first_order_decay; inverse-variance mean``).
    n_segments : int
        Segments or records it rests on (0: not known).
    consistency_p : float
        p-value that the per-segment values agree (NaN: single segment or not tested).
    """

    name: str
    value: float
    stderr: float = math.nan
    unit: str = ""
    ci95: tuple[float, float] = (math.nan, math.nan)
    success: bool = True
    message: str = ""
    method: str = ""
    n_segments: int = 0
    consistency_p: float = math.nan


@dataclass(frozen=True)
class FitResult:
    """Any fitter's output in one shape (lmfit's ``ModelResult`` in the parts vesselid uses).

    Every result type of the pipeline converts to it (``to_fit_result`` on the records here,
    :func:`pipeline.report.fit_results.as_fit_result` for the rest), and the report reads only this
    shape. lmfit itself is not a dependency: its ``Parameters``/``MinimizerResult`` hold
    the same numbers, but the pipeline's fitters are exact-ZOH, prediction-error and casadi
    problems lmfit cannot pose, so lmfit would add a dependency only to be a container.

    Attributes
    ----------
    model : str
        What was fitted (``first_order_decay``, ``nomoto_pem``, ``greybox_coupled``, ...).
    params : Mapping[str, FitParameter]
        Parameters by name, in covariance order.
    covariance : numpy.ndarray, shape (p, p)
        Parameter covariance in ``params`` order [products of the units]; NaN entries where a
        covariance was not estimated (e.g. between coefficients combined separately).
    aic, bic : float
        Akaike and Bayesian information criteria (NaN when the fit has no single likelihood).
    success : bool
        The fit converged and passed its checks.
    message : str
        Solver status and doubts.
    provenance : Mapping[str, str]
        Where the numbers come from: ``fitter`` (function or class), ``data`` (segments,
        records), ``covariance`` (how it was estimated), and any others a converter adds.
    ndata : int
        Residuals (data points) used (0: not known).
    statistics : Mapping[str, float]
        Other scalar fit statistics (``rmse``, ``lag1``, ``s2``, ...) in the fitter's units.
    """

    model: str
    params: Mapping[str, FitParameter]
    covariance: np.ndarray
    aic: float = math.nan
    bic: float = math.nan
    success: bool = True
    message: str = ""
    provenance: Mapping[str, str] = field(default_factory=dict)
    ndata: int = 0
    statistics: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self):
        cov = np.asarray(self.covariance, dtype=float)
        p = len(self.params)
        if cov.shape != (p, p):
            raise ValueError(f"FitResult {self.model!r}: covariance expected shape ({p}, {p}) for the "
                             f"parameters {list(self.params)}, found {cov.shape}")
        for key, par in self.params.items():
            if par.name != key:
                raise ValueError(f"FitResult {self.model!r}: parameter stored under {key!r} is named {par.name!r}")
        object.__setattr__(self, "covariance", cov)

    @property
    def names(self) -> tuple[str, ...]:
        """Parameter names in covariance order."""
        return tuple(self.params)

    @property
    def nvarys(self) -> int:
        """Number of parameters estimated."""
        return len(self.params)

    def value(self, name: str) -> float:
        """Estimate of parameter ``name`` [its unit] (``KeyError`` for an unknown name).

        Parameters
        ----------
        name : str
            One of ``names``.
        """
        return float(self.params[name].value)

    def stderr(self, name: str) -> float:
        """Standard error of parameter ``name`` [its unit].

        Parameters
        ----------
        name : str
            One of ``names``.
        """
        return float(self.params[name].stderr)


def fit_result_from_arrays(model: str, names, values, stderr, covariance, units: Mapping[str, str] | None = None,
                           dof: float = math.inf, **kwargs) -> FitResult:
    """A :class:`FitResult` from the parallel arrays most fitters keep.

    Parameters
    ----------
    model : str
        What was fitted.
    names : sequence of str
        Parameter names, in covariance order.
    values, stderr : array_like
        Estimates and standard errors [parameter units].
    covariance : array_like, shape (p, p)
        Covariance; None or an empty array gives NaN.
    units : Mapping[str, str], optional
        Unit per name (missing names: ``""``).
    dof : float
        Residual degrees of freedom for the 95% intervals (``inf``: normal).
    **kwargs
        The other :class:`FitResult` fields (``aic``, ``bic``, ``success``, ``message``,
        ``provenance``, ``ndata``, ``statistics``).
    """
    names = tuple(str(n) for n in names)
    values = np.asarray(values, dtype=float).reshape(-1)
    stderr = np.asarray(stderr, dtype=float).reshape(-1) if stderr is not None else np.full(len(names), math.nan)
    if values.size != len(names) or stderr.size != len(names):
        raise ValueError(f"{model}: {len(names)} names but {values.size} values and {stderr.size} errors")
    cov = np.full((len(names), len(names)), math.nan) if covariance is None or np.size(covariance) == 0 \
        else np.asarray(covariance, dtype=float)
    units = units or {}
    params = {n: FitParameter(n, float(v), float(e), units.get(n, ""), confidence_interval(float(v), float(e), dof),
                              method=model)
              for n, v, e in zip(names, values, stderr)}
    return FitResult(model=model, params=params, covariance=cov, **kwargs)


# --------------------------------------------------------------------------- autopilot
# ``Fits -> AutopilotResult`` (the autopilot stage): the identified Nomoto K and T (and, from a wave
# record, a wave model) -> PD gains, a discrete Kalman filter, an ArduPilot export and the closed-loop
# check. What the stage does with them (design, TOML and JSON files, the simulation) is in
# ``pipeline.autopilot``. One field type is named, not imported, so this module stays free of the
# stages (and fast to import): ``WaveParams`` is :class:`pipeline.model.waves.WaveParams`.
@dataclass(frozen=True)
class SourceFile:
    """An input file the autopilot configuration was built from.

    Attributes
    ----------
    role : str
        ``coefficients``, ``waves``, ``vessel``, ``still``, ...
    path : str
        Path as given.
    sha256 : str
        Hex digest of the file's bytes.
    """

    role: str
    path: str
    sha256: str


@dataclass(frozen=True)
class NomotoCoefficients:
    """The Nomoto K and T the autopilot is designed on (from :class:`Fits` or ``coefficients.json``).

    Attributes
    ----------
    K, K_stderr : float
        Gain and standard error [1/s] (stderr NaN if null).
    T, T_stderr : float
        Time constant and standard error [s].
    vessel : str
        Vessel name in the file.
    source : SourceFile or None
        The file and its hash (None: read from a record in memory).
    """

    K: float
    K_stderr: float
    T: float
    T_stderr: float
    vessel: str = ""
    source: SourceFile | None = None

    def to_fit_result(self) -> FitResult:
        """K and T as a :class:`FitResult` (standard errors only: the file holds no covariance)."""
        source = self.source
        return fit_result_from_arrays(
            "nomoto_coefficients", ("K", "T"), [self.K, self.T], [self.K_stderr, self.T_stderr], None,
            {"K": "1/s", "T": "s"}, success=math.isfinite(self.K) and math.isfinite(self.T),
            message="read from coefficients.json: only the standard errors are known, not the covariance",
            provenance={"fitter": "pipeline.autopilot.config.read_coefficients_json", "vessel": self.vessel,
                        **({"data": f"{source.path} (sha256 {source.sha256})"} if source is not None else {})})


@dataclass(frozen=True, kw_only=True)
class WaveFit(FitResult):
    """The wave-model fit: a :class:`FitResult` of the second-order wave model, with the Welch PSD it
    was fitted to (:func:`pipeline.autopilot.waves_fit.fit_wave_spectrum`).

    ``params`` are ``omega0`` (peak frequency [rad/s]), ``lam`` (relative damping lambda [-]) and
    ``kw`` (gain K_w [rad s^-1/2]) with their standard errors, ``covariance`` their 3x3 covariance, all
    in the module convention of :mod:`pipeline.model.waves` (two-sided PSD per rad/s).
    ``statistics`` holds ``sigma`` and ``sigma_se`` (``sigma = sqrt(peak PSD) = K_w / (2 lambda
    omega_0)`` and its error [rad s^1/2]), ``rel_residual_std`` (RMS of ``(P_welch - P_model) /
    P_model`` over the bins where the model is within a factor ten of its peak [-]) and
    ``expected_rel_std`` (the same scatter expected from the Welch estimate alone for a Gaussian
    record [-]; a much larger ``rel_residual_std`` means the model does not have the record's shape).
    ``success`` is False when the optimiser failed or the result is outside the band.

    Attributes
    ----------
    omega : numpy.ndarray
        Welch frequencies [rad/s].
    psd : numpy.ndarray
        Welch PSD estimate, two-sided omega convention [rad^2 s].
    band : tuple[float, float]
        Frequency band fitted [rad/s].
    peak_omega : float
        Frequency of the largest Welch bin in the band [rad/s] (the seed's omega_0).
    peak_psd : float
        Largest Welch bin in the band [rad^2 s] (the seed's sigma^2, module convention).
    fs : float
        Sample rate of the record [Hz].
    nperseg : int
        Welch segment length [samples] (Hann window, 50 % overlap, linear detrend).
    n_samples : int
        Samples in the record.
    """

    omega: np.ndarray
    psd: np.ndarray
    band: tuple[float, float]
    peak_omega: float
    peak_psd: float
    fs: float
    nperseg: int
    n_samples: int


@dataclass(frozen=True)
class PDGains:
    """Gains of the PD heading controller ``K_pd (1 + T_d s) / (1 + T_f s)``.

    Attributes
    ----------
    kpd : float
        Proportional gain [rad rudder per rad heading error].
    td : float
        Derivative time [s] (= T of the design model).
    tf : float
        Derivative filter time constant [s].
    crossover : float
        Design crossover frequency [rad/s].
    phase_margin : float
        Design phase margin [rad].
    """

    kpd: float
    td: float
    tf: float
    crossover: float
    phase_margin: float


@dataclass(frozen=True)
class KalmanModel:
    """Everything the discrete heading filter needs, plus the continuous model it came from.

    Attributes
    ----------
    ts : float
        Sample time [s].
    ad, bd, ed, c : numpy.ndarray
        Discrete model (5x5, 5x1, 5x2, 1x5); states ``pipeline.autopilot.kalman.KALMAN_STATES``
        ``[xi_w, psi_w, psi, r, b]`` [rad s, rad, rad, rad/s, rad].
    qd : numpy.ndarray
        Discrete process-noise covariance (Van Loan), 5x5 [state units^2].
    r : float
        Sampled compass-noise variance [rad^2].
    p0 : numpy.ndarray
        Initial a-priori covariance, 5x5 [state units^2].
    x0 : numpy.ndarray
        Initial a-priori state, 5 [state units].
    a, b, e : numpy.ndarray
        Continuous model (NaN when read back from a file, which does not hold it).
    q : numpy.ndarray
        Continuous noise intensity ``diag(q_w [-], q_b [rad^2/s])``.
    """

    ts: float
    ad: np.ndarray
    bd: np.ndarray
    ed: np.ndarray
    c: np.ndarray
    qd: np.ndarray
    r: float
    p0: np.ndarray
    x0: np.ndarray
    a: np.ndarray
    b: np.ndarray
    e: np.ndarray
    q: np.ndarray


@dataclass(frozen=True)
class ArduPilotExport:
    """ArduPilot Rover steering parameters equivalent to the PD design.

    Attributes
    ----------
    params : Mapping[str, float]
        Parameter name -> value, in ArduPilot's units.
    notes : tuple[str, ...]
        The mapping's assumptions and any value outside ArduPilot's documented range.
    """

    params: Mapping[str, float] = field(default_factory=dict)
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class AutopilotConfig:
    """Everything a heading controller needs, with where it came from (``autopilot.toml``).

    Attributes
    ----------
    ts : float
        Sample time of the filter and the controller [s].
    K, T : float
        Nomoto gain [1/s] and time constant [s] the design used.
    K_stderr, T_stderr : float
        Their standard errors [1/s], [s] (NaN if unknown).
    waves : WaveParams
        Wave model of the filter (:class:`pipeline.model.waves.WaveParams`: omega0 [rad/s],
        lambda [-], kw [rad s^-1/2]).
    waves_stderr : Mapping[str, float]
        Standard errors of ``omega0``, ``lambda``, ``kw`` [their units] (empty if not fitted).
    wave_source : str
        Where the wave model came from.
    pd : PDGains
        PD gains.
    kalman : KalmanModel
        Discrete filter.
    rudder_max_angle, rudder_max_rate : float
        Saturation [rad] and rate limit [rad/s].
    rudder_source : str
        Vessel config or the stated default.
    sources : tuple[SourceFile, ...]
        Input files and their hashes.
    notes : tuple[str, ...]
        Defaults used and caveats, one sentence each.
    version : str
        vesselid version.
    """

    ts: float
    K: float
    T: float
    K_stderr: float
    T_stderr: float
    waves: WaveParams  # noqa: F821 (named only, see above)
    waves_stderr: Mapping[str, float]
    wave_source: str
    pd: PDGains
    kalman: KalmanModel
    rudder_max_angle: float
    rudder_max_rate: float
    rudder_source: str
    sources: tuple[SourceFile, ...] = ()
    notes: tuple[str, ...] = ()
    version: str = __version__

    def to_fit_result(self) -> FitResult:
        """The coefficients the design used, as a :class:`FitResult`: ``K``, ``T`` and the wave
        model's ``omega0``, ``lam``, ``kw``, with the standard errors they came with (no covariance:
        they come from different fits)."""
        names = ("K", "T", "omega0", "lam", "kw")
        ws = self.waves_stderr
        return fit_result_from_arrays(
            "autopilot_design_coefficients", names, [self.K, self.T, self.waves.omega0, self.waves.lam, self.waves.kw],
            [self.K_stderr, self.T_stderr, ws.get("omega0", math.nan), ws.get("lambda", math.nan), ws.get("kw", math.nan)],
            None, {n: parameter_unit(n) for n in names}, message="standard errors only: K, T and the wave model "
                                                                   "come from different fits",
            provenance={"fitter": "pipeline.autopilot.config.build_autopilot_config", "waves": self.wave_source})


# The closed-loop check (pipeline.autopilot.closed_loop.closed_loop_check): scenarios, per-run metrics
# and time series.
#: Default heading step of a closed-loop scenario [rad] (the seed's psi_r = 30 deg).
DEFAULT_STEP = math.radians(30.0)
#: Peak-to-peak heading in the steady window above which a run is reported as a limit cycle [rad].
#: A rate-limited rudder and the filter's lag can sustain one after a large step when the ship is
#: faster than the identified model.
LIMIT_CYCLE = math.radians(5.0)


@dataclass(frozen=True)
class Scenario:
    """One closed-loop experiment.

    Attributes
    ----------
    name : str
        Short name (``model``, ``sea``).
    K, T : float
        Nomoto gain [1/s] and time constant [s] of the simulated ship (may differ from the design).
    duration : float
        Simulated time [s].
    psi_ref : float
        Heading reference, stepped at t = 0 from psi = 0 [rad].
    current_bias : float
        Rudder bias standing for the current [rad].
    waves : WaveParams or None
        Wave model added to the compass; None for calm water.
    noise_var : float
        Compass noise variance per sample [rad^2]; 0 for none.
    seed : int
        Seed of the wave and noise generator.
    description : str
        One line for the report.
    """

    name: str
    K: float
    T: float
    duration: float = 600.0
    psi_ref: float = DEFAULT_STEP
    current_bias: float = 0.0
    waves: WaveParams | None = None  # noqa: F821 (named only, see above)
    noise_var: float = 0.0
    seed: int = 0
    description: str = ""


@dataclass(frozen=True)
class LoopMetrics:
    """What one closed-loop run measured (SI units).

    Attributes
    ----------
    steady_error : float
        Mean of ``psi_ref - psi`` over the steady window [rad] (``psi`` the ship's heading without
        the wave-induced oscillation, which averages out).
    settling_time : float
        Time after which ``|psi - psi_ref|`` stays within ``settle_band`` [s]; NaN if it never does.
    settle_band : float
        Settling band [rad]: 5 % of the step (at least 0.5 deg).
    rms_rudder_rate : float
        RMS rudder rate over the steady window [rad/s].
    max_swing : float
        Largest peak-to-peak rudder travel within any 5 s in the steady window [rad].
    max_swing_cmd : float
        The same for the controller's command before saturation and rate limit [rad] (the seed's
        simulator had no rate limit, so its "40 deg in 5 s" compares with this).
    rate_limited : float
        Fraction of steady-window samples at the rudder-rate limit [-].
    mean_rudder : float
        Mean rudder over the steady window [rad].
    heading_estimate_rms : float
        RMS of ``psi_hat - psi`` over the steady window [rad] (the filter's wave removal).
    compass_error_rms : float
        RMS of ``y - psi`` over the steady window [rad] (what PD alone feeds back).
    bias_estimate : float
        Mean ``b_hat`` over the steady window [rad].
    heading_swing : float
        Peak-to-peak of ``psi`` over the steady window [rad]: a settled loop keeps it near the
        waves' small effect on the ship; degrees to tens of degrees mean a limit cycle (see
        ``LIMIT_CYCLE``).
    steady_window : tuple of float
        ``(t0, t1)`` [s].
    """

    steady_error: float
    settling_time: float
    settle_band: float
    rms_rudder_rate: float
    max_swing: float
    max_swing_cmd: float
    rate_limited: float
    mean_rudder: float
    heading_estimate_rms: float
    compass_error_rms: float
    bias_estimate: float
    heading_swing: float
    steady_window: tuple[float, float]

    @property
    def limit_cycle(self) -> bool:
        """True when the heading still swings more than ``LIMIT_CYCLE`` in the steady window."""
        return self.heading_swing > LIMIT_CYCLE

    def to_dict(self) -> dict:
        """Report-ready values in degrees, keys naming their unit; NaN becomes None."""
        d = math.degrees

        def num(x):
            return float(x) if math.isfinite(x) else None

        return {
            "steady_error_deg": num(d(self.steady_error)),
            "settling_time_s": num(self.settling_time),
            "settle_band_deg": num(d(self.settle_band)),
            "rms_rudder_rate_deg_s": num(d(self.rms_rudder_rate)),
            "max_rudder_swing_5s_deg": num(d(self.max_swing)),
            "max_command_swing_5s_deg": num(d(self.max_swing_cmd)),
            "rate_limited_fraction": num(self.rate_limited),
            "mean_rudder_deg": num(d(self.mean_rudder)),
            "heading_estimate_rms_deg": num(d(self.heading_estimate_rms)),
            "compass_error_rms_deg": num(d(self.compass_error_rms)),
            "bias_estimate_deg": num(d(self.bias_estimate)),
            "heading_swing_deg": num(d(self.heading_swing)),
            "limit_cycle": bool(self.limit_cycle),
            "steady_window_s": [float(self.steady_window[0]), float(self.steady_window[1])],
        }


@dataclass(frozen=True)
class ClosedLoopRun:
    """Time series and metrics of one case in one scenario.

    Attributes
    ----------
    scenario : Scenario
    case : str
        One of ``pipeline.autopilot.closed_loop.CASES`` (``pd``, ``pd_kalman``, ``pd_kalman_ff``).
    t : numpy.ndarray
        Time [s].
    psi, r : numpy.ndarray
        Ship heading without waves [rad] and yaw rate [rad/s].
    psi_w : numpy.ndarray
        Wave-induced heading [rad].
    y : numpy.ndarray
        Compass [rad].
    psi_hat, psi_w_hat, b_hat : numpy.ndarray
        Filter estimates [rad].
    delta, delta_cmd : numpy.ndarray
        Rudder applied and commanded [rad].
    metrics : LoopMetrics
    """

    scenario: Scenario
    case: str
    t: np.ndarray
    psi: np.ndarray
    r: np.ndarray
    psi_w: np.ndarray
    y: np.ndarray
    psi_hat: np.ndarray
    psi_w_hat: np.ndarray
    b_hat: np.ndarray
    delta: np.ndarray
    delta_cmd: np.ndarray
    metrics: LoopMetrics


@dataclass(frozen=True)
class ClosedLoopCheck:
    """All cases in all scenarios.

    Attributes
    ----------
    scenarios : tuple[Scenario, ...]
    runs : tuple[ClosedLoopRun, ...]
        One per (scenario, case), scenario-major in ``pipeline.autopilot.closed_loop.CASES`` order.
    """

    scenarios: tuple[Scenario, ...]
    runs: tuple[ClosedLoopRun, ...]

    def run(self, scenario: str, case: str) -> ClosedLoopRun:
        """The run of one scenario and case; ``KeyError`` naming what exists.

        Parameters
        ----------
        scenario : str
            Scenario name (``Scenario.name``).
        case : str
            Controller case (``pd``, ``pd_kalman``, ``pd_kalman_ff``).
        """
        for r in self.runs:
            if r.scenario.name == scenario and r.case == case:
                return r
        raise KeyError(f"no run ({scenario!r}, {case!r}); have "
                       f"{[(r.scenario.name, r.case) for r in self.runs]}")

    def to_dict(self) -> dict:
        """Metrics per scenario and case, degrees, JSON-ready."""
        out = {}
        for s in self.scenarios:
            out[s.name] = {
                "description": s.description, "K": s.K, "T": s.T, "duration_s": s.duration,
                "psi_ref_deg": math.degrees(s.psi_ref), "current_bias_deg": math.degrees(s.current_bias),
                "waves": None if s.waves is None else {"omega0": s.waves.omega0, "lambda": s.waves.lam,
                                                        "kw": s.waves.kw},
                "noise_std_deg": math.degrees(math.sqrt(s.noise_var)), "seed": s.seed,
                "cases": {r.case: r.metrics.to_dict() for r in self.runs if r.scenario.name == s.name},
            }
        return out


@dataclass(frozen=True)
class AutopilotResult:
    """The autopilot stage's output.

    Attributes
    ----------
    config : AutopilotConfig
        What a controller needs.
    observability : dict
        Rank of each of the seed's four model variants (:func:`pipeline.autopilot.kalman.observability`).
    margins : list of dict
        Crossover [rad/s] and phase margin [rad] on the identified model and at the corners of its
        95 % box.
    ardupilot : ArduPilotExport
        ArduPilot Rover steering parameters.
    check : ClosedLoopCheck or None
        Closed-loop simulation (:func:`pipeline.autopilot.closed_loop.closed_loop_check`), if run.
    wave_fit : WaveFit or None
        The wave-spectrum fit, if the wave model was fitted in this run.
    """

    config: AutopilotConfig
    observability: dict
    margins: list
    ardupilot: ArduPilotExport
    check: ClosedLoopCheck | None = None
    wave_fit: WaveFit | None = None


# --------------------------------------------------------------------------- report
@dataclass(frozen=True)
class Provenance:
    """What produced a report: shown in its footer.

    Attributes
    ----------
    version : str
        As ``vesselid --version`` prints it.
    created : str
        UTC time, ISO 8601.
    command : str
        The command line.
    inputs : tuple[tuple[str, str], ...]
        ``(path, sha256)`` of every input file (empty hash: unreadable).
    """

    version: str
    created: str
    command: str
    inputs: tuple[tuple[str, str], ...] = ()



# --------------------------------------------------------------------------- diagnose
# ``Trial + Fits -> GapReport`` (the diagnose stage): where the identified model disagrees with the
# boat, which unmodelled effects explain it (in order), how far the gap shrinks, and what is left
# unexplained. Gaps are dimensionless: the held-out RMS of the open-loop simulation error of a
# channel in units of that channel's white-noise level at the analysis step (1 = nothing left but
# sensor noise); a DOF's gap is the RMS over its channels, the trial's gap the RMS over every
# channel of every DOF. "Explained" errors are relative to the channel's scale instead (its
# standard deviation over the DOF's own manoeuvres), so that a tiny but statistically visible
# error is not named.

@dataclass(frozen=True)
class EffectParam:
    """One fitted parameter of a candidate.

    Attributes
    ----------
    name : str
        Parameter name (``d2``, ``V_n``, ``tau_d``, ``R``, ``k_rev``, ``omega0``, ``c``, ...).
    value : float
        Value fitted on every window [``unit``].
    stderr : float
        Delete-a-group jackknife standard error over the cross-validation folds [``unit``];
        NaN with fewer than two folds.
    unit : str
        Unit.
    """

    name: str
    value: float
    stderr: float
    unit: str = ""


@dataclass(frozen=True)
class ChannelGap:
    """Held-out gap of one channel before and after a candidate.

    Attributes
    ----------
    channel : str
        Channel name.
    gap_before, gap_after : float
        Normalised held-out RMS error [-].
    p_value : float
        Held-out F-test p-value of this channel (NaN when not computable).
    n_eff : float
        Effective number of independent samples.
    """

    channel: str
    gap_before: float
    gap_after: float
    p_value: float
    n_eff: float


@dataclass(frozen=True)
class CandidateResult:
    """A candidate effect refitted and scored in one DOF.

    Attributes
    ----------
    effect : str
        Effect name (``nonlinear_damping``, ``current``, ``actuator_delay``, ``actuator_rate_limit``,
        ``thrust_asymmetry``, ``waves``, ``coupling``).
    dof : str
        DOF name.
    label : str
        ``effect`` or ``effect[input]`` for per-input candidates (``effect[actuator]`` in actuator
        space, :mod:`pipeline.diagnose.actuators`).
    input_channel : str or None
        Input concerned (rate limit, thrust asymmetry), actuator name (actuator space: a delay, rate
        limit or asymmetry of one actuator) or regressor (coupling), else None.
    gap_before, gap_after : float
        The DOF's held-out gap with the baseline and with the candidate [-].
    shrink : float
        ``100 (1 - gap_after / gap_before)`` [%].
    explained : float
        RMS error the effect accounts for, ``sqrt(e_before^2 - e_after^2)`` of the held-out RMS
        errors over the channel's scale, largest over the DOF's channels [-] (negative when the
        candidate makes things worse).
    p_value : float
        Bonferroni-corrected held-out F-test p-value.
    significant : bool
        Passed the calibrated significance test.
    params : tuple[EffectParam, ...]
        The effect's own parameters.
    model : tuple[EffectParam, ...]
        Every parameter of the augmented model (T, gains, effect).
    channels : tuple[ChannelGap, ...]
        Per-channel detail.
    gain : float
        Reduction of the trial's summed squared channel gaps (the ranking key) [-].
    """

    effect: str
    dof: str
    label: str
    input_channel: str | None
    gap_before: float
    gap_after: float
    shrink: float
    explained: float
    p_value: float
    significant: bool
    params: tuple[EffectParam, ...] = ()
    model: tuple[EffectParam, ...] = ()
    channels: tuple[ChannelGap, ...] = ()
    gain: float = 0.0


@dataclass(frozen=True)
class Place:
    """A place where the baseline's held-out gap lives, and its share.

    Attributes
    ----------
    category : str
        ``channel``, ``segment kind``, ``frequency band``, ``speed`` or ``input amplitude``.
    dof : str
        DOF.
    name : str
        The place (``r``, ``zigzag``, ``below wave band``, ``0.5-1.0 m/s``, ...).
    share : float
        Share of the trial's excess squared gap (above the sensor noise) within its category
        [0-1]; the shares of one category sum to one.
    gap : float
        Normalised RMS error inside the place [-].
    n : int
        Analysis samples in the place.
    """

    category: str
    dof: str
    name: str
    share: float
    gap: float
    n: int


@dataclass(frozen=True)
class Trace:
    """Time series for an overlay plot (windows joined with NaN between them).

    Attributes
    ----------
    dof, channel : str
        DOF and channel plotted.
    kind : str
        ``heldout`` (cross-validated predictions on the windows) or ``replay`` (whole trial).
    effect : str or None
        Label of the candidate in ``with_effect`` (None when there is none).
    t : numpy.ndarray
        Time [s, trial clock].
    measured, baseline, with_effect : numpy.ndarray
        Measured channel, baseline model, model with the effect [SI]; ``with_effect`` is all NaN
        when ``effect`` is None.
    """

    dof: str
    channel: str
    kind: str
    effect: str | None
    t: np.ndarray
    measured: np.ndarray
    baseline: np.ndarray
    with_effect: np.ndarray


@dataclass(frozen=True)
class Spectrum:
    """Pooled PSD of the baseline's held-out residual of one channel.

    Attributes
    ----------
    dof, channel : str
        DOF and channel.
    omega : numpy.ndarray
        Frequency [rad/s].
    psd : numpy.ndarray
        One-sided PSD of the normalised residual [1/(rad/s)].
    band : tuple[float, float]
        Wave band used for the split [rad/s].
    """

    dof: str
    channel: str
    omega: np.ndarray
    psd: np.ndarray
    band: tuple[float, float]


@dataclass(frozen=True)
class DofSummary:
    """The baseline of one DOF and how it was analysed.

    Attributes
    ----------
    dof : str
        DOF name.
    channels : tuple[str, ...]
        Output channels scored.
    inputs : tuple[str, ...]
        Inputs driving it.
    dt : float
        Analysis step [s].
    n_windows : int
        Windows (segments and time blocks) replayed.
    n_folds : int
        Cross-validation folds.
    baseline : tuple[EffectParam, ...]
        Baseline parameters (``T`` [s], gains ``k_<input>``) with jackknife errors.
    gap : float
        Held-out gap of the baseline [-].
    noise_floor : float
        White-noise standard deviation of the response at the analysis step [SI]: the unit of
        the gaps (a gap of 1 is measurement noise, not model error).
    replay_gap : float
        Gap of the baseline replayed over the whole trial from its start [-].
    heldout_floor : Mapping[str, float]
        Per channel, the held-out gap a correct model would leave (noise plus the noise of its
        fitted parameters, :mod:`pipeline.diagnose.floor`) [-, >= 1]; empty when not measured.
    """

    dof: str
    channels: tuple[str, ...]
    inputs: tuple[str, ...]
    dt: float
    n_windows: int
    n_folds: int
    baseline: tuple[EffectParam, ...]
    gap: float
    noise_floor: float
    replay_gap: float
    heldout_floor: Mapping[str, float] = field(default_factory=dict)


#: How the diagnosis ranks candidates (written into every GapReport and its JSON).
RANKING_RULE = (
    "candidates are ranked by their held-out shrink: 100 (1 - gap_after / gap_before) of the RMS gap over "
    "the channels of the DOF they act on, each step refitted on training windows and scored on held-out "
    "ones; only significant candidates (held-out F test below alpha, shrink and explained error above "
    "their minimums) can be selected; forward selection takes the best, refits the rest on top of it, "
    "and stops when none is significant; where none is significant alone but the DOF's gap stays above "
    "what a correct model leaves, two candidates that are each significant on top of the other are "
    "selected together (two effects that hide each other)")


@dataclass(frozen=True)
class SelectedEffect:
    """One step of the forward selection.

    Attributes
    ----------
    step : int
        1 for the verdict, 2 for the effect selected on top of it, ...
    effect, dof, label : str
        Effect name, DOF, label (``effect[input]`` for per-input candidates, ``effect[actuator]``
        for one actuator's).
    input_channel : str or None
        Input, actuator, regressor or sensor group concerned.
    gap_before, gap_after : float
        The DOF's held-out gap with the effects selected before this one, and with this one added [-].
    shrink : float
        ``100 (1 - gap_after / gap_before)`` [%] on top of the previous steps.
    trial_gap_after : float
        The trial's held-out gap with every effect up to this one [-].
    p_value : float
        Held-out F-test p-value of this step.
    params : tuple[EffectParam, ...]
        The effect's fitted parameters with jackknife errors.
    why : str
        How the name was decided when it is not the candidate's own (``sensor_delay``: which
        channel driven by the same inputs showed no delay).
    candidate : str
        Label of the candidate that was selected (``actuator_delay`` behind a ``sensor_delay``).
    """

    step: int
    effect: str
    dof: str
    label: str
    input_channel: str | None
    gap_before: float
    gap_after: float
    shrink: float
    trial_gap_after: float
    p_value: float
    params: tuple[EffectParam, ...] = ()
    why: str = ""
    candidate: str = ""


@dataclass(frozen=True)
class Unexplained:
    """A channel whose held-out gap stays above the noise after every selected effect.

    Attributes
    ----------
    dof, channel : str
        DOF and channel.
    gap : float
        Held-out gap left after the selected effects [-] (1 = sensor noise).
    share : float
        Share of the trial's remaining excess squared gap (above 1 per channel) in this channel [0-1].
    p_value : float
        Chi-square test of "only noise is left": probability of an RMS this large from white noise
        of unit variance with the channel's effective number of independent samples.
    place : str
        Where most of this DOF's gap lives (segment kind and operating regime).
    band : str
        Frequency band holding most of the residual's power (below, in or above the wave band).
    peak_omega : float
        Frequency of the residual's spectral peak [rad/s].
    correlations : Mapping[str, float]
        Correlation of the residual with speed (``sog`` or ``u``), with each input, and with
        ``cos``/``sin`` of the heading [-1, 1].
    looks_like : str
        One sentence: what the residual looks like.
    """

    dof: str
    channel: str
    gap: float
    share: float
    p_value: float
    place: str = ""
    band: str = ""
    peak_omega: float = float("nan")
    correlations: Mapping[str, float] = field(default_factory=dict)
    looks_like: str = ""


@dataclass(frozen=True)
class GapReport:
    """The diagnosis of one trial.

    Attributes
    ----------
    trial, vessel : str
        Names.
    effect, dof : str or None
        Verdict: the best significant candidate, or None.
    gap_before, gap_after : float
        Trial gap (held out) of the baseline and of the model with the verdict's effect added in
        every DOF where it is significant [-].
    candidates : tuple[CandidateResult, ...]
        Every candidate in every DOF, best (largest gain) first.
    places : tuple[Place, ...]
        Where the baseline's gap lives, largest share first.
    dofs : tuple[DofSummary, ...]
        Per-DOF baselines.
    traces : tuple[Trace, ...]
        Overlay series (held-out, with the verdict's or DOF's best candidate; and replays).
    spectra : tuple[Spectrum, ...]
        Residual spectra per channel.
    thresholds : Mapping[str, float]
        Significance constants used.
    notes : tuple[str, ...]
        What was done and what was doubtful.
    effects : tuple[SelectedEffect, ...]
        Forward selection: the verdict first, then each effect significant on top of the previous ones.
    gap_final : float
        Trial gap (held out) with every selected effect [-].
    unexplained : tuple[Unexplained, ...]
        Channels whose gap stays above the noise after the selected effects, largest share first.
    ranking_rule : str
        The rule the candidates are ranked and selected by.
    unexplained_test : str
        The test that decides whether a channel's remaining gap is unexplained.
    """

    trial: str
    vessel: str
    effect: str | None
    dof: str | None
    gap_before: float
    gap_after: float
    candidates: tuple[CandidateResult, ...]
    places: tuple[Place, ...] = ()
    dofs: tuple[DofSummary, ...] = ()
    traces: tuple[Trace, ...] = field(default=(), repr=False)
    spectra: tuple[Spectrum, ...] = field(default=(), repr=False)
    thresholds: Mapping[str, float] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    effects: tuple[SelectedEffect, ...] = ()
    gap_final: float = float("nan")
    unexplained: tuple[Unexplained, ...] = ()
    ranking_rule: str = RANKING_RULE
    unexplained_test: str = ""

    @property
    def status(self) -> str:
        """``explained`` (nothing left above the noise), ``partly explained`` (effects selected, a
        gap left) or ``unexplained`` (no library effect, a gap left); ``model fine`` only when
        there is neither an effect nor a gap left."""
        if self.unexplained:
            return "partly explained" if self.effects else "unexplained"
        return "explained" if self.effects else "model fine"

    @property
    def shrink(self) -> float:
        """``100 (1 - gap_after / gap_before)`` [%] (0 when there is no verdict)."""
        return 100.0 * (1.0 - self.gap_after / self.gap_before) if self.gap_before > 0 else 0.0

    @property
    def verdict(self) -> CandidateResult | None:
        """The winning candidate, if any."""
        if self.effects:
            first = self.effects[0]
            return next((c for c in self.candidates if c.dof == first.dof and c.label == first.candidate), None)
        for c in self.candidates:
            if c.significant and c.effect == self.effect and c.dof == self.dof:
                return c
        return None

    def to_dict(self) -> dict[str, object]:
        """The JSON contract of ``vesselid diagnose --json`` (NaN and inf become null).

        ``{"verdict": {"effect", "dof"}, "gap_before", "gap_after", "shrink", "candidates":
        [{"effect", "dof", "gap_before", "gap_after", "shrink", "significant", ...}], ...}``
        """
        def num(x: float) -> float | None:
            return float(x) if x is not None and math.isfinite(float(x)) else None

        def params(ps: tuple[EffectParam, ...]) -> dict:
            return {p.name: {"value": num(p.value), "stderr": num(p.stderr), "unit": p.unit} for p in ps}

        return {
            "trial": self.trial,
            "vessel": self.vessel,
            "verdict": {"effect": self.effect, "dof": self.dof},
            "gap_before": num(self.gap_before),
            "gap_after": num(self.gap_after),
            "shrink": num(self.shrink),
            "candidates": [{
                "effect": c.effect, "dof": c.dof, "label": c.label, "input": c.input_channel,
                "gap_before": num(c.gap_before), "gap_after": num(c.gap_after), "shrink": num(c.shrink),
                "explained": num(c.explained), "p_value": num(c.p_value), "significant": bool(c.significant),
                "params": params(c.params),
            } for c in self.candidates],
            "dofs": [{
                "dof": d.dof, "channels": list(d.channels), "inputs": list(d.inputs), "dt": num(d.dt),
                "windows": d.n_windows, "folds": d.n_folds, "baseline": params(d.baseline), "gap": num(d.gap),
                "noise_floor": num(d.noise_floor), "replay_gap": num(d.replay_gap),
                "heldout_floor": {k: num(v) for k, v in d.heldout_floor.items()},
            } for d in self.dofs],
            "places": [{"category": p.category, "dof": p.dof, "name": p.name, "share": num(p.share),
                        "gap": num(p.gap), "n": p.n} for p in self.places],
            "thresholds": {k: num(v) for k, v in self.thresholds.items()},
            "notes": list(self.notes),
            "status": self.status,
            "effects": [{
                "step": e.step, "effect": e.effect, "dof": e.dof, "label": e.label, "input": e.input_channel,
                "gap_before": num(e.gap_before), "gap_after": num(e.gap_after), "shrink": num(e.shrink),
                "trial_gap_after": num(e.trial_gap_after), "p_value": num(e.p_value), "params": params(e.params),
                "why": e.why, "candidate": e.candidate,
            } for e in self.effects],
            "gap_final": num(self.gap_final),
            "unexplained": [{
                "dof": u.dof, "channel": u.channel, "gap": num(u.gap), "share": num(u.share),
                "p_value": num(u.p_value), "place": u.place, "band": u.band, "peak_omega": num(u.peak_omega),
                "correlations": {k: num(v) for k, v in u.correlations.items()}, "looks_like": u.looks_like,
            } for u in self.unexplained],
            "ranking_rule": self.ranking_rule,
            "unexplained_test": self.unexplained_test,
        }
