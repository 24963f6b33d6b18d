"""align stage: RawLog(s) + vessel -> Trial (one clock, resampled, body frame, SI units)."""

from .align import align

__all__ = ["align"]
