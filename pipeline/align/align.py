"""Align raw logs into one Trial: one clock, uniform rate, body frame, derived channels."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from ..errors import AlignError
from ..geo import latlon_to_ned, wrap_pi
from ..records import CHANNEL_UNITS, INPUT_UNITS, Channel, RawLog, Trial
from ..vessel import Vessel
from .antenna import apply_sensors
from .clock import estimate_offsets
from .plausibility import check_duration, plausibility_notes
from .resample import find_gaps, resample_channel

#: Highest rate the aligner resamples to by default [Hz]; faster sensors are decimated by
#: interpolation, which is fine for the dynamics of a surface vessel.
MAX_DEFAULT_RATE = 100.0


def _native_rate(ch: Channel) -> float:
    dt = np.diff(ch.t)
    return 1.0 / float(np.median(dt)) if len(dt) else 0.0


def align(logs: Sequence[RawLog], name: str = "trial", fs: float | None = None,
          offsets: Mapping[str, float] | str | None = "auto", gap_threshold: float | None = None,
          vessel: Vessel | None = None) -> Trial:
    """Put the channels of one or more raw logs on one uniform clock.

    Parameters
    ----------
    logs : Sequence[RawLog]
        Logs of the same trial.
    name : str
        Trial name.
    fs : float, optional
        Output rate [Hz]; default the fastest state channel, at most ``MAX_DEFAULT_RATE``.
    offsets : Mapping[str, float] or "auto" or None
        ``"auto"`` (the default; None means the same): with more than one log, estimate the
        offsets with :func:`pipeline.align.clock.estimate_offsets` (absolute time where a log
        has ``start_time``, else cross-correlated rates) and record each offset, its standard
        error and method in ``Trial.notes``. A mapping gives the clock offset [s] to add to each
        log (keyed by ``RawLog.source``); logs it does not name share the first log's clock, so
        ``{}`` means "the logs already share one clock".
    gap_threshold : float, optional
        Dropout threshold [s] (default: :func:`pipeline.align.resample.find_gaps`).
    vessel : Vessel, optional
        Its ``[sensors]`` table (:mod:`pipeline.align.antenna`): dual-antenna headings
        ``psi@<baseline>`` and GPS lever-arm corrections to the body origin, applied on the
        uniform grid before body velocities are derived.

    Returns
    -------
    Trial
        Column ``t`` from 0 at the earliest sample, canonical channels, derived ``x_n``, ``y_e``
        (from lat/lon) and ``u``, ``v`` (from speed and course over ground and heading) where they
        were not logged.

    Raises
    ------
    AlignError
        No logs, no channels, a channel with non-increasing time, logs that share no time, or
        (``offsets="auto"``) a log that can be put on the common clock neither by absolute time
        nor by a significant cross-correlation.
    ConfigError
        A malformed ``[sensors]`` table in the vessel config.
    """
    if not logs:
        raise AlignError("align: expected at least one log, found none")
    notes: list[str] = []
    if offsets is None or isinstance(offsets, str):
        if offsets not in (None, "auto"):
            raise AlignError(f"align: offsets expected 'auto' or a mapping source -> seconds, found {offsets!r}")
        offsets = {}
        if len(logs) > 1:
            for src, est in estimate_offsets(logs).items():
                offsets[src] = est.offset_s
                notes.append(f"clock: {src} offset {est.offset_s:+.6f} s +- {est.stderr_s:.3g} s ({est.method})")
    offsets = dict(offsets)
    chans: dict[str, Channel] = {}
    for log in logs:
        off = float(offsets.get(log.source, 0.0))
        if off:
            notes.append(f"{log.source}: clock offset {off:+.3f} s applied")
        for ch in log.channels.values():
            if len(ch.t) and np.any(np.diff(ch.t) <= 0):
                raise AlignError(f"{log.source}: channel {ch.name!r}: expected strictly increasing time, "
                                 f"found a step back at t = {ch.t[np.flatnonzero(np.diff(ch.t) <= 0)[0] + 1]:.6f} s")
            key = ch.name
            if key in chans:
                # Same channel from two files: keep both, the second under a file-specific name.
                key = f"{ch.name}@{Path(log.source).stem}"
                while key in chans:
                    key += "_"
                notes.append(f"{log.source}: channel {ch.name} also in another log; kept as {key}")
            chans[key] = Channel(key, ch.t + off, ch.values, ch.source)
    chans = {k: c for k, c in chans.items() if len(c.t)}
    if not chans:
        raise AlignError(f"align: expected channels with samples, found none in {[l.source for l in logs]}")
    t0 = min(float(c.t[0]) for c in chans.values())
    t1 = max(float(c.t[-1]) for c in chans.values())
    states = [c for k, c in chans.items() if k.split("@")[0] not in INPUT_UNITS]
    if fs is None:
        rates = [_native_rate(c) for c in (states or chans.values())]
        fs = min(max(rates), MAX_DEFAULT_RATE)
    check_duration(chans.values(), fs)
    if not fs > 0:
        raise AlignError(f"align: expected a positive sample rate [Hz], found {fs}")
    n = int(np.floor((t1 - t0) * fs + 1e-9)) + 1
    grid = t0 + np.arange(n) / fs
    data = {"t": grid - t0}
    gaps = []
    for key, ch in chans.items():
        g = find_gaps(ch, gap_threshold)
        gaps += g
        data[key] = resample_channel(ch, grid, g)
    if gaps:
        notes.append(f"{len(gaps)} dropout(s): " + ", ".join(f"{g.channel} {g.t_start - t0:.2f}-{g.t_end - t0:.2f} s"
                                                              for g in gaps[:10]))
    frame = pd.DataFrame(data)
    if vessel is not None:
        frame, sensor_notes = apply_sensors(frame, vessel)
        notes += sensor_notes
    frame, derived = _derive(frame, {k: _native_rate(c) for k, c in chans.items()})
    notes += derived
    notes += plausibility_notes(frame, fs)
    shifted = tuple(type(g)(g.channel, g.t_start - t0, g.t_end - t0) for g in gaps)
    return Trial(name=name, data=frame, fs=float(fs), gaps=shifted, sources=tuple(l.source for l in logs),
                 notes=tuple(notes), summaries=tuple(l.summary for l in logs))


def _first_present(frame: pd.DataFrame, base: str) -> str | None:
    if base in frame and np.isfinite(frame[base]).any():
        return base
    for c in frame.columns:
        if c.split("@")[0] == base and np.isfinite(frame[c]).any():
            return c
    return None


def _fastest_velocity(frame: pd.DataFrame, rates: Mapping[str, float]) -> tuple[str | None, str | None]:
    """The sog/cog pair from one sensor (same suffix) with the highest native rate.

    A fast navigation-filter velocity resolves a sway time constant of 0.4 s where a 10 Hz GPS
    cannot, so the fastest complete pair feeds the body velocities.
    """
    best, best_rate = (None, None), -1.0
    for c in frame.columns:
        if c.split("@")[0] != "sog" or not np.isfinite(frame[c]).any():
            continue
        cog = "cog" + c[3:]
        if cog in frame and np.isfinite(frame[cog]).any() and rates.get(c, 0.0) > best_rate:
            best, best_rate = (c, cog), rates.get(c, 0.0)
    return best


def _derive(frame: pd.DataFrame, rates: Mapping[str, float] | None = None) -> tuple[pd.DataFrame, list[str]]:
    """Add x_n, y_e from lat/lon and body u, v from sog/cog/psi when not logged.

    Parameters
    ----------
    frame : pandas.DataFrame
        Resampled channels.
    rates : Mapping[str, float], optional
        Native sample rate of each channel [Hz], to pick the fastest velocity source.
    """
    notes = []
    out = frame.copy()
    lat, lon = _first_present(out, "lat"), _first_present(out, "lon")
    if "x_n" not in out and lat and lon:
        la, lo = out[lat].to_numpy(), out[lon].to_numpy()
        first = np.flatnonzero(np.isfinite(la) & np.isfinite(lo))[0]
        out["x_n"], out["y_e"] = latlon_to_ned(la, lo, la[first], lo[first])
        notes.append(f"x_n, y_e from {lat}/{lon} (flat earth about the first fix {la[first]:.6f}, {lo[first]:.6f} deg)")
    sog, cog = _fastest_velocity(out, rates or {})
    psi = _first_present(out, "psi")
    if sog and cog and psi and not ("u" in out and "v" in out):
        # Velocity over ground in the body frame: [u, v] = R(psi)^T [v_n, v_e]. With a water
        # current this is not the velocity through the water; the diagnosis tests for that.
        beta = wrap_pi(out[cog].to_numpy() - out[psi].to_numpy())
        speed = out[sog].to_numpy()
        if "u" not in out:
            out["u"] = speed * np.cos(beta)
        if "v" not in out:
            out["v"] = speed * np.sin(beta)
        notes.append(f"u, v over ground from {sog}, {cog} ({(rates or {}).get(sog, float('nan')):.3g} Hz) "
                     f"and heading {psi}")
    ordered = ["t"] + [c for c in CHANNEL_UNITS if c in out] + sorted(c for c in out if c != "t" and c not in CHANNEL_UNITS)
    return out[ordered], notes
