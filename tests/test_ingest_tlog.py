"""MAVLink .tlog writer and reader: round trips through real pymavlink frames, and bad input.

Every file is written into ``tmp_path``: either by ``write_tlog`` from a hand-built RawLog, or
record by record with pymavlink's generated dialect (for the malformed cases).
"""

from __future__ import annotations

import math
import os
import struct

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from pipeline.errors import IngestError, SimError
from pipeline.ingest.mavlink_tlog import VARIABLE_MAP, read_tlog
from pipeline.records import Channel, IngestSummary, RawLog
from pipeline.sim.writers.tlog import write_tlog
from pipeline.terminal import want_progress
from pipeline.vessel import ActuatorMap, Vessel

BOOT_OFFSET = 5.0  # [s], write_tlog's default boot_offset_ms / 1000
WALL_START = 1714903200.0  # 2024-05-05 10:00 UTC [s]
G0 = 9.80665

DELTA_MAP = ActuatorMap("servo", 1, "delta", pwm_trim=1500, pwm_span=400, full_scale=0.6, reverse_scale=0.6)
THRUST_MAP = ActuatorMap("servo", 3, "tau_x", pwm_trim=1500, pwm_span=400, full_scale=20.0, reverse_scale=10.0)
VESSEL = Vessel(name="testboat", actuators=(DELTA_MAP, THRUST_MAP))


def _wrap(a):
    return math.pi - np.mod(math.pi - np.asarray(a, float), 2 * math.pi)


def _angle_diff(a, b):
    return np.abs(_wrap(np.asarray(a) - np.asarray(b)))


def _log(channels: dict[str, tuple[np.ndarray, np.ndarray]]) -> RawLog:
    ch = {n: Channel(n, np.asarray(t, float), np.asarray(v, float), "sim") for n, (t, v) in channels.items()}
    return RawLog(source="hand-built", format="sim", channels=ch, summary=IngestSummary("hand-built", "sim"))


def _trial(seed: int = 7, with_sog: bool = True) -> RawLog:
    """20 s of smooth analytic signals, each sensor at its own rate; psi crosses +-pi."""
    rng = np.random.default_rng(seed)
    ph = rng.uniform(0, 2 * np.pi, 8)
    t_att = np.arange(1000) * 0.02   # 50 Hz
    t_gps = np.arange(200) * 0.1     # 10 Hz
    t_imu = np.arange(2000) * 0.01   # 100 Hz
    t_srv = np.arange(1000) * 0.02   # 50 Hz
    w = 2 * np.pi / 20.0
    psi = np.pi + 0.6 * np.sin(w * t_att + ph[0])  # unwrapped on purpose: the writer must wrap it
    c = {
        "phi": (t_att, 0.12 * np.sin(1.3 * t_att + ph[1])),
        "theta": (t_att, 0.04 * np.cos(0.9 * t_att + ph[2])),
        "psi": (t_att, psi),
        "p": (t_att, 0.156 * np.cos(1.3 * t_att + ph[1])),
        "q": (t_att, -0.036 * np.sin(0.9 * t_att + ph[2])),
        "r": (t_att, 0.6 * w * np.cos(w * t_att + ph[0])),
        "lat": (t_gps, 56.98 + 1.5e-5 * t_gps + 2e-6 * np.sin(t_gps)),
        "lon": (t_gps, 10.12 - 2.5e-5 * t_gps),
        "u": (t_gps, 2.0 + 0.3 * np.sin(0.4 * t_gps)),
        "v": (t_gps, 0.2 * np.cos(0.4 * t_gps)),
        "ax": (t_imu, 0.3 * np.sin(0.7 * t_imu + ph[3]) + rng.normal(0, 0.05, t_imu.size)),
        "ay": (t_imu, 0.2 * np.cos(0.5 * t_imu + ph[4]) + rng.normal(0, 0.05, t_imu.size)),
        "az": (t_imu, -G0 + 0.4 * np.sin(1.1 * t_imu) + rng.normal(0, 0.05, t_imu.size)),
        "p@imu": (t_imu, 0.156 * np.cos(1.3 * t_imu + ph[1]) + rng.normal(0, 0.01, t_imu.size)),
        "q@imu": (t_imu, -0.036 * np.sin(0.9 * t_imu + ph[2]) + rng.normal(0, 0.01, t_imu.size)),
        "r@imu": (t_imu, 0.6 * w * np.cos(w * t_imu + ph[0]) + rng.normal(0, 0.01, t_imu.size)),
        "delta": (t_srv, 0.35 * np.sin(0.8 * t_srv + ph[5])),
        "tau_x": (t_srv, 12.0 * np.sin(0.3 * t_srv + ph[6])),  # crosses 0: forward and reverse scales
    }
    if with_sog:
        c["sog"] = (t_gps, 2.0 + 0.3 * np.sin(0.4 * t_gps))
        c["cog"] = (t_gps, np.pi - 0.3 + 0.6 * np.sin(0.25 * t_gps + ph[7]))  # crosses +-pi too
        for n in ("lat", "lon", "sog", "cog"):
            c[f"{n}@gps"] = c[n]
    return _log(c)


