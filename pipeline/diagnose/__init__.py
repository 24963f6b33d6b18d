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

from ..lazy import lazy_exports

#: Public name -> module defining it; loaded on first use, so ``vesselid diagnose --help`` stays fast.
_EXPORTS = {
    "diagnose": ".verdict",
    "diagnose_segments": ".segments",
    "EFFECTS": ".candidates",
    "GapReport": "..records", "CandidateResult": "..records", "ChannelGap": "..records", "DofSummary": "..records",
    "EffectParam": "..records", "Place": "..records", "Spectrum": "..records", "Trace": "..records",
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
