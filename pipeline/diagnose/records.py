"""Records of the diagnose stage (to move into :mod:`pipeline.records` later, after ``Fits``).

``Trial + Fits -> GapReport``: where the identified model disagrees with the boat, which
unmodelled effect explains it, and how far the gap shrinks with that effect added. Every record is
frozen. Gaps are dimensionless: the held-out RMS of the open-loop simulation error of a channel
in units of that channel's white-noise level at the analysis step (1 = nothing left but sensor
noise); a DOF's gap is the RMS over its channels, the trial's gap the RMS over every channel of
every DOF. "Explained" errors are relative to the channel's scale instead (its standard deviation
over the DOF's own manoeuvres), so that a tiny but statistically visible error is not named.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np


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
        ``effect`` or ``effect[input]`` for per-input candidates.
    input_channel : str or None
        Input concerned (rate limit, thrust asymmetry) or regressor (coupling), else None.
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

    @property
    def shrink(self) -> float:
        """``100 (1 - gap_after / gap_before)`` [%] (0 when there is no verdict)."""
        return 100.0 * (1.0 - self.gap_after / self.gap_before) if self.gap_before > 0 else 0.0

    @property
    def verdict(self) -> CandidateResult | None:
        """The winning candidate, if any."""
        for c in self.candidates:
            if c.significant and c.effect == self.effect and c.dof == self.dof:
                return c
        return None

    def to_dict(self) -> dict[str, Any]:
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
            } for d in self.dofs],
            "places": [{"category": p.category, "dof": p.dof, "name": p.name, "share": num(p.share),
                        "gap": num(p.gap), "n": p.n} for p in self.places],
            "thresholds": {k: num(v) for k, v in self.thresholds.items()},
            "notes": list(self.notes),
        }
