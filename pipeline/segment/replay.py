"""Segments for an open-loop replay of the identified model (what the diagnosis replays).

The detector (:func:`pipeline.segment.segment_trial`) ends a step once it judges the response
settled; an open-loop replay stays valid, and informative, as long as the inputs hold, so
:func:`extend_segments` runs input-driven segments on to the next change of any input. For logs
without a usable input record:

- :func:`velocity_decays`: a velocity *free decay* (surge speed after the throttle is cut, yaw rate
  after a spin-up) found in the response itself, for a DOF with no input logged;
- :func:`free_runs`: a *free run* per continuous stretch of data, for a DOF with a varying input
  in which the detector finds no manoeuvre (closed-loop autopilot runs): the recorded input is
  simply replayed.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import scipy.ndimage

from ..records import DOF_ANGLE, DOF_CHANNELS, INPUT_UNITS, RUN_BOUNDARY, Gap, Segment, Trial
from .quality import noise_std, true_runs

#: Smallest free decay: its peak over the noise, and its length in samples.
DECAY_SNR = 8.0
DECAY_MIN_SAMPLES = 10
#: A free run is cut into pieces of at most this length [s] so it can be cross-validated.
FREE_RUN_PIECE = 60.0


def velocity_decays(trial: Trial, dof: str, channel: str) -> list[Segment]:
    """Free decays of a velocity with no input logged: from where it starts to fall, to where it
    has lost 90% of its peak or the data ends.

    Parameters
    ----------
    trial : Trial
        Aligned trial.
    dof : str
        DOF name.
    channel : str
        Response channel (``u``, ``sog``, ``r``, ...).

    Returns
    -------
    list[Segment]
        ``coast_down`` segments with ``input_channel=None``.
    """
    y = trial.data[channel].to_numpy(float)
    t = trial.t
    fs = trial.fs
    noise = noise_std(y)
    if not np.isfinite(noise):
        return []
    noise = max(noise, 1e-12)
    w = max(int(0.5 * fs), 1)
    out = []
    for a, b in true_runs(np.isfinite(y), DECAY_MIN_SAMPLES):
        seg = y[a:b]
        # A median over half a second ignores the gyro spikes digitised records carry; edges are
        # held, not zero-padded, which would fake a decay at the end of the data.
        ys = scipy.ndimage.median_filter(seg, size=w, mode="nearest") if len(seg) > 2 * w else seg
        i = 0
        while i < len(seg) - DECAY_MIN_SAMPLES:
            mag = np.abs(ys[i:])
            k = int(np.argmax(mag))
            peak = float(mag[k])
            if peak < DECAY_SNR * noise:
                break
            k += i
            # Start: the last sample near the peak level before it falls below 90% of it.
            below = np.flatnonzero(np.abs(ys[k:]) < 0.9 * peak)
            if len(below) == 0:
                i = k + w
                continue
            k90 = k + int(below[0])
            near = np.flatnonzero(np.abs(ys[k:k90 + 1]) >= 0.99 * peak)
            start = k + int(near[-1]) if len(near) else k
            gone = np.flatnonzero(np.abs(ys[k90:]) < 0.1 * peak)
            end = k90 + int(gone[0]) if len(gone) else len(seg) - 1
            # A decay loses most of its peak; a plateau that merely wobbles does not.
            fell = np.abs(ys[end]) < 0.4 * peak
            if end - start >= DECAY_MIN_SAMPLES and fell:
                out.append(Segment("coast_down", dof, float(t[a + start]), float(t[a + end]), None, float(seg[start]),
                                   0.0, quality=float(np.clip(1 - np.exp(-peak / noise / 20), 0, 1)),
                                   label=f"{channel} free decay from {seg[start]:.3g} (no input logged)"))
            i = end + 1
    return out


def free_runs(trial: Trial, dof: str, channel: str, inputs: tuple[str, ...]) -> list[Segment]:
    """The recorded input replayed over each continuous stretch of data, in pieces.

    Parameters
    ----------
    trial, dof, channel : Trial, str, str
        As in :func:`velocity_decays`.
    inputs : tuple[str, ...]
        The DOF's input channels.
    """
    y = trial.data[channel].to_numpy(float)
    t = trial.t
    piece = max(int(FREE_RUN_PIECE * trial.fs), 2)
    out = []
    for a, b in true_runs(np.isfinite(y), max(int(5 * trial.fs), DECAY_MIN_SAMPLES)):
        n = int(np.ceil((b - a) / piece))
        edges = np.linspace(a, b, n + 1).astype(int)
        for i0, i1 in zip(edges[:-1], edges[1:]):
            out.append(Segment("free_run", dof, float(t[i0]), float(t[i1 - 1]), inputs[0], 0.0, 0.0, quality=0.5,
                               label=f"free run ({', '.join(inputs)} replayed)"))
    return out


def input_changes(trial: Trial) -> np.ndarray:
    """Times [s] at which any logged input changes by more than 1% of its range.

    Parameters
    ----------
    trial : Trial
        Aligned trial.
    """
    t = trial.t
    times = [t[-1]]
    for c in INPUT_UNITS:
        if not trial.has(c):
            continue
        u = trial.data[c].to_numpy(float)
        ok = np.isfinite(u)
        tol = max(0.01 * float(np.ptp(u[ok])), 1e-12)
        idx = np.flatnonzero(ok[1:] & ok[:-1] & (np.abs(np.diff(u)) > tol)) + 1
        times += list(t[idx])
    return np.unique(np.asarray(times, float))


def gaps_of(trial: Trial, channels) -> tuple[Gap, ...]:
    """The trial's gaps that interrupt any of ``channels``.

    A gap interrupts them when it is a dropout of one of them (a suffixed source, ``sog@gnss2``,
    counts as ``sog``), a run boundary, or a dropout of another channel during which one of them
    is missing on the trial grid (a channel derived from the one that dropped out: ``u`` and ``v``
    from ``sog``, ``cog`` and ``psi``). A GNSS dropout does not interrupt a yaw record of gyro,
    compass and rudder.

    Parameters
    ----------
    trial : Trial
        Aligned trial.
    channels : iterable of str
        Canonical channel names; those the trial does not hold are ignored.

    Returns
    -------
    tuple[Gap, ...]
        In the trial's order.
    """
    names = {c for c in channels if c}
    held = [trial.data[c].to_numpy(float) for c in sorted(names) if trial.has(c)]
    t = trial.t
    out = []
    for g in trial.gaps:
        if g.channel == RUN_BOUNDARY or g.channel.split("@")[0] in names:
            out.append(g)
            continue
        a, b = int(np.searchsorted(t, g.t_start, "right")), int(np.searchsorted(t, g.t_end, "left"))
        if b > a and any(not np.isfinite(x[a:b]).all() for x in held):
            out.append(g)
    return tuple(out)


def dof_channels(trial: Trial, dof: str, inputs=()) -> tuple[str, ...]:
    """Channels a replay of ``dof`` uses: its velocity (speed over ground for a surge without
    ``u``), its attitude angle and ``inputs``.

    Parameters
    ----------
    trial : Trial
        Aligned trial.
    dof : str
        DOF name (``surge``, ``sway``, ``yaw``, ``roll``, ``pitch``).
    inputs : iterable of str
        Input channels that drive it.
    """
    vel, force = DOF_CHANNELS.get(dof, (None, None))
    out = [vel if vel is None or trial.has(vel) or dof != "surge" else "sog", DOF_ANGLE.get(dof), force, *inputs]
    return tuple(dict.fromkeys(c for c in out if c))


def extend_segments(trial: Trial, items: list[Segment]) -> list[Segment]:
    """Input-driven segments run on to the next input change (never across a dropout of a channel
    the segment's DOF uses, :func:`gaps_of`).

    Parameters
    ----------
    trial : Trial
        Aligned trial.
    items : list[Segment]
        Segments.
    """
    changes = input_changes(trial)
    out = []
    cut: dict = {}
    for s in items:
        if s.input_channel is None or s.kind == "free_run":
            out.append(s)
            continue
        later = changes[changes > s.t_end - 1.5 / trial.fs]
        end = float(later[0]) - 1.0 / trial.fs if len(later) else s.t_end
        key = (s.dof, s.input_channel)
        if key not in cut:
            cut[key] = gaps_of(trial, dof_channels(trial, s.dof, (s.input_channel,)))
        for g in cut[key]:
            if s.t_start < g.t_start < end:
                end = g.t_start
        out.append(replace(s, t_end=max(s.t_end, end)))
    return out
