"""Put a RawLog channel onto a writer's message times (shared by the binary-format writers)."""

from __future__ import annotations

import numpy as np

from ...records import ANGLE_CHANNELS, Channel


def interp_channel(ch: Channel, t: np.ndarray) -> np.ndarray:
    """Linear interpolation of a state onto ``t`` [s]; angles through their unwrapped form."""
    tc = np.asarray(ch.t, float)
    v = np.asarray(ch.values, float)
    if tc.shape == t.shape and np.array_equal(tc, t):
        return v
    if ch.name.split("@")[0] in ANGLE_CHANNELS:
        return np.interp(t, tc, np.unwrap(v))
    return np.interp(t, tc, v)


def hold_channel(ch: Channel, t: np.ndarray) -> np.ndarray:
    """Zero-order hold of an input command onto ``t`` [s]: an actuator keeps its last command.

    A measured actuator state (``Channel.input_kind == "measured"``: a rudder-angle sensor) is a
    continuous signal and is interpolated instead, as align reads it back.
    """
    if ch.input_kind == "measured":
        return interp_channel(ch, t)
    idx = np.clip(np.searchsorted(ch.t, t, side="right") - 1, 0, len(ch.t) - 1)
    return np.asarray(ch.values, float)[idx]
