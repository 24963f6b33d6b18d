"""ROS 1 / ROS 2 bag reader and simulator writer: round trips, frames, custom types, bad input, fuzz.

Bags are written with rosbags' own writers; the frame and custom-type tests build their bags by
hand with rosbags (not with the pipeline's writer), so reader and writer are not only checked
against each other.
"""

from __future__ import annotations

import hashlib
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin, Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from pipeline.errors import IngestError, SimError
from pipeline.ingest.rosbag import (VARIABLE_MAP, enu_flu_to_ned_frd, euler_to_quat, looks_like_rosbag,
                                    ned_frd_to_enu_flu, quat_to_euler, read_rosbag)
from pipeline.records import Channel, IngestSummary, RawLog
from pipeline.sim.manoeuvres import chain, rudder_step, step_and_coast
from pipeline.sim.simulate import simulate
from pipeline.sim.writers.rosbag import ACTUATORS_MSGTYPE, write_rosbag
from pipeline.vessel import load_vessel, parse_vessel

REPO = Path(__file__).resolve().parents[1]
EPOCH_NS = 1_714_903_200 * 10**9     # 2024-05-05 10:00 UTC, the writer's default epoch
ROS2 = ("ros2-sqlite3", "ros2-mcap")
ANGLES = ("phi", "theta", "psi", "cog")


def _wrap(a):
    return np.angle(np.exp(1j * np.asarray(a)))


def _sha(p: Path) -> str:
    files = sorted(p.rglob("*")) if p.is_dir() else [p]
    h = hashlib.sha256()
    for f in files:
        if f.is_file():
            h.update(f.name.encode() + f.read_bytes())
    return h.hexdigest()


def _bag_name(version: str) -> str:
    return "trial.bag" if version == "ros1" else "trial"


@pytest.fixture(scope="module")
def sim(aauship):
    vessel = aauship
    schedule = chain(step_and_coast("surge", 4.0, 3.0, 3.0), rudder_step(math.radians(10), 3.0, 3.0, {"tau_x": 3.0}),
                     rest_s=1.0)
    return simulate(vessel, schedule, seed=7)


@pytest.fixture(scope="module")
def short_sim(aauship):
    vessel = aauship
    return simulate(vessel, chain(rudder_step(math.radians(10), 1.5, 1.0, {"tau_x": 3.0}), rest_s=0.5), seed=11)


def _assert_same(log: RawLog, truth: RawLog, names=None) -> None:
    for name in names or truth.channels:
        got, want = log.channels[name], truth.channels[name]
        assert len(got.t) == len(want.t), name
        # Header stamps are integer ns: times agree to float precision, not to the receive time.
        np.testing.assert_allclose(got.t, want.t - min(c.t[0] for c in truth.channels.values()), atol=2e-9,
                                   err_msg=name)
        diff = got.values - want.values
        if name.split("@")[0] in ANGLES:
            diff = _wrap(diff)
        assert np.max(np.abs(diff)) < 1e-9, name


# ------------------------------------------------------------------------------ round trips
@pytest.mark.parametrize("version", ["ros1", *ROS2])
def test_round_trip_sim(sim, tmp_path, version):
    path = write_rosbag(sim.log, tmp_path / _bag_name(version), version=version)
    assert looks_like_rosbag(path) and not looks_like_rosbag(tmp_path)
    before = _sha(path)
    log = read_rosbag(path)
    assert _sha(path) == before, "the reader must not change its input"
    assert log.format == ("rosbag1" if version == "ros1" else "rosbag2")
    assert log.time_reference == "unix"
    _assert_same(log, sim.log)
    # The rudder feedback topic (Float64, no header) comes back on receive time: later than the
    # stamp by the writer's latency (5 ms) plus jitter (up to 2 ms), and renamed after the
    # actuator message's delta, which has header stamps and keeps the plain name.
    rud, cmd = log.channels["delta@rudder"], sim.log.channels["delta"]
    np.testing.assert_array_equal(rud.values, cmd.values)
    lag = rud.t - (cmd.t - cmd.t[0])
    assert np.all((lag >= 0.005 - 1e-9) & (lag <= 0.007 + 1e-9))
    text = " | ".join(log.summary.warnings)
    assert "timed by bag receive time" in text and f"/rudder/angle {len(cmd.t)}" in text
    assert "kept as delta@rudder" in text
    assert "roles inferred from message types" in text and "/gps/fix -> navsatfix@gps" in text
    assert log.summary.read["sensor_msgs/msg/Imu"] == len(sim.log.channels["p"].t)
    assert log.summary.read[ACTUATORS_MSGTYPE] == len(sim.log.channels["tau_x"].t)
    assert "2024-05-05T10:00:00" in log.summary.warnings[0]


