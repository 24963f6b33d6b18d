"""The autopilot stage end to end: identified Nomoto model (+ wave fit) -> config, checks and files.

``vesselid autopilot`` and ``vesselid run`` both call :func:`build_autopilot`; :func:`write_autopilot_outputs`
puts ``autopilot.toml`` (and on request the closed-loop metrics, figures and an ArduPilot parameter
file) into a folder.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ..errors import AutopilotError
from ..model.waves import WaveParams
from ..records import AutopilotResult, NomotoCoefficients, PDGains, SourceFile, WaveFit
from .closed_loop import closed_loop_check, default_scenarios
from .config import ardupilot_params, build_autopilot_config
from .kalman import DEFAULT_P0, DEFAULT_Q, observability
from .pd import DEFAULT_PHASE_MARGIN, margin_table, pd_gains
from .waves_fit import wave_params


def nomoto_from_fits(fits) -> NomotoCoefficients:
    """K and T from a :class:`pipeline.records.Fits` (estimates ``K_nomoto`` and ``T_nomoto``).

    Parameters
    ----------
    fits : pipeline.records.Fits
        The fit stage's record.

    Returns
    -------
    NomotoCoefficients
        Values and standard errors (no source file: the record is in memory).

    Raises
    ------
    AutopilotError
        Either estimate missing, failed or not finite.
    """
    est = getattr(fits, "estimates", None)
    if not isinstance(est, Mapping):
        raise AutopilotError(f"fits: expected a Fits record with estimates, found {type(fits).__name__}")
    vals = []
    for name in ("K_nomoto", "T_nomoto"):
        e = est.get(name)
        if e is None:
            raise AutopilotError(f"fits: expected estimate {name}, found only {sorted(est)}")
        if not (getattr(e, "success", True) and math.isfinite(e.value)):
            raise AutopilotError(f"fits: expected an identified {name}, found value {e.value!r} "
                                 f"({getattr(e, 'message', '') or 'fit failed'})")
        vals.append((float(e.value), float(e.stderr)))
    return NomotoCoefficients(K=vals[0][0], K_stderr=vals[0][1], T=vals[1][0], T_stderr=vals[1][1],
                              vessel=str(getattr(fits, "vessel", "")))


def build_autopilot(coefficients: NomotoCoefficients, *, waves: WaveFit | WaveParams | None = None,
                    waves_stderr: Mapping[str, float] | None = None, wave_source: str = "",
                    vessel=None, ts: float = 0.1, crossover: float | None = None,
                    phase_margin: float = DEFAULT_PHASE_MARGIN, r: float | None = None, r_source: str = "",
                    q: tuple[float, float] = DEFAULT_Q, p0: tuple[float, ...] = DEFAULT_P0,
                    sources: tuple[SourceFile, ...] = (), check: bool = True,
                    duration: float = 600.0, seed: int = 1) -> AutopilotResult:
    """Design the autopilot and, optionally, run the closed-loop check.

    Parameters
    ----------
    coefficients : NomotoCoefficients
        Identified K [1/s] and T [s] with standard errors (:func:`read_coefficients_json` or
        :func:`nomoto_from_fits`).
    waves : WaveFit or WaveParams, optional
        Wave model; a :class:`~pipeline.records.WaveFit` also gives standard errors and the report's spectrum figure.
    waves_stderr : Mapping, optional
        Standard errors when ``waves`` is a :class:`WaveParams`.
    wave_source : str
        Where the wave model came from.
    vessel : pipeline.vessel.Vessel, optional
        Gives ``[rudder]`` limits and, if it has ``[nomoto]`` K and T, the ship simulated in the
        ``sea`` scenario (so the check also tests the identified model against the truth).
    ts : float
        Sample time [s].
    crossover : float, optional
        PD crossover [rad/s]; default :func:`pipeline.autopilot.pd.default_crossover` of the identified T.
    phase_margin : float
        PD phase margin [rad].
    r : float, optional
        Sampled compass-noise variance [rad^2].
    r_source : str
        Where ``r`` came from.
    q, p0 : tuple
        Kalman tuning (continuous intensities; initial covariance diagonal).
    sources : tuple of SourceFile
        Input files for the provenance (the coefficients file is added from ``coefficients``).
    check : bool
        Run the closed-loop check (about 2 s).
    duration : float
        Closed-loop simulation length [s].
    seed : int
        Seed of the closed-loop waves and noise.

    Returns
    -------
    AutopilotResult
    """
    fit = waves if isinstance(waves, WaveFit) else None
    if fit is not None:
        wp = wave_params(fit)
        wse = {"omega0": fit.stderr("omega0"), "lambda": fit.stderr("lam"), "kw": fit.stderr("kw")}
    else:
        wp, wse = waves, dict(waves_stderr or {})
    srcs = tuple(sources)
    if coefficients.source is not None:
        srcs = (coefficients.source,) + srcs
    rudder, rudder_source, plant_k, plant_t = None, "", None, None
    if vessel is not None:
        rudder = {k: v for k, v in dict(vessel.rudder).items() if k in ("max_angle", "max_rate")}
        rudder_source = f"vessel config {getattr(vessel, 'path', '') or vessel.name}" if rudder else ""
        nom = dict(getattr(vessel, "nomoto", {}) or {})
        if "K" in nom and "T" in nom:
            plant_k, plant_t = float(nom["K"]), float(nom["T"])
    cfg = build_autopilot_config(
        coefficients.K, coefficients.T, K_stderr=coefficients.K_stderr, T_stderr=coefficients.T_stderr,
        waves=wp, waves_stderr=wse, wave_source=wave_source, ts=ts, crossover=crossover,
        phase_margin=phase_margin, r=r, r_source=r_source, q=q, p0=p0, rudder=rudder,
        rudder_source=rudder_source, sources=srcs)
    obs = observability(cfg.K, cfg.T, cfg.waves)
    margins = margin_table(cfg.K, cfg.T, cfg.K_stderr, cfg.T_stderr, cfg.pd)
    chk = None
    if check:
        chk = closed_loop_check(cfg, default_scenarios(cfg, plant_K=plant_k, plant_T=plant_t,
                                                       duration=duration, seed=seed))
    return AutopilotResult(config=cfg, observability=obs, margins=margins, ardupilot=ardupilot_params(cfg),
                           check=chk, wave_fit=fit)


@dataclass(frozen=True)
class ScheduledGains:
    """PD gains designed on the Nomoto model linearised at one speed.

    Attributes
    ----------
    speed : float
        Operating speed [m/s].
    K, K_stderr : float
        Nomoto gain at that speed and its standard error [1/s].
    T, T_stderr : float
        Time constant and standard error [s].
    gains : PDGains
        :func:`pipeline.autopilot.pd.pd_gains` of ``K(U)``, ``T(U)``.
    worst_phase_margin : float
        Smallest phase margin over the corners of the 95 % box of K and T at this speed [rad].
    """

    speed: float
    K: float
    K_stderr: float
    T: float
    T_stderr: float
    gains: PDGains
    worst_phase_margin: float


@dataclass(frozen=True)
class GainSchedule:
    """PD gains over speed (gain scheduling on the identified K(U), T(U)).

    Attributes
    ----------
    entries : tuple[ScheduledGains, ...]
        One design per scheduling speed, ascending.
    speed_dependent : bool
        K or T of the model varies with speed (otherwise every entry has the same gains).
    message : str
        Where K(U) and T(U) came from.
    """

    entries: tuple[ScheduledGains, ...]
    speed_dependent: bool
    message: str = ""

    def gains_at(self, speed: float) -> PDGains:
        """Gains at ``speed``, linearly interpolated between scheduling speeds and held beyond them.

        Parameters
        ----------
        speed : float
            Operating speed [m/s].
        """
        u = np.array([e.speed for e in self.entries])
        pick = {name: float(np.interp(speed, u, [getattr(e.gains, name) for e in self.entries]))
                for name in ("kpd", "td", "tf", "crossover")}
        return PDGains(kpd=pick["kpd"], td=pick["td"], tf=pick["tf"], crossover=pick["crossover"],
                       phase_margin=self.entries[0].gains.phase_margin)


def gain_schedule(speed_map, speeds, crossover: float | None = None,
                  phase_margin: float = DEFAULT_PHASE_MARGIN) -> GainSchedule:
    """Design the PD autopilot at each speed on the Nomoto model linearised there.

    Parameters
    ----------
    speed_map : object
        Anything with ``at(speed) -> {"K", "K_stderr", "T", "T_stderr"}`` and ``speed_dependent``,
        e.g. :class:`pipeline.fit.nomoto_speed.NomotoSpeedMap`.
    speeds : sequence of float
        Scheduling speeds [m/s], positive.
    crossover : float, optional
        Fixed crossover [rad/s]; default :func:`pipeline.autopilot.pd.default_crossover` of ``T(U)``
        at each speed (the loop shape is kept as T changes).
    phase_margin : float
        Design phase margin [rad].

    Returns
    -------
    GainSchedule

    Raises
    ------
    AutopilotError
        No speed, a non-positive speed, or K(U), T(U) not positive at a scheduling speed.
    """
    us = sorted(float(u) for u in speeds)
    if not us or any(not (math.isfinite(u) and u > 0) for u in us):
        raise AutopilotError(f"gain schedule: expected positive scheduling speeds [m/s], found {list(speeds)!r}")
    entries = []
    for u in us:
        kt = speed_map.at(u)
        if not (kt["K"] > 0 and kt["T"] > 0):
            raise AutopilotError(f"gain schedule: expected K > 0 and T > 0 at {u:g} m/s, found K = {kt['K']:.4g} 1/s, "
                                 f"T = {kt['T']:.4g} s (outside the identified speeds?)")
        g = pd_gains(kt["K"], kt["T"], crossover, phase_margin)
        corners = margin_table(kt["K"], kt["T"], kt["K_stderr"], kt["T_stderr"], g)
        worst = min((m["phase_margin"] for m in corners if math.isfinite(m["phase_margin"])), default=math.nan)
        entries.append(ScheduledGains(u, kt["K"], kt["K_stderr"], kt["T"], kt["T_stderr"], g, worst))
    dep = bool(getattr(speed_map, "speed_dependent", True))
    return GainSchedule(tuple(entries), dep, str(getattr(speed_map, "message", "")))


def coefficients_at_speed(speed_map, speed: float, vessel: str = "") -> NomotoCoefficients:
    """The Nomoto model linearised at the operating speed, for :func:`build_autopilot`.

    Parameters
    ----------
    speed_map : object
        Anything with ``at(speed) -> {"K", "K_stderr", "T", "T_stderr"}``, e.g.
        :class:`pipeline.fit.nomoto_speed.NomotoSpeedMap`.
    speed : float
        Operating speed [m/s], positive.
    vessel : str
        Vessel name for the provenance.

    Returns
    -------
    NomotoCoefficients
        ``K(U)`` [1/s] and ``T(U)`` [s] with their standard errors from the speed law.

    Raises
    ------
    AutopilotError
        Non-positive speed, or K, T not positive there.
    """
    if not (math.isfinite(float(speed)) and float(speed) > 0):
        raise AutopilotError(f"operating speed: expected a positive speed [m/s], found {speed!r}")
    kt = speed_map.at(float(speed))
    if not (kt["K"] > 0 and kt["T"] > 0):
        raise AutopilotError(f"operating speed {speed:g} m/s: expected K > 0 and T > 0, found K = {kt['K']:.4g} 1/s, "
                             f"T = {kt['T']:.4g} s")
    return NomotoCoefficients(K=kt["K"], K_stderr=kt["K_stderr"], T=kt["T"], T_stderr=kt["T_stderr"], vessel=vessel)
