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
    """

    name: str
    data: pd.DataFrame
    fs: float
    gaps: tuple[Gap, ...] = ()
    sources: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    summaries: tuple[IngestSummary, ...] = ()
    runs: tuple[Run, ...] = ()

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

    @property
    def duration(self) -> float:
        """Segment length [s]."""
        return self.t_end - self.t_start


@dataclass(frozen=True)
class Segments:
    """The segments of one trial, in time order."""

    trial: str
    items: tuple[Segment, ...]

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