@pytest.mark.parametrize("version,suffix", [("ros2-sqlite3", ".db3"), ("ros2-mcap", ".mcap")])
def test_round_trip_bare_storage_file(short_sim, tmp_path, version, suffix):
    path = write_rosbag(short_sim.log, tmp_path / f"run{suffix}", version=version)
    assert path.is_file() and list(tmp_path.iterdir()) == [path]     # no temporary left behind
    _assert_same(read_rosbag(path, progress=True), short_sim.log)


def test_writer_replaces_existing_bag_atomically(short_sim, tmp_path):
    path = write_rosbag(short_sim.log, tmp_path / "trial", version="ros2-mcap")
    path2 = write_rosbag(short_sim.log, tmp_path / "trial", version="ros2-sqlite3")
    assert path2 == path and sorted(f.name for f in path.iterdir()) == ["metadata.yaml", "trial.db3"]
    assert [f.name for f in tmp_path.iterdir()] == ["trial"]
    _assert_same(read_rosbag(path), short_sim.log)
    (tmp_path / "notabag").mkdir()
    (tmp_path / "notabag" / "precious.txt").write_text("keep me")
    with pytest.raises(SimError, match="without metadata.yaml"):
        write_rosbag(short_sim.log, tmp_path / "notabag")
    assert (tmp_path / "notabag" / "precious.txt").read_text() == "keep me"


def test_writer_rejects_bad_arguments(short_sim, tmp_path):
    with pytest.raises(SimError, match="version: expected one of"):
        write_rosbag(short_sim.log, tmp_path / "x", version="ros3")
    with pytest.raises(SimError, match=r"ending in \.bag"):
        write_rosbag(short_sim.log, tmp_path / "x.db3", version="ros1")
    with pytest.raises(SimError, match=r"ending in \.mcap"):
        write_rosbag(short_sim.log, tmp_path / "x.db3", version="ros2-mcap")
    with pytest.raises(SimError, match="role 'gyro'"):
        write_rosbag(short_sim.log, tmp_path / "x", topics={"/a": "gyro"})
    assert list(tmp_path.iterdir()) == []


def test_odometry_and_float64_channels_round_trip(tmp_path):
    # Channels the simulator does not produce: body velocity, local position and roll/pitch
    # moments go through nav_msgs/Odometry and std_msgs/Float64 topics.
    t = np.arange(0, 2.0, 0.02)
    vals = {"x_n": 3.0 * t, "y_e": -1.0 * t, "u": 1.5 + 0 * t, "v": 0.1 * np.sin(t), "w": 0.01 * t,
            "tau_k": 0.2 * np.cos(t), "tau_m@port": 0.3 + 0 * t}
    chans = {n: Channel(n, t, v) for n, v in vals.items()}
    log = RawLog("hand", "sim", chans, IngestSummary("hand", "sim"))
    for version in ("ros1", "ros2-sqlite3"):
        path = write_rosbag(log, tmp_path / _bag_name(version), version=version, receive_jitter=0.0)
        back = read_rosbag(path)
        for n in ("x_n", "y_e", "u", "v", "w"):
            np.testing.assert_allclose(back.channels[n].values, vals[n], atol=1e-12)
            np.testing.assert_allclose(back.channels[n].t, t, atol=2e-9)
        # Float64 topics carry no stamp: receive time = stamp + 5 ms.
        np.testing.assert_allclose(back.channels["tau_k"].values, vals["tau_k"])
        np.testing.assert_allclose(back.channels["tau_k"].t, t + 0.005, atol=2e-9)
        np.testing.assert_allclose(back.channels["tau_m@port"].values, vals["tau_m@port"])
        assert "phi" not in back.channels          # NaN orientation in the odometry: not a channel
        assert "no attitude channel" in " | ".join(back.summary.warnings)