# --------------------------------------------------------------------------- hand-built records
_MAV = mav2.MAVLink(None, srcSystem=1, srcComponent=1)


def _record(msg, mav=_MAV, stamp_s: float = WALL_START) -> bytes:
    return struct.pack(">Q", round(stamp_s * 1e6)) + msg.pack(mav)


def _att(boot_ms: int, yaw: float = 0.5, mav=_MAV) -> bytes:
    return _record(mav.attitude_encode(boot_ms, 0.01, 0.02, yaw, 0.0, 0.0, 0.1), mav, WALL_START + boot_ms / 1000)


def _write(tmp_path, name: str, data: bytes):
    p = tmp_path / name
    p.write_bytes(data)
    return p


# --------------------------------------------------------------------------- round trip
@pytest.mark.parametrize("mavlink2", [True, False], ids=["mavlink2", "mavlink1"])
def test_round_trip_within_field_quantisation(tmp_path, mavlink2):
    log = _trial()
    path = write_tlog(log, tmp_path / "trial.tlog", VESSEL, mavlink2=mavlink2)
    data = path.read_bytes()
    assert data[8] == (0xFD if mavlink2 else 0xFE)
    assert sorted(os.listdir(tmp_path)) == ["trial.tlog"]  # atomic write leaves no temporary file

    raw = read_tlog(path, VESSEL)
    assert raw.time_reference == "boot" and raw.format == "tlog"
    assert set(raw.channels) == set(log.channels) - {"u", "v"} | {"sog", "cog"}
    assert dict(raw.summary.read) == {"ATTITUDE": 1000, "GLOBAL_POSITION_INT": 200, "GPS_RAW_INT": 200,
                                      "SCALED_IMU": 1000 * 2, "SERVO_OUTPUT_RAW": 1000, "SYSTEM_TIME": 20}
    assert dict(raw.summary.skipped) == {"HEARTBEAT": 20}
    # SYSTEM_TIME (UTC against boot time) puts the boot clock on UTC: boot was 5 s before the wall start.
    assert raw.start_time == pytest.approx(WALL_START - BOOT_OFFSET, abs=1e-6)
    assert raw.summary.warnings == ("t = 0 (boot) is 2024-05-05T09:59:55.000+00:00 UTC, from 20 SYSTEM_TIME "
                                    "message(s) (spread 0.0 ms)",)

    src = log.channels
    # Stamps are the boot clock (time_boot_ms / time_usec), not the wall-clock receive time.
    for name, ch in raw.channels.items():
        assert np.allclose(ch.t, src[name].t + BOOT_OFFSET, rtol=0, atol=1e-9), name
    expected_source = {"phi": "ATTITUDE", "lat": "GLOBAL_POSITION_INT", "lat@gps": "GPS_RAW_INT",
                       "ax": "SCALED_IMU", "p@imu": "SCALED_IMU", "delta": "SERVO_OUTPUT_RAW"}
    for name, s in expected_source.items():
        assert raw.channel(name).source == s

    def err(name):
        return np.abs(raw.channel(name).values - src[name].values)

    for name in ("phi", "theta", "p", "q", "r"):  # float32
        assert err(name).max() <= 4e-7, name
    assert _angle_diff(raw.channel("psi").values, src["psi"].values).max() <= 4e-7
    for name in ("lat", "lon", "lat@gps", "lon@gps"):  # degE7
        assert err(name).max() <= 0.5e-7 + 1e-12, name
    assert err("sog@gps").max() <= 0.005 + 1e-12                      # vel cm/s
    assert _angle_diff(raw.channel("cog@gps").values, src["cog@gps"].values).max() <= math.radians(0.005) + 1e-12
    # vx, vy each round to 1 cm/s: |d sog| <= 0.5 sqrt(2) cm/s, |d cog| <= that / sog.
    assert err("sog").max() <= 0.0071
    assert np.all(_angle_diff(raw.channel("cog").values, src["cog"].values) <= 0.0071 / src["sog"].values)
    for name in ("ax", "ay", "az"):  # 1 mG
        assert err(name).max() <= 0.5e-3 * G0 + 1e-12, name
    for name in ("p@imu", "q@imu", "r@imu"):  # 1 mrad/s
        assert err(name).max() <= 0.5e-3 + 1e-12, name
    # PWM 1 us: half a microsecond of the map's slope.
    assert err("delta").max() <= 0.5 * 0.6 / 400 + 1e-12
    assert err("tau_x").max() <= 0.5 * 20.0 / 400 + 1e-12
    assert raw.channel("tau_x").values.min() < 0 < raw.channel("tau_x").values.max()


