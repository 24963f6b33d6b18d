"""Plausibility of an aligned trial: is the data physically possible for a vessel under way?

Readers account for every message but cannot judge whether the numbers make sense together.
Four checks run on the uniform grid after alignment; each failure is a note in ``Trial.notes``
starting with ``plausibility: FAIL [<channels>]:`` and the channels named there yield no segments
(:func:`without_implausible`, called by segment detection). Passing checks add one
``plausibility: ok`` note that lists what was checked.

1. **Gravity on the wrong axis** (IMU mounting). At rest and under way alike a vessel's mean
   specific force is gravity: ``f = g [sin(theta), -sin(phi) cos(theta), -cos(phi) cos(theta)]``
   in Fossen's body frame (z down), so the median of ``az`` is close to -9.81 m/s^2 and those of
   ``ax``, ``ay`` much smaller. A median |ax| or |ay| above 0.5 g, or ``az`` above +0.5 g, means
   the IMU is mounted rotated (or upside down) relative to the body axes: its accelerations and
   rates of that sensor fail.
2. **Constant or zero channels.** An IMU or attitude channel whose every sample is the same value
   (all zeros is the common case: a sensor that is configured but not sampled) fails; so does a
   roll or pitch whose median magnitude no floating vessel holds (``MAX_ROLL_DEG``,
   ``MAX_PITCH_DEG``: a board mounted upside down reads roll +-180 deg).
3. **Attitude contradicting the IMU.** Where the accelerometer is plausible, the roll and pitch
   it implies, ``phi_f = atan2(-f_y, -f_z)``, ``theta_f = atan2(f_x, sqrt(f_y^2 + f_z^2))``,
   are compared over 10 s medians with the logged ``phi``/``theta``; a median disagreement above
   ``ATTITUDE_TOL_DEG`` fails the attitude channel (a wrong board orientation, or an attitude
   from another sensor).
4. **Vessel at rest.** Speed below ``REST_SPEED`` m/s in 95 % of the samples, yaw rate below
   1 deg/s, roll and pitch spanning less than 2 deg (1st-99th percentile) and no input change:
   nothing in the trial can identify dynamics, and decays found in sensor noise would be
   spurious. Every channel fails.
"""

from __future__ import annotations

import math
import re
from dataclasses import replace
from typing import Iterable

import numpy as np
import pandas as pd

from ..errors import AlignError

G = 9.80665
#: Largest median disagreement between logged and accelerometer roll/pitch [deg].
ATTITUDE_TOL_DEG = 20.0
#: Median |roll| and |pitch| above which a vessel cannot be floating upright [deg].
MAX_ROLL_DEG = 60.0
MAX_PITCH_DEG = 45.0
#: Speed below which the vessel counts as at rest [m/s].
REST_SPEED = 0.1
#: Fewest samples a channel needs before it is judged constant.
MIN_SAMPLES = 20
#: Largest uniform grid the aligner builds [samples]; a log that would need more has a corrupted
#: time stamp or a wrong rate (100 Hz for 10 days is 8.6e7).
MAX_GRID = 100_000_000
_IMU_BASES = ("p", "q", "r", "ax", "ay", "az")
_ATT_BASES = ("phi", "theta", "psi")
_FAIL_RE = re.compile(r"^plausibility: FAIL \[([^\]]*)\]")


def _base(col: str) -> str:
    return col.split("@")[0]


def _suffix(col: str) -> str:
    return col[len(_base(col)):]


def check_duration(chans: Iterable, fs: float | None = None) -> None:
    """Raise when the logs are too short to put on a grid, naming the duration and what is needed.

    Parameters
    ----------
    chans : iterable of pipeline.records.Channel
        Channels after clock offsets.
    fs : float, optional
        Requested output rate [Hz].

    Raises
    ------
    AlignError
        Every channel has fewer than two samples, or all samples share one time, or the grid from
        first to last sample would exceed ``MAX_GRID`` samples.
    """
    chans = [c for c in chans if len(c.t)]
    if not chans:
        return
    t0 = min(float(c.t[0]) for c in chans)
    t1 = max(float(c.t[-1]) for c in chans)
    most = max(len(c.t) for c in chans)
    if most < 2 or not t1 > t0:
        raise AlignError(f"align: expected a log of at least two samples in time (a trial needs tens of seconds "
                         f"of motion), found {most} sample(s) per channel spanning {t1 - t0:.3g} s")
    if fs is not None and fs > 0 and (t1 - t0) * fs > MAX_GRID:
        raise AlignError(f"align: expected logs spanning at most {MAX_GRID / fs:.3g} s at {fs:g} Hz, found "
                         f"{t1 - t0:.6g} s from first to last sample (a corrupted time stamp, or logs of different "
                         f"days without a common clock)")