# ------------------------------------------------------------------------------ frames
def _rot(axis: str, a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def _quat_to_matrix(q) -> np.ndarray:
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def test_frame_conversion_heading_north_east_rolled_to_starboard():
    phi, theta, psi = math.radians(10), math.radians(5), math.radians(45)   # NE, starboard down, bow up
    q_enu_flu = ned_frd_to_enu_flu(euler_to_quat(phi, theta, psi))
    r_enu_flu = _quat_to_matrix(q_enu_flu)
    # Independent construction from matrices: R_enu_flu = T_enu_ned R_ned_frd T_frd_flu.
    t_enu_ned = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]])
    t_frd_flu = np.diag([1, -1, -1])
    r_ned_frd = _rot("z", psi) @ _rot("y", theta) @ _rot("x", phi)
    np.testing.assert_allclose(r_enu_flu, t_enu_ned @ r_ned_frd @ t_frd_flu, atol=1e-12)
    # And from ROS's own Euler angles: yaw_enu = pi/2 - psi, roll_flu = phi, pitch_flu = -theta.
    np.testing.assert_allclose(r_enu_flu, _rot("z", math.pi / 2 - psi) @ _rot("y", -theta) @ _rot("x", phi),
                               atol=1e-12)
    # Physical check in ENU: the bow points north-east and up; the starboard side is down.
    bow = r_enu_flu @ [1, 0, 0]
    starboard = r_enu_flu @ [0, -1, 0]
    assert bow[0] > 0 and bow[1] > 0 and bow[0] == pytest.approx(bow[1]) and bow[2] == pytest.approx(math.sin(theta))
    assert starboard[2] < 0 and starboard[2] == pytest.approx(-math.sin(phi) * math.cos(theta))
    # Back again.
    back = quat_to_euler(enu_flu_to_ned_frd(q_enu_flu))
    np.testing.assert_allclose(back, (phi, theta, psi), atol=1e-12)


def _hand_bag(path: Path, version: str, topics: list[tuple[str, str, list[tuple[int, object]]]],
              extra_types: str = "", extra_name: str = "") -> Path:
    """A bag written directly with rosbags: topics = [(topic, msgtype, [(receive ns, message)])]."""
    ros1 = version == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if extra_types:
        store.register(get_types_from_msg(extra_types, extra_name))
    if ros1:
        writer = Writer1(path)
    else:
        writer = Writer2(path, version=9,
                         storage_plugin=StoragePlugin.MCAP if version == "ros2-mcap" else StoragePlugin.SQLITE3)
    ser = store.serialize_ros1 if ros1 else store.serialize_cdr
    with writer:
        conns = [writer.add_connection(t, mt, typestore=store) for t, mt, _ in topics]
        for (topic, mt, msgs), con in zip(topics, conns):
            for ns, msg in msgs:
                writer.write(con, ns, bytes(ser(msg, mt)))
    return path


def _types(version: str):
    return get_typestore(Stores.ROS1_NOETIC if version == "ros1" else Stores.ROS2_HUMBLE).types


def _header(T, version: str, ns: int, frame: str = "imu_link"):
    stamp = T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
    if version == "ros1":
        return T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
    return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def _imu(T, version, ns, q, w=(0.0, 0.0, 0.1), a=(0.0, 0.0, 9.81)):
    V = T["geometry_msgs/msg/Vector3"]
    return T["sensor_msgs/msg/Imu"](
        header=_header(T, version, ns), orientation=T["geometry_msgs/msg/Quaternion"](w=q[0], x=q[1], y=q[2], z=q[3]),
        orientation_covariance=np.zeros(9), angular_velocity=V(x=w[0], y=w[1], z=w[2]),
        angular_velocity_covariance=np.zeros(9), linear_acceleration=V(x=a[0], y=a[1], z=a[2]),
        linear_acceleration_covariance=np.zeros(9))


