"""GPS time <-> Unix time (UTC) with the leap-second table, for the readers' ``RawLog.start_time``.

GPS time runs without leap seconds from its epoch 1980-01-06 00:00:00 UTC; UTC (and Unix time,
which ignores leap seconds) has fallen behind it by one second at each leap second since. A log's
absolute time is wanted to put files from several receivers and loggers on one clock, so the
offset must be right to the second: a fixed 18 s would misplace every log recorded before 2017.
"""

from __future__ import annotations

import math
from datetime import datetime, timezone

#: Unix time of the GPS epoch, 1980-01-06 00:00:00 UTC [s].
GPS_EPOCH_UNIX = 315_964_800.0
#: Seconds in a GPS week.
WEEK_S = 604_800.0

#: (Unix time [s] of the UTC instant a leap second took effect, GPS - UTC [s] from then on).
#: IERS Bulletin C; no leap second has been announced after 2017-01-01 (checked up to Bulletin C 69).
LEAP_SECONDS: tuple[tuple[float, int], ...] = tuple(
    (datetime(y, m, 1, tzinfo=timezone.utc).timestamp(), n) for (y, m), n in (
        ((1981, 7), 1), ((1982, 7), 2), ((1983, 7), 3), ((1985, 7), 4), ((1988, 1), 5), ((1990, 1), 6),
        ((1991, 1), 7), ((1992, 7), 8), ((1993, 7), 9), ((1994, 7), 10), ((1996, 1), 11), ((1997, 7), 12),
        ((1999, 1), 13), ((2006, 1), 14), ((2009, 1), 15), ((2012, 7), 16), ((2015, 7), 17), ((2017, 1), 18)))


def leap_seconds(unix_s: float) -> int:
    """GPS - UTC [s] at a UTC instant.

    Parameters
    ----------
    unix_s : float
        UTC instant [s since the Unix epoch].

    Returns
    -------
    int
        Leap seconds between GPS time and UTC at that instant (0 before 1981-07-01).
    """
    n = 0
    for when, count in LEAP_SECONDS:
        if unix_s >= when:
            n = count
    return n


def gps_to_unix(week: float, tow_s: float) -> float:
    """Unix time (UTC) of a GPS week and time of week.

    Parameters
    ----------
    week : float
        Full GPS week number (weeks since 1980-01-06, not modulo 1024).
    tow_s : float
        Time of week [s], may exceed a week (it is simply added).

    Returns
    -------
    float
        UTC [s since the Unix epoch]; NaN for a non-finite input.
    """
    if not (math.isfinite(week) and math.isfinite(tow_s)):
        return math.nan
    gps_unix = GPS_EPOCH_UNIX + week * WEEK_S + tow_s
    # The leap count is looked up at the UTC instant, found by subtracting the count of a moment
    # before; two rounds settle it except inside the leap second itself.
    return gps_unix - leap_seconds(gps_unix - leap_seconds(gps_unix))


def unix_text(unix_s: float) -> str:
    """ISO 8601 UTC text of a Unix time, for summaries and notes (``'unknown'`` for NaN).

    Parameters
    ----------
    unix_s : float
        UTC [s since the Unix epoch].
    """
    if not math.isfinite(unix_s):
        return "unknown"
    return datetime.fromtimestamp(unix_s, timezone.utc).isoformat(timespec="milliseconds")


__all__ = ["GPS_EPOCH_UNIX", "WEEK_S", "LEAP_SECONDS", "leap_seconds", "gps_to_unix", "unix_text"]
