"""Trial shapes of issue 10 through the whole pipeline (one seed each; the benchmark,
``benchmarks/trial_shapes.py``, runs many): the same AAUSHIP identification day logged slowly
and fast, and by a GNSS-only boat as one file (the logger holds each fix in every IMU row) and as
one file per run (the GNSS in its own ISO-stamped file beside the IMU file)."""

from __future__ import annotations

import math

import pytest

#: Every identified coefficient of one seed lies within this many standard errors of the truth
#: (3 SE: about 1 in 370 by chance per coefficient when unbiased).
Z_MAX = 3.0


def _day(rate: float, body_velocities: bool, layouts: tuple[str, ...], diagnose: bool) -> dict[str, dict]:
    from benchmarks import trial_shapes as shapes

    rows = shapes.run_day(5, rate, body_velocities, layouts, diagnose, None)
    for r in rows:
        assert not r["error"], r["error"]
    return {r["layout"]: r for r in rows}


@pytest.mark.slow  # a 50 Hz day fitted, a 1 Hz day fitted and diagnosed: 98 s wall at load 8
def test_logged_at_one_hertz_gives_the_fifty_hertz_coefficients_and_no_effect():
    """Commands held by the actuator and logged at 1 Hz: the same coefficients, within their standard
    errors, as 50 Hz on the same manoeuvres, and no effect on clean data (before: interpolated
    commands gave a false actuator delay on a 1 Hz log)."""
    slow = _day(1.0, True, ("one file",), True)["one file"]
    fast = _day(50.0, True, ("one file",), False)["one file"]
    assert slow["effect"] == "none", slow["effect"]
    both = sorted(set(slow["z"]) & set(fast["z"]))
    assert {"X_u", "N_r", "K_nomoto", "T_nomoto"} <= set(both), (both, slow["missing"])
    for name in both:
        (_, v1, s1, *_), (_, v50, s50, *_) = slow["z"][name], fast["z"][name]
        assert abs(v1 - v50) < 2 * math.hypot(s1, s50), (name, v1, s1, v50, s50)
    for row in (slow, fast):
        for name, (z, *_) in row["z"].items():
            assert abs(z) < Z_MAX, (row["rate"], name, z)


@pytest.mark.slow  # two 5 Hz days fitted and diagnosed: 167 s wall at load 8
def test_a_gnss_only_boat_gives_unbiased_coefficients_and_a_null_diagnosis():
    """No logged u, v: body velocities from GNSS course, speed and heading; in one file the held fixes
    count once each, per run the GNSS file joins its IMU file by absolute time (before: a false
    "waves/sway" verdict on a clean day of this shape)."""
    rows = _day(5.0, False, ("one file", "file per run"), True)
    assert rows["one file"]["runs"] == 1 and rows["file per run"]["runs"] == 3
    for layout, row in rows.items():
        assert row["effect"] == "none", (layout, row["effect"])
        assert {"X_u", "Y_v", "N_r", "K_nomoto", "T_nomoto"} <= set(row["z"]), (layout, row["missing"])
        for name, (z, *_) in row["z"].items():
            assert abs(z) < Z_MAX, (layout, name, z)