@pytest.mark.parametrize("version", ["ros1", "ros2-mcap"])
def test_hand_made_imu_and_twist_convert_from_enu_flu(tmp_path, version):
    T = _types(version)
    # ROS orientation of a boat heading north-east (ENU yaw 45 deg), rolled 10 deg to starboard
    # (FLU roll +10: left side up) and bow up 5 deg (FLU pitch -5), built from ROS's own RPY.
    roll, pitch, yaw = math.radians(10), math.radians(-5), math.radians(45)
    cr, sr, cp, sp, cy, sy = (math.cos(roll / 2), math.sin(roll / 2), math.cos(pitch / 2), math.sin(pitch / 2),
                              math.cos(yaw / 2), math.sin(yaw / 2))
    q = (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
         cr * cp * sy - sr * sp * cy)
    V = T["geometry_msgs/msg/Vector3"]
    twist = T["geometry_msgs/msg/Twist"]
    imu = [(EPOCH_NS + k * 10**7 + 3 * 10**6, _imu(T, version, EPOCH_NS + k * 10**7, q)) for k in range(5)]
    # ENU ground velocity 1 m/s east, 1 m/s north: 1.414 m/s, course 45 deg.
    vel = [(EPOCH_NS + k * 10**8 + 10**6, T["geometry_msgs/msg/TwistStamped"](
        header=_header(T, version, EPOCH_NS + k * 10**8, "gps"), twist=twist(linear=V(x=1.0, y=1.0, z=0.0),
                                                                             angular=V(x=0.0, y=0.0, z=0.0))))
           for k in range(3)]
    # Body-frame twist (base_link, FLU): forward 2 m/s, drifting left 0.1 m/s, yawing left.
    body = [(EPOCH_NS + k * 10**8 + 10**6, T["geometry_msgs/msg/TwistStamped"](
        header=_header(T, version, EPOCH_NS + k * 10**8, "base_link"),
        twist=twist(linear=V(x=2.0, y=0.1, z=0.0), angular=V(x=0.0, y=0.0, z=0.2)))) for k in range(3)]
    path = _hand_bag(tmp_path / _bag_name(version), version,
                     [("/imu/data", "sensor_msgs/msg/Imu", imu), ("/gps/vel", "geometry_msgs/msg/TwistStamped", vel),
                      ("/body/vel", "geometry_msgs/msg/TwistStamped", body)])
    log = read_rosbag(path)
    np.testing.assert_allclose(log.channels["psi"].values, math.radians(45), atol=1e-12)
    np.testing.assert_allclose(log.channels["phi"].values, math.radians(10), atol=1e-12)     # starboard down
    np.testing.assert_allclose(log.channels["theta"].values, math.radians(5), atol=1e-12)    # bow up
    np.testing.assert_allclose(log.channels["r"].values, -0.1)   # ROS +z (to port) is NED -r
    np.testing.assert_allclose(log.channels["az"].values, -9.81)  # specific force at rest: -g in z down
    np.testing.assert_allclose(log.channels["sog"].values, math.sqrt(2))
    np.testing.assert_allclose(log.channels["cog"].values, math.radians(45))
    # Header stamps, not receive time (3 ms late for the IMU).
    np.testing.assert_allclose(log.channels["psi"].t, np.arange(5) * 0.01, atol=1e-12)
    # Two inferred twist topics with equal counts: the shorter name keeps plain channel names,
    # the other is suffixed with its namespace. The body twist gives body velocities.
    np.testing.assert_allclose(log.channels["u@body"].values, 2.0)
    np.testing.assert_allclose(log.channels["v@body"].values, -0.1)   # drifting left is negative sway
    np.testing.assert_allclose(log.channels["r@body"].values, -0.2)
    assert "/body/vel -> twist@body" in " | ".join(log.summary.warnings)


def test_parts_flagged_absent_keep_samples_aligned(tmp_path):
    version = "ros2-sqlite3"
    T = _types(version)
    q = euler_to_quat(0.0, 0.0, 0.3)
    q_enu = ned_frd_to_enu_flu(q)
    imu = []
    for k in range(5):
        msg = _imu(T, version, EPOCH_NS + k * 10**7, q_enu, w=(0.0, 0.0, 0.01 * k))
        if k == 2:   # REP-145: orientation not provided in this message
            msg.orientation_covariance[0] = -1.0
        imu.append((EPOCH_NS + k * 10**7 + 10**6, msg))
    path = _hand_bag(tmp_path / "imu", version, [("/imu/data", "sensor_msgs/msg/Imu", imu)])
    log = read_rosbag(path)
    np.testing.assert_allclose(log.channels["psi"].t, [0.0, 0.01, 0.03, 0.04], atol=1e-12)
    np.testing.assert_allclose(log.channels["psi"].values, 0.3, atol=1e-12)
    np.testing.assert_allclose(log.channels["r"].t, np.arange(5) * 0.01, atol=1e-12)
    np.testing.assert_allclose(log.channels["r"].values, -0.01 * np.arange(5), atol=1e-15)
    assert log.summary.skipped["sensor_msgs/msg/Imu psi not available"] == 1


