"""ArduPilot DataFlash: simulator writer -> reader round trip, pymavlink reference, bad input, fuzz."""

from __future__ import annotations

import dataclasses
import hashlib
import re
import struct
import time

import numpy as np
import pytest
from fuzz import fuzz_reader
from pymavlink.DFReader import DFReader_binary

from pipeline.errors import IngestError, SimError
from pipeline.ingest.dataflash import build_index, read_dataflash, read_dataflash_slow
from pipeline.records import Channel, IngestSummary, RawLog
from pipeline.sim import chain, default_sensors, free_decay, rudder_step, simulate, step_and_coast
from pipeline.sim.sensors import SensorSpec
from pipeline.sim.writers.dataflash import (DEFINITIONS, IMU2_ACCEL_BIAS, IMU2_GYRO_BIAS, record_dtype,
                                            write_dataflash)
from pipeline.vessel import ActuatorMap

BOOT = 5.0
CDEG = np.radians(0.01)


def _wrap(a):
    return np.angle(np.exp(1j * np.asarray(a)))


@pytest.fixture(scope="module")
def vessel(aauship):
    v = aauship
    # Twin surge thrusters on servo 3 and 6, and the RC sticks for rudder and throttle.
    extra = (ActuatorMap("servo", 6, "tau_x", full_scale=10.0, reverse_scale=10.0),
             ActuatorMap("rc", 1, "delta", full_scale=0.6109), ActuatorMap("rc", 3, "tau_x", full_scale=10.0))
    return dataclasses.replace(v, actuators=v.actuators + extra)


@pytest.fixture(scope="module")
def sim(vessel):
    sched = chain(step_and_coast("surge", 5.0, 4.0, 4.0), free_decay("roll", 0.3, 4.0),
                  rudder_step(0.17, 4.0, 4.0, {"tau_x": 3.0}), rest_s=1.0)
    sensors = default_sensors() + (SensorSpec("gps2", ("lat", "lon", "sog", "cog"), 5.0,
                                              noise={"lat": 0.5, "lon": 0.5, "sog": 0.03}, suffix="@gps2"),)
    return simulate(vessel, sched, sensors=sensors, seed=3)


@pytest.fixture(scope="module")
def binfile(sim, vessel, tmp_path_factory):
    return write_dataflash(sim.log, tmp_path_factory.mktemp("df") / "trial.bin", vessel, boot_offset_s=BOOT)


@pytest.fixture(scope="module")
def log(binfile, vessel):
    return read_dataflash(binfile, vessel)


def _same_time(read: Channel, written: Channel) -> None:
    assert len(read.t) == len(written.t)
    np.testing.assert_allclose(read.t - BOOT, written.t, atol=1e-6)


# ----------------------------------------------------------------------------- round trip
def test_round_trip_channels_and_names(log, sim):
    expected = {"phi", "theta", "psi", "p", "q", "r", "ax", "ay", "az",
                "p@imu1", "q@imu1", "r@imu1", "ax@imu1", "ay@imu1", "az@imu1",
                "lat", "lon", "sog", "cog", "lat@gps2", "lon@gps2", "sog@gps2", "cog@gps2",
                "lat@ekf", "lon@ekf", "sog@ekf", "cog@ekf",
                "delta", "tau_x", "delta@rc", "tau_x@rc"}
    assert set(log.channels) == expected
    # The vessel maps tau_y and tau_n to servos this schedule never drives: PWM 0 is reported.
    assert any("of tau_y (RCOU.C4) not used: PWM 0" in w for w in log.summary.warnings)
    assert log.format == "dataflash" and log.time_reference == "boot"
    for c in log.channels.values():
        assert np.all(np.diff(c.t) > 0)
    assert log.summary.read["IMU"] == 2 * len(sim.log.channels["ax"].t)
    assert log.summary.skipped["FMT"] == len(DEFINITIONS)
    assert not any("truncated" in w or "garbage" in w for w in log.summary.warnings)