#: Shortest trial segment detection can work on [s]: a coast-down or step spans several seconds, a
#: pool roll decay of a 1 m model (AAUSHIP: 0.6 s period) two to three (the 2014 Vicon decays: 2-3 s).
MIN_SEGMENT_S = 2.0


def check_segmentable(trial) -> None:
    """Raise when a trial is too short for segment detection, naming its duration and the minimum.

    Parameters
    ----------
    trial : pipeline.records.Trial
        Aligned trial.

    Raises
    ------
    SegmentError
        The trial spans less than ``MIN_SEGMENT_S`` seconds.
    """
    from ..errors import SegmentError

    t = trial.t
    span = float(t[-1] - t[0]) if len(t) else 0.0
    if span < MIN_SEGMENT_S:
        raise SegmentError(f"segment: expected a trial of at least {MIN_SEGMENT_S:g} s (a decay, step or coast-down "
                           f"spans seconds), found {span:.3g} s ({len(t)} sample(s) at {trial.fs:.3g} Hz)")


def _rolling_median(x: np.ndarray, n: int) -> np.ndarray:
    return pd.Series(x).rolling(max(n, 1), center=True, min_periods=max(n // 4, 1)).median().to_numpy()


def plausibility_notes(frame: pd.DataFrame, fs: float) -> list[str]:
    """Run the four checks on an aligned frame.

    Parameters
    ----------
    frame : pandas.DataFrame
        Aligned channels on a uniform grid (column ``t`` [s]).
    fs : float
        Grid rate [Hz].

    Returns
    -------
    list of str
        ``plausibility: FAIL [channels]: why`` notes, then one ``plausibility: ok ...`` note
        naming the checks passed.
    """
    notes: list[str] = []
    failed: set[str] = set()
    checked: list[str] = []
    cols = [c for c in frame.columns if c != "t"]

    def finite(c: str) -> np.ndarray:
        v = frame[c].to_numpy(dtype=float)
        return v[np.isfinite(v)]

    # 2. Constant or zero channels.
    for c in cols:
        if _base(c) not in _IMU_BASES + _ATT_BASES:
            continue
        v = finite(c)
        if len(v) < MIN_SAMPLES:
            continue
        if float(np.ptp(v)) == 0.0:
            what = "all zero" if v[0] == 0 else f"constant at {v[0]:.6g}"
            notes.append(f"plausibility: FAIL [{c}]: {what} over {len(v)} samples (a sensor logged but not sampled)")
            failed.add(c)
    checked.append("constant channels")

    # 2b. Roll or pitch a floating vessel cannot hold (capsized, or the board mounted upside down).
    for c in cols:
        if _base(c) not in ("phi", "theta") or c in failed:
            continue
        v = finite(c)
        if len(v) < MIN_SAMPLES:
            continue
        typical = math.degrees(float(np.median(np.abs(v))))
        limit = MAX_ROLL_DEG if _base(c) == "phi" else MAX_PITCH_DEG
        if typical > limit:
            notes.append(f"plausibility: FAIL [{c}]: median |{c}| is {typical:.0f} deg, expected below {limit:.0f} deg "
                         f"for a floating vessel (upside-down mounting or a capsized log)")
            failed.add(c)
    checked.append("attitude range")

    # 1. Gravity on the wrong axis, per accelerometer (suffix group).
    good_acc: list[str] = []
    for sfx in sorted({_suffix(c) for c in cols if _base(c) == "az"}):
        names = [f"ax{sfx}", f"ay{sfx}", f"az{sfx}"]
        if not all(n in frame for n in names) or any(n in failed for n in names):
            continue
        med = [float(np.median(finite(n))) if len(finite(n)) else math.nan for n in names]
        if any(math.isnan(m) for m in med):
            continue
        norm = math.sqrt(sum(m * m for m in med))
        group = [f"{b}{sfx}" for b in _IMU_BASES if f"{b}{sfx}" in frame]
        if not 0.5 * G < norm < 1.5 * G:
            notes.append(f"plausibility: FAIL [{', '.join(group)}]: median specific force "
                         f"({med[0]:.2f}, {med[1]:.2f}, {med[2]:.2f}) m/s^2 has magnitude {norm:.2f}, expected about "
                         f"{G:.2f} (gravity): wrong units or not an accelerometer")
            failed.update(group)
        elif abs(med[0]) > 0.5 * G or abs(med[1]) > 0.5 * G or med[2] > -0.5 * G:
            axis = ["x", "y", "z"][int(np.argmax(np.abs(med)))]
            sign = "+" if med[int(np.argmax(np.abs(med)))] > 0 else "-"
            notes.append(f"plausibility: FAIL [{', '.join(group)}]: gravity on the {sign}{axis} axis (median specific "
                         f"force {med[0]:.2f}, {med[1]:.2f}, {med[2]:.2f} m/s^2), expected on -z (body z down): the "
                         f"IMU is mounted rotated relative to the body axes")
            failed.update(group)
        else:
            good_acc.append(sfx)
    checked.append("gravity axis")

    # 3. Attitude against the accelerometer's roll and pitch.
    if good_acc:
        sfx = "" if "" in good_acc else good_acc[0]
        f = [frame[f"{b}{sfx}"].to_numpy(dtype=float) for b in ("ax", "ay", "az")]
        win = max(int(10 * fs), 1)
        fx, fy, fz = (_rolling_median(x, win) for x in f)
        implied = {"phi": np.arctan2(-fy, -fz), "theta": np.arctan2(fx, np.hypot(fy, fz))}
        for ang, ref in implied.items():
            for c in [c for c in cols if _base(c) == ang and c not in failed]:
                y = _rolling_median(frame[c].to_numpy(dtype=float), win)
                d = np.abs(np.angle(np.exp(1j * (y - ref))))
                d = d[np.isfinite(d)]
                if len(d) < MIN_SAMPLES:
                    continue
                dev = math.degrees(float(np.median(d)))
                if dev > ATTITUDE_TOL_DEG:
                    notes.append(f"plausibility: FAIL [{c}]: {c} differs from the {ang} the accelerometer{sfx} "
                                 f"implies by {dev:.0f} deg (median over 10 s windows; tolerance "
                                 f"{ATTITUDE_TOL_DEG:.0f} deg): attitude contradicts the IMU")
                    failed.add(c)
        checked.append(f"attitude against accelerometer{sfx or ''}")

    # 4. Vessel at rest.
    speed = [c for c in cols if _base(c) in ("sog", "u") and c not in failed]
    motion = [c for c in cols if _base(c) in ("r", "phi", "theta") and c not in failed]
    if speed or motion:
        quiet = True
        why = []
        for c in speed:
            v = np.abs(finite(c))
            if len(v) < MIN_SAMPLES or np.quantile(v, 0.95) >= REST_SPEED:
                quiet = False
            else:
                why.append(f"{c} < {REST_SPEED:g} m/s")
        for c in motion:
            v = finite(c)
            if len(v) < MIN_SAMPLES:
                continue
            if _base(c) == "r":
                big = float(np.quantile(np.abs(v), 0.95)) >= math.radians(1.0)
                note = f"|{c}| < 1 deg/s"
            else:
                big = float(np.quantile(v, 0.99) - np.quantile(v, 0.01)) >= math.radians(2.0)
                note = f"{c} spans < 2 deg"
            if big:
                quiet = False
            else:
                why.append(note)
        inputs_move = any(_base(c) in ("delta", "tau_x", "tau_y", "tau_k", "tau_m", "tau_n")
                          and len(finite(c)) and float(np.ptp(finite(c))) > 0 for c in cols)
        if quiet and why and not inputs_move:
            everything = [c for c in cols]
            notes.append(f"plausibility: FAIL [{', '.join(everything)}]: vessel at rest ({'; '.join(why)}; no input "
                         f"change): nothing to identify, no segments")
            failed.update(everything)
        checked.append("vessel at rest")
    notes.append(f"plausibility: ok ({', '.join(checked)} checked; "
                 f"{len(failed)} channel(s) failed)" if failed else
                 f"plausibility: ok ({', '.join(checked)} checked; all channels pass)")
    return notes


def failed_channels(notes: Iterable[str]) -> set[str]:
    """Channels named by ``plausibility: FAIL [...]`` notes.

    Parameters
    ----------
    notes : iterable of str
        ``Trial.notes``.
    """
    out: set[str] = set()
    for n in notes:
        m = _FAIL_RE.match(n)
        if m:
            out.update(s.strip() for s in m.group(1).split(",") if s.strip())
    return out


def without_implausible(trial):
    """The trial with every channel that failed a plausibility check blanked (NaN), so no segment uses it.

    Parameters
    ----------
    trial : pipeline.records.Trial
        Aligned trial (not modified).

    Returns
    -------
    pipeline.records.Trial
        The same trial when nothing failed, else a copy with those columns NaN.
    """
    bad = [c for c in failed_channels(trial.notes) if c in trial.data.columns and c != "t"]
    if not bad:
        return trial
    data = trial.data.copy()
    data[bad] = np.nan
    return replace(trial, data=data)