# ------------------------------------------------------------------------------ custom type
CUSTOM_MSGDEF = """\
std_msgs/Header header
float64 delta
float64 tau_x
string note
"""


@pytest.mark.parametrize("version", ["ros1", *ROS2])
def test_custom_message_type_read_without_being_told(tmp_path, version, short_sim):
    # The pipeline's own actuator type: stored in the bag by the writer ...
    path = write_rosbag(short_sim.log, tmp_path / _bag_name(version), version=version)
    store = get_typestore(Stores.ROS1_NOETIC if version == "ros1" else Stores.ROS2_HUMBLE)
    assert ACTUATORS_MSGTYPE not in store.fielddefs
    with AnyReader([path]) as reader:
        con = next(c for c in reader.connections if c.msgtype == ACTUATORS_MSGTYPE)
        assert "float64 tau_x" in con.msgdef.data and "float64 delta" in con.msgdef.data
    log = read_rosbag(path)
    np.testing.assert_array_equal(log.channels["tau_x"].values, short_sim.log.channels["tau_x"].values)
    # ... and a type nobody here has heard of, written by hand, found by its field names.
    name = "harbour_msgs/msg/Helm"
    own = get_typestore(Stores.ROS1_NOETIC if version == "ros1" else Stores.ROS2_HUMBLE)
    own.register(get_types_from_msg(CUSTOM_MSGDEF, name))
    msgs = [(EPOCH_NS + k * 10**8 + 10**6, own.types[name](
        header=_header(own.types, version, EPOCH_NS + k * 10**8, "base_link"), delta=0.1 * k, tau_x=2.0, note="x"))
        for k in range(4)]
    path2 = _hand_bag(tmp_path / ("helm.bag" if version == "ros1" else "helm"), version, [("/helm", name, msgs)],
                      CUSTOM_MSGDEF, name)
    log2 = read_rosbag(path2)
    np.testing.assert_allclose(log2.channels["delta"].values, [0.0, 0.1, 0.2, 0.3])
    np.testing.assert_allclose(log2.channels["tau_x"].t, [0.0, 0.1, 0.2, 0.3], atol=1e-12)
    assert "/helm -> actuators" in " | ".join(log2.summary.warnings)


# ------------------------------------------------------------------------------ topic map
def test_topic_map_override_from_vessel_config(sim, tmp_path):
    topics = {"/boat/ahrs": "imu", "/boat/rtk/fix": "navsatfix@rtk", "/boat/ekf/fix": "navsatfix",
              "/boat/rtk/vel": "twist@rtk", "/boat/ekf/vel": "twist", "/boat/helm": "actuators",
              "/boat/rudder_fb": "rudder@fb"}
    vessel = parse_vessel({"name": "boat", "topics": topics})
    # The simulator's @gps channels are written where the map puts its @rtk roles.
    gps_as_rtk = RawLog(sim.log.source, "sim",
                        {n.replace("@gps", "@rtk"): Channel(n.replace("@gps", "@rtk"), c.t, c.values)
                         for n, c in sim.log.channels.items()}, sim.log.summary)
    path = write_rosbag(gps_as_rtk, tmp_path / "mapped", version="ros2-mcap", topics=topics)
    with AnyReader([path]) as reader:
        assert {c.topic for c in reader.connections} >= {"/boat/ahrs", "/boat/rtk/fix", "/boat/ekf/fix", "/boat/helm"}
    log = read_rosbag(path, topics=vessel.extra["topics"])
    _assert_same(log, gps_as_rtk)
    assert "roles inferred" not in " | ".join(log.summary.warnings)
    # The rudder role from the map with its own suffix: no rename needed.
    assert "delta@fb" in log.channels and "kept as" not in " | ".join(log.summary.warnings)
    # Without the map the roles are inferred from the types, the names differ and it is said so.
    inferred = read_rosbag(path)
    assert "roles inferred from message types" in inferred.summary.warnings[1]
    assert "lat@boat" in inferred.channels        # second NavSatFix topic, named from its namespace
    # A map can also switch a topic off or override only part of the inference.
    partial = read_rosbag(path, topics={"/boat/rtk/fix": "ignore", "/boat/ekf/fix": "navsatfix@ekf"})
    assert "lat@ekf" in partial.channels and "lat@rtk" not in partial.channels
    assert partial.summary.skipped["sensor_msgs/msg/NavSatFix"] == len(sim.log.channels["lat@gps"].t)
    # Map entries for topics the bag lacks, and roles that do not fit the type, are reported.
    odd = read_rosbag(path, topics={"/not/there": "imu", "/boat/helm": "navsatfix"})
    text = " | ".join(odd.summary.warnings)
    assert "not in the bag: /not/there" in text and "does not fit its type" in text


