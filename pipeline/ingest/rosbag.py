"""ROS 1 bags (``.bag``) and ROS 2 bags (a directory with ``metadata.yaml``, or a bare ``.db3`` or
``.mcap`` storage file), read with ``rosbags.highlevel.AnyReader``.

Message types are taken from the definitions stored in the bag (ROS 1 connection headers, ROS 2
metadata / storage schemas), so a custom type such as ``vesselid_msgs/msg/Actuators`` is read
without being known here; a bag without definitions falls back to the ROS 2 Humble or ROS 1
Noetic standard types.

Topics and roles
----------------
Each topic has a *role* that says how its messages become channels: ``imu``, ``navsatfix``,
``twist``, ``odometry``, ``rudder``, ``actuators``, ``float64:<channel>`` or ``ignore``, with an
optional ``@sensor`` suffix for the channel names (``navsatfix@gps`` gives ``lat@gps``,
``lon@gps``). The roles come from a topic map (topic -> role; the vessel config's ``[topics]``
table or a manifest), and for topics the map does not name, from the message type:

- ``sensor_msgs/msg/Imu`` -> imu; ``sensor_msgs/msg/NavSatFix`` -> navsatfix;
  ``geometry_msgs/msg/TwistStamped`` or ``TwistWithCovarianceStamped`` -> twist;
  ``nav_msgs/msg/Odometry`` -> odometry;
- a message with a ``data`` number (``std_msgs/msg/Float64``, ...) -> ``rudder`` when the topic name
  contains ``rudder``, ``float64:<name>`` when a component of the topic name is a canonical channel
  (``/vesselid/tau_k``, ``/vesselid/tau_k/port`` -> ``tau_k@port``);
- a message with a header and float fields named like canonical inputs (``tau_x``, ``delta``, ...)
  -> actuators.

When several inferred topics share a role, the one with the most messages gets the plain channel
names and the others ``@<first component of the topic name>`` (``/gps/fix`` -> ``lat@gps``). When
two topics give the same channel (IMU and odometry attitude, actuator and rudder-feedback
``delta``), the topic of the more specific role keeps the name (imu, navsatfix, twist, actuators,
odometry, rudder, float64, in that order) and the other gets ``@<its first name component>``.
Every inference and rename is reported in the summary warnings.

Frames (REP-103/105 -> Fossen)
------------------------------
ROS uses ENU world and FLU body (x forward, y left, z up); the pipeline uses NED and FRD:
positions and world velocities ``n = y_enu, e = x_enu, d = -z_enu``; body vectors ``x = x_flu,
y = -y_flu, z = -z_flu`` (so ``p = wx, q = -wy, r = -wz``); attitude
``q_ned_frd = q_ned_enu * q_enu_flu * q_flu_frd`` and Fossen's ZYX angles from it (so
``psi_ned = pi/2 - yaw_enu``, ``phi = roll_flu``, ``theta = -pitch_flu``). A twist whose
``frame_id`` is a body frame (``base_link``, ``base_footprint``, ``body``) is a body velocity
(u, v, w, p, q, r); any other frame (``gps``, ``odom``, ``map``, ``enu``...) is an ENU ground
velocity, giving ``sog`` and ``cog``. Inputs in the actuator message are in the pipeline's own
convention (Fossen body frame; ``delta`` positive gives a positive yaw rate), because that message
is ours, not a ROS standard; ``/rudder/angle`` (Float64) likewise. An input topic is a command
(held until the next message) unless its name says it is the actuator's measured state
(``feedback``, ``state``, ``actual``, ``measured``, ``sensor``, ``encoder`` as a word of the name:
``/rudder/feedback``); then it is interpolated, and the summary says so.

Time
----
Dynamics use the header stamps; the bag's receive time is only a fallback, for messages without
a header (Float64), and for a topic whose stamps are all zero or on another clock than the
other topics (median stamp - receive time more than ``CLOCK_MISMATCH_S`` away from theirs); each
fallback is counted in a warning. Repeated or out-of-order stamps are dropped and counted per
topic. ``t`` is seconds from the earliest stamp; ``time_reference`` is ``unix`` for wall-clock
stamps and ``trial`` for stamps from a clock that starts near zero (simulation time); the UTC of
``t = 0`` is in the summary and, for wall-clock stamps, in ``RawLog.start_time`` [s, Unix].
"""

from __future__ import annotations

import math
import re
from collections import Counter, defaultdict
from dataclasses import dataclass
from datetime import datetime, timezone
from operator import attrgetter
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from ..errors import IngestError
from ..records import ANGLE_CHANNELS, CHANNEL_UNITS, INPUT_UNITS, Channel, IngestSummary, RawLog
from ..terminal import want_progress
from ._common import describe_failure, increasing

#: Roles a topic can have (besides ``float64:<channel>``).
ROLES = ("imu", "navsatfix", "twist", "odometry", "rudder", "actuators", "ignore")
#: Message type -> role, for topics the topic map does not name.
TYPE_ROLES: Mapping[str, str] = {
    "sensor_msgs/msg/Imu": "imu",
    "sensor_msgs/msg/NavSatFix": "navsatfix",
    "geometry_msgs/msg/TwistStamped": "twist",
    "geometry_msgs/msg/TwistWithCovarianceStamped": "twist",
    "nav_msgs/msg/Odometry": "odometry",
}
#: Which role keeps a channel name two topics both give (lower first).
ROLE_RANK: Mapping[str, int] = {"imu": 0, "navsatfix": 1, "twist": 2, "actuators": 3, "odometry": 4,
                                "rudder": 5, "float64": 6}

