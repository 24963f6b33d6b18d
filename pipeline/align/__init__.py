"""align stage: RawLog(s) + vessel -> Trial (one clock, resampled, body frame, SI units).

:func:`align` resamples; :mod:`.clock` estimates the clock offsets between files (absolute time or
cross-correlated rates); :mod:`.antenna` applies GPS lever arms and dual-antenna headings.
"""

from .align import align
from .clock import ClockOffset, estimate_offsets
from .runs import RunGroup, group_runs, grouping_text

__all__ = ["align", "estimate_offsets", "ClockOffset", "RunGroup", "group_runs", "grouping_text"]
