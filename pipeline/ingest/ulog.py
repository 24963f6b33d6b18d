"""PX4 ULog files (``.ulg``), as the PX4 autopilot logs them (boats and rovers run PX4 too).

The file is parsed by pyulog (``pyulog.ULog``), the PX4 project's own reader. A ULog holds
topics (uORB messages), each possibly in several instances (``multi_id``), every sample with a
``timestamp`` [us since boot]; plus parameters, logged text messages and "dropouts" (gaps where
the logger could not keep up).

Mapping (``VARIABLE_MAP``; SI units, radians; PX4's body frame is FRD and its world frame NED,
the same as Fossen's, so no frame change is needed)
-------------------------------------------------------------------------------------------
vehicle_attitude            q[0..3] (w, x, y, z; body FRD -> NED)  -> phi, theta, psi [rad] (ZYX Euler)
vehicle_angular_velocity    xyz[0..2] [rad/s]                        -> p, q, r
sensor_combined             gyro_rad[0..2] [rad/s]                   -> p, q, r (only when the log has no
                                                                        vehicle_angular_velocity)
                            accelerometer_m_s2[0..2] [m/s^2]         -> ax, ay, az (specific force)
vehicle_gps_position / sensor_gps   lat, lon [1e-7 deg] or latitude_deg, longitude_deg [deg]
                                                                     -> lat, lon; vel_m_s -> sog;
                                    cog_rad -> cog (samples with fix_type < 2 dropped)
vehicle_local_position      x, y [m] -> x_n, y_e (when xy_valid); vx, vy [m/s] -> sog@ekf, cog@ekf
                            (when v_xy_valid)
actuator_outputs            output[0..15] [us]   -> inputs through the vessel's ``[[actuators]]``
                            (source servo, channel k = output[k-1])
actuator_motors             control[0..11] [-1, 1] -> inputs through ``[[actuators]]`` with source motor
                            (channel k = control[k-1]; NaN = motor off, not read)
actuator_servos             control[0..7] [-1, 1]  -> inputs through ``[[actuators]]`` with source
                            servo_control (channel k = control[k-1]; NaN = not driven, not read)

Instance ``multi_id`` 0 gives the plain names; instance k >= 1 gives ``name@<topic-short>k``
(``p@imu1`` style: ``lat@gps1``, ``p@rate1``); when a log has both ``vehicle_gps_position``
(PX4's selected or blended receiver) and ``sensor_gps`` (each receiver), the latter are
``lat@sensor_gps<k>``. Topics not in the map (battery, estimator internals, ...; and the
actuator topics when the vessel maps none of their channels) are counted per topic
in ``summary.skipped``; every sample of a used topic is either read or counted as skipped with
the reason (no fix, invalid flag, repeated or out-of-order timestamp).

Time: ``time_reference='boot'``; ``t`` [s] = timestamp * 1e-6. ``RawLog.start_time`` [s, Unix]
is the UTC of boot: the median over GPS samples with ``time_utc_usec > 0`` of
(time_utc_usec - timestamp); NaN without. Parameters (count and the changed ones), logged
messages of level warning or worse, and dropouts are in ``summary.warnings``.
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path
from typing import Mapping

import numpy as np

from ..errors import IngestError
from ..geo import wrap_pi
from ..records import Channel, IngestSummary, RawLog
from ..vessel import ActuatorMap, Vessel
from ._common import check_file, describe_failure

#: (topic, field) -> (canonical channel, scale to SI). Euler angles come from the quaternion.
VARIABLE_MAP: dict[tuple[str, str], tuple[str, float]] = {
    ("vehicle_attitude", "q"): ("phi theta psi", 1.0),
    ("vehicle_angular_velocity", "xyz[0]"): ("p", 1.0),
    ("vehicle_angular_velocity", "xyz[1]"): ("q", 1.0),
    ("vehicle_angular_velocity", "xyz[2]"): ("r", 1.0),
    ("sensor_combined", "gyro_rad[0]"): ("p", 1.0),
    ("sensor_combined", "gyro_rad[1]"): ("q", 1.0),
    ("sensor_combined", "gyro_rad[2]"): ("r", 1.0),
    ("sensor_combined", "accelerometer_m_s2[0]"): ("ax", 1.0),
    ("sensor_combined", "accelerometer_m_s2[1]"): ("ay", 1.0),
    ("sensor_combined", "accelerometer_m_s2[2]"): ("az", 1.0),
    ("vehicle_gps_position", "lat"): ("lat", 1e-7),
    ("vehicle_gps_position", "lon"): ("lon", 1e-7),
    ("vehicle_gps_position", "vel_m_s"): ("sog", 1.0),
    ("vehicle_gps_position", "cog_rad"): ("cog", 1.0),
    ("vehicle_local_position", "x"): ("x_n", 1.0),
    ("vehicle_local_position", "y"): ("y_e", 1.0),
    ("vehicle_local_position", "vx vy"): ("sog@ekf cog@ekf", 1.0),
}
_GPS_TOPICS = ("vehicle_gps_position", "sensor_gps")
#: Actuator topic -> (``[[actuators]]`` source that maps it, field of channel k (k from 0), what a sample
#: must satisfy to be a command: a PWM above 0 us, or a finite normalised value).
ACTUATOR_TOPICS = {"actuator_outputs": ("servo", "output[{}]", "pwm > 0"),
                   "actuator_motors": ("motor", "control[{}]", "finite"),
                   "actuator_servos": ("servo_control", "control[{}]", "finite")}
_USED = ("vehicle_attitude", "vehicle_angular_velocity", "sensor_combined", *_GPS_TOPICS, "vehicle_local_position",
         *ACTUATOR_TOPICS)
_SHORT = {"vehicle_attitude": "att", "vehicle_angular_velocity": "rate", "sensor_combined": "imu",
          "vehicle_gps_position": "gps", "sensor_gps": "gps", "vehicle_local_position": "ekf"}




def quaternion_to_euler(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ZYX Euler angles of unit quaternions (Fossen 2021, eq. 2.86 inverted).

    Parameters
    ----------
    q : numpy.ndarray
        Shape (n, 4): w, x, y, z of the rotation body -> NED.

    Returns
    -------
    (phi, theta, psi) : numpy.ndarray
        Roll, pitch, yaw [rad]; psi in (-pi, pi].
    """
    q = np.asarray(q, float)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    q = q / np.where(norm > 0, norm, 1.0)
    w, x, y, z = q.T
    phi = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    theta = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    psi = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return phi, theta, wrap_pi(psi)


