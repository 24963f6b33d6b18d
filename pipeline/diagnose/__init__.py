"""diagnose stage: Trial (+ Fits) -> :class:`GapReport` -- where the identified model disagrees with
the boat, which unmodelled effect explains it, and how far the gap shrinks with it.

- where (:mod:`.replay`): the baseline replayed open-loop from every window's measured start and
  over the whole trial; its held-out gap split by channel, segment kind, frequency band and
  operating regime, ranked by share;
- which (:mod:`.candidates`, :mod:`.crossval`, :mod:`.significance`): a library of small model
  augmentations, each refitted on training windows and scored on held-out ones, significant only
  beyond what noise alone produces (thresholds calibrated on clean simulated trials);
- how far (:mod:`.verdict`): held-out gap before and after, shrink, fitted effect parameters with
  jackknife errors, overlay figures (:mod:`.figures`) and an HTML section (:mod:`.html`).
"""

from .candidates import EFFECTS
from ..records import CandidateResult, ChannelGap, DofSummary, EffectParam, GapReport, Place, Spectrum, Trace
from .segments import diagnose_segments
from .verdict import diagnose

__all__ = ["diagnose", "diagnose_segments", "EFFECTS", "GapReport", "CandidateResult", "ChannelGap", "DofSummary",
           "EffectParam", "Place", "Spectrum", "Trace"]