#: (role, message field) -> (canonical channel, scale). ENU/FLU -> NED/FRD is the sign in the
#: scale; ``v_n``/``v_e`` are intermediate NED ground velocities [m/s] that become ``sog`` and
#: ``cog``; the orientation quaternions become phi/theta/psi (``quaternion``, see module doc).
VARIABLE_MAP: dict[tuple[str, str], tuple[str, float]] = {
    ("imu", "angular_velocity.x"): ("p", 1.0),
    ("imu", "angular_velocity.y"): ("q", -1.0),
    ("imu", "angular_velocity.z"): ("r", -1.0),
    ("imu", "linear_acceleration.x"): ("ax", 1.0),
    ("imu", "linear_acceleration.y"): ("ay", -1.0),
    ("imu", "linear_acceleration.z"): ("az", -1.0),
    ("navsatfix", "latitude"): ("lat", 1.0),
    ("navsatfix", "longitude"): ("lon", 1.0),
    ("twist", "linear.x"): ("v_e", 1.0),          # ENU ground velocity (world frame_id)
    ("twist", "linear.y"): ("v_n", 1.0),
    ("twist_body", "linear.x"): ("u", 1.0),       # body velocity (body frame_id)
    ("twist_body", "linear.y"): ("v", -1.0),
    ("twist_body", "linear.z"): ("w", -1.0),
    ("twist_body", "angular.x"): ("p", 1.0),
    ("twist_body", "angular.y"): ("q", -1.0),
    ("twist_body", "angular.z"): ("r", -1.0),
    ("odometry", "pose.pose.position.y"): ("x_n", 1.0),
    ("odometry", "pose.pose.position.x"): ("y_e", 1.0),
    ("odometry", "twist.twist.linear.x"): ("u", 1.0),   # child frame (body, FLU)
    ("odometry", "twist.twist.linear.y"): ("v", -1.0),
    ("odometry", "twist.twist.linear.z"): ("w", -1.0),
    ("odometry", "twist.twist.angular.x"): ("p", 1.0),
    ("odometry", "twist.twist.angular.y"): ("q", -1.0),
    ("odometry", "twist.twist.angular.z"): ("r", -1.0),
    ("rudder", "data"): ("delta", 1.0),
    **{("actuators", name): (name, 1.0) for name in INPUT_UNITS},
}
#: frame_id values that mark a twist as a body velocity.
BODY_FRAMES = frozenset({"base_link", "base_footprint", "body", "base_link_frd", "base_link_flu"})
#: A topic whose header stamps sit further than this from the other topics' (relative to the
#: receive time) is on another clock and is timed by receive time instead [s].
CLOCK_MISMATCH_S = 1.0
#: Stamps before this are not wall-clock time (2001-09-09) [ns].
_UNIX_MIN_NS = 10**18
#: Bags above this size get a progress bar when stderr is a terminal [bytes].
_PROGRESS_MIN_BYTES = 16 * 1024 * 1024
_SENSOR_RE = re.compile(r"[A-Za-z0-9_]+")
_ROS1_MAGIC = b"#ROSBAG V2.0"
_SQLITE_MAGIC = b"SQLite format 3\x00"
_MCAP_MAGIC = b"\x89MCAP0\r\n"

# ---------------------------------------------------------------------------------- frames
#: q_ned_enu (= q_enu_ned): a half turn about (1, 1, 0)/sqrt(2), swapping x/y and negating z.
Q_NED_ENU = np.array([0.0, math.sqrt(0.5), math.sqrt(0.5), 0.0])
#: q_flu_frd (= q_frd_flu): a half turn about x, negating y and z.
Q_FLU_FRD = np.array([0.0, 1.0, 0.0, 0.0])


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of quaternions.

    Parameters
    ----------
    a, b : numpy.ndarray
        Quaternions ``[w, x, y, z]`` along the last axis [-]; shapes broadcast.

    Returns
    -------
    numpy.ndarray
        ``a * b`` [-], the rotation ``b`` followed by ``a`` when both map child to parent frame.
    """
    aw, ax, ay, az = np.moveaxis(np.asarray(a, float), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, float), -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def euler_to_quat(phi, theta, psi) -> np.ndarray:
    """Unit quaternion of Fossen's ZYX Euler angles, R = Rz(psi) Ry(theta) Rx(phi).

    Parameters
    ----------
    phi, theta, psi : float or numpy.ndarray
        Roll, pitch and yaw [rad] (body relative to the world frame).

    Returns
    -------
    numpy.ndarray
        Quaternions ``[w, x, y, z]`` on the last axis [-].
    """
    cr, sr = np.cos(np.asarray(phi, float) / 2), np.sin(np.asarray(phi, float) / 2)
    cp, sp = np.cos(np.asarray(theta, float) / 2), np.sin(np.asarray(theta, float) / 2)
    cy, sy = np.cos(np.asarray(psi, float) / 2), np.sin(np.asarray(psi, float) / 2)
    return np.stack([cr * cp * cy + sr * sp * sy,
                     sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy,
                     cr * cp * sy - sr * sp * cy], axis=-1)


def quat_to_euler(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ZYX Euler angles of unit quaternions (inverse of :func:`euler_to_quat`; Fossen 2021, sec. 2.2).

    Parameters
    ----------
    q : numpy.ndarray
        Unit quaternions ``[w, x, y, z]`` on the last axis [-].

    Returns
    -------
    phi, theta, psi : numpy.ndarray
        Roll and yaw in (-pi, pi], pitch in [-pi/2, pi/2] [rad].
    """
    w, x, y, z = np.moveaxis(np.asarray(q, float), -1, 0)
    phi = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    theta = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    psi = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return phi, theta, psi


def enu_flu_to_ned_frd(q_enu_flu: np.ndarray) -> np.ndarray:
    """ROS orientation (FLU body in ENU) -> Fossen attitude (FRD body in NED).

    Parameters
    ----------
    q_enu_flu : numpy.ndarray
        Quaternions ``[w, x, y, z]`` on the last axis [-], as in ``sensor_msgs/Imu.orientation``.

    Returns
    -------
    numpy.ndarray
        ``q_ned_frd = q_ned_enu * q_enu_flu * q_flu_frd`` [-].
    """
    return quat_multiply(quat_multiply(Q_NED_ENU, q_enu_flu), Q_FLU_FRD)


def ned_frd_to_enu_flu(q_ned_frd: np.ndarray) -> np.ndarray:
    """Fossen attitude (FRD body in NED) -> ROS orientation (FLU body in ENU).

    Parameters
    ----------
    q_ned_frd : numpy.ndarray
        Quaternions ``[w, x, y, z]`` on the last axis [-].

    Returns
    -------
    numpy.ndarray
        ``q_enu_flu = q_enu_ned * q_ned_frd * q_frd_flu`` [-].
    """
    # Both fixed rotations are half turns, so each is its own inverse.
    return quat_multiply(quat_multiply(Q_NED_ENU, q_ned_frd), Q_FLU_FRD)


