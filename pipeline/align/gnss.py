"""GNSS fixes held by a logger: one fix repeated at the logger's rate is one measurement.

A small boat's logger often writes one CSV row per IMU sample (10-100 Hz) and repeats the last
GNSS fix (1-5 Hz) in every row until the next arrives. Interpolating those rows would turn each
fix into a staircase and differentiate it into spikes, and counting them as samples would tell
every later stage that a 1 Hz receiver measured at 50 Hz. A fix is recognised as held when all
GNSS channels of one receiver (same ``@sensor`` suffix, same sample times) repeat their previous
values exactly; only the first row of each repeat is kept. Its time is the receiver's fix time
when the fixes come on a regular clock (:func:`fix_times`), else the row where the new fix appeared.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ..records import Channel

#: Channels that a GNSS receiver produces; a fix is held when all of one receiver's repeat.
GNSS_CHANNELS = ("lat", "lon", "sog", "cog")
#: Rows per new fix from which repeats are held fixes whatever their pattern.
MIN_ROWS_PER_FIX = 3.0
#: Share of fixes that must appear in at least two rows for a logger at 1.5-3 rows per fix to be
#: holding them (a 10 Hz logger, a 5 Hz receiver: every fix in two rows).
MIN_HELD_SHARE = 0.9


def is_held(new: np.ndarray) -> bool:
    """Whether the repeated rows of one receiver are a logger holding its fixes.

    Parameters
    ----------
    new : numpy.ndarray
        True where a row differs from the one before (a new fix).

    Notes
    -----
    At ``MIN_ROWS_PER_FIX`` or more rows per fix the repeats are held fixes. Below that, they are
    when nearly every fix (``MIN_HELD_SHARE``, the first and last left out) appears in two rows or
    more: a logger at twice the receiver's rate repeats every fix, also while the boat moves. A
    boat at rest repeats a quantised position and zero speed in long runs, but while it moves each
    real sample differs from the last, so a log whose repeats come only at rest (a MAVLink
    GLOBAL_POSITION_INT at low noise: most runs one row long) is left alone.
    """
    n_fix = int(new.sum())
    if n_fix < 4:
        return False
    if n_fix * MIN_ROWS_PER_FIX <= new.size:
        return True
    starts = np.flatnonzero(new)
    runs = np.diff(np.append(starts, new.size))[1:-1]
    return bool(runs.size >= 3 and np.mean(runs >= 2) >= MIN_HELD_SHARE)


def fix_times(t_rows: np.ndarray, first: np.ndarray) -> tuple[np.ndarray, str]:
    """Fix times of held fixes from the rows where each first appears, when they come on one clock.

    A fix first written in row ``k`` was measured after row ``k - 1`` and no later than row ``k``.
    A receiver fixes on its own regular clock ``t_j = a + j P``; its period ``P`` is the
    least-squares line through the rows where the fixes first appear (fix numbers counted from the
    median interval, so a dropped fix is skipped), and every fix bounds the phase ``a`` from both
    sides. When all bounds agree, each fix is put at the latest time they allow (no latency
    assumed: with a fix period a whole number of rows, that is the first row of each fix, the time
    a logger that writes a fix in the row it arrives at gives it); a fix period that is not a whole
    number of rows pins the phase to a fraction of a row. Otherwise (a jittery logger clock, a
    receiver that re-synchronises) the first rows are kept.

    Parameters
    ----------
    t_rows : numpy.ndarray
        Row times of the log [s], increasing.
    first : numpy.ndarray
        True on the row where each fix first appears.

    Returns
    -------
    numpy.ndarray
        Fix times [s], one per True in ``first``.
    str
        How they were found, for the note.
    """
    idx = np.flatnonzero(first)
    t_new = t_rows[idx]
    if idx.size < 4:
        return t_new, "fix times: the rows where each fix first appears"
    d = np.diff(t_new)
    p0 = float(np.median(d))
    if not p0 > 0:
        return t_new, "fix times: the rows where each fix first appears"
    j = np.concatenate([[0], np.cumsum(np.maximum(np.rint(d / p0), 1))])
    period, _ = np.polyfit(j, t_new, 1)
    # The first row of the log has no row before it: it bounds the phase from above only.
    hi = float(np.min(t_new - j * period))
    lo = float(np.max(t_rows[idx[1:] - 1] - j[1:] * period))
    if not (period > 0 and lo < hi):
        return t_new, (f"fix times: the rows where each fix first appears (no single receiver clock fits them "
                       f"between their rows)")
    return hi + j * period, (f"fix times on the receiver's clock (period {period:.6g} s, phase bounded within "
                             f"{hi - lo:.3g} s by the rows before and at each new fix; latest time taken)")


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
    still moves. The repeats are held fixes when :func:`is_held` says so (three rows per fix, or
    nearly every fix in two rows or more); an occasional identical pair is noise. The fixes' times
    come from :func:`fix_times`.
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
            if not is_held(new):
                continue
            t_fix, how = fix_times(t, new)
            for n in group:
                c = channels[n]
                out[n] = Channel(c.name, t_fix, c.values[new], c.source, c.input_kind)
            dt = np.diff(t_fix)
            rate = 1.0 / float(np.median(dt)) if len(dt) else float("nan")
            notes.append(f"GNSS {', '.join(sorted(group))}: {len(t)} rows hold {n_fix} fixes (about {rate:.3g} Hz); "
                         f"repeated values are one fix each; {how}")
    return out, notes


__all__ = ["collapse_held_fixes", "fix_times", "is_held", "GNSS_CHANNELS"]