def test_bad_topic_map_entries(short_sim, tmp_path):
    path = write_rosbag(short_sim.log, tmp_path / "trial", version="ros2-sqlite3")
    with pytest.raises(IngestError, match=r"role 'gyro': expected one of"):
        read_rosbag(path, topics={"/imu/data": "gyro"})
    with pytest.raises(IngestError, match=r"float64:<channel>.*found 'speed'"):
        read_rosbag(path, topics={"/x": "float64:speed"})
    with pytest.raises(IngestError, match="sensor suffix"):
        read_rosbag(path, topics={"/x": "imu@a b"})


# ------------------------------------------------------------------------------ time handling
def test_out_of_order_zero_and_foreign_stamps(tmp_path):
    version = "ros2-sqlite3"
    T = _types(version)
    q = (1.0, 0.0, 0.0, 0.0)
    stamps_ms = [0, 10, 10, 5, 20, 30]       # a repeat and a step back
    imu = [(EPOCH_NS + k * 10**7 + 10**6, _imu(T, version, EPOCH_NS + s * 10**6, q)) for k, s in enumerate(stamps_ms)]
    zero = [(EPOCH_NS + k * 10**7 + 2 * 10**6, _imu(T, version, 0 if k == 2 else EPOCH_NS + k * 10**7, q))
            for k in range(4)]
    # A device clock that counts from boot: stamps ~100 s while the others are wall clock.
    boot = [(EPOCH_NS + k * 10**7 + 10**6, _imu(T, version, 100 * 10**9 + k * 10**7, q)) for k in range(4)]
    path = _hand_bag(tmp_path / "stamps", version, [("/imu/data", "sensor_msgs/msg/Imu", imu),
                                                     ("/imu2/data", "sensor_msgs/msg/Imu", zero),
                                                     ("/imu3/data", "sensor_msgs/msg/Imu", boot)],)
    log = read_rosbag(path, topics={"/imu2/data": "imu@two", "/imu3/data": "imu@three"})
    np.testing.assert_allclose(log.channels["psi"].t, [0.0, 0.01, 0.02, 0.03], atol=1e-12)
    np.testing.assert_allclose(log.channels["psi@two"].t, [0.0, 0.01, 0.03], atol=1e-12)
    # Foreign clock: timed by receive time (1 ms after the wall-clock grid).
    np.testing.assert_allclose(log.channels["psi@three"].t, np.arange(4) * 0.01 + 0.001, atol=1e-12)
    sk = log.summary.skipped
    assert sk["sensor_msgs/msg/Imu repeated or out-of-order stamp"] == 2
    assert sk["sensor_msgs/msg/Imu zero stamp"] == 1
    text = " | ".join(log.summary.warnings)
    assert "/imu/data: 2 repeated or out-of-order header stamp(s) dropped" in text
    assert "/imu2/data: 1 message(s) with a zero header stamp" in text
    assert "/imu3/data: header stamps are" in text and "another clock" in text