# ---------------------------------------------------------------------------------- roles
@dataclass(frozen=True)
class Role:
    """A parsed topic role: kind, channel (``float64`` only) and channel-name suffix."""

    kind: str
    channel: str = ""
    sensor: str = ""

    @property
    def suffix(self) -> str:
        return f"@{self.sensor}" if self.sensor else ""

    def text(self) -> str:
        """The role as a topic-map spec (``imu``, ``navsatfix@gps``, ``float64:tau_k``).

        The inverse of :func:`parse_role`.
        """
        head = f"float64:{self.channel}" if self.kind == "float64" else self.kind
        return head + self.suffix


def parse_role(spec: str, where: str = "topic map") -> Role:
    """Parse a topic-map role such as ``imu``, ``navsatfix@gps`` or ``float64:tau_k``.

    Parameters
    ----------
    spec : str
        ``<role>[@sensor]`` with role one of ``ROLES`` or ``float64:<canonical channel>``.
    where : str
        What the spec belongs to, for the error message.

    Returns
    -------
    Role

    Raises
    ------
    IngestError
        Unknown role, unknown channel, or a malformed sensor suffix.
    """
    if not isinstance(spec, str):
        raise IngestError(f"{where}: expected a role string, found {spec!r}")
    head, _, sensor = spec.strip().partition("@")
    if sensor and not _SENSOR_RE.fullmatch(sensor):
        raise IngestError(f"{where}: sensor suffix in {spec!r}: expected letters, digits or '_', found {sensor!r}")
    if head.startswith("float64:"):
        ch = head.split(":", 1)[1]
        if ch not in CHANNEL_UNITS:
            raise IngestError(f"{where}: role {spec!r}: expected float64:<channel> with a channel in "
                              f"{sorted(CHANNEL_UNITS)}, found {ch!r}")
        return Role("float64", ch, sensor)
    if head not in ROLES:
        raise IngestError(f"{where}: role {spec!r}: expected one of {list(ROLES)} or float64:<channel>, "
                          f"optionally with @sensor; found {head!r}")
    return Role(head, "", sensor)


def looks_like_rosbag(path: str | Path) -> bool:
    """True for a ROS 2 bag directory (with ``metadata.yaml``) or a ``.bag``/``.db3``/``.mcap`` file.

    Parameters
    ----------
    path : str or Path
        Candidate log path (for a reader registry that must route directories too).

    Returns
    -------
    bool
    """
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").is_file()
    return p.is_file() and p.suffix.lower() in (".bag", ".db3", ".mcap")


def _namespace(topic: str) -> str:
    first = next((c for c in topic.split("/") if c), "topic")
    return re.sub(r"[^A-Za-z0-9_]", "_", first)


def _fields(fielddefs: Mapping[str, Any], msgtype: str) -> dict[str, Any]:
    try:
        return {name: desc for name, desc in fielddefs[msgtype][1]}
    except (KeyError, IndexError, TypeError, ValueError):
        return {}


def _is_number(desc: Any) -> bool:
    try:
        return desc[0] == 1 and desc[1][0] in {"float64", "float32", "int8", "int16", "int32", "int64",
                                               "uint8", "uint16", "uint32", "uint64"}
    except (TypeError, IndexError):
        return False


def _infer_role(topic: str, msgtype: str, fielddefs: Mapping[str, Any]) -> Role | None:
    if msgtype in TYPE_ROLES:
        return Role(TYPE_ROLES[msgtype])
    fields = _fields(fielddefs, msgtype)
    if set(fields) == {"data"} and _is_number(fields["data"]):
        if "rudder" in topic.lower():
            return Role("rudder")
        comps = [c for c in topic.split("/") if c]
        if comps and comps[-1] in CHANNEL_UNITS:
            return Role("float64", comps[-1])
        if len(comps) >= 2 and comps[-2] in CHANNEL_UNITS and _SENSOR_RE.fullmatch(comps[-1]):
            return Role("float64", comps[-2], comps[-1])
        return None
    if "header" in fields and any(n in INPUT_UNITS and _is_number(d) for n, d in fields.items()):
        return Role("actuators")
    return None


#: Topic-name words that mark an input topic as the actuator's measured state (a rudder-angle sensor,
#: servo feedback, shaft encoder) rather than the command sent to it.
_MEASURED_WORDS = re.compile(r"(?:^|[/_\-])(?:feedback|fb|state|status|actual|measured|meas|sensor|encoder)(?:$|[/_\-])",
                             re.IGNORECASE)


def _input_kind(topic: str) -> str:
    """``measured`` when the topic's name says it carries the actuator's measured state, else ``""``.

    An input topic is a command (held until the next message, the default for every format) unless
    its name says otherwise: ``/rudder/feedback``, ``/rudder_state``, ``/rudder/angle_measured`` are
    measured actuator states (interpolated like the other measurements). A manifest's ``[inputs]``
    overrides either way.

    Parameters
    ----------
    topic : str
        ROS topic name.

    Returns
    -------
    str
        ``"measured"`` or ``""`` (the reader's default: a command).
    """
    return "measured" if _MEASURED_WORDS.search(topic) else ""


def _compatible(role: Role, msgtype: str, fielddefs: Mapping[str, Any]) -> bool:
    if role.kind in ("imu", "navsatfix", "twist", "odometry"):
        return TYPE_ROLES.get(msgtype) == role.kind
    fields = _fields(fielddefs, msgtype)
    if role.kind in ("rudder", "float64"):
        return "data" in fields and _is_number(fields["data"])
    if role.kind == "actuators":
        return any(n in INPUT_UNITS and _is_number(d) for n, d in fields.items())
    return True


# ---------------------------------------------------------------------------------- extraction
_GETTERS: dict[tuple[str, str], Callable[[Any], Any]] = {key: attrgetter(key[1]) for key in VARIABLE_MAP}
_NAN = float("nan")
_NAN_QUAT = (_NAN, _NAN, _NAN, _NAN)


