"""GNSS fixes held by a logger: one fix repeated at the logger's rate is one measurement.

A small boat's logger often writes one CSV row per IMU sample (10-100 Hz) and repeats the last
GNSS fix (1-5 Hz) in every row until the next arrives. Interpolating those rows would turn each
fix into a staircase and differentiate it into spikes, and counting them as samples would tell
every later stage that a 1 Hz receiver measured at 50 Hz. A fix is recognised as held when all
GNSS channels of one receiver (same ``@sensor`` suffix, same sample times) repeat their previous
values exactly; only the first row of each repeat is kept, at the time the new fix appeared.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ..records import Channel

#: Channels that a GNSS receiver produces; a fix is held when all of one receiver's repeat.
GNSS_CHANNELS = ("lat", "lon", "sog", "cog")


def collapse_held_fixes(channels: Mapping[str, Channel]) -> tuple[dict[str, Channel], list[str]]:
    """Drop repeated (held) GNSS fixes, keeping the first sample of each.

    Parameters
    ----------
    channels : Mapping[str, Channel]
        The channels of one log.

    Returns
    -------
    dict[str, Channel]
        The same channels, the GNSS ones without their held repeats.
    list[str]
        One note per receiver whose fixes were held: rows before and fixes after, native rate.

    Notes
    -----
    Channels of one receiver are grouped by their ``@sensor`` suffix; channels on the same sample
    times are tested together (a row repeats only when every one of them repeats), so a boat at
    rest whose speed reads exactly 0.0 twice is not mistaken for a held fix while its position
    still moves. A receiver needs at least 3 repeats per new fix on average (a logger at three
    times the fix rate) before anything is dropped: an occasional identical pair is noise.
    """
    out = dict(channels)
    notes: list[str] = []
    by_sensor: dict[str, list[str]] = {}
    for name in channels:
        base, _, sensor = name.partition("@")
        if base in GNSS_CHANNELS:
            by_sensor.setdefault(sensor, []).append(name)
    for sensor, names in by_sensor.items():
        # Group channels sampled on identical times (one receiver written row by row).
        by_times: dict[tuple, list[str]] = {}
        for n in names:
            t = channels[n].t
            by_times.setdefault((len(t), float(t[0]) if len(t) else 0.0, float(t[-1]) if len(t) else 0.0), []).append(n)
        for group in by_times.values():
            t = channels[group[0]].t
            if len(t) < 4 or not all(np.array_equal(channels[n].t, t) for n in group):
                continue
            vals = np.vstack([channels[n].values for n in group])
            same = np.all(vals[:, 1:] == vals[:, :-1], axis=0)
            new = np.concatenate([[True], ~same])
            n_fix = int(new.sum())
            if n_fix * 3 > len(t):
                continue
            for n in group:
                c = channels[n]
                out[n] = Channel(c.name, c.t[new], c.values[new], c.source, c.input_kind)
            dt = np.diff(t[new])
            rate = 1.0 / float(np.median(dt)) if len(dt) else float("nan")
            notes.append(f"GNSS {', '.join(sorted(group))}: {len(t)} rows hold {n_fix} fixes (about {rate:.3g} Hz); "
                         f"repeated values are one fix each, kept at the row where each new fix appeared")
    return out, notes


__all__ = ["collapse_held_fixes", "GNSS_CHANNELS"]