def test_empty_topics_and_missing_channel_types_are_warned(tmp_path):
    version = "ros1"
    T = _types(version)
    fix = [(EPOCH_NS + k * 10**8, T["sensor_msgs/msg/NavSatFix"](
        header=_header(T, version, EPOCH_NS + k * 10**8, "gps"),
        status=T["sensor_msgs/msg/NavSatStatus"](status=-1 if k == 1 else 0, service=1),
        latitude=57.0 + 1e-5 * k, longitude=9.9, altitude=0.0, position_covariance=np.zeros(9),
        position_covariance_type=0)) for k in range(3)]
    path = _hand_bag(tmp_path / "gps.bag", version, [("/gps/fix", "sensor_msgs/msg/NavSatFix", fix),
                                                     ("/imu/data", "sensor_msgs/msg/Imu", []),
                                                     ("/chatter", "std_msgs/msg/String", [])])
    log = read_rosbag(path)
    np.testing.assert_allclose(log.channels["lat"].values, [57.0, 57.00002])
    text = " | ".join(log.summary.warnings)
    assert "2 topic(s) without messages: /chatter, /imu/data" in text
    assert "1 fix(es) with status NO_FIX" in text
    for group in ("attitude", "angular rate", "velocity", "input"):
        assert f"no {group} channel" in text
    assert "topics with no role skipped" not in text     # /chatter had no messages to skip


