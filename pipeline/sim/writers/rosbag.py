"""Write a RawLog as a ROS 1 bag or a ROS 2 bag (sqlite3 or mcap), as a boat running ROS records it.

Messages (REP-103/105 frames: ENU world, FLU body; converted from the RawLog's NED/FRD)
-------------------------------------------------------------------------------------
``/imu/data``       sensor_msgs/msg/Imu: orientation from phi/theta/psi, angular_velocity from
                    p/q/r, linear_acceleration from ax/ay/az (a missing part has covariance[0] = -1)
``/nav/fix``        sensor_msgs/msg/NavSatFix from lat/lon
``/nav/vel``        geometry_msgs/msg/TwistStamped, ENU ground velocity from sog/cog (frame ``gps``)
``/<s>/fix``, ``/<s>/vel``, ``/<s>/data``  the same for channels with suffix ``@<s>``
                    (``lat@gps`` -> ``/gps/fix``, ``sog@gps`` -> ``/gps/vel``)
``/odom``           nav_msgs/msg/Odometry, only when the log has x_n/y_e/u/v/w: position (ENU, frame
                    ``odom``), orientation, body twist (FLU, child frame ``base_link``)
``/actuators``      ``vesselid_msgs/msg/Actuators`` (custom: header, tau_x, tau_y, tau_n, delta in the
                    pipeline's own Fossen convention), its definition registered from
                    ``ACTUATORS_MSGDEF`` and stored in the bag, so a reader can decode it unseen
``/rudder/angle``   std_msgs/msg/Float64, rudder angle (``delta@rudder`` if logged, else ``delta``)
``/vesselid/<ch>[/<sensor>]``  std_msgs/msg/Float64 for any other channel (tau_k, tau_m, ...)

An IMU message is sent at the rate channels' times; attitude sampled elsewhere is interpolated
onto them (angles unwrapped first), and inputs are held between their samples (zero-order hold).
A topic map (topic -> role, as :func:`pipeline.ingest.rosbag.read_rosbag` takes it) moves a role's
messages to another topic name. Header stamps carry the trial time plus ``epoch``; the bag's
receive time is the stamp plus a latency and a seeded jitter, as a recorder on a busy computer
sees it (and the reader must not use it). A channel that a message needs but the log lacks is
written as NaN (the reader drops NaN samples). The bag is written into a temporary folder beside
the target and renamed into place, so a failed write leaves no partial bag.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ...errors import IngestError, SimError
from ...ingest.rosbag import Role, euler_to_quat, ned_frd_to_enu_flu, parse_role
from ...records import CHANNEL_UNITS, RawLog

#: Custom actuator message: name and definition (ROS .msg syntax; Fossen body frame, SI units).
ACTUATORS_MSGTYPE = "vesselid_msgs/msg/Actuators"
ACTUATORS_MSGDEF = """\
# Actuator commands of a vesselid vessel, in the Fossen body frame (x forward, y starboard, z down).
std_msgs/Header header
float64 tau_x   # surge force [N]
float64 tau_y   # sway force [N]
float64 tau_n   # yaw moment [N m]
float64 delta   # rudder angle [rad]; positive gives a positive (starboard) yaw rate
"""
_ACT_FIELDS = ("tau_x", "tau_y", "tau_n", "delta")
VERSIONS = ("ros2-sqlite3", "ros2-mcap", "ros1")
_DEFAULT_EPOCH = datetime(2024, 5, 5, 10, 0, tzinfo=timezone.utc)
_IMU = ("p", "q", "r", "ax", "ay", "az", "phi", "theta", "psi")
_ODOM = ("x_n", "y_e", "u", "v", "w")
_SUFFIX_FILES = {"ros2-sqlite3": ".db3", "ros2-mcap": ".mcap", "ros1": ".bag"}


def _split(name: str) -> tuple[str, str]:
    base, _, sensor = name.partition("@")
    return base, sensor


def _default_topic(role: Role) -> str:
    s = role.sensor
    if role.kind == "imu":
        return "/imu/data" if not s else f"/{s}/data"
    if role.kind == "navsatfix":
        return "/nav/fix" if not s else f"/{s}/fix"
    if role.kind == "twist":
        return "/nav/vel" if not s else f"/{s}/vel"
    if role.kind == "odometry":
        return "/odom" if not s else f"/{s}/odom"
    if role.kind == "actuators":
        return "/actuators"
    if role.kind == "rudder":
        return "/rudder/angle"
    return f"/vesselid/{role.channel}" + (f"/{s}" if s else "")


def _plan(log: RawLog) -> list[Role]:
    """The roles the log's channels fill, in a stable order."""
    names = set(log.channels)
    sensors = sorted({_split(n)[1] for n in names})
    roles: list[Role] = []
    covered: set[str] = set()
    for s in sensors:
        sfx = f"@{s}" if s else ""
        groups = (("imu", _IMU), ("navsatfix", ("lat", "lon")), ("twist", ("sog", "cog")), ("odometry", _ODOM))
        for kind, chans in groups:
            if any(c + sfx in names for c in chans):
                roles.append(Role(kind, "", s))
                covered |= {c + sfx for c in chans}
    if any(c in names for c in _ACT_FIELDS):
        roles.append(Role("actuators"))
        covered |= set(_ACT_FIELDS)
    rudder = "delta@rudder" if "delta@rudder" in names else ("delta" if "delta" in names else None)
    if rudder:
        roles.append(Role("rudder", "", "rudder" if rudder == "delta@rudder" else ""))
        covered.add(rudder)
    for n in sorted(names - covered):
        base, s = _split(n)
        if base in CHANNEL_UNITS:
            roles.append(Role("float64", base, s))
    return roles