def _scalar(getter: Callable[[Any], Any], obj: Any) -> float:
    try:
        return float(getter(obj))
    except (AttributeError, TypeError, ValueError):
        return _NAN


def _quat(o: Any) -> tuple[float, float, float, float]:
    return (float(o.w), float(o.x), float(o.y), float(o.z))


def _extract(role: Role, msg: Any) -> dict[str, float]:
    """Raw values of one message, in NED/FRD and SI, keyed by (pre-suffix) channel name."""
    out: dict[str, float] = {}
    kind = role.kind
    if kind == "imu":
        # sensor_msgs/Imu: covariance element 0 = -1 means "this part is not provided".
        for part in ("angular_velocity", "linear_acceleration"):
            if float(getattr(msg, f"{part}_covariance")[0]) != -1.0:
                for axis in "xyz":
                    key = ("imu", f"{part}.{axis}")
                    out[VARIABLE_MAP[key][0]] = VARIABLE_MAP[key][1] * _scalar(_GETTERS[key], msg)
        if float(msg.orientation_covariance[0]) != -1.0:
            out["_quat"] = _quat(msg.orientation)  # type: ignore[assignment]
    elif kind == "navsatfix":
        if int(msg.status.status) >= 0:   # STATUS_NO_FIX = -1
            out["lat"] = float(msg.latitude)
            out["lon"] = float(msg.longitude)
        else:
            out["_nofix"] = 1.0
    elif kind == "twist":
        twist = msg.twist.twist if hasattr(msg.twist, "twist") else msg.twist
        frame = str(msg.header.frame_id).strip("/").lower()
        if frame in BODY_FRAMES or frame.endswith("base_link"):
            for (r, f), (ch, scale) in VARIABLE_MAP.items():
                if r == "twist_body":
                    out[ch] = scale * _scalar(_GETTERS[(r, f)], twist)
        else:
            v_e = _scalar(_GETTERS[("twist", "linear.x")], twist)
            v_n = _scalar(_GETTERS[("twist", "linear.y")], twist)
            out["sog"] = math.hypot(v_n, v_e)
            out["cog"] = math.atan2(v_e, v_n)
    elif kind == "odometry":
        for (r, f), (ch, scale) in VARIABLE_MAP.items():
            if r == "odometry":
                out[ch] = scale * _scalar(_GETTERS[(r, f)], msg)
        out["_quat"] = _quat(msg.pose.pose.orientation)  # type: ignore[assignment]
    elif kind == "rudder":
        out["delta"] = _scalar(_GETTERS[("rudder", "data")], msg)
    elif kind == "float64":
        out[role.channel] = _scalar(_GETTERS[("rudder", "data")], msg)
    elif kind == "actuators":
        for name in INPUT_UNITS:
            if hasattr(msg, name):
                out[name] = _scalar(_GETTERS[("actuators", name)], msg)
    return out


def _stamp_ns(msg: Any) -> int | None:
    header = getattr(msg, "header", None)
    if header is None:
        return None
    try:
        return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
    except (AttributeError, TypeError, ValueError):
        return None


@dataclass
class _TopicData:
    topic: str
    msgtype: str
    role: Role
    count: int
    inferred: bool
    stamps: list = None  # type: ignore[assignment]
    bag: list = None  # type: ignore[assignment]
    values: dict = None  # type: ignore[assignment]
    undecodable: int = 0
    no_fix: int = 0

    def __post_init__(self) -> None:
        self.stamps, self.bag, self.values = [], [], {}

    def add(self, stamp: int | None, bag_ns: int, values: Mapping[str, Any]) -> None:
        """Append one message; keys a message lacks (a part flagged absent, another frame) get NaN,
        so every value list stays aligned with the stamps."""
        n = len(self.stamps)
        self.stamps.append(-1 if stamp is None else stamp)
        self.bag.append(int(bag_ns))
        for key, series in self.values.items():
            if key not in values:
                series.append(_NAN_QUAT if key == "_quat" else _NAN)
        for key, v in values.items():
            if key not in self.values:
                self.values[key] = [_NAN_QUAT if key == "_quat" else _NAN] * n
            self.values[key].append(v)


# ---------------------------------------------------------------------------------- reader
def _check_path(path: str | Path) -> Path:
    p = Path(path)
    expected = "a ROS 1 .bag file or a ROS 2 bag (directory with metadata.yaml, .db3 or .mcap file)"
    if not p.exists():
        raise IngestError(f"ROS bag: expected {expected}, found nothing at {p}")
    if p.is_dir():
        if not (p / "metadata.yaml").is_file():
            raise IngestError(f"{p}: expected {expected}, found a directory without metadata.yaml "
                              f"({len(list(p.iterdir()))} entries)")
        return p
    if p.stat().st_size == 0:
        raise IngestError(f"{p}: expected {expected}, found an empty file (0 bytes)")
    with open(p, "rb") as fh:
        head = fh.read(16)
    magic = {".bag": _ROS1_MAGIC, ".db3": _SQLITE_MAGIC, ".mcap": _MCAP_MAGIC}
    suffix = p.suffix.lower()
    if suffix not in magic:
        kind = next((k for k, m in magic.items() if head.startswith(m)), None)
        hint = f" (its content is a {kind} bag: rename it to end in {kind})" if kind else ""
        raise IngestError(f"{p}: expected {expected}, found extension {p.suffix or 'none'!r}{hint}")
    if not head.startswith(magic[suffix]):
        raise IngestError(f"{p}: expected a {suffix} bag starting with {magic[suffix]!r}, found {head[:12]!r}; "
                          f"not a bag or damaged")
    return p




def _size(p: Path) -> int:
    if p.is_dir():
        return sum(f.stat().st_size for f in p.iterdir() if f.is_file())
    return p.stat().st_size