def test_heading_wraps_to_minus_pi_pi(tmp_path):
    log = _trial(seed=3)
    raw = read_tlog(write_tlog(log, tmp_path / "h.tlog", VESSEL), VESSEL)
    psi = raw.channel("psi").values
    assert np.all((psi > -math.pi) & (psi <= math.pi))
    assert psi.max() > 3.0 and psi.min() < -3.0  # both sides of the +-pi cut are present
    jumps = np.abs(np.diff(psi))
    assert np.count_nonzero(jumps > math.pi) >= 2  # crossings appear as wraps, not as smoothed values
    assert np.count_nonzero(_angle_diff(psi[1:], psi[:-1]) > 0.05) == 0
    cog = raw.channel("cog@gps").values
    assert np.all((cog > -math.pi) & (cog <= math.pi)) and cog.max() > 3.0 and cog.min() < -3.0


def test_ground_velocity_from_body_u_v_and_heading(tmp_path):
    log = _trial(with_sog=False)
    raw = read_tlog(write_tlog(log, tmp_path / "uv.tlog", VESSEL), VESSEL)
    assert "lat@gps" not in raw.channels and "GPS_RAW_INT" not in raw.summary.read
    t = log.channels["lat"].t
    u, v = log.channels["u"].values, log.channels["v"].values
    psi = np.interp(t, log.channels["psi"].t, log.channels["psi"].values)
    sog = np.hypot(u, v)
    assert np.abs(raw.channel("sog").values - sog).max() <= 0.0071
    cog = psi + np.arctan2(v, u)  # course = heading + drift angle
    assert np.all(_angle_diff(raw.channel("cog").values, cog) <= 0.0071 / sog)