def _channel_names(role: Role) -> tuple[str, ...]:
    sfx = role.suffix
    if role.kind == "imu":
        return tuple(c + sfx for c in _IMU)
    if role.kind == "navsatfix":
        return ("lat" + sfx, "lon" + sfx)
    if role.kind == "twist":
        return ("sog" + sfx, "cog" + sfx)
    if role.kind == "odometry":
        return tuple(c + sfx for c in _ODOM + ("phi", "theta", "psi", "p", "q", "r"))
    if role.kind == "actuators":
        return _ACT_FIELDS
    if role.kind == "rudder":
        return ("delta" + sfx,)
    return (role.channel + sfx,)


def _times(log: RawLog, names: tuple[str, ...], prefer: tuple[str, ...] = ()) -> np.ndarray:
    for n in prefer + names:
        if n in log.channels and len(log.channels[n].t):
            return np.asarray(log.channels[n].t, float)
    return np.zeros(0)


def _on(log: RawLog, name: str, times: np.ndarray, hold: bool = False) -> np.ndarray:
    """Channel ``name`` at ``times``: exact on its own samples, else interpolated (angles
    unwrapped) or held (inputs, zero-order hold as the actuator applies them); NaN outside."""
    ch = log.channels.get(name)
    if ch is None or len(ch.t) == 0:
        return np.full(len(times), np.nan)
    t, v = np.asarray(ch.t, float), np.asarray(ch.values, float)
    if len(t) == len(times) and np.array_equal(t, times):
        return v.copy()
    if hold and ch.input_kind != "measured":
        i = np.searchsorted(t, times + 1e-12, side="right") - 1
        out = v[np.clip(i, 0, len(v) - 1)]
        return np.where(i >= 0, out, np.nan)
    base = _split(name)[0]
    out = np.interp(times, t, np.unwrap(v) if base in ("phi", "theta", "psi", "cog") else v)
    out[(times < t[0] - 1e-9) | (times > t[-1] + 1e-9)] = np.nan
    return out


def _quat_enu_flu(phi: np.ndarray, theta: np.ndarray, psi: np.ndarray) -> np.ndarray:
    return ned_frd_to_enu_flu(euler_to_quat(phi, theta, psi))


