"""Put raw channels on one uniform clock: interpolation, input hold, gap detection."""

from __future__ import annotations

import numpy as np

from ..records import ANGLE_CHANNELS, Channel, Gap


def _base(name: str) -> str:
    return name.split("@", 1)[0]


def dropout_limit(interval: float) -> float:
    """Largest sample spacing [s] that is not a dropout, for a channel sampled every ``interval`` [s].

    Five nominal sample intervals or 0.5 s, whichever is larger: jitter is not a gap, a lost
    second of GPS is. The same rule tells whether two files of one logger continue each other
    (:func:`pipeline.align.runs.group_runs`).

    Parameters
    ----------
    interval : float
        The channel's median sample interval [s].
    """
    return max(5 * interval, 0.5)


def find_gaps(channel: Channel, threshold: float | None = None) -> tuple[Gap, ...]:
    """Dropouts in a channel: intervals longer than ``threshold`` [s].

    The default threshold is five nominal sample intervals (the median spacing) or 0.5 s,
    whichever is larger, so jitter is not a gap but a lost second of GPS is.

    Parameters
    ----------
    channel : Channel
        Raw channel with increasing sample times ``t`` [s].
    threshold : float, optional
        Largest sample spacing [s] that is not a dropout; default as above.

    Returns
    -------
    tuple[Gap, ...]
        One per spacing above the threshold, bounded by the samples either side; empty for a
        channel of fewer than two samples.
    """
    dt = np.diff(channel.t)
    if len(dt) == 0:
        return ()
    limit = threshold if threshold is not None else dropout_limit(float(np.median(dt)))
    idx = np.flatnonzero(dt > limit)
    return tuple(Gap(channel.name, float(channel.t[i]), float(channel.t[i + 1])) for i in idx)


#: A held command stamped within this fraction of a grid step after a grid point takes effect at
#: that grid point.
HOLD_TOLERANCE = 1e-3


def resample_channel(channel: Channel, grid: np.ndarray, gaps: tuple[Gap, ...]) -> np.ndarray:
    """Channel values on ``grid`` [s]; NaN outside its span and inside its gaps.

    States and measured inputs (``Channel.input_kind == "measured"``: a rudder-angle sensor,
    shaft rpm) are interpolated linearly (angles after unwrapping, then wrapped back to
    (-pi, pi]); commanded inputs (the default) are held from the last command (zero-order
    hold), because an actuator keeps a command until the next one and linear interpolation
    would smear every step into a ramp.

    Parameters
    ----------
    channel : Channel
        Raw channel with increasing sample times ``t`` [s] on the common clock; its base name
        (before ``@``) decides state, angle or input treatment, and ``input_kind`` hold or
        interpolation of an input.
    grid : numpy.ndarray
        Uniform output times [s].
    gaps : tuple[Gap, ...]
        Dropouts of this channel (:func:`find_gaps`); grid points strictly inside one are NaN.

    Returns
    -------
    numpy.ndarray
        Values on ``grid`` [SI], as long as ``grid``; all NaN for an empty channel.
    """
    t, v = channel.t, channel.values
    base = _base(channel.name)
    if len(t) == 0:
        return np.full(len(grid), np.nan)
    if channel.held:
        # A command stamped a hair after a grid point (a clock offset, or times written with
        # microseconds, as ISO stamps are) is that grid point's command, not the next one's: held
        # from the next grid point it would act a whole step late.
        tol = max(1e-9, HOLD_TOLERANCE * float(np.min(np.diff(grid)))) if len(grid) > 1 else 1e-9
        idx = np.searchsorted(t, grid + tol, side="right") - 1
        out = np.where(idx >= 0, v[np.clip(idx, 0, len(v) - 1)], np.nan)
        out[grid > t[-1] + tol] = np.nan
    else:
        if base in ANGLE_CHANNELS:
            out = np.interp(grid, t, np.unwrap(v))
            out = np.pi - np.mod(np.pi - out, 2 * np.pi)
            # Just above pi, (pi - x) mod 2 pi rounds to 2 pi and gives -pi: keep (-pi, pi].
            out[out <= -np.pi] = np.pi
        else:
            out = np.interp(grid, t, v)
        out[(grid < t[0] - 1e-9) | (grid > t[-1] + 1e-9)] = np.nan
    for g in gaps:
        out[(grid > g.t_start) & (grid < g.t_end)] = np.nan
    return out