def test_file_is_a_real_tlog_with_wall_clock_receive_stamps(tmp_path, monkeypatch):
    from pymavlink import mavutil

    path = write_tlog(_trial(), tmp_path / "w.tlog", VESSEL, latency_s=0.03)
    # mavutil switches dialects through process-wide state; put it back after the test.
    monkeypatch.setenv("MAVLINK20", "1")
    monkeypatch.setattr(mavutil, "mavlink", mavutil.mavlink)
    monkeypatch.setattr(mavutil, "current_dialect", mavutil.current_dialect)
    conn = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    stamps, boots, yaws = [], [], []
    while (msg := conn.recv_match(type="ATTITUDE")) is not None:
        stamps.append(msg._timestamp)
        boots.append(msg.time_boot_ms)
        yaws.append(msg.yaw)
    conn.close()
    stamps, boots = np.array(stamps), np.array(boots)
    assert len(stamps) == 1000
    assert np.allclose(stamps, WALL_START + (boots / 1000 - BOOT_OFFSET) + 0.03, atol=2e-6)
    raw = read_tlog(path, VESSEL)
    assert raw.channel("phi").t[0] == pytest.approx(BOOT_OFFSET)  # boot clock, not 1.7e9
    assert np.array_equal(raw.channel("psi").t, boots / 1000)
    # Same field values as pymavlink's own decoder.
    assert _angle_diff(raw.channel("psi").values, yaws).max() == 0.0


def test_rc_channels_and_twin_thrusters(tmp_path):
    t = np.arange(200) * 0.05
    log = _log({"delta": (t, 0.3 * np.sin(t)), "tau_x": (t, 8.0 + 4.0 * np.cos(t))})
    vessel = Vessel(name="twin", actuators=(
        ActuatorMap("servo", 1, "tau_x", full_scale=10.0), ActuatorMap("servo", 3, "tau_x", full_scale=10.0),
        ActuatorMap("servo", 2, "delta", full_scale=0.6, reverse_scale=0.6),
        ActuatorMap("rc", 4, "delta", full_scale=0.6, reverse_scale=0.6)))
    raw = read_tlog(write_tlog(log, tmp_path / "rc.tlog", vessel), vessel)
    assert raw.channel("delta").source == "SERVO_OUTPUT_RAW"
    assert raw.channel("delta@rc").source == "RC_CHANNELS"
    assert raw.summary.read["RC_CHANNELS"] == 200
    assert np.abs(raw.channel("delta@rc").values - 0.3 * np.sin(t)).max() <= 0.5 * 0.6 / 400 + 1e-12
    # Two thrusters share tau_x half and half; the reader adds them back.
    assert np.abs(raw.channel("tau_x").values - (8.0 + 4.0 * np.cos(t))).max() <= 2 * 0.5 * 10.0 / 400 + 1e-12


def test_servo_time_usec_uint32_wrap_is_unwrapped(tmp_path):
    # SERVO_OUTPUT_RAW.time_usec is uint32: it wraps 4294.967296 s after boot.
    t = 4285.0 + np.arange(500) * 0.02
    log = _log({"delta": (t, 0.1 * np.sin(t))})
    rudder_only = Vessel(name="rudder", actuators=(DELTA_MAP,))
    raw = read_tlog(write_tlog(log, tmp_path / "wrap.tlog", rudder_only), rudder_only)
    assert np.allclose(raw.channel("delta").t, t + BOOT_OFFSET, rtol=0, atol=1e-6)
    assert raw.summary.read["SERVO_OUTPUT_RAW"] == 500
    assert [w for w in raw.summary.warnings if not w.startswith("t = 0 (boot) is")] == []


def test_variable_map_is_visible():
    assert VARIABLE_MAP[("ATTITUDE", "yaw")] == ("psi", 1.0)
    assert VARIABLE_MAP[("GLOBAL_POSITION_INT", "lat")] == ("lat", 1e-7)
    assert VARIABLE_MAP[("SCALED_IMU", "xacc")] == ("ax", pytest.approx(G0 / 1000))
    assert VARIABLE_MAP[("GPS_RAW_INT", "cog")] == ("cog@gps", pytest.approx(math.pi / 18000))