class _Msgs:
    """Builds ROS messages for one typestore (ROS 1 headers have a ``seq``)."""

    def __init__(self, typestore: Any, ros1: bool) -> None:
        self.T = typestore.types
        self.ros1 = ros1
        self.seq = 0

    def header(self, stamp_ns: int, frame: str) -> Any:
        sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
        stamp = self.T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
        if self.ros1:
            self.seq += 1
            return self.T["std_msgs/msg/Header"](seq=self.seq, stamp=stamp, frame_id=frame)
        return self.T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def vec(self, x: float, y: float, z: float) -> Any:
        return self.T["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z))

    def quat(self, q: np.ndarray) -> Any:
        return self.T["geometry_msgs/msg/Quaternion"](w=float(q[0]), x=float(q[1]), y=float(q[2]), z=float(q[3]))


def _messages(log: RawLog, role: Role, b: _Msgs, epoch_ns: int) -> tuple[str, np.ndarray, list]:
    """(message type, stamps [ns], messages) for one role."""
    T = b.T
    names = _channel_names(role)
    sfx = role.suffix

    def stamps(times: np.ndarray) -> np.ndarray:
        return epoch_ns + np.round(times * 1e9).astype(np.int64)

    if role.kind == "imu":
        times = _times(log, names, prefer=("p" + sfx, "ax" + sfx))
        v = {n: _on(log, n + sfx, times) for n in _IMU}
        has_att = any(n + sfx in log.channels for n in ("phi", "theta", "psi"))
        has_rate = any(n + sfx in log.channels for n in ("p", "q", "r"))
        has_acc = any(n + sfx in log.channels for n in ("ax", "ay", "az"))
        # A sensor that gives only heading (a compass) still fills the full quaternion: roll and
        # pitch are then written as zero, as such sensors report.
        att = {n: np.nan_to_num(v[n]) if has_att and n + sfx not in log.channels else v[n]
               for n in ("phi", "theta", "psi")}
        q = _quat_enu_flu(att["phi"], att["theta"], att["psi"]) if has_att else np.zeros((len(times), 4))
        st = stamps(times)
        msgs = []
        cov_none = np.array([-1.0] + [0.0] * 8)
        zeros = np.zeros(9)
        for k in range(len(times)):
            msgs.append(T["sensor_msgs/msg/Imu"](
                header=b.header(st[k], "imu_link"),
                orientation=b.quat(q[k]), orientation_covariance=zeros if has_att else cov_none,
                # FRD -> FLU: x stays, y and z change sign.
                angular_velocity=b.vec(v["p"][k], -v["q"][k], -v["r"][k]),
                angular_velocity_covariance=zeros if has_rate else cov_none,
                linear_acceleration=b.vec(v["ax"][k], -v["ay"][k], -v["az"][k]),
                linear_acceleration_covariance=zeros if has_acc else cov_none))
        return "sensor_msgs/msg/Imu", st, msgs
    if role.kind == "navsatfix":
        times = _times(log, names)
        lat, lon = _on(log, "lat" + sfx, times), _on(log, "lon" + sfx, times)
        st = stamps(times)
        status_t = T["sensor_msgs/msg/NavSatStatus"]
        msgs = [T["sensor_msgs/msg/NavSatFix"](
            header=b.header(st[k], "gps"),
            status=status_t(status=0 if np.isfinite(lat[k]) and np.isfinite(lon[k]) else -1, service=1),
            latitude=float(lat[k]), longitude=float(lon[k]), altitude=float("nan"),
            position_covariance=np.zeros(9), position_covariance_type=0) for k in range(len(times))]
        return "sensor_msgs/msg/NavSatFix", st, msgs
    if role.kind == "twist":
        times = _times(log, names)
        sog, cog = _on(log, "sog" + sfx, times), _on(log, "cog" + sfx, times)
        v_n, v_e = sog * np.cos(cog), sog * np.sin(cog)
        st = stamps(times)
        twist_t = T["geometry_msgs/msg/Twist"]
        msgs = [T["geometry_msgs/msg/TwistStamped"](
            header=b.header(st[k], "gps"),
            # ENU: x east, y north.
            twist=twist_t(linear=b.vec(v_e[k], v_n[k], 0.0), angular=b.vec(0.0, 0.0, 0.0)))
            for k in range(len(times))]
        return "geometry_msgs/msg/TwistStamped", st, msgs
    if role.kind == "odometry":
        times = _times(log, names)
        v = {n: _on(log, n + sfx, times) for n in _ODOM + ("phi", "theta", "psi", "p", "q", "r")}
        q = _quat_enu_flu(v["phi"], v["theta"], v["psi"])
        st = stamps(times)
        pose_t, posec_t = T["geometry_msgs/msg/Pose"], T["geometry_msgs/msg/PoseWithCovariance"]
        twist_t, twistc_t = T["geometry_msgs/msg/Twist"], T["geometry_msgs/msg/TwistWithCovariance"]
        point_t = T["geometry_msgs/msg/Point"]
        msgs = []
        for k in range(len(times)):
            pose = pose_t(position=point_t(x=float(v["y_e"][k]), y=float(v["x_n"][k]), z=0.0), orientation=b.quat(q[k]))
            twist = twist_t(linear=b.vec(v["u"][k], -v["v"][k], -v["w"][k]),
                            angular=b.vec(v["p"][k], -v["q"][k], -v["r"][k]))
            msgs.append(T["nav_msgs/msg/Odometry"](
                header=b.header(st[k], "odom"), child_frame_id="base_link",
                pose=posec_t(pose=pose, covariance=np.zeros(36)),
                twist=twistc_t(twist=twist, covariance=np.zeros(36))))
        return "nav_msgs/msg/Odometry", st, msgs
    if role.kind == "actuators":
        present = [n for n in _ACT_FIELDS if n in log.channels]
        times = np.unique(np.concatenate([np.asarray(log.channels[n].t, float) for n in present]))
        v = {n: _on(log, n, times, hold=True) for n in _ACT_FIELDS}
        st = stamps(times)
        msgs = [T[ACTUATORS_MSGTYPE](header=b.header(st[k], "base_link"),
                                     **{n: float(v[n][k]) for n in _ACT_FIELDS}) for k in range(len(times))]
        return ACTUATORS_MSGTYPE, st, msgs
    # rudder, float64: one number, no header (its time is the receive time only).
    name = names[0]
    if role.kind == "rudder" and name not in log.channels:
        name = "delta"
    times = _times(log, (name,))
    vals = _on(log, name, times)
    st = stamps(times)
    return "std_msgs/msg/Float64", st, [T["std_msgs/msg/Float64"](data=float(x)) for x in vals]


def write_rosbag(log: RawLog, path: str | Path, version: str = "ros2-sqlite3",
                 topics: Mapping[str, str] | None = None, *, epoch: datetime = _DEFAULT_EPOCH,
                 receive_latency: float = 0.005, receive_jitter: float = 0.002, seed: int = 0) -> Path:
    """Write ``log`` as a ROS bag (atomically: temporary folder, then rename).

    Parameters
    ----------
    log : RawLog
        Channels in the pipeline's frames (NED/FRD) and SI units.
    path : str or Path
        ROS 1: a ``.bag`` file. ROS 2: a bag directory (``metadata.yaml`` + one storage file), or
        a path ending in ``.db3`` / ``.mcap`` for a bare storage file. An existing bag there is
        replaced.
    version : str
        ``ros2-sqlite3``, ``ros2-mcap`` or ``ros1``.
    topics : Mapping[str, str], optional
        Topic -> role (``imu``, ``navsatfix@gps``, ``float64:tau_k`` ...): write that role's
        channels on that topic instead of the default one (see the module doc). Roles whose
        channels the log lacks are not written.
    epoch : datetime
        UTC time of ``t = 0`` in the header stamps [timezone-aware].
    receive_latency, receive_jitter : float
        Bag receive time = stamp + latency + uniform(0, jitter) [s].
    seed : int
        Seed of the receive-time jitter.

    Returns
    -------
    Path
        The bag written.

    Raises
    ------
    SimError
        Unknown version, a path whose extension does not fit the version, a naive ``epoch``, a
        malformed topic map, a log with no channel to write, or an existing non-bag target.
    """
    if version not in VERSIONS:
        raise SimError(f"version: expected one of {list(VERSIONS)}, found {version!r}")
    if epoch.tzinfo is None:
        raise SimError(f"epoch: expected a timezone-aware UTC datetime, found naive {epoch!r}")
    if receive_latency < 0 or receive_jitter < 0:
        raise SimError(f"receive_latency, receive_jitter: expected >= 0 [s], found {receive_latency}, {receive_jitter}")
    target = Path(path)
    ros1 = version == "ros1"
    bare = target.suffix.lower() in (".db3", ".mcap", ".bag")
    if ros1 and target.suffix.lower() != ".bag":
        raise SimError(f"{target}: expected a path ending in .bag for a ROS 1 bag, found {target.suffix or 'none'!r}")
    if not ros1 and bare and target.suffix.lower() != _SUFFIX_FILES[version]:
        raise SimError(f"{target}: expected a bag directory or a path ending in {_SUFFIX_FILES[version]} for "
                       f"{version}, found {target.suffix!r}")
    if target.is_dir() and not (target / "metadata.yaml").is_file():
        raise SimError(f"{target}: expected a new path or an existing ROS 2 bag to replace, found a directory "
                       f"without metadata.yaml (not overwritten)")

    try:
        overrides = {parse_role(spec, f"topic map entry {topic!r}"): str(topic) for topic, spec in (topics or {}).items()}
    except IngestError as exc:
        raise SimError(str(exc)) from None
    roles = _plan(log)
    # A mapped rudder role with its own suffix (``rudder@fb``) takes the rudder topic even when
    # the log has only the plain ``delta``: the reader then names that feedback ``delta@fb``.
    for role in overrides:
        if role.kind == "rudder" and role not in roles:
            roles = [role if r.kind == "rudder" else r for r in roles]
    if not roles:
        raise SimError(f"{log.source}: expected canonical channels to write, found {sorted(log.channels)}")

    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    typestore = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    typestore.register(get_types_from_msg(ACTUATORS_MSGDEF, ACTUATORS_MSGTYPE))
    builder = _Msgs(typestore, ros1)
    since = epoch - datetime(1970, 1, 1, tzinfo=timezone.utc)   # exact integer arithmetic, no float
    epoch_ns = (since.days * 86400 + since.seconds) * 1_000_000_000 + since.microseconds * 1000
    rng = np.random.default_rng(seed)

    planned: list[tuple[str, str, np.ndarray, list]] = []
    used_topics: set[str] = set()
    for role in roles:
        topic = overrides.get(role, _default_topic(role))
        if topic in used_topics:
            raise SimError(f"topic {topic!r}: expected one role per topic, found a second ({role.text()})")
        used_topics.add(topic)
        msgtype, st, msgs = _messages(log, role, builder, epoch_ns)
        if msgs:
            planned.append((topic, msgtype, st, msgs))
    if not planned:
        raise SimError(f"{log.source}: expected samples to write, found empty channels")

    records: list[tuple[int, int, int, Any]] = []   # (receive ns, plan index, order, message)
    for i, (_, msgtype, st, msgs) in enumerate(planned):
        recv = st + np.round((receive_latency + receive_jitter * rng.random(len(st))) * 1e9).astype(np.int64)
        records += [(int(recv[k]), i, k, msgs[k]) for k in range(len(msgs))]
    records.sort(key=lambda r: (r[0], r[1], r[2]))

    target.parent.mkdir(parents=True, exist_ok=True)
    tmpdir = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent))
    try:
        # Inside the temporary folder the bag has its final name, so a ROS 2 storage file
        # (named after its directory) and metadata.yaml need no rewriting after the rename.
        inner = tmpdir / (target.name if ros1 or not bare else target.stem)
        _write(inner, version, typestore, planned, records)
        built = inner if ros1 or not bare else inner / f"{target.stem}{_SUFFIX_FILES[version]}"
        if target.is_dir():
            # os.replace cannot replace a non-empty directory: move the old bag aside first.
            os.replace(target, tmpdir / "previous")
        os.replace(built, target)
    finally:
        shutil.rmtree(tmpdir, ignore_errors=True)
    return target


def _write(inner: Path, version: str, typestore: Any, planned: list, records: list) -> None:
    if version == "ros1":
        from rosbags.rosbag1 import Writer as Writer1

        writer = Writer1(inner)
        serialize = typestore.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer as Writer2

        plugin = StoragePlugin.MCAP if version == "ros2-mcap" else StoragePlugin.SQLITE3
        writer = Writer2(inner, version=Writer2.VERSION_LATEST, storage_plugin=plugin)
        serialize = typestore.serialize_cdr
    with writer:
        conns = [writer.add_connection(topic, msgtype, typestore=typestore) for topic, msgtype, _, _ in planned]
        for recv_ns, i, _, msg in records:
            writer.write(conns[i], recv_ns, bytes(serialize(msg, planned[i][1])))