def _strict(t: np.ndarray) -> np.ndarray:
    """Mask of samples whose time is above every earlier one."""
    ok = np.ones(len(t), bool)
    if len(t) > 1:
        ok[1:] = t[1:] > np.maximum.accumulate(t)[:-1]
    return ok


def _actuator_inputs(topic: str, data: Mapping[str, np.ndarray], keep: np.ndarray, maps: tuple[ActuatorMap, ...],
                     warnings: list[str]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Target input -> (values [SI], samples that are commands) of one actuator topic through ``maps``.

    Several channels on one target (twin thrusters) add up to the generalised force; a sample
    counts only when every channel on its target holds a command.
    """
    source, pattern, rule = ACTUATOR_TOPICS[topic]
    sums: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for a in maps:
        field_name = pattern.format(a.channel - 1)
        if field_name not in data:
            warnings.append(f"actuator map {source} channel {a.channel} ({a.target}): {topic} has no "
                            f"{field_name}; not read")
            continue
        raw = data[field_name].astype(float)
        ok = keep & ((raw > 0) if rule == "pwm > 0" else np.isfinite(raw))
        value = a.to_input(np.where(ok, raw, 0.0))
        if a.target in sums:
            sums[a.target] = (sums[a.target][0] + value, sums[a.target][1] & ok)
        else:
            sums[a.target] = (value, ok)
    return sums


class _Topics:
    """What :func:`read_ulog` accumulates over the topics: counts, notes, channels, inputs, GPS clock offsets."""

    def __init__(self, names: set[str], actuators: tuple[ActuatorMap, ...]) -> None:
        self.read: Counter = Counter()
        self.skipped: Counter = Counter()
        self.warnings: list[str] = []
        self.chans: dict[str, Channel] = {}
        self.inputs: dict[str, tuple[np.ndarray, np.ndarray, str]] = {}
        self.gps_offsets: list[np.ndarray] = []
        self.has_rates = "vehicle_angular_velocity" in names
        self.has_vgps = "vehicle_gps_position" in names
        self.actuators = actuators

    def name_of(self, base: str, topic: str, inst: int) -> str:
        """Channel name of ``base`` from instance ``inst`` of ``topic`` (``p``, ``p@imu1``, ``lat@sensor_gps0``)."""
        if topic == "sensor_gps" and self.has_vgps:
            # The receiver itself, next to PX4's selected/blended vehicle_gps_position.
            return f"{base}@sensor_gps{inst}"
        if inst == 0:
            return base
        if "@" in base:
            return f"{base}{inst}"
        return f"{base}@{_SHORT.get(topic, topic)}{inst}"

    def add(self, base: str, topic: str, inst: int, t: np.ndarray, v: np.ndarray, src: str) -> None:
        """A channel from finite samples ``v`` at ``t`` [s]."""
        ok = np.isfinite(v)
        name = self.name_of(base, topic, inst)
        self.chans[name] = Channel(name, t[ok], np.asarray(v[ok], float), source=f"ulog:{src}")

    def take(self, topic: str, inst: int, data: Mapping[str, np.ndarray]) -> None:
        """Read one topic instance, counting every sample as read or skipped with its reason."""
        n = len(data["timestamp"])
        handler = _HANDLERS.get(topic)
        if handler is None or (topic == "sensor_combined" and self.has_rates and "accelerometer_m_s2[0]" not in data):
            self.skipped[topic] += n
            return
        t_us = data["timestamp"].astype(np.int64)
        keep = _strict(t_us) & (t_us > 0)
        if (~keep).any():
            self.skipped[f"{topic} repeated, out-of-order or zero timestamp"] += int((~keep).sum())
        used = handler(self, topic, inst, data, t_us, keep)
        if used is None:   # the handler counted the topic as skipped
            return
        self.read[topic] += int(used.sum())
        left = keep & ~used
        if left.any() and topic not in _GPS_TOPICS and topic != "vehicle_local_position":
            self.skipped[f"{topic} unusable"] += int(left.sum())


# ----------------------------------------------------------------------------- one handler per topic
# Each takes (reader, topic, instance, data, timestamps [us], samples with a good timestamp) and
# returns the samples it used, or None when it counted the whole topic as skipped.

def _attitude(r: _Topics, topic: str, inst: int, data, t_us: np.ndarray, keep: np.ndarray) -> np.ndarray | None:
    """vehicle_attitude: the quaternion -> phi, theta, psi."""
    if "q[0]" not in data:
        r.skipped[topic] += len(t_us)
        return None
    t = t_us * 1e-6
    q = np.column_stack([data[f"q[{i}]"] for i in range(4)])
    good = keep & (np.linalg.norm(q, axis=1) > 0.5)
    phi, theta, psi = quaternion_to_euler(q[good])
    for base, v in (("phi", phi), ("theta", theta), ("psi", psi)):
        r.add(base, topic, inst, t[good], v, f"{topic}.q")
    return good


def _rates(r: _Topics, topic: str, inst: int, data, t_us: np.ndarray, keep: np.ndarray) -> np.ndarray | None:
    """vehicle_angular_velocity: xyz -> p, q, r."""
    if "xyz[0]" not in data:
        r.skipped[topic] += len(t_us)
        return None
    t = t_us * 1e-6
    for i, base in enumerate(("p", "q", "r")):
        r.add(base, topic, inst, t[keep], data[f"xyz[{i}]"][keep], f"{topic}.xyz[{i}]")
    return keep.copy()


def _imu(r: _Topics, topic: str, inst: int, data, t_us: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """sensor_combined: gyro (when the log has no vehicle_angular_velocity) and accelerometer."""
    t = t_us * 1e-6
    used = np.zeros(len(t_us), bool)
    if not r.has_rates and "gyro_rad[0]" in data:
        for i, base in enumerate(("p", "q", "r")):
            r.add(base, topic, inst, t[keep], data[f"gyro_rad[{i}]"][keep], f"{topic}.gyro_rad[{i}]")
        used |= keep
    if "accelerometer_m_s2[0]" in data:
        for i, base in enumerate(("ax", "ay", "az")):
            field_name = f"accelerometer_m_s2[{i}]"
            r.add(base, topic, inst, t[keep], data[field_name][keep], f"{topic}.{field_name}")
        used |= keep
    return used


def _gps(r: _Topics, topic: str, inst: int, data, t_us: np.ndarray, keep: np.ndarray) -> np.ndarray | None:
    """vehicle_gps_position / sensor_gps: position, speed and course with a fix; UTC for the boot clock."""
    n = len(t_us)
    if "latitude_deg" in data:
        lat, lon = data["latitude_deg"].astype(float), data["longitude_deg"].astype(float)
    elif "lat" in data:
        lat, lon = data["lat"] * 1e-7, data["lon"] * 1e-7
    else:
        r.skipped[topic] += n
        return None
    t = t_us * 1e-6
    fix = data["fix_type"] if "fix_type" in data else np.full(n, 3)
    good = keep & (fix >= 2) & (np.abs(lat) <= 90) & (np.abs(lon) <= 180) & ((lat != 0) | (lon != 0))
    if (keep & ~good).any():
        r.skipped[f"{topic} no fix"] += int((keep & ~good).sum())
    r.add("lat", topic, inst, t[good], lat[good], f"{topic}.lat")
    r.add("lon", topic, inst, t[good], lon[good], f"{topic}.lon")
    if "vel_m_s" in data:
        r.add("sog", topic, inst, t[good], data["vel_m_s"][good], f"{topic}.vel_m_s")
    if "cog_rad" in data:
        r.add("cog", topic, inst, t[good], wrap_pi(data["cog_rad"][good]), f"{topic}.cog_rad")
    if "time_utc_usec" in data:
        utc = data["time_utc_usec"].astype(np.int64)
        ok = good & (utc > 0)
        if ok.any():
            r.gps_offsets.append((utc[ok] - t_us[ok]) * 1e-6)
    return good


def _local_position(r: _Topics, topic: str, inst: int, data, t_us: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """vehicle_local_position: x, y (when xy_valid); speed and course from vx, vy (when v_xy_valid)."""
    t = t_us * 1e-6
    xy_ok = keep & (data["xy_valid"].astype(bool) if "xy_valid" in data else True)
    v_ok = keep & (data["v_xy_valid"].astype(bool) if "v_xy_valid" in data else True)
    if xy_ok.any():
        r.add("x_n", topic, inst, t[xy_ok], data["x"][xy_ok], f"{topic}.x")
        r.add("y_e", topic, inst, t[xy_ok], data["y"][xy_ok], f"{topic}.y")
    if v_ok.any():
        vx, vy = data["vx"][v_ok].astype(float), data["vy"][v_ok].astype(float)
        r.add("sog@ekf", topic, inst, t[v_ok], np.hypot(vx, vy), f"{topic}.vx,vy")
        r.add("cog@ekf", topic, inst, t[v_ok], wrap_pi(np.arctan2(vy, vx)), f"{topic}.vx,vy")
    if (keep & ~(xy_ok | v_ok)).any():
        r.skipped[f"{topic} invalid (xy_valid and v_xy_valid false)"] += int((keep & ~(xy_ok | v_ok)).sum())
    return xy_ok | v_ok


def _actuators(r: _Topics, topic: str, inst: int, data, t_us: np.ndarray, keep: np.ndarray) -> np.ndarray | None:
    """actuator_outputs / actuator_motors / actuator_servos through the vessel's ``[[actuators]]``."""
    source = ACTUATOR_TOPICS[topic][0]
    maps = tuple(a for a in r.actuators if a.source == source)
    if not maps:
        r.skipped[f"{topic} (no actuator map with source '{source}')"] += int(keep.sum())
        return None
    t = t_us * 1e-6
    used = np.zeros(len(t_us), bool)
    for target, (value, ok) in _actuator_inputs(topic, data, keep, maps, r.warnings).items():
        r.inputs[r.name_of(target, topic, inst)] = (t[ok], value[ok], topic)
        used |= ok
    return used


_HANDLERS = {"vehicle_attitude": _attitude, "vehicle_angular_velocity": _rates, "sensor_combined": _imu,
             "vehicle_gps_position": _gps, "sensor_gps": _gps, "vehicle_local_position": _local_position,
             **{topic: _actuators for topic in ACTUATOR_TOPICS}}


def _open_ulog(p: Path):
    """pyulog's ``ULog`` of a file whose header is checked first; IngestError on anything else."""
    with open(p, "rb") as fh:
        head = fh.read(16)
    if not head.startswith(b"ULog\x01\x12\x35"):
        raise IngestError(f"{p}: expected a PX4 ULog (magic 'ULog' 01 12 35), found {head[:8]!r}")
    if len(head) < 16:
        raise IngestError(f"{p}: expected a PX4 ULog header of 16 bytes, found {len(head)} (truncated)")
    from pyulog import ULog

    try:
        return ULog(str(p))
    except Exception as exc:  # pyulog raises bare exceptions of many kinds on a corrupt file
        raise IngestError(f"{p}: expected a readable PX4 ULog, found a file pyulog cannot parse "
                          f"({describe_failure(exc)})") from None


def _log_notes(ulog, gps_offsets: list[np.ndarray], warnings: list[str]) -> float:
    """Boot time [s, Unix] from the GPS samples with UTC (NaN without); parameters, messages, dropouts noted."""
    start_time = math.nan
    if gps_offsets:
        off = np.concatenate(gps_offsets)
        start_time = float(np.median(off))
        warnings.append(f"boot time from {len(off)} GPS sample(s) with UTC: t = 0 at Unix {start_time:.3f} s")
    params = ulog.initial_parameters
    changed = getattr(ulog, "changed_parameters", [])
    warnings.append(f"parameters: {len(params)} logged at start, {len(changed)} change(s) during the log")
    n_bad_msgs = sum(1 for m in ulog.logged_messages if int(getattr(m, "log_level", 7)) <= 4)
    if n_bad_msgs:
        warnings.append(f"{n_bad_msgs} logged message(s) of level warning or worse")
    if ulog.dropouts:
        total_ms = sum(int(d.duration) for d in ulog.dropouts)
        warnings.append(f"logger dropouts: {len(ulog.dropouts)} totalling {total_ms} ms (samples lost there)")
    if getattr(ulog, "file_corruption", False):
        warnings.append("pyulog reports file corruption: the parts it could not parse are not read")
    return start_time


def read_ulog(path: str | Path, vessel: Vessel | None = None) -> RawLog:
    """Read a PX4 ULog into canonical channels on the autopilot's boot clock.

    Parameters
    ----------
    path : str or Path
        The ``.ulg`` file (opened read-only).
    vessel : Vessel, optional
        Its ``[[actuators]]`` map actuator channels to inputs: source ``servo`` reads
        ``actuator_outputs`` (PWM), ``motor`` reads ``actuator_motors`` and ``servo_control`` reads
        ``actuator_servos`` (both normalised to [-1, 1]).

    Returns
    -------
    RawLog
        ``format='ulog'``, ``time_reference='boot'``; channels as in ``VARIABLE_MAP``.

    Raises
    ------
    IngestError
        Missing, empty, truncated-header or unreadable file; no topic that gives a channel.
    """
    p = check_file(path, "PX4 ULog")
    ulog = _open_ulog(p)
    topics = {(d.name, d.multi_id): d for d in ulog.data_list}
    r = _Topics({name for name, _ in topics}, vessel.actuators if vessel is not None else ())
    for (topic, inst), d in sorted(topics.items()):
        r.take(topic, inst, d.data)
    for key, (t_in, v_in, topic) in r.inputs.items():
        r.chans[key] = Channel(key, t_in, v_in, source=f"ulog:{topic}")
    start_time = _log_notes(ulog, r.gps_offsets, r.warnings)
    chans = {k: c for k, c in r.chans.items() if len(c.t)}
    if not chans:
        found = ", ".join(f"{k} {v}" for k, v in sorted((r.read + r.skipped).items())) or "no topics"
        raise IngestError(f"{p}: expected ULog topics that give channels ({', '.join(_USED)}), found none "
                          f"usable ({found})")
    summary = IngestSummary(path=str(p), format="ulog", read={k: v for k, v in r.read.items() if v},
                            skipped={k: v for k, v in r.skipped.items() if v}, warnings=tuple(r.warnings))
    return RawLog(source=str(p), format="ulog", channels=chans, summary=summary, time_reference="boot",
                  start_time=start_time)
