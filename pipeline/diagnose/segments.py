"""Segments for the diagnosis: the segment stage's detector, plus what it cannot see.

Every segment comes from the segment stage (:mod:`pipeline.segment`): the detected ones
(:func:`pipeline.segment.segment_trial`), run on to the next input change, and, per DOF, the
replay segments of :mod:`pipeline.segment.replay` where the detector finds nothing: velocity free
decays in a DOF with no input logged, free runs in a DOF whose input varies.
"""

from __future__ import annotations

from ..fit.data import first_present_channel
from ..records import Segments, Trial
from ..segment import segment_trial
from ..segment.replay import extend_segments, free_runs, velocity_decays
from .problem import FORCE, RESPONSE, dof_inputs


def diagnose_segments(trial: Trial, detected: Segments | None = None) -> Segments:
    """Detected segments, plus velocity free decays and free runs where the detector sees nothing.

    Parameters
    ----------
    trial : Trial
        Aligned trial.
    detected : Segments, optional
        The segment stage's detection on this trial, ``segment_trial(trial)`` with no manifest
        segments (the flow has it already); default: detected here.

    Returns
    -------
    Segments
        In time order; input-driven segments extended to the next input change.
    """
    if detected is None:
        detected = segment_trial(trial)
    items = extend_segments(trial, list(detected.items))
    for dof in ("surge", "sway", "yaw"):
        ch = first_present_channel(trial, RESPONSE[dof])
        if ch is None:
            continue
        inputs = dof_inputs(trial, None, dof)
        mine = [s for s in items if s.dof == dof]
        if not inputs and not mine:
            items += velocity_decays(trial, dof, ch)
        elif inputs and not mine:
            items += free_runs(trial, dof, ch, inputs)
    items.sort(key=lambda s: (s.t_start, s.dof))
    return Segments(trial.name, tuple(items))


__all__ = ["diagnose_segments", "velocity_decays", "free_runs", "FORCE"]