def read_rosbag(path: str | Path, topics: Mapping[str, str] | None = None,
                progress: bool | None = None) -> RawLog:
    """Read a ROS 1 or ROS 2 bag into canonical channels (NED/FRD, SI units).

    Parameters
    ----------
    path : str or Path
        ROS 1 ``.bag`` file, ROS 2 bag directory (``metadata.yaml`` + storage files), or a bare
        ROS 2 ``.db3`` (sqlite3) or ``.mcap`` storage file.
    topics : Mapping[str, str], optional
        Topic -> role (``imu``, ``navsatfix``, ``twist``, ``odometry``, ``rudder``,
        ``actuators``, ``float64:<channel>``, ``ignore``; each optionally ``@sensor``), for
        example the vessel config's ``[topics]`` table. It overrides the roles inferred from the
        message types; topics it does not name are still inferred.
    progress : bool, optional
        Show a progress bar; default only for bags above 16 MB when stderr is a terminal.

    Returns
    -------
    RawLog
        Channels from the roles: imu -> ``phi theta psi`` [rad], ``p q r`` [rad/s],
        ``ax ay az`` [m/s^2]; navsatfix -> ``lat lon`` [deg]; twist -> ``sog`` [m/s], ``cog``
        [rad] (ENU ground velocity) or ``u v w`` [m/s], ``p q r`` (body velocity); odometry ->
        ``x_n y_e`` [m], ``u v w``, ``p q r``, ``phi theta psi``; rudder -> ``delta`` [rad];
        actuators -> its canonical input fields (``tau_x`` [N], ``tau_n`` [N m], ``delta``, ...);
        ``float64:<channel>`` -> that channel. ``format='rosbag1'`` or ``'rosbag2'``;
        ``start_time`` [s, Unix UTC] of ``t = 0`` for wall-clock stamps, NaN for simulation time.

    Raises
    ------
    IngestError
        Missing path, not a bag, an unreadable or damaged bag, a bag without messages or without
        any topic that gives a canonical channel, or a malformed topic map.
    """
    p = _check_path(path)
    roles_given = {str(k): parse_role(v, f"topic map entry {k!r}") for k, v in dict(topics or {}).items()}
    is_ros1 = p.suffix.lower() == ".bag"
    fmt = "rosbag1" if is_ros1 else "rosbag2"

    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    fallback = get_typestore(Stores.ROS1_NOETIC if is_ros1 else Stores.ROS2_HUMBLE)
    try:
        reader = AnyReader([p], default_typestore=fallback)
        reader.open()
    except Exception as exc:  # noqa: BLE001 - rosbags raises many low-level types on damaged files
        # (ReaderError, struct.error, sqlite3.DatabaseError, KeyError, UnicodeDecodeError, YAML
        # errors ...); all mean the same thing to the user: this bag cannot be opened.
        hint = "; a truncated ROS 1 bag has lost its index (try `rosbag reindex`)" if is_ros1 else ""
        undefined = re.search(r"MSG: ([\w/]+)", str(exc)) if "Could not parse" in str(exc) else None
        if undefined:  # rosbags cannot parse a stored message definition (e.g. a service event type)
            raise IngestError(f"{p}: expected message definitions rosbags can parse, found one it cannot "
                              f"({undefined.group(1)})") from None
        raise IngestError(f"{p}: expected a readable {fmt} bag, found one that cannot be opened "
                          f"({describe_failure(exc)}){hint}") from None
    try:
        return _read_open(p, reader, fallback, roles_given, fmt, is_ros1, progress)
    finally:
        try:
            reader.close()
        except Exception:  # noqa: BLE001 - closing a damaged bag must not hide the real result
            pass