# --------------------------------------------------------------------------- writer errors
def test_writer_needs_actuator_map_for_inputs(tmp_path):
    log = _trial()
    with pytest.raises(SimError, match=r"input channels \['delta', 'tau_x'\] but no vessel"):
        write_tlog(log, tmp_path / "x.tlog")
    with pytest.raises(SimError, match=r"actuator map for input\(s\) \['tau_x'\]"):
        write_tlog(log, tmp_path / "x.tlog", Vessel(name="half", actuators=(DELTA_MAP,)))
    assert not any(tmp_path.iterdir())


def test_writer_rejects_bad_channels(tmp_path):
    bad_t = _log({"psi": (np.array([0.0, 0.1, 0.1]), np.zeros(3))})
    with pytest.raises(SimError, match=r"channel psi: expected strictly increasing t"):
        write_tlog(bad_t, tmp_path / "x.tlog")
    servo9 = Vessel(name="v", actuators=(ActuatorMap("servo", 9, "delta"),))
    log = _log({"delta": (np.arange(3) * 0.1, np.zeros(3))})
    with pytest.raises(SimError, match=r"expected channel 1..8 for delta \(MAVLink 1\), found channel 9"):
        write_tlog(log, tmp_path / "x.tlog", servo9, mavlink2=False)
    write_tlog(log, tmp_path / "ok.tlog", servo9, mavlink2=True)  # servo9_raw is a MAVLink 2 extension
    assert np.allclose(read_tlog(tmp_path / "ok.tlog", servo9).channel("delta").values, 0.0)


# --------------------------------------------------------------------------- reader: bad input
def test_missing_file(tmp_path):
    with pytest.raises(IngestError, match=r"expected a file, found nothing at .*nope\.tlog"):
        read_tlog(tmp_path / "nope.tlog")


def test_empty_file(tmp_path):
    p = _write(tmp_path, "empty.tlog", b"")
    with pytest.raises(IngestError, match=r"empty\.tlog: expected a MAVLink tlog .*, found an empty file \(0 bytes\)"):
        read_tlog(p)


def test_text_file(tmp_path):
    p = _write(tmp_path, "notes.tlog", b"t,psi\n0.0,0.1\n0.1,0.2\n" * 20)
    with pytest.raises(IngestError, match=r"found no MAVLink messages in 440 bytes \(starts with b't,psi"):
        read_tlog(p)


def test_truncated_mid_message_reads_complete_messages(tmp_path):
    recs = [_att(100), _att(120), _att(140)]
    last = _att(160)
    p = _write(tmp_path, "cut.tlog", b"".join(recs) + last[:15])
    raw = read_tlog(p)
    assert "truncated: 15 trailing bytes ignored" in raw.summary.warnings
    assert raw.summary.read == {"ATTITUDE": 3}
    assert np.allclose(raw.channel("psi").t, [0.1, 0.12, 0.14])
    # Cut inside the 8-byte receive stamp.
    p = _write(tmp_path, "cut2.tlog", b"".join(recs) + last[:5])
    assert "truncated: 5 trailing bytes ignored" in read_tlog(p).summary.warnings


def test_truncated_real_log(tmp_path):
    full = write_tlog(_trial(), tmp_path / "full.tlog", VESSEL).read_bytes()
    cut = len(full) // 2 + 3
    pos = 0  # walk the record lengths to find where the cut falls
    while True:
        frame_len = (10 if full[pos + 8] == 0xFD else 6) + full[pos + 9] + 2
        if pos + 8 + frame_len > cut:
            break
        pos += 8 + frame_len
    p = _write(tmp_path, "half.tlog", full[:cut])
    raw = read_tlog(p, VESSEL)
    assert raw.summary.warnings[0] == f"truncated: {cut - pos} trailing bytes ignored"
    assert [w for w in raw.summary.warnings[1:] if not w.startswith("t = 0 (boot) is")] == []
    ref = read_tlog(tmp_path / "full.tlog", VESSEL)
    psi = raw.channel("psi")
    assert np.array_equal(psi.values, ref.channel("psi").values[:len(psi.values)])
    assert 5.0 < psi.t[-1] < 15.0 + BOOT_OFFSET


