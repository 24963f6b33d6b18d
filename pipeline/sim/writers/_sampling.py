"""What the binary-format writers share: a RawLog channel checked, put onto the writer's message times,
and packed into an integer field."""

from __future__ import annotations

import numpy as np

from ...errors import SimError
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


def check_channel(name: str, ch: Channel) -> None:
    """Raise unless ``ch`` has one finite, strictly increasing ``t`` [s] per value.

    Parameters
    ----------
    name : str
        Channel name, for the message.
    ch : Channel
        The channel.

    Raises
    ------
    SimError
        ``t`` and ``values`` of different shapes, a non-finite ``t`` or a ``t`` that does not
        increase.
    """
    t = np.asarray(ch.t, float)
    v = np.asarray(ch.values)
    if t.ndim != 1 or t.shape != v.shape:
        raise SimError(f"channel {name}: expected t and values of one length, found shapes {t.shape} and {v.shape}")
    if len(t) == 0:
        return
    if not np.all(np.isfinite(t)):
        raise SimError(f"channel {name}: expected finite t [s], found {int((~np.isfinite(t)).sum())} non-finite")
    if np.any(np.diff(t) <= 0):
        i = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise SimError(f"channel {name}: expected strictly increasing t [s], found t[{i}]={t[i]} "
                       f"then t[{i + 1}]={t[i + 1]}")


def to_int_field(values: np.ndarray, lo: int, hi: int, what: str) -> np.ndarray:
    """Values rounded to integers for a message field that holds ``lo..hi``.

    Parameters
    ----------
    values : numpy.ndarray
        Scaled values [field units].
    lo, hi : int
        The field's range.
    what : str
        Field and channel, for the message.

    Returns
    -------
    numpy.ndarray
        ``int64`` values.

    Raises
    ------
    SimError
        A non-finite value or one outside the field.
    """
    v = np.asarray(values, float)
    if not np.all(np.isfinite(v)):
        raise SimError(f"{what}: expected finite values, found {int((~np.isfinite(v)).sum())} NaN/inf")
    r = np.round(v).astype(np.int64)
    if r.size and (r.min() < lo or r.max() > hi):
        raise SimError(f"{what}: expected field values in [{lo}, {hi}], found {r.min()}..{r.max()}")
    return r
