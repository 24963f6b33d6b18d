"""segment stage: Trial -> Segments (coast-down, step, free decay, rudder step, zig-zag, sinusoid)."""

from .detect import detect_segments, noise_std, segment_table
from .manifest_segments import apply_manifest_segments
from .trial import segment_trial

__all__ = ["detect_segments", "segment_table", "apply_manifest_segments", "noise_std", "segment_trial"]