def _read_open(p: Path, reader: Any, fallback: Any, roles_given: Mapping[str, Role], fmt: str,
               is_ros1: bool, progress: bool | None) -> RawLog:
    warnings: list[str] = []
    read: Counter = Counter()
    skipped: Counter = Counter()
    conns_by_topic: dict[str, list] = defaultdict(list)
    for con in reader.connections:
        conns_by_topic[con.topic].append(con)
    if not conns_by_topic:
        raise IngestError(f"{p}: expected a bag with topics and messages, found an empty bag (no topics)")
    counts = {t: sum(max(int(c.msgcount), 0) for c in cs) for t, cs in conns_by_topic.items()}
    if sum(counts.values()) == 0:
        raise IngestError(f"{p}: expected messages, found an empty bag ({len(counts)} topic(s), 0 messages)")
    empty = sorted(t for t, n in counts.items() if n == 0)
    if empty:
        warnings.append(f"{len(empty)} topic(s) without messages: {', '.join(empty)}")
    missing = sorted(set(roles_given) - set(conns_by_topic))
    if missing:
        warnings.append(f"topic map names {len(missing)} topic(s) not in the bag: {', '.join(missing)}")

    fielddefs = reader.typestore.fielddefs
    topics: dict[str, _TopicData] = {}
    inferred: list[str] = []
    unmapped: list[str] = []
    for topic, cons in sorted(conns_by_topic.items()):
        msgtype = cons[0].msgtype
        role = roles_given.get(topic)
        was_inferred = role is None
        if role is None:
            role = _infer_role(topic, msgtype, fielddefs if msgtype in fielddefs else fallback.fielddefs)
        if role is None:
            if counts[topic]:
                unmapped.append(f"{topic} ({msgtype})")
                skipped[msgtype] += counts[topic]
            continue
        if role.kind == "ignore":
            skipped[msgtype] += counts[topic]
            continue
        if not _compatible(role, msgtype, fielddefs if msgtype in fielddefs else fallback.fielddefs):
            warnings.append(f"{topic}: role {role.text()!r} from the topic map does not fit its type {msgtype}; "
                            f"topic skipped")
            skipped[msgtype] += counts[topic]
            continue
        if counts[topic] == 0:
            continue
        topics[topic] = _TopicData(topic, msgtype, role, counts[topic], was_inferred)

    # Several inferred topics in one role: the busiest keeps plain names, others get @namespace.
    by_role: dict[tuple[str, str, str], list[_TopicData]] = defaultdict(list)
    for td in topics.values():
        if td.inferred:
            by_role[(td.role.kind, td.role.channel, td.role.sensor)].append(td)
    for group in by_role.values():
        group.sort(key=lambda d: (-d.count, len(d.topic), d.topic))
        for td in group[1:]:
            td.role = Role(td.role.kind, td.role.channel, _namespace(td.topic))
    for td in topics.values():
        if td.inferred:
            inferred.append(f"{td.topic} -> {td.role.text()}")
    if inferred:
        warnings.append("roles inferred from message types (no topic map entry): " + ", ".join(inferred))
    if unmapped:
        warnings.append(f"topics with no role skipped (give one in the topic map): {', '.join(unmapped)}")
    if not topics:
        raise IngestError(f"{p}: expected at least one topic with a role ({', '.join(TYPE_ROLES)}, Float64 "
                          f"rudder/channel topics or an actuator message), found only "
                          f"{', '.join(f'{t} ({cs[0].msgtype})' for t, cs in sorted(conns_by_topic.items()))}")

    wanted = [c for t in topics for c in conns_by_topic[t]]
    total = sum(topics[t].count for t in topics)
    stream = reader.messages(connections=wanted)
    if want_progress(progress, _size(p), _PROGRESS_MIN_BYTES):
        from tqdm import tqdm

        stream = tqdm(stream, total=total, desc=p.name, unit="msg", leave=False)
    # Messages are first collected per topic as raw bytes; each topic is then decoded in one go
    # (see _decode_topic_fast) or, when its layout is not fixed, message by message through
    # rosbags. Deserialising every message into objects was 60% of an hour's ingest, as slow as the
    # plain AnyReader loop.
    raw_by_topic: dict[str, tuple[bytearray, list, list, list]] = {t: (bytearray(), [], [], []) for t in topics}
    n_seen = 0
    try:
        for con, bag_ns, raw in stream:
            n_seen += 1
            buf, lens, bags, types = raw_by_topic[con.topic]
            buf += raw
            lens.append(len(raw))
            bags.append(bag_ns)
            types.append(con.msgtype)
    except Exception as exc:  # noqa: BLE001 - storage-level damage (truncated chunk, bad page, ...)
        if n_seen == 0:
            raise IngestError(f"{p}: expected readable messages, found damaged storage "
                              f"({describe_failure(exc)})") from None
        warnings.append(f"bag damaged: reading stopped after {n_seen} message(s) ({describe_failure(exc)})")

    deser_bag = reader.deserialize
    deser_fallback = fallback.deserialize_ros1 if is_ros1 else fallback.deserialize_cdr
    for topic, (buf, lens, bags, types) in raw_by_topic.items():
        td = topics[topic]
        msgtype = types[0] if types else td.msgtype
        defs = reader.typestore.fielddefs if msgtype in reader.typestore.fielddefs else fallback.fielddefs
        if FAST_DECODE and len(set(types)) == 1 and _decode_topic_fast(td, buf, lens, bags, defs, msgtype, is_ros1):
            continue
        pos = 0
        for n, bag_ns, mtype in zip(lens, bags, types):
            raw = bytes(buf[pos:pos + n])
            pos += n
            try:
                if mtype in reader.typestore.fielddefs:
                    msg = deser_bag(raw, mtype)
                else:
                    msg = deser_fallback(raw, mtype)
                values = _extract(td.role, msg)
            except Exception:  # noqa: BLE001 - a damaged message must not end the read
                td.undecodable += 1
                continue
            if "_nofix" in values:
                td.no_fix += 1
                continue
            td.add(_stamp_ns(msg), bag_ns, values)

    return _build(p, fmt, topics, read, skipped, warnings)


# ---------------------------------------------------------------------------------- fast decoding
#: Decode topics of a fixed layout in one vectorised step (False: always message by message).
FAST_DECODE = True
#: ROS primitive type -> little-endian numpy type (CDR little-endian and ROS 1 serialisation).
_PRIMITIVES: Mapping[str, str] = {
    "bool": "u1", "byte": "u1", "octet": "u1", "char": "u1", "uint8": "u1", "int8": "i1", "uint16": "<u2",
    "int16": "<i2", "uint32": "<u4", "int32": "<i4", "uint64": "<u8", "int64": "<i8", "float32": "<f4",
    "float64": "<f8"}


class _NoLayout(Exception):
    """The message has a part whose size varies (a sequence) or an unknown type."""


