"""GPS antennas away from the body origin: lever-arm correction and moving-baseline heading.

A GNSS receiver measures its antenna, not the body origin the model is written about. With the
antenna at ``r_a`` in the body frame (x forward, y starboard, z down) and the attitude
``Theta = (phi, theta, psi)`` (Fossen 2021, eq. 2.18, ZYX), the origin is at
``p_o = p_a - R(Theta) r_a`` and moves with ``v_o = v_a - R(Theta) (omega x r_a)``, where
``omega = (p, q, r)``. On a yawing boat an antenna 0.5 m from the origin sees 0.5 r m/s of
sway that the hull does not have, which would show up as a wrong sway velocity and drift angle.

Two antennas on one boat give the heading without a compass: the horizontal baseline from the
first antenna to the second points along ``psi + yaw_b``, where ``yaw_b`` is the baseline's
mounting yaw in the body frame (``atan2`` of the body baseline after roll and pitch,
``c = R_y(theta) R_x(phi) (r_2 - r_1)``), so ``psi = atan2(dE, dN) - atan2(c_y, c_x)``. A
moving-base receiver pair does this itself (UBX NAV-RELPOSNED, read as ``psi@dual``); the same
mounting-yaw correction applies to its heading.

Vessel config schema (``[sensors]``, kept in ``Vessel.extra['sensors']`` by the config reader)
-------------------------------------------------------------------------------------------
::

    [sensors.gps]                    # an antenna; its channels are lat@gps lon@gps sog@gps cog@gps
    lever_arm = [0.5, 0.2, -0.3]     # m, body frame (x fwd, y stbd, z down) from the body origin
    [sensors.gps2]
    lever_arm = [-0.5, 0.2, -0.3]
    suffix = "@gps2"                 # optional channel suffix; default "@<name>", "" for lat lon sog cog
    [sensors.dual]                   # a baseline: heading psi@dual from two antennas' positions
    antennas = ["gps2", "gps"]       # from the first antenna to the second
    mounting_yaw = 0.0               # optional [rad]; default from the two lever arms

A table with ``lever_arm`` is an antenna, one with ``antennas`` a baseline; anything else, and any
unknown key, is a :class:`~pipeline.errors.ConfigError` naming what was expected.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
import pandas as pd

from ..errors import ConfigError
from ..geo import latlon_to_ned, ned_to_latlon, wrap_pi

_ANTENNA_KEYS = {"lever_arm", "suffix"}
_BASELINE_KEYS = {"antennas", "mounting_yaw"}
#: A measured baseline shorter than this fraction of the configured one makes no heading [-].
MIN_BASELINE_FRACTION = 0.5


@dataclass(frozen=True)
class Antenna:
    """A GNSS antenna on the hull.

    Attributes
    ----------
    name : str
        Sensor name (the ``[sensors.<name>]`` table).
    suffix : str
        Channel suffix of its ``lat lon sog cog`` (``@gps``, or ``""``).
    lever_arm : tuple[float, float, float]
        Position of the antenna phase centre in the body frame [m] (x fwd, y stbd, z down).
    """

    name: str
    suffix: str
    lever_arm: tuple[float, float, float]


@dataclass(frozen=True)
class Baseline:
    """Two antennas whose baseline gives the heading ``psi@<name>``.

    Attributes
    ----------
    name : str
        Baseline name; the heading channel is ``psi@<name>``.
    first, second : str
        Antenna names; the baseline points from the first to the second.
    mounting_yaw : float or None
        Yaw of the baseline in the body frame [rad]; None: from the lever arms (with roll and
        pitch when logged).
    """

    name: str
    first: str
    second: str
    mounting_yaw: float | None = None


@dataclass(frozen=True)
class SensorConfig:
    """The validated ``[sensors]`` table.

    Attributes
    ----------
    antennas : Mapping[str, Antenna]
        Antennas by name.
    baselines : tuple[Baseline, ...]
        Dual-antenna headings.
    """

    antennas: Mapping[str, Antenna]
    baselines: tuple[Baseline, ...] = ()


def _vector3(value: Any, where: str) -> tuple[float, float, float]:
    if (not isinstance(value, (list, tuple)) or len(value) != 3
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in value)):
        raise ConfigError(f"{where}: expected three finite numbers [x, y, z] in metres (body frame), found {value!r}")
    return (float(value[0]), float(value[1]), float(value[2]))


def parse_sensors(table: Mapping[str, Any] | None, where: str = "[sensors]") -> SensorConfig:
    """Validate a ``[sensors]`` table (schema in the module docstring).

    Parameters
    ----------
    table : Mapping[str, Any] or None
        The table as read from TOML; None or empty gives an empty config.
    where : str
        Name of the table for messages (the vessel config file).

    Returns
    -------
    SensorConfig

    Raises
    ------
    ConfigError
        A sensor that is not a table, unknown keys, a lever arm that is not three numbers, a
        suffix that is not ``""`` or ``@name``, a baseline naming antennas that are not defined
        (or the same one twice), or a non-numeric mounting yaw.
    """
    if not table:
        return SensorConfig({}, ())
    if not isinstance(table, Mapping):
        raise ConfigError(f"{where}: expected a table of sensors ([sensors.<name>]), found {table!r}")
    antennas: dict[str, Antenna] = {}
    raw_baselines: list[tuple[str, Mapping[str, Any]]] = []
    for name, body in table.items():
        here = f"{where}.{name}"
        if not isinstance(body, Mapping):
            raise ConfigError(f"{here}: expected a table with lever_arm (an antenna) or antennas (a baseline), "
                              f"found {body!r}")
        if "@" in name or not name:
            raise ConfigError(f"{here}: expected a sensor name without '@', found {name!r}")
        keys = set(body)
        if "antennas" in keys:
            unknown = keys - _BASELINE_KEYS
            if unknown:
                raise ConfigError(f"{here}: unknown key(s) {sorted(unknown)} in a baseline; allowed: "
                                  f"{sorted(_BASELINE_KEYS)}")
            raw_baselines.append((name, body))
            continue
        if "lever_arm" not in keys:
            raise ConfigError(f"{here}: expected lever_arm = [x, y, z] (an antenna) or antennas = [first, second] "
                              f"(a baseline), found keys {sorted(keys)}")
        unknown = keys - _ANTENNA_KEYS
        if unknown:
            raise ConfigError(f"{here}: unknown key(s) {sorted(unknown)} in an antenna; allowed: "
                              f"{sorted(_ANTENNA_KEYS)}")
        suffix = body.get("suffix", f"@{name}")
        if not isinstance(suffix, str) or not (suffix == "" or (suffix.startswith("@") and len(suffix) > 1)):
            raise ConfigError(f"{here}.suffix: expected \"\" (channels lat lon sog cog) or \"@<sensor>\", "
                              f"found {suffix!r}")
        antennas[name] = Antenna(name, suffix, _vector3(body["lever_arm"], f"{here}.lever_arm"))
    baselines = []
    for name, body in raw_baselines:
        here = f"{where}.{name}"
        pair = body["antennas"]
        if not (isinstance(pair, (list, tuple)) and len(pair) == 2 and all(isinstance(a, str) for a in pair)):
            raise ConfigError(f"{here}.antennas: expected two antenna names [first, second], found {pair!r}")
        missing = [a for a in pair if a not in antennas]
        if missing:
            raise ConfigError(f"{here}.antennas: expected antennas defined with a lever_arm in {where} "
                              f"({sorted(antennas) or 'none'}), found {missing}")
        if pair[0] == pair[1]:
            raise ConfigError(f"{here}.antennas: expected two different antennas, found {pair[0]!r} twice")
        yaw = body.get("mounting_yaw")
        if yaw is not None and (isinstance(yaw, bool) or not isinstance(yaw, (int, float)) or not math.isfinite(yaw)):
            raise ConfigError(f"{here}.mounting_yaw: expected a finite angle [rad], found {yaw!r}")
        a1, a2 = antennas[pair[0]].lever_arm, antennas[pair[1]].lever_arm
        if yaw is None and math.hypot(a2[0] - a1[0], a2[1] - a1[1]) < 1e-6:
            raise ConfigError(f"{here}: the lever arms of {pair[0]} and {pair[1]} have no horizontal separation; "
                              f"expected a baseline or an explicit mounting_yaw")
        baselines.append(Baseline(name, pair[0], pair[1], None if yaw is None else float(yaw)))
    return SensorConfig(antennas, tuple(baselines))


def sensor_config(vessel: Any) -> SensorConfig:
    """The validated ``[sensors]`` of a :class:`pipeline.vessel.Vessel` (empty when it has none).

    Parameters
    ----------
    vessel : pipeline.vessel.Vessel or None
        The vessel; its ``extra['sensors']`` holds the raw table.
    """
    if vessel is None:
        return SensorConfig({}, ())
    return parse_sensors(dict(getattr(vessel, "extra", {}) or {}).get("sensors"),
                         f"vessel {getattr(vessel, 'name', '?')!r} [sensors]")


# --------------------------------------------------------------------------- kinematics
def rotation_matrix(phi: np.ndarray, theta: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """Body-to-NED rotation ``R = R_z(psi) R_y(theta) R_x(phi)`` (Fossen 2021, eq. 2.18).

    Parameters
    ----------
    phi, theta, psi : numpy.ndarray
        Roll, pitch and yaw [rad], broadcastable to one shape ``S``.

    Returns
    -------
    numpy.ndarray
        Shape ``S + (3, 3)`` [-].
    """
    phi, theta, psi = np.broadcast_arrays(*(np.asarray(a, float) for a in (phi, theta, psi)))
    cf, sf, ct, st, cp, sp = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta), np.cos(psi), np.sin(psi)
    r = np.empty(phi.shape + (3, 3))
    r[..., 0, 0] = cp * ct
    r[..., 0, 1] = -sp * cf + cp * st * sf
    r[..., 0, 2] = sp * sf + cp * cf * st
    r[..., 1, 0] = sp * ct
    r[..., 1, 1] = cp * cf + sf * st * sp
    r[..., 1, 2] = -cp * sf + st * sp * cf
    r[..., 2, 0] = -st
    r[..., 2, 1] = ct * sf
    r[..., 2, 2] = ct * cf
    return r


def lever_arm_offsets(lever_arm, phi, theta, psi, p, q, r) -> tuple[np.ndarray, np.ndarray]:
    """Antenna position and velocity relative to the body origin, in NED.

    Parameters
    ----------
    lever_arm : array_like
        Antenna position in the body frame ``r_a`` [m], shape (3,).
    phi, theta, psi : numpy.ndarray
        Attitude [rad].
    p, q, r : numpy.ndarray
        Body angular rates [rad/s].

    Returns
    -------
    dp, dv : numpy.ndarray
        ``R(Theta) r_a`` [m] and ``R(Theta) (omega x r_a)`` [m/s], each shape ``S + (3,)``
        (north, east, down); ``p_a = p_o + dp`` and ``v_a = v_o + dv``.
    """
    ra = np.asarray(lever_arm, float)
    rot = rotation_matrix(phi, theta, psi)
    omega = np.stack(np.broadcast_arrays(*(np.asarray(a, float) for a in (p, q, r))), axis=-1)
    return rot @ ra, np.einsum("...ij,...j->...i", rot, np.cross(omega, ra))


# --------------------------------------------------------------------------- applied to a trial frame
def _col(frame: pd.DataFrame, base: str, notes_missing: list[str], default: float | None = 0.0) -> np.ndarray | None:
    for c in [base] + [c for c in frame.columns if c.split("@")[0] == base and c != base]:
        if c in frame and np.isfinite(frame[c].to_numpy()).any():
            return frame[c].to_numpy(float)
    if default is None:
        return None
    notes_missing.append(base)
    return np.full(len(frame), default)


def _heading_column(frame: pd.DataFrame, prefer: tuple[str, ...] = ()) -> str | None:
    for c in ("psi",) + prefer + tuple(c for c in frame.columns if c.split("@")[0] == "psi"):
        if c in frame and np.isfinite(frame[c].to_numpy()).any():
            return c
    return None


def dual_antenna_heading(frame: pd.DataFrame, cfg: SensorConfig, baseline: Baseline) -> tuple[np.ndarray, str]:
    """Heading ``psi`` [rad] from the positions of a baseline's two antennas on the trial grid.

    Parameters
    ----------
    frame : pandas.DataFrame
        Resampled channels with ``lat<s1> lon<s1> lat<s2> lon<s2>`` [deg] of both antennas.
    cfg : SensorConfig
        The antennas' lever arms.
    baseline : Baseline
        Which antennas, and the mounting yaw when configured.

    Returns
    -------
    psi, note : numpy.ndarray, str
        Heading [rad, (-pi, pi]] (NaN where either position is missing or the measured baseline
        is shorter than ``MIN_BASELINE_FRACTION`` of the configured one), and what was done.
    """
    a1, a2 = cfg.antennas[baseline.first], cfg.antennas[baseline.second]
    lat1, lon1 = frame[f"lat{a1.suffix}"].to_numpy(float), frame[f"lon{a1.suffix}"].to_numpy(float)
    lat2, lon2 = frame[f"lat{a2.suffix}"].to_numpy(float), frame[f"lon{a2.suffix}"].to_numpy(float)
    d_n, d_e = latlon_to_ned(lat2, lon2, lat1, lon1)
    b = np.subtract(a2.lever_arm, a1.lever_arm)
    missing: list[str] = []
    if baseline.mounting_yaw is not None:
        yaw_b = np.full(len(frame), baseline.mounting_yaw)
        how = f"mounting yaw {baseline.mounting_yaw:+.4f} rad (configured)"
    else:
        phi = _col(frame, "phi", missing)
        theta = _col(frame, "theta", missing)
        # c = R_y(theta) R_x(phi) b: the baseline levelled but not yet turned by psi.
        c = rotation_matrix(phi, theta, np.zeros(len(frame))) @ b
        yaw_b = np.arctan2(c[:, 1], c[:, 0])
        how = (f"mounting yaw {math.atan2(b[1], b[0]):+.4f} rad from the lever arms"
               + (" with roll and pitch" if not missing else f" (no {', '.join(missing)}: taken as level)"))
    horiz = float(math.hypot(b[0], b[1]))
    length = np.hypot(d_n, d_e)
    psi = wrap_pi(np.arctan2(d_e, d_n) - yaw_b)
    short = length < MIN_BASELINE_FRACTION * horiz
    psi[short | ~np.isfinite(length)] = np.nan
    ok = np.isfinite(length)
    err = float(np.sqrt(np.nanmean((length[ok] - horiz) ** 2))) if ok.any() else math.nan
    note = (f"psi@{baseline.name} from the baseline {baseline.first} -> {baseline.second} "
            f"({horiz:.3f} m horizontal), {how}; measured length RMS error {err:.3f} m"
            + (f"; {int((short & ok).sum())} sample(s) shorter than {MIN_BASELINE_FRACTION:g} of it not used"
               if (short & ok).any() else ""))
    return psi, note


def correct_antenna(frame: pd.DataFrame, antenna: Antenna, heading: str) -> tuple[pd.DataFrame, str]:
    """Move one antenna's ``lat lon sog cog`` to the body origin (lever-arm correction).

    Parameters
    ----------
    frame : pandas.DataFrame
        Resampled channels on the trial grid; the antenna's channels and heading ``heading``;
        ``phi theta`` and ``p q r`` when present (else taken as 0; ``r`` from the heading rate).
    antenna : Antenna
        Its channel suffix and lever arm.
    heading : str
        Column of the heading to rotate the lever arm with.

    Returns
    -------
    frame, note : pandas.DataFrame, str
        A new frame with the antenna's channels replaced, and what was done.
    """
    out = frame.copy()
    n = len(out)
    missing: list[str] = []
    psi = out[heading].to_numpy(float)
    phi = _col(out, "phi", missing)
    theta = _col(out, "theta", missing)
    p = _col(out, "p", missing)
    q = _col(out, "q", missing)
    r = _col(out, "r", [], default=None)
    if r is None:
        t = out["t"].to_numpy(float)
        r = np.gradient(np.unwrap(np.nan_to_num(psi)), t) if n > 1 else np.zeros(n)
        missing.append(f"r (from d{heading}/dt)")
    dp, dv = lever_arm_offsets(antenna.lever_arm, phi, theta, psi, p, q, r)
    sfx = antenna.suffix
    done = []
    if f"lat{sfx}" in out and f"lon{sfx}" in out:
        lat, lon = out[f"lat{sfx}"].to_numpy(float), out[f"lon{sfx}"].to_numpy(float)
        # p_o = p_a - R r_a, as north/east metres about the antenna's own position.
        out[f"lat{sfx}"], out[f"lon{sfx}"] = ned_to_latlon(-dp[:, 0], -dp[:, 1], lat, lon)
        done.append("position")
    if f"sog{sfx}" in out and f"cog{sfx}" in out:
        sog, cog = out[f"sog{sfx}"].to_numpy(float), out[f"cog{sfx}"].to_numpy(float)
        v_n = sog * np.cos(cog) - dv[:, 0]
        v_e = sog * np.sin(cog) - dv[:, 1]
        out[f"sog{sfx}"] = np.hypot(v_n, v_e)
        out[f"cog{sfx}"] = wrap_pi(np.arctan2(v_e, v_n))
        done.append("velocity (v_o = v_a - R (omega x r_a))")
    arm = ", ".join(f"{x:g}" for x in antenna.lever_arm)
    note = (f"{antenna.name} ({'lat lon sog cog' if not sfx else f'*{sfx}'}): {' and '.join(done) or 'nothing'} "
            f"moved from the antenna at [{arm}] m to the body origin using {heading}"
            + (f"; not logged, taken as 0: {', '.join(missing)}" if missing else ""))
    return out, note


def apply_sensors(frame: pd.DataFrame, vessel: Any) -> tuple[pd.DataFrame, list[str]]:
    """Dual-antenna headings, then lever-arm corrections, from the vessel's ``[sensors]``.

    Parameters
    ----------
    frame : pandas.DataFrame
        Resampled channels on the trial grid (column ``t`` [s]).
    vessel : pipeline.vessel.Vessel or None
        Its ``[sensors]`` table (see the module docstring); None or no table changes nothing.

    Returns
    -------
    frame, notes : pandas.DataFrame, list[str]
        A new frame (``psi@<baseline>`` added or its mounting yaw removed; antenna channels at the
        body origin) and one note per step, including steps skipped for lack of channels.

    Raises
    ------
    ConfigError
        A malformed ``[sensors]`` table.
    """
    cfg = sensor_config(vessel)
    notes: list[str] = []
    if not cfg.antennas and not cfg.baselines:
        return frame, notes
    out = frame
    # Headings first, from the raw antenna positions: the lever-arm correction needs a heading.
    for bl in cfg.baselines:
        name = f"psi@{bl.name}"
        if name in out and np.isfinite(out[name].to_numpy()).any():
            # A receiver's own moving-base heading (NAV-RELPOSNED) is the baseline's direction.
            b = np.subtract(cfg.antennas[bl.second].lever_arm, cfg.antennas[bl.first].lever_arm)
            yaw = bl.mounting_yaw if bl.mounting_yaw is not None else math.atan2(b[1], b[0])
            if yaw:
                out = out.copy()
                out[name] = wrap_pi(out[name].to_numpy(float) - yaw)
            notes.append(f"{name} logged by the receiver: mounting yaw {yaw:+.4f} rad removed")
            continue
        need = [f"{k}{cfg.antennas[a].suffix}" for a in (bl.first, bl.second) for k in ("lat", "lon")]
        absent = [c for c in need if c not in out or not np.isfinite(out[c].to_numpy()).any()]
        if absent:
            notes.append(f"{name} not formed: baseline {bl.first} -> {bl.second} needs {need}, found no {absent}")
            continue
        psi, note = dual_antenna_heading(out, cfg, bl)
        out = out.copy()
        out[name] = psi
        notes.append(note)
    heading = _heading_column(out, tuple(f"psi@{b.name}" for b in cfg.baselines))
    for ant in cfg.antennas.values():
        chans = [f"{k}{ant.suffix}" for k in ("lat", "lon", "sog", "cog") if f"{k}{ant.suffix}" in out]
        if not chans:
            notes.append(f"{ant.name}: lever arm configured but no lat{ant.suffix}/sog{ant.suffix} channels; "
                         "nothing to correct")
            continue
        if heading is None:
            notes.append(f"{ant.name}: not corrected for its lever arm: expected a heading (psi or a "
                         f"dual-antenna psi@...), found none")
            continue
        out, note = correct_antenna(out, ant, heading)
        notes.append(note)
    return out, notes


__all__ = ["Antenna", "Baseline", "SensorConfig", "parse_sensors", "sensor_config", "rotation_matrix",
           "lever_arm_offsets", "dual_antenna_heading", "correct_antenna", "apply_sensors"]
