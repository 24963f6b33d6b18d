"""A trial's diagnosis frame: each DOF's windows, analysis step, input timing and noise units, so that
another trial of the same schedule and log can be diagnosed on exactly them.

Why: what a diagnosis can see of one effect is measured by diagnosing the same trial with that effect
switched off (benchmarks/diagnose.py, ``power_off``). Diagnosed on its own, that trial is cut into other
windows (the fit's time constant sizes the blocks), its log timing of the commands is pinned or not
for other reasons, and its noise unit is measured on other windows (randomised seed 46 r005, a GNSS lag:
22 surge windows with the lag, 24 without, sog's noise unit 11 % apart). The difference of the two
diagnoses then mixes the effect with the windowing. On the frame of the trial with the effect
(:func:`diagnosis_frame`, passed as ``diagnose(..., frame=...)``) the trial without it differs from it
only by the effect.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Mapping

import numpy as np

from ..records import Segments, Trial
from ..vessel import Vessel
from .actuators import actuator_key
from .candidates import Candidate
from .gridfit import grid_data
from .problem import DofProblem, Window, build_problems
from .segments import diagnose_segments
from .timing import advance_input, input_timing


@dataclass(frozen=True)
class DofFrame:
    """One DOF's frame.

    Attributes
    ----------
    windows : tuple[Window, ...]
        The DOF's windows (after cutting into blocks).
    m : int
        Trial samples per analysis step.
    t_guess : float
        Time constant of the first pass [s].
    advance : float
        Input timing: inputs taken this much earlier than logged [s] (0: none).
    noise_unit : Mapping[str, float]
        Output channel -> noise per analysis step [SI].
    """

    windows: tuple[Window, ...]
    m: int
    t_guess: float
    advance: float
    noise_unit: Mapping[str, float] = field(default_factory=dict)


def first_pass_time_constants(trial: Trial, segments: Segments, vessel: Vessel | None) -> dict[str, float]:
    """First pass of a diagnosis: the baseline fitted on every window of each DOF, its T [s] per DOF, which
    sizes the analysis step and the blocks.

    Parameters
    ----------
    trial : Trial
        Aligned trial.
    segments : Segments
        Its segments.
    vessel : Vessel, optional
        Vessel config.
    """
    out = {}
    for p in build_problems(trial, segments, vessel):
        d = grid_data(p)
        fitted = Candidate(p, d).fit(np.arange(len(p.windows)))
        out[p.dof] = float(fitted.params["T"])
    return out


def diagnosis_frame(trial: Trial, vessel: Vessel | None = None, segments: Segments | None = None
                    ) -> dict[str, DofFrame]:
    """The frame a diagnosis of ``trial`` uses, per DOF (the steps of
    :func:`pipeline.diagnose.verdict.diagnose` before the cross-validation).

    Parameters
    ----------
    trial : Trial
        Aligned trial.
    vessel : Vessel, optional
        Vessel config.
    segments : Segments, optional
        Segments; default: detected.

    Returns
    -------
    dict[str, DofFrame]
        DOF name -> its frame (roll and pitch are not framed).
    """
    segs = segments if segments is not None else diagnose_segments(trial)
    out = {}
    for p in build_problems(trial, segs, vessel, time_constants=first_pass_time_constants(trial, segs, vessel)):
        timed, advance = input_timing(p)
        d = grid_data(timed)
        units = {p.channel: float(d.sigma_y)}
        if p.angle:
            units[p.angle] = float(d.sigma_angle)
        out[p.dof] = DofFrame(tuple(p.windows), int(p.m), float(p.t_guess), float(advance), units)
    return out


def on_frame(p: DofProblem, f: DofFrame) -> DofProblem:
    """``p`` (built on another trial of the same schedule and log) on the frame ``f``: its windows, analysis
    step, first-pass time constant and noise units, and its inputs advanced by the frame's timing.

    Parameters
    ----------
    p : DofProblem
        The DOF's problem of the trial being diagnosed.
    f : DofFrame
        The same DOF's frame of the other trial.

    Returns
    -------
    DofProblem

    Raises
    ------
    ValueError
        A window of the frame reaches past the trial's samples (not the same log).
    """
    n = len(p.raw[p.channel])
    if any(w.i1 > n for w in f.windows):
        raise ValueError(f"{p.dof}: expected a frame of a trial of {n} samples, found a window ending at sample "
                         f"{max(w.i1 for w in f.windows)}")
    raw = dict(p.raw)
    if f.advance > 0:
        for c in tuple(p.inputs) + tuple(actuator_key(a.name) for a in p.actuators):
            raw[c] = advance_input(p.raw[c], f.advance * p.fs)
    return replace(p, windows=tuple(f.windows), m=f.m, dt=f.m / p.fs, t_guess=f.t_guess, raw=raw,
                   noise_unit=dict(f.noise_unit))


__all__ = ["DofFrame", "diagnosis_frame", "first_pass_time_constants", "on_frame"]
