"""The segment stage of one trial: detected segments, then hand-named ones, each tagged with its run."""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Mapping, Sequence

from ..records import Segments, Trial
from .detect import detect_segments
from .manifest_segments import apply_manifest_segments


def segment_trial(trial: Trial, manual: Sequence[Mapping[str, Any]] = (), mode: str = "replace") -> Segments:
    """Detect segments, then apply hand-named ones from a manifest; each is tagged with its run.

    ``Segment.run`` is the index of the run (``Trial.run_list()``) the segment starts in; no
    segment spans a run boundary (the NaN gap between runs cuts every detector).

    Parameters
    ----------
    trial : Trial
        The aligned trial.
    manual : Sequence[Mapping[str, Any]]
        The manifest's ``[[segments]]`` tables; empty keeps the detected segments.
    mode : str
        ``replace`` (only the manifest's segments) or ``add`` (manifest segments plus detected
        ones that do not overlap them); see :func:`pipeline.segment.apply_manifest_segments`.
    """
    segs = apply_manifest_segments(trial, detect_segments(trial), manual, mode)
    return Segments(segs.trial, tuple(replace(s, run=trial.run_index(s.t_start)) for s in segs.items), segs.notes)