def message_layout(fielddefs: Mapping[str, Any], msgtype: str, raw: bytes, ros1: bool
                   ) -> tuple[dict[str, tuple[int, str]], dict[str, tuple[int, int]]] | None:
    """Byte offsets of every numeric field of one serialised message, or None when not fixed.

    Strings (``header.frame_id``) are sized from this message; a topic whose messages all have
    the same strings (checked by the caller) then has one layout for all of them.

    Parameters
    ----------
    fielddefs : Mapping[str, Any]
        rosbags typestore field definitions.
    msgtype : str
        Message type (``sensor_msgs/msg/Imu``).
    raw : bytes
        One serialised message: CDR little-endian with its 4-byte encapsulation header (ROS 2)
        or ROS 1 serialisation.
    ros1 : bool
        ROS 1 serialisation (no alignment, no encapsulation header).

    Returns
    -------
    fields, strings : dict, dict
        Dotted field path (``angular_velocity.x``, ``orientation_covariance[0]``) -> (offset
        [bytes], numpy type); string path -> (offset of its length prefix, total bytes). None when
        the message holds a sequence, an unknown type, is big-endian CDR or the sizes do not add up.
    """
    base = 0 if ros1 else 4
    if not ros1 and (len(raw) < 4 or raw[0] != 0 or raw[1] != 1):
        return None  # only little-endian plain CDR
    fields: dict[str, tuple[int, str]] = {}
    strings: dict[str, tuple[int, int]] = {}
    pos = base

    def align(size: int) -> None:
        nonlocal pos
        if not ros1:  # CDR aligns a primitive to its size, counted from the end of the header
            pos = base + -(-(pos - base) // size) * size

    def walk(mt: str, prefix: str) -> None:
        nonlocal pos
        entry = fielddefs.get(mt)
        if entry is None:
            raise _NoLayout(mt)
        for name, (node, spec) in entry[1]:
            path = prefix + name
            if node == 1 and spec[0] == "string":
                align(4)
                if pos + 4 > len(raw):
                    raise _NoLayout(path)
                length = int.from_bytes(raw[pos:pos + 4], "little")
                strings[path] = (pos, 4 + length)
                pos += 4 + length
            elif node == 1 and spec[0] in _PRIMITIVES:
                size = np.dtype(_PRIMITIVES[spec[0]]).itemsize
                align(size)
                fields[path] = (pos, _PRIMITIVES[spec[0]])
                pos += size
            elif node == 2:
                walk(spec, path + ".")
            elif node == 3 and spec[0][0] == 1 and spec[0][1][0] in _PRIMITIVES:
                dtype = _PRIMITIVES[spec[0][1][0]]
                size = np.dtype(dtype).itemsize
                align(size)
                for i in range(spec[1]):
                    fields[f"{path}[{i}]"] = (pos + i * size, dtype)
                pos += spec[1] * size
            elif node == 3 and spec[0][0] == 2:
                for i in range(spec[1]):
                    walk(spec[0][1], f"{path}[{i}].")
            else:
                raise _NoLayout(path)

    try:
        walk(msgtype, "")
    except _NoLayout:
        return None
    # CDR writers may pad the end to a multiple of 4 (or 8); anything more is not this layout.
    if pos > len(raw) or len(raw) - pos >= 8:
        return None
    return fields, strings


def _decode_topic_fast(td: _TopicData, buf: bytearray, lens: list, bags: list, fielddefs: Mapping[str, Any],
                       msgtype: str, ros1: bool) -> bool:
    """Decode all messages of one topic at once when they share one layout; False to fall back.

    The values are those :func:`_extract` gives message by message (same roles, frames, NaN for
    a part flagged absent, fixes with status NO_FIX dropped and counted).
    """
    n = len(lens)
    if not n or len(set(lens)) != 1:
        return False
    size = lens[0]
    layout = message_layout(fielddefs, msgtype, bytes(buf[:size]), ros1)
    if layout is None:
        return False
    fields, strings = layout
    rows = np.frombuffer(buf, np.uint8).reshape(n, size)
    for off, length in strings.values():
        if not (rows[:, off:off + length] == rows[0, off:off + length]).all():
            return False  # different frame_ids: possibly another layout, and another twist frame

    def get(path: str) -> np.ndarray:
        off, dtype = fields[path]
        width = np.dtype(dtype).itemsize
        return np.ascontiguousarray(rows[:, off:off + width]).view(dtype).ravel().astype(np.float64)

    def text(path: str) -> str:
        off, length = strings[path]
        return bytes(rows[0, off + 4:off + length]).decode("utf-8", "replace").rstrip("\x00")

    out: dict[str, np.ndarray] = {}
    keep = np.ones(n, bool)
    kind = td.role.kind
    try:
        if kind == "imu":
            for part in ("angular_velocity", "linear_acceleration"):
                present = get(f"{part}_covariance[0]") != -1.0
                for axis in "xyz":
                    ch, scale = VARIABLE_MAP[("imu", f"{part}.{axis}")]
                    out[ch] = np.where(present, scale * get(f"{part}.{axis}"), np.nan)
            present = get("orientation_covariance[0]") != -1.0
            quat = np.column_stack([get(f"orientation.{a}") for a in "wxyz"])
            out["_quat"] = np.where(present[:, None], quat, np.nan)
        elif kind == "navsatfix":
            keep = get("status.status") >= 0  # STATUS_NO_FIX = -1
            td.no_fix += int((~keep).sum())
            out["lat"], out["lon"] = get("latitude"), get("longitude")
        elif kind == "twist":
            pre = "twist.twist." if "twist.twist.linear.x" in fields else "twist."
            frame = text("header.frame_id").strip("/").lower() if "header.frame_id" in strings else ""
            if frame in BODY_FRAMES or frame.endswith("base_link"):
                for (r, f), (ch, scale) in VARIABLE_MAP.items():
                    if r == "twist_body":
                        out[ch] = scale * get(pre + f)
            else:
                v_e, v_n = get(pre + "linear.x").tolist(), get(pre + "linear.y").tolist()
                # math, not numpy: bit for bit what the message-by-message path gives.
                out["sog"] = np.array([math.hypot(a, b) for a, b in zip(v_n, v_e)], float)
                out["cog"] = np.array([math.atan2(b, a) for a, b in zip(v_n, v_e)], float)
        elif kind == "odometry":
            for (r, f), (ch, scale) in VARIABLE_MAP.items():
                if r == "odometry":
                    out[ch] = scale * get(f)
            out["_quat"] = np.column_stack([get(f"pose.pose.orientation.{a}") for a in "wxyz"])
        elif kind == "rudder":
            out["delta"] = get("data")
        elif kind == "float64":
            out[td.role.channel] = get("data")
        elif kind == "actuators":
            for name in INPUT_UNITS:
                if name in fields:
                    out[name] = get(name)
    except KeyError:
        return False  # a field the role needs is not where the standard type has it
    if "header.stamp.sec" in fields and "header.stamp.nanosec" in fields:
        off_s, _ = fields["header.stamp.sec"]
        sec = np.ascontiguousarray(rows[:, off_s:off_s + 4]).view("<i4").ravel().astype(np.int64)
        off_n, _ = fields["header.stamp.nanosec"]
        nsec = np.ascontiguousarray(rows[:, off_n:off_n + 4]).view("<u4").ravel().astype(np.int64)
        stamps = sec * 1_000_000_000 + nsec
    else:
        stamps = np.full(n, -1, np.int64)
    td.stamps = stamps[keep]
    td.bag = np.asarray(bags, np.int64)[keep]
    td.values = {k: v[keep] for k, v in out.items()}
    return True


def _build(p: Path, fmt: str, topics: Mapping[str, _TopicData], read: Counter, skipped: Counter,
           warnings: list[str]) -> RawLog:
    # Clock choice per topic: header stamps, unless absent, zero, or on another clock.
    offsets: dict[str, float] = {}
    for td in topics.values():
        st = np.asarray(td.stamps, np.int64)
        good = st > 0
        if good.any():
            offsets[td.topic] = float(np.median((st[good] - np.asarray(td.bag, np.int64)[good]) / 1e9))
    ref = float(np.median(list(offsets.values()))) if offsets else 0.0
    times: dict[str, tuple[np.ndarray, np.ndarray]] = {}   # topic -> (t_ns, index of messages kept)
    bag_timed: list[str] = []
    for td in topics.values():
        st = np.asarray(td.stamps, np.int64)
        bag = np.asarray(td.bag, np.int64)
        idx = np.arange(len(st))
        if td.topic in offsets and abs(offsets[td.topic] - ref) <= CLOCK_MISMATCH_S:
            good = st > 0
            if (~good).any():
                skipped[f"{td.msgtype} zero stamp"] += int((~good).sum())
                warnings.append(f"{td.topic}: {int((~good).sum())} message(s) with a zero header stamp dropped")
            t_ns, idx = st[good], idx[good]
        else:
            if td.topic in offsets:
                warnings.append(f"{td.topic}: header stamps are {offsets[td.topic] - ref:+.3f} s from the other "
                                f"topics' (relative to receive time); another clock, so timed by bag receive time")
            if len(bag):
                bag_timed.append(f"{td.topic} {len(bag)}")
            t_ns = bag
        times[td.topic] = (t_ns, idx)
    if bag_timed:
        warnings.append(f"messages timed by bag receive time (no usable header stamp): {', '.join(bag_timed)}")
    nonempty = [t for t in times.values() if len(t[0])]
    if not nonempty:
        raise IngestError(f"{p}: expected decodable messages on {', '.join(topics)}, found none "
                          f"({sum(td.undecodable for td in topics.values())} undecodable)")
    t0 = min(int(t[0].min()) for t in nonempty)

    produced: dict[str, tuple[Channel, _TopicData]] = {}
    order = sorted(topics.values(), key=lambda d: (ROLE_RANK[d.role.kind], -d.count, d.topic))
    for td in order:
        t_ns, idx = times[td.topic]
        if td.undecodable:
            skipped[f"{td.msgtype} undecodable"] += td.undecodable
            warnings.append(f"{td.topic}: {td.undecodable} message(s) could not be decoded and were skipped")
        if td.no_fix:
            skipped[f"{td.msgtype} no fix"] += td.no_fix
            warnings.append(f"{td.topic}: {td.no_fix} fix(es) with status NO_FIX skipped")
        # Stamps in receive order: keep those above every earlier one (repeats, clock steps back).
        rel = (t_ns - t0).astype(np.float64) / 1e9
        rel, idx, dropped = increasing(rel, idx)
        if dropped:
            skipped[f"{td.msgtype} repeated or out-of-order stamp"] += dropped
            warnings.append(f"{td.topic}: {dropped} repeated or out-of-order header stamp(s) dropped")
        read[td.msgtype] += len(idx)
        vals: dict[str, np.ndarray] = {}
        for key, series in td.values.items():
            if key == "_quat":
                q = np.asarray(series, float)[idx].reshape(-1, 4)
                with np.errstate(over="ignore", invalid="ignore"):   # damaged messages: inf/NaN
                    norm = np.linalg.norm(q, axis=1, keepdims=True)
                ok = np.isfinite(norm[:, 0]) & (norm[:, 0] > 1e-6)
                q = np.where(ok[:, None], q / np.where(ok[:, None], norm, 1.0), np.nan)
                phi, theta, psi = quat_to_euler(enu_flu_to_ned_frd(q))
                vals.update(phi=phi, theta=theta, psi=psi)
            else:
                vals[key] = np.asarray(series, float)[idx]
        for name, v in vals.items():
            ok = np.isfinite(v)
            if not ok.any():
                continue
            if not ok.all():
                skipped[f"{td.msgtype} {name} not available"] += int((~ok).sum())
            values = v[ok]
            if name in ANGLE_CHANNELS:
                values = np.pi - np.mod(np.pi - values, 2 * np.pi)
            full = name + td.role.suffix
            if full in produced:
                other = produced[full][1]
                base_ns = _namespace(td.topic)
                alt, k = f"{name}@{base_ns}", 2
                while alt in produced:
                    alt, k = f"{name}@{base_ns}{k}", k + 1
                warnings.append(f"{td.topic}: {full} is already read from {other.topic}; kept as {alt}")
                full = alt
            kind = _input_kind(td.topic) if name in INPUT_UNITS else ""
            if kind == "measured":
                warnings.append(f"{td.topic}: {full} taken as a measured actuator state (interpolated), from the "
                                f"topic name; declare [inputs] {name} = \"command\" if it is a command")
            produced[full] = (Channel(full, rel[ok], values, source=f"{td.topic} ({td.msgtype})", input_kind=kind),
                              td)
    chans = {name: ch for name, (ch, _) in produced.items()}
    if not chans:
        raise IngestError(f"{p}: expected finite samples on {', '.join(topics)}, found none")

    bases = {n.split("@")[0] for n in chans}
    for group, names in (("attitude", {"phi", "theta", "psi"}), ("angular rate", {"p", "q", "r"}),
                         ("position", {"lat", "lon", "x_n", "y_e"}), ("velocity", {"sog", "u", "v"}),
                         ("input", set(INPUT_UNITS))):
        if not bases & names:
            warnings.append(f"no {group} channel in the bag (expected one of {', '.join(sorted(names))})")
    when = datetime.fromtimestamp(t0 / 1e9, timezone.utc).isoformat(timespec="microseconds")
    wall = t0 >= _UNIX_MIN_NS
    warnings.insert(0, f"time origin: t = 0 is stamp {t0} ns" + (f" ({when})" if wall else " (not wall-clock time)"))
    summary = IngestSummary(path=str(p), format=fmt, read=dict(read),
                            skipped={k: v for k, v in skipped.items() if v}, warnings=tuple(warnings))
    # Header stamps are Unix time (ROS wall clock, UTC) unless the bag ran on simulation time.
    return RawLog(source=str(p), format=fmt, channels=chans, summary=summary,
                  time_reference="unix" if wall else "trial", start_time=t0 / 1e9 if wall else math.nan)