# ------------------------------------------------------------------------------ bad input
def test_errors_name_expected_and_found(tmp_path, short_sim):
    with pytest.raises(IngestError, match="expected a ROS 1 .bag file or a ROS 2 bag.*found nothing"):
        read_rosbag(tmp_path / "missing.bag")
    (tmp_path / "empty.bag").write_bytes(b"")
    with pytest.raises(IngestError, match="found an empty file"):
        read_rosbag(tmp_path / "empty.bag")
    (tmp_path / "text.bag").write_text("this is not a bag\n")
    with pytest.raises(IngestError, match="not a bag or damaged"):
        read_rosbag(tmp_path / "text.bag")
    (tmp_path / "adir").mkdir()
    with pytest.raises(IngestError, match="directory without metadata.yaml"):
        read_rosbag(tmp_path / "adir")
    ros1 = write_rosbag(short_sim.log, tmp_path / "real.bag", version="ros1")
    shutil.copy(ros1, tmp_path / "real.dat")
    with pytest.raises(IngestError, match=r"extension '.dat' \(its content is a .bag bag"):
        read_rosbag(tmp_path / "real.dat")
    T = _types("ros2-sqlite3")
    no_msgs = _hand_bag(tmp_path / "nomsgs", "ros2-sqlite3", [("/imu/data", "sensor_msgs/msg/Imu", [])])
    with pytest.raises(IngestError, match=r"expected messages, found an empty bag \(1 topic"):
        read_rosbag(no_msgs)
    chatter = _hand_bag(tmp_path / "chatter", "ros2-sqlite3",
                        [("/chatter", "std_msgs/msg/String", [(EPOCH_NS, T["std_msgs/msg/String"](data="hi"))])])
    with pytest.raises(IngestError, match=r"expected at least one topic with a role.*found only /chatter"):
        read_rosbag(chatter)
    (tmp_path / "yaml").mkdir()
    (tmp_path / "yaml" / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
    with pytest.raises(IngestError, match="cannot be opened"):
        read_rosbag(tmp_path / "yaml")


# ------------------------------------------------------------------------------ fuzz
def _storage_file(path: Path) -> Path:
    return path if path.is_file() else next(f for f in path.iterdir() if f.suffix in (".db3", ".mcap"))


@pytest.mark.parametrize("version", ["ros1", *ROS2])
def test_fuzz_truncated_and_corrupted_bags(short_sim, tmp_path, version):
    src = write_rosbag(short_sim.log, tmp_path / ("src.bag" if version == "ros1" else "src"), version=version)
    data = _storage_file(src).read_bytes()
    rng = np.random.default_rng({"ros1": 1, "ros2-sqlite3": 2, "ros2-mcap": 3}[version])
    outcomes = {"ok": 0, "error": 0}
    for k in range(16):
        case = tmp_path / f"case{k}"
        case.mkdir()
        if src.is_dir():
            bag = case / "bag"
            shutil.copytree(src, bag)
            target = _storage_file(bag)
        else:
            bag = target = case / "bag.bag"
        buf = bytearray(data)
        if k % 2 == 0:
            buf = buf[: int(rng.integers(0, len(buf)))]
        else:
            for i in rng.integers(0, len(buf), int(rng.integers(1, 200))):
                buf[i] = int(rng.integers(0, 256))
        target.write_bytes(bytes(buf))
        if src.is_dir() and k % 4 == 3:
            meta = bag / "metadata.yaml"
            text = meta.read_bytes()
            cut = int(rng.integers(0, len(text)))
            meta.write_bytes(text[:cut] + bytes(rng.integers(0, 256, 8, dtype=np.uint8)) + text[cut + 8:])
        before = _sha(bag)
        try:
            log = read_rosbag(bag)
        except IngestError as exc:
            assert "expected" in str(exc)
            outcomes["error"] += 1
        else:
            outcomes["ok"] += 1
            for ch in log.channels.values():
                assert np.all(np.diff(ch.t) > 0) and np.all(np.isfinite(ch.values))
        assert _sha(bag) == before, "the reader must not change its input"
    assert outcomes["error"] > 0


def test_variable_map_signs_follow_rep103():
    assert VARIABLE_MAP[("imu", "angular_velocity.z")] == ("r", -1.0)
    assert VARIABLE_MAP[("odometry", "pose.pose.position.y")] == ("x_n", 1.0)
    assert VARIABLE_MAP[("twist_body", "linear.y")] == ("v", -1.0)


@pytest.mark.parametrize("version", ["ros1", "ros2-sqlite3"])
def test_rudder_feedback_topic_is_measured_and_a_command_topic_is_held(tmp_path, version):
    # A servo's angle sensor is a continuous signal (interpolated by align), the order sent to it is
    # held until the next one: the topic name tells them apart, the summary says which was taken.
    from pipeline.align import align

    T = _types(version)
    ns = [10**9 + k * 10**8 for k in range(40)]                      # 10 Hz
    cmd = [0.0] * 10 + [0.2] * 30                                     # a step order
    meas = [min(0.2, max(0.0, 0.05 * (k - 10))) for k in range(40)]  # the servo's ramp
    imu = [(n, _imu(T, version, n, (1.0, 0.0, 0.0, 0.0))) for n in ns]
    bag = _hand_bag(tmp_path / _bag_name(version), version, [
        ("/imu/data", "sensor_msgs/msg/Imu", imu),
        ("/rudder/cmd", "std_msgs/msg/Float64", [(n, T["std_msgs/msg/Float64"](data=v)) for n, v in zip(ns, cmd)]),
        ("/rudder/feedback", "std_msgs/msg/Float64",
         [(n, T["std_msgs/msg/Float64"](data=v)) for n, v in zip(ns, meas)])])
    log = read_rosbag(bag)
    kinds = {name: ch.input_kind for name, ch in log.channels.items() if name.startswith("delta")}
    assert sorted(kinds.values()) == ["", "measured"], kinds
    fb = next(name for name, kind in kinds.items() if kind == "measured")
    assert log.channels[fb].source.startswith("/rudder/feedback")
    assert any("/rudder/feedback" in w and "measured actuator state" in w for w in log.summary.warnings)
    # On a grid finer than the log, the measured ramp is interpolated and the order held.
    trial = align([log], fs=50.0)
    d = trial.data
    t, held, ramp = d["t"].to_numpy(), d[next(n for n, k in kinds.items() if k == "")].to_numpy(), d[fb].to_numpy()
    mid = np.argmin(abs(t - (t[0] + 1.25)))                           # between two 10 Hz samples of the ramp
    assert 0.0 < ramp[mid] < 0.2 and ramp[mid] not in meas
    assert set(np.round(held[np.isfinite(held)], 12)) <= {0.0, 0.2}


def test_topic_names_that_mark_a_measured_actuator_state():
    from pipeline.ingest.rosbag import _input_kind

    for topic in ("/rudder/feedback", "/rudder_state", "/boat/rudder/angle_measured", "/servo/actual", "/rudder/fb"):
        assert _input_kind(topic) == "measured", topic
    for topic in ("/rudder/angle", "/rudder/cmd", "/cmd_rudder", "/vesselid/tau_x", "/statesman/rudder"):
        assert _input_kind(topic) == "", topic