def test_file_cut_inside_first_message_is_an_error(tmp_path):
    p = _write(tmp_path, "stub.tlog", _att(100)[:20])
    with pytest.raises(IngestError, match=r"expected at least one complete MAVLink message, found none in 20 "
                                          r"bytes \(truncated"):
        read_tlog(p)


def test_garbage_between_messages_is_counted(tmp_path):
    rng = np.random.default_rng(11)
    garbage = bytes(rng.integers(0, 256, 200, dtype=np.uint8)) + b"\xfe\xfd\xfe"  # magics included
    p = _write(tmp_path, "junk.tlog", _att(100) + garbage + _att(120) + _att(140))
    raw = read_tlog(p)
    assert raw.summary.read == {"ATTITUDE": 3}
    assert raw.summary.skipped["BAD_DATA"] == 1
    assert ("bad data: 0 frame(s) with a bad CRC and 1 stretch(es) of garbage bytes skipped (203 bytes in total)"
            in raw.summary.warnings)


def test_bad_crc_is_counted(tmp_path):
    bad = bytearray(_att(120))
    bad[8 + 10 + 5] ^= 0x40  # flip a payload bit; the CRC no longer matches
    p = _write(tmp_path, "crc.tlog", _att(100) + bytes(bad) + _att(140))
    raw = read_tlog(p)
    assert raw.summary.read == {"ATTITUDE": 2}
    assert raw.summary.skipped == {"BAD_CRC": 1}
    assert (f"bad data: 1 frame(s) with a bad CRC and 0 stretch(es) of garbage bytes skipped ({len(bad)} bytes "
            "in total)" in raw.summary.warnings)
    assert np.allclose(raw.channel("psi").t, [0.1, 0.14])


def test_unknown_message_id_is_skipped_whole(tmp_path):
    payload = b"\x01\x02\x03"
    msgid = 0x7FFF01  # not in ardupilotmega
    frame = bytes([0xFD, len(payload), 0, 0, 9, 1, 1]) + msgid.to_bytes(3, "little") + payload + b"\x00\x00"
    p = _write(tmp_path, "unk.tlog", _att(100) + struct.pack(">Q", 1) + frame + _att(120))
    raw = read_tlog(p)
    assert raw.summary.read == {"ATTITUDE": 2}
    assert raw.summary.skipped == {f"UNKNOWN_{msgid}": 1}
    assert f"message ids not in the ardupilotmega dialect skipped: {msgid} (1)" in raw.summary.warnings


def test_signed_mavlink2_frames_are_read(tmp_path):
    signer = mav2.MAVLink(None, srcSystem=1, srcComponent=1)
    signer.signing.secret_key = bytes(range(32))
    signer.signing.sign_outgoing = True
    frames = [_att(ms, mav=signer) for ms in (100, 120)]
    assert frames[0][8 + 2] & 0x01  # incompat flag: signed, 13 extra bytes
    raw = read_tlog(_write(tmp_path, "signed.tlog", b"".join(frames) + _att(140)))
    assert raw.summary.read == {"ATTITUDE": 3} and raw.summary.warnings == ()


def test_servo_messages_without_actuator_map_warn(tmp_path):
    path = write_tlog(_trial(), tmp_path / "s.tlog", VESSEL)
    raw = read_tlog(path)
    assert "delta" not in raw.channels and "tau_x" not in raw.channels
    assert raw.summary.skipped["SERVO_OUTPUT_RAW"] == 1000 and "SERVO_OUTPUT_RAW" not in raw.summary.read
    assert ("inputs not mapped: 1000 SERVO_OUTPUT_RAW message(s) present but no actuator map with source "
            "'servo' given (pass a vessel with [[actuators]]); counted as skipped") in raw.summary.warnings
    rc_only = Vessel(name="rc", actuators=(ActuatorMap("rc", 1, "delta"),))
    raw = read_tlog(path, rc_only)
    assert "actuator map expects RC_CHANNELS for delta (channel 1), found no RC_CHANNELS messages" in \
        raw.summary.warnings