def test_round_trip_attitude_and_imu(log, sim):
    w = sim.log.channels
    for name in ("phi", "theta", "psi"):
        _same_time(log.channels[name], w[name])
        err = _wrap(log.channels[name].values - w[name].values)
        assert np.max(np.abs(err)) <= 0.5 * CDEG + 1e-9, name  # centidegree fields
        assert np.all(np.abs(log.channels[name].values) <= np.pi)
    for k, name in enumerate(("p", "q", "r")):
        _same_time(log.channels[name], w[name])
        np.testing.assert_allclose(log.channels[name].values, w[name].values, rtol=1e-6, atol=1e-9)  # float32
        np.testing.assert_allclose(log.channels[f"{name}@imu1"].values - IMU2_GYRO_BIAS[k], w[name].values,
                                   rtol=1e-6, atol=1e-7)
    for k, name in enumerate(("ax", "ay", "az")):
        np.testing.assert_allclose(log.channels[name].values, w[name].values, rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(log.channels[f"{name}@imu1"].values - IMU2_ACCEL_BIAS[k], w[name].values,
                                   rtol=1e-6, atol=1e-6)
    assert log.channels["p@imu1"].source == "IMU[1]"


def test_round_trip_gps_pos_ekf(log, sim):
    w = sim.log.channels
    for read_sfx, written_sfx in (("", "@gps"), ("@gps2", "@gps2")):
        for q in ("lat", "lon"):
            _same_time(log.channels[q + read_sfx], w[q + written_sfx])
            assert np.max(np.abs(log.channels[q + read_sfx].values - w[q + written_sfx].values)) <= 0.5e-7 + 1e-12
        np.testing.assert_allclose(log.channels["sog" + read_sfx].values, w["sog" + written_sfx].values, rtol=1e-6,
                                   atol=1e-7)
        err = _wrap(log.channels["cog" + read_sfx].values - w["cog" + written_sfx].values)
        assert np.max(np.abs(err)) < 1e-6
    for q in ("lat", "lon"):
        _same_time(log.channels[f"{q}@ekf"], w[q])
        assert np.max(np.abs(log.channels[f"{q}@ekf"].values - w[q].values)) <= 0.5e-7 + 1e-12
    sog, cog = log.channels["sog@ekf"], log.channels["cog@ekf"]
    _same_time(sog, w["sog"])
    np.testing.assert_allclose(sog.values, w["sog"].values, rtol=1e-5, atol=1e-6)
    moving = w["sog"].values > 0.05  # course is undefined at rest
    assert np.max(np.abs(_wrap(cog.values - w["cog"].values)[moving])) < 1e-4


def test_round_trip_inputs(log, sim, vessel):
    w = sim.log.channels
    # One PWM microsecond is full_scale / span; twin thrusters carry half each and add two roundings.
    step = {a.target: a.full_scale / a.pwm_span for a in vessel.actuators if a.source == "servo"}
    for name in ("delta", "tau_x"):
        c = log.channels[name]
        _same_time(c, w[name])
        tol = step[name] * (1.0 if name == "tau_x" else 0.5) + 1e-9
        assert np.max(np.abs(c.values - w[name].values)) <= tol, name
        assert c.source == "RCOU"
    for name in ("delta", "tau_x"):
        c = log.channels[f"{name}@rc"]
        assert c.source == "RCIN"
        assert np.max(np.abs(c.values - w[name].values)) <= step[name] * 0.5 + 1e-9


def test_without_vessel_inputs_are_reported_not_read(binfile):
    log = read_dataflash(binfile)
    assert "delta" not in log.channels
    assert log.summary.skipped["RCOU"] > 0
    assert any("inputs not mapped" in w and "RCOU" in w for w in log.summary.warnings)


# ----------------------------------------------------------------------------- reference paths
def test_vectorised_equals_pymavlink_recv_match(binfile, vessel):
    t0 = time.perf_counter()
    fast = read_dataflash(binfile, vessel)
    t1 = time.perf_counter()
    slow = read_dataflash_slow(binfile, vessel)
    t2 = time.perf_counter()
    assert set(fast.channels) == set(slow.channels)
    for name, c in fast.channels.items():
        assert np.array_equal(c.t, slow.channels[name].t), name
        assert np.array_equal(c.values, slow.channels[name].values), name
        assert c.source == slow.channels[name].source
    assert fast.summary == dataclasses.replace(slow.summary)
    n = sum(fast.summary.read.values()) + sum(fast.summary.skipped.values())
    ratio = (t2 - t1) / (t1 - t0)
    print(f"\nDataFlash {n} records: vectorised {n / (t1 - t0):,.0f} msg/s, pymavlink recv_match "
          f"{n / (t2 - t1):,.0f} msg/s, ratio {ratio:.0f}x")
    assert ratio >= 3.0


def test_index_matches_pymavlink_on_a_clean_log(binfile):
    stock = DFReader_binary(str(binfile))
    try:
        buf = np.frombuffer(stock.data_map, np.uint8)
        idx = build_index(buf)
        del buf
        for t, offs in idx.offsets.items():
            assert list(offs) == list(stock.offsets[t]), idx.names[t]
        assert sum(len(o) for o in idx.offsets.values()) == sum(stock.counts)
        assert idx.garbage_bytes == 0 and idx.truncated == 0
    finally:
        stock.close()


def test_pymavlink_reads_the_writer_with_units_and_instances(binfile):
    r = DFReader_binary(str(binfile))
    try:
        imu = r.formats[r.name_to_id["IMU"]]
        assert imu.instance_field == "I"
        assert imu.get_unit("GyrX") == "rad/s"
        assert r.formats[r.name_to_id["ATT"]].get_unit("Roll") == "deg"
        m = r.recv_match(type="GPS")
        assert m.I == 0 and m.Status == 3 and m.GWk > 2000
        r.rewind()
        m = r.recv_match(type="ATT")
        assert m.TimeUS == round(BOOT * 1e6)
    finally:
        r.close()


def test_reading_leaves_the_file_unchanged(binfile, vessel):
    before = hashlib.sha256(binfile.read_bytes()).hexdigest()
    read_dataflash(binfile, vessel)
    read_dataflash_slow(binfile, vessel)
    assert hashlib.sha256(binfile.read_bytes()).hexdigest() == before


# ----------------------------------------------------------------------------- damaged files
def _offsets(data: bytes, name: str) -> np.ndarray:
    idx = build_index(np.frombuffer(data, np.uint8))
    t = next(k for k, v in idx.names.items() if v == name)
    return idx.offsets[t]


def test_truncated_file_reads_what_is_complete(binfile, vessel, tmp_path, log):
    data = binfile.read_bytes()
    p = tmp_path / "cut.bin"
    p.write_bytes(data[:-7])
    cut = read_dataflash(p, vessel)
    warn = [w for w in cut.summary.warnings if w.startswith("truncated")]
    assert len(warn) == 1
    n = int(re.search(r"truncated: (\d+) trailing bytes", warn[0]).group(1))
    assert 0 < n < 256
    total = sum(cut.summary.read.values()) + sum(v for k, v in cut.summary.skipped.items() if k != "GARBAGE_BYTES")
    assert total == sum(log.summary.read.values()) + sum(log.summary.skipped.values()) - 1


def test_garbage_and_unknown_type_between_records_are_counted(binfile, vessel, tmp_path, log):
    data = binfile.read_bytes()
    att = _offsets(data, "ATT")
    a, b = int(att[100]), int(att[2000])
    junk1 = b"\x00\x11garbage\xa3"
    junk2 = b"\xa3\x95\xee" + bytes(20)  # a header with a type id that has no FMT
    p = tmp_path / "junk.bin"
    p.write_bytes(data[:a] + junk1 + data[a:b] + junk2 + data[b:])
    bad = read_dataflash(p, vessel)
    assert bad.summary.skipped["GARBAGE_BYTES"] == len(junk1) + len(junk2)
    assert any("garbage: 33 byte(s) in 2 stretch(es)" in w for w in bad.summary.warnings)
    for name, c in log.channels.items():
        assert np.array_equal(bad.channels[name].values, c.values), name
    # pymavlink's own index stops at the unknown type id and loses the rest of the log.
    stock = DFReader_binary(str(p))
    try:
        assert stock.counts[DEFINITIONS["ATT"].type] < len(log.channels["phi"].t)
    finally:
        stock.close()


def test_duplicate_and_out_of_range_timeus_are_skipped(binfile, vessel, tmp_path, log):
    data = bytearray(binfile.read_bytes())
    att = _offsets(bytes(data), "ATT")
    size = record_dtype(DEFINITIONS["ATT"].format, DEFINITIONS["ATT"].columns).itemsize
    # A corrupted stamp far ahead (no checksum in DataFlash) must not hide the rest of ATT.
    struct.pack_into("<Q", data, int(att[300]) + 3, 10**15)
    a = int(att[200])
    dup = bytes(data[a:a + size])
    p = tmp_path / "dup.bin"
    p.write_bytes(bytes(data[:a + size]) + dup + bytes(data[a + size:]))
    bad = read_dataflash(p, vessel)
    assert bad.summary.skipped["ATT"] == 2
    assert any(w.startswith("ATT: 2 record(s) with a duplicate") for w in bad.summary.warnings)
    assert len(bad.channels["phi"].t) == len(log.channels["phi"].t) - 1
    assert np.all(np.diff(bad.channels["phi"].t) > 0)


@pytest.mark.parametrize("content, expected", [
    (b"", "empty file"),
    (b"not a dataflash log\n" * 50, "found no valid FMT record"),
    (bytes(range(256)) * 20, "found no valid FMT record"),
])
def test_not_a_dataflash_file(tmp_path, content, expected):
    p = tmp_path / "x.bin"
    p.write_bytes(content)
    with pytest.raises(IngestError, match=expected) as err:
        read_dataflash(p)
    assert "expected" in str(err.value) and "found" in str(err.value)


def test_missing_file(tmp_path):
    with pytest.raises(IngestError, match="expected a file, found nothing"):
        read_dataflash(tmp_path / "nope.bin")


def test_only_definitions_is_no_usable_message(binfile, tmp_path):
    data = binfile.read_bytes()
    first = min(int(_offsets(data, n)[0]) for n in ("ATT", "IMU"))
    p = tmp_path / "defs.bin"
    p.write_bytes(data[:first])
    with pytest.raises(IngestError, match=r"expected usable ATT, IMU, GPS, .* found none \(records: FMT 12"):
        read_dataflash(p)
    p.write_bytes(data[:40])
    with pytest.raises(IngestError, match="cut inside its first FMT record"):
        read_dataflash(p)


def test_fuzz_truncation_and_byte_flips(binfile, vessel, tmp_path):
    data = binfile.read_bytes()
    outcomes = fuzz_reader(data, lambda p: read_dataflash(p, vessel), tmp_path, ".bin", seed=20240505)
    assert outcomes["read"] >= 25
    print(f"\nDataFlash fuzz: {outcomes}")


# ----------------------------------------------------------------------------- progress, writer errors
def test_progress_bar_only_when_asked_or_on_a_terminal(binfile, vessel, capsys, monkeypatch):
    read_dataflash(binfile, vessel, progress=True)
    assert binfile.name in capsys.readouterr().err
    monkeypatch.setenv("CI", "1")
    read_dataflash(binfile, vessel)
    assert capsys.readouterr().err == ""


def test_writer_needs_a_vessel_for_inputs(sim, tmp_path):
    with pytest.raises(SimError, match="no vessel was given"):
        write_dataflash(sim.log, tmp_path / "x.bin")
    assert not (tmp_path / "x.bin").exists()


def test_writer_rejects_non_increasing_time(tmp_path):
    bad = Channel("phi", np.array([0.0, 0.1, 0.1]), np.zeros(3))
    log = RawLog("hand", "sim", {"phi": bad}, IngestSummary("hand", "sim"))
    with pytest.raises(SimError, match="expected strictly increasing t"):
        write_dataflash(log, tmp_path / "x.bin")


def test_hand_built_log_with_legacy_messages(tmp_path):
    """Older ArduPilot logs name the second GPS 'GPS2' and have no instance field."""
    def fmt(t, name, f, cols):
        size = 3 + struct.calcsize("<" + f.replace("L", "i").replace("c", "h"))
        return b"\xa3\x95\x80" + struct.pack("<BB4s16s64s", t, size, name.encode(), f.encode(), cols.encode())

    recs = [fmt(50, "GPS", "QBLLff", "TimeUS,Status,Lat,Lng,Spd,GCrs"),
            fmt(51, "GPS2", "QBLLff", "TimeUS,Status,Lat,Lng,Spd,GCrs")]
    for k in range(5):
        for t, lat in ((50, 57.0), (51, 57.1)):
            recs.append(b"\xa3\x95" + bytes([t]) + struct.pack("<QBiiff", 1_000_000 * (k + 1), 3 if k else 1,
                                                              int(lat * 1e7), int(9.9e7), 2.0, 350.0))
    p = tmp_path / "old.bin"
    p.write_bytes(b"".join(recs))
    log = read_dataflash(p)
    assert set(log.channels) == {"lat", "lon", "sog", "cog", "lat@gps2", "lon@gps2", "sog@gps2", "cog@gps2"}
    assert len(log.channels["lat"].t) == 4  # Status 1 (no fix) dropped
    np.testing.assert_allclose(log.channels["lat@gps2"].values, 57.1)
    np.testing.assert_allclose(log.channels["cog"].values, np.radians(-10.0), atol=1e-6)
    assert any("without a fix" in w for w in log.summary.warnings)


def test_wrong_unit_declared_by_fmtu_is_an_error(binfile, tmp_path):
    data = binfile.read_bytes()
    # The FMTU of IMU declares the gyro in 'E' (rad/s); a firmware logging deg/s would say 'k'.
    good = DEFINITIONS["IMU"].units.encode()
    assert data.count(good) == 1
    p = tmp_path / "degs.bin"
    p.write_bytes(data.replace(good, good.replace(b"EEE", b"kkk")))
    with pytest.raises(IngestError, match=r"IMU.GyrX expected in rad/s \(FMTU unit\), found unit 'k' = 'deg/s'"):
        read_dataflash(p)