def test_duplicate_and_backward_stamps_keep_first(tmp_path):
    p = _write(tmp_path, "dup.tlog", b"".join(_att(ms, yaw=ms / 1000) for ms in (100, 120, 120, 110, 140)))
    raw = read_tlog(p)
    assert np.allclose(raw.channel("psi").t, [0.1, 0.12, 0.14])
    assert np.allclose(raw.channel("psi").values, [0.1, 0.12, 0.14])
    assert raw.summary.read == {"ATTITUDE": 3} and raw.summary.skipped == {"ATTITUDE": 2}
    assert ("ATTITUDE: 2 message(s) with a duplicate or non-increasing time_boot_ms skipped (first kept)"
            in raw.summary.warnings)


def test_second_sender_is_not_interleaved(tmp_path):
    other = mav2.MAVLink(None, srcSystem=2, srcComponent=1)
    p = _write(tmp_path, "two.tlog", _att(100) + _att(50, mav=other) + _att(120) + _att(140))
    raw = read_tlog(p)
    assert np.allclose(raw.channel("psi").t, [0.1, 0.12, 0.14])
    assert raw.summary.skipped == {"ATTITUDE": 1}
    assert ("ATTITUDE: 1 message(s) from other senders skipped (system 2 component 1 (1)); kept system 1 "
            "component 1") in raw.summary.warnings


def test_gps_without_fix_is_not_used(tmp_path):
    def gps(us, fix):
        return _record(_MAV.gps_raw_int_encode(us, fix, 569800000 if fix else 0, 101200000 if fix else 0,
                                               0, 80, 120, 150, 9000, 12))
    p = _write(tmp_path, "fix.tlog", gps(1_000_000, 0) + gps(1_100_000, 3) + gps(1_200_000, 3))
    raw = read_tlog(p)
    assert np.allclose(raw.channel("lat@gps").t, [1.1, 1.2])
    assert np.allclose(raw.channel("cog@gps").values, math.pi / 2)
    assert raw.summary.read == {"GPS_RAW_INT": 2} and raw.summary.skipped == {"GPS_RAW_INT": 1}
    assert ("1 sample(s) of lat@gps, lon@gps, sog@gps, cog@gps not used: no fix (fix_type < 2)"
            in raw.summary.warnings)


def test_reading_leaves_the_file_untouched(tmp_path):
    data = _att(100) + b"garbage!" * 4 + _att(120) + _att(140)[:-3]
    p = _write(tmp_path, "keep.tlog", data)
    os.utime(p, ns=(1_600_000_000_000_000_000, 1_600_000_000_000_000_000))
    before = p.stat()
    raw = read_tlog(p, VESSEL, progress=True)
    assert raw.summary.read == {"ATTITUDE": 2}
    after = p.stat()
    assert p.read_bytes() == data
    assert after.st_mtime_ns == before.st_mtime_ns and after.st_size == before.st_size


def test_progress_bar_and_ci_quiet(tmp_path, monkeypatch, capsys):
    path = write_tlog(_trial(), tmp_path / "p.tlog", VESSEL)
    read_tlog(path, VESSEL, progress=True)
    assert "p.tlog" in capsys.readouterr().err
    read_tlog(path, VESSEL, progress=False)
    assert capsys.readouterr().err == ""
    monkeypatch.setenv("CI", "true")
    assert want_progress(None, 10**9, 4 * 1024 * 1024) is False
    assert want_progress(True, 10, 4 * 1024 * 1024) is True
    monkeypatch.delenv("CI")
    assert want_progress(None, 10, 4 * 1024 * 1024) is False  # a small file reads too fast for a bar
