"""Real third-party files (tests/data, see each SOURCE.md) and the readers added for them.

ULog, marine NMEA (HDG/HDM/VHW/ROT/GLL/ZDA/PASHR/PTNL), UBX extras (NMEA inside, HNR, ESF-MEAS,
RTCM3), content sniffing, DataFlash TimeMS and corrupted records, short logs. The independent
references are the formats' own libraries (pyulog, pyubx2, pyrtcm, pynmeagps) and scipy's
rotations; files written by hand here are built byte by byte from the format specifications.
"""

from __future__ import annotations

import struct
from functools import reduce
from operator import xor
from pathlib import Path

import numpy as np
import pytest

from pipeline.align import align
from pipeline.errors import AlignError, IngestError, SegmentError
from pipeline.ingest import read_log
from pipeline.ingest.dataflash import read_dataflash
from pipeline.ingest.nmea import read_nmea
from pipeline.ingest.sniff import sniff
from pipeline.ingest.ubx import read_ubx
from pipeline.ingest.ulog import quaternion_to_euler, read_ulog
from pipeline.segment import detect_segments

DATA = Path(__file__).parent / "data"
ALL = sorted(p for p in DATA.glob("*/*") if p.name != "SOURCE.md")


def _line(body: str) -> str:
    return f"${body}*{reduce(xor, body.encode(), 0):02X}"


# ----------------------------------------------------------------------------- every real file
def test_enough_real_files_from_enough_repositories():
    assert len(ALL) >= 40
    assert len({p.parent.name for p in ALL}) >= 8
    for folder in {p.parent for p in ALL}:
        text = (folder / "SOURCE.md").read_text()
        assert "Commit:" in text and "Licence:" in text
        assert all(f"`{p.name}`" in text for p in folder.iterdir() if p.name != "SOURCE.md")


@pytest.mark.parametrize("path", ALL, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_real_file_reads_or_names_expected_and_found(path):
    try:
        log = read_log(path)
    except IngestError as exc:
        msg = str(exc)
        assert "expected" in msg and "found" in msg and "\n" not in msg and "Traceback" not in msg
        return
    assert log.channels
    for ch in log.channels.values():
        assert len(ch.t) == len(ch.values) and np.all(np.diff(ch.t) > 0) and np.all(np.isfinite(ch.values))
    assert sum(log.summary.read.values()) > 0


# ----------------------------------------------------------------------------- ULog
def test_ulog_every_sample_accounted_and_euler_as_scipy():
    from pyulog import ULog
    from scipy.spatial.transform import Rotation

    path = DATA / "pyulog" / "sample_appended_multiple.ulg"
    ref = ULog(str(path))
    total = sum(len(d.data["timestamp"]) for d in ref.data_list)
    log = read_log(path)
    assert log.format == "ulog" and log.time_reference == "boot"
    assert sum(log.summary.read.values()) + sum(log.summary.skipped.values()) == total
    att = next(d for d in ref.data_list if d.name == "vehicle_attitude" and d.multi_id == 0).data
    q = np.column_stack([att[f"q[{i}]"] for i in range(4)])
    yaw, pitch, roll = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_euler("ZYX").T
    phi, theta, psi = quaternion_to_euler(q)
    np.testing.assert_allclose(phi, roll, atol=1e-9)
    np.testing.assert_allclose(theta, pitch, atol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * (psi - yaw))), 0.0, atol=1e-9)
    np.testing.assert_allclose(log.channels["psi"].values, psi[: len(log.channels["psi"].values)], atol=1e-12)
    sc = next(d for d in ref.data_list if d.name == "sensor_combined").data
    np.testing.assert_allclose(log.channels["az"].values, sc["accelerometer_m_s2[2]"])
    np.testing.assert_allclose(log.channels["az"].t, sc["timestamp"] * 1e-6)
    assert any(w.startswith("parameters:") for w in log.summary.warnings)


def test_ulog_actuator_outputs_through_the_vessel_map():
    import dataclasses

    from pyulog import ULog

    from pipeline.vessel import ActuatorMap, load_vessel

    path = DATA / "pyulog" / "sample_appended_multiple.ulg"
    vessel = dataclasses.replace(load_vessel(Path(__file__).parents[1] / "vessel_configs" / "aauship.toml"),
                                 actuators=(ActuatorMap("servo", 1, "delta", full_scale=0.5),))
    out = next(d for d in ULog(str(path)).data_list if d.name == "actuator_outputs" and d.multi_id == 0).data
    pwm = out["output[0]"].astype(float)
    log = read_log(path, vessel=vessel)
    ok = pwm > 0
    np.testing.assert_allclose(log.channels["delta"].values, 0.5 * (pwm[ok] - 1500.0) / 400.0)
    np.testing.assert_allclose(log.channels["delta"].t, out["timestamp"][ok] * 1e-6)


#: PX4's own events sample: the one public ULog we know with ``actuator_motors`` (1.5 MB, so not
#: kept under tests/data; read from a local mirror of PX4/pyulog at the pinned commit when present).
PX4_EVENTS = ("/work/.mirror/PX4+pyulog/repo", "3cf17793f14709713ab297d3743314c658874068", "test/sample_px4_events.ulg")


def test_ulog_motor_topic_through_a_normalised_actuator_map(tmp_path):
    import subprocess

    from pyulog import ULog

    from pipeline.vessel import parse_vessel

    git_dir, commit, name = PX4_EVENTS
    path = tmp_path / Path(name).name
    try:
        path.write_bytes(subprocess.run(["git", "--git-dir", git_dir, "show", f"{commit}:{name}"], capture_output=True,
                                        check=True).stdout)
    except (OSError, subprocess.CalledProcessError):
        pytest.skip(f"{name} not available (no mirror of PX4/pyulog at {git_dir})")
    vessel = parse_vessel({"name": "quad as a boat", "actuators": [
        {"source": "motor", "channel": 1, "target": "tau_x", "full_scale": 10.0},
        {"source": "motor", "channel": 3, "target": "tau_x", "full_scale": 10.0},
        {"source": "motor", "channel": 2, "target": "tau_n", "full_scale": 2.0, "reverse_scale": 1.0}]})
    assert vessel.actuators[0].pwm_trim == 0.0 and vessel.actuators[0].pwm_span == 1.0  # normalised defaults
    ref = ULog(str(path))
    motors = next(d for d in ref.data_list if d.name == "actuator_motors").data
    c0, c1, c2 = (motors[f"control[{k}]"].astype(float) for k in range(3))
    log = read_log(path, vessel=vessel)
    both = np.isfinite(c0) & np.isfinite(c2)
    np.testing.assert_allclose(log.channels["tau_x"].values, 10.0 * (c0[both] + c2[both]))  # twin motors add
    np.testing.assert_allclose(log.channels["tau_x"].t, motors["timestamp"][both] * 1e-6)
    ok = np.isfinite(c1)
    np.testing.assert_allclose(log.channels["tau_n"].values, np.where(c1[ok] >= 0, 2.0, 1.0) * c1[ok])
    assert log.channels["tau_x"].source == "ulog:actuator_motors"
    total = sum(len(d.data["timestamp"]) for d in ref.data_list)
    assert sum(log.summary.read.values()) + sum(log.summary.skipped.values()) == total
    assert log.summary.read["actuator_motors"] == int((both | ok).sum())
    # Without a motor map the topic is counted as skipped, with the reason.
    bare = read_log(path)
    assert bare.summary.skipped["actuator_motors (no actuator map with source 'motor')"] == len(c0)


def test_ulog_bad_input(tmp_path):
    cut = tmp_path / "cut.ulg"
    cut.write_bytes((DATA / "pyulog" / "sample_appended_multiple.ulg").read_bytes()[:10])
    with pytest.raises(IngestError, match="expected a PX4 ULog header of 16 bytes, found 10"):
        read_ulog(cut)
    other = tmp_path / "other.ulg"
    other.write_bytes(b"not a ulog at all, just text\n")
    with pytest.raises(IngestError, match="expected a PX4 ULog"):
        read_ulog(other)


# ----------------------------------------------------------------------------- NMEA
def test_instrument_log_hdg_with_variation_ten_per_epoch_and_vhw():
    path = DATA / "signalk-server" / "gofree-merrimac.log"
    log = read_log(path)
    s = log.summary
    assert s.read["HDG"] == 1375 and s.read["VHW"] == 142 and s.read["ZDA"] == 142
    # $SDHDG,181.7,,,0.6,E: magnetic 181.7 + variation 0.6 E = 182.3 deg true.
    assert log.channels["psi"].values[0] == pytest.approx(np.angle(np.exp(1j * np.radians(182.3))), abs=1e-9)
    psi_t = log.channels["psi"].t
    assert len(psi_t) == 1375 and np.all(np.diff(psi_t) > 0)
    text = " | ".join(s.warnings)
    assert "HDG up to 10 an epoch" in text and "sentence types:" in text and "VDM 1507 (not used: AIS 1507)" in text
    assert "u is the VHW log speed" in text


def test_numeric_talkers_and_no_time_bearing_sentence():
    with pytest.raises(IngestError, match=r"with a time.*HDG before the first time-bearing sentence"):
        read_log(DATA / "signalk-server" / "n2kd-183-merrimac.log")


def test_numeric_talker_hdm_with_rmc_variation_and_rot(tmp_path):
    lines = [_line("GPRMC,120000.00,A,5703.0,N,00955.0,E,5.0,090.0,050524,2.5,W,A"),
             _line("24HDG,100.0,1.0,E,,"), _line("04HDM,101.0,M"), _line("TIROT,-30.0,A"),
             _line("GPRMC,120001.00,A,5703.0,N,00955.1,E,5.0,090.0,050524,2.5,W,A"), _line("24HDG,100.5,1.0,E,,")]
    p = tmp_path / "bus.txt"
    p.write_text("\n".join(lines) + "\n")
    log = read_log(p)
    assert log.summary.read == {"RMC": 2, "HDG": 2, "HDM": 1, "ROT": 1}
    # HDG wins over HDM at one epoch: 100.0 + 1.0 deviation - 2.5 variation (W) = 98.5 deg.
    np.testing.assert_allclose(np.degrees(log.channels["psi"].values), [98.5, 99.0])
    np.testing.assert_allclose(log.channels["r"].values, [np.radians(-30.0) / 60.0])


def test_gll_zda_time_and_duplicate_epochs_counted_once(tmp_path):
    lines = [_line("IIZDA,235959.00,31,12,2024,00,00"), _line("GPGLL,5703.000,N,00955.000,E,235959.00,A,A"),
             _line("IIVHW,,T,,M,3.0,N,5.556,K"),
             _line("IIZDA,000000.00,01,01,2025,00,00"), _line("GPGLL,5703.001,N,00955.000,E,000000.00,A,A"),
             _line("GPGLL,5703.001,N,00955.000,E,000000.00,A,A"),
             _line("GPRMC,000001.00,A,5703.0,N,00955.0,E,5.0,090.0,010125,,,A"),
             _line("GPRMC,000001.00,A,5703.0,N,00955.0,E,5.0,090.0,010125,,,A")]
    p = tmp_path / "race.log"
    p.write_text("\n".join(lines) + "\n")
    log = read_nmea(p)
    np.testing.assert_allclose(log.channels["lat"].t, [0.0, 1.0, 2.0])
    assert log.start_time == pytest.approx(1735689599.0)   # 2024-12-31 23:59:59 UTC
    assert log.summary.skipped["GLL repeated or out of order"] == 1
    assert log.summary.skipped["RMC repeated or out of order"] == 1
    assert sum("repeating an earlier epoch" in w for w in log.summary.warnings) == 1
    np.testing.assert_allclose(log.channels["u"].values, [5.556 / 3.6])


def test_proprietary_attitude_against_the_sentence_fields():
    from pynmeagps import NMEAReader

    path = DATA / "pynmeagps" / "trimble_nmea.log"
    log = read_log(path)
    assert log.summary.read == {"PTNL,AVR": 2, "PASHR": 1}
    lines = path.read_bytes().splitlines()
    pashr = NMEAReader.parse([ln for ln in lines if ln.startswith(b"$PASHR,1")][0])   # the attitude layout
    assert log.channels["phi"].values[0] == pytest.approx(np.radians(float(pashr.roll)))
    assert log.channels["theta"].values[0] == pytest.approx(np.radians(float(pashr.pitch)))
    avr = [NMEAReader.parse(ln) for ln in lines if ln.startswith(b"$PTNL,AVR")]
    yaw = {float(m.yaw) for m in avr} | {float(pashr.trueHdg)}
    np.testing.assert_allclose(sorted(np.degrees(np.mod(log.channels["psi"].values, 2 * np.pi))), sorted(yaw))


# ----------------------------------------------------------------------------- UBX
def test_ubx_saved_as_log_is_sniffed_and_nmea_inside_is_read():
    path = DATA / "gpsd" / "ublox-zed-f9r.log"
    assert sniff(path)[0] == "ubx"
    log = read_log(path)
    assert log.format == "ubx"
    assert log.summary.read["NAV-PVT"] == 30 and log.summary.read["NMEA GGA"] == 30
    # The NMEA fixes, placed through their UTC date and time, land on the NAV-PVT epochs.
    np.testing.assert_allclose(log.channels["lat@nmea"].t, log.channels["lat"].t, atol=1e-6)
    np.testing.assert_allclose(log.channels["lat@nmea"].values, log.channels["lat"].values, atol=1e-6)
    # Every frame accounted for, by protocol, as pyubx2 counts them.
    from pyubx2 import UBXReader

    ref = {"UBX": 0, "NMEA": 0, "RTCM": 0}
    with open(path, "rb") as fh:
        for raw, _ in UBXReader(fh, protfilter=7, quitonerror=0, parsing=False):
            if raw is not None:
                ref["UBX" if raw[:2] == b"\xb5\x62" else "RTCM" if raw[:1] == b"\xd3" else "NMEA"] += 1
    every = {**log.summary.skipped, **log.summary.read}
    assert sum(v for k, v in every.items() if k.startswith("RTCM3-")) == ref["RTCM"]
    assert sum(v for k, v in every.items() if k.startswith("NMEA ")) == ref["NMEA"]
    assert sum(v for k, v in every.items() if not k.startswith(("NMEA ", "RTCM3-", "GARBAGE"))) == ref["UBX"]


def test_hnr_pvt_against_pyubx2():
    from pyubx2 import UBXReader

    path = DATA / "pyubx2" / "pygpsdata-HNR.log"
    with open(path, "rb") as fh:
        ref = [m for _, m in UBXReader(fh, protfilter=2, quitonerror=0) if m is not None and m.identity == "HNR-PVT"]
    log = read_ubx(path)
    assert log.summary.read["HNR-PVT"] == len(ref) == 13
    np.testing.assert_allclose(log.channels["lat"].values, [m.lat for m in ref])
    np.testing.assert_allclose(log.channels["sog"].values, [m.gSpeed / 1000 for m in ref])


def test_esf_meas_on_gps_time_against_pyubx2(tmp_path):
    from pyubx2 import GET, UBXMessage, UBXReader

    real = (DATA / "pyubx2" / "pygpsdata-ESF.log").read_bytes()
    with pytest.raises(IngestError, match="ESF-MEAS 19"):
        read_ubx(DATA / "pyubx2" / "pygpsdata-ESF.log")   # no epoch to put the sensor time tags on
    with open(DATA / "pyubx2" / "pygpsdata-ESF.log", "rb") as fh:
        frames = [(raw, m) for raw, m in UBXReader(fh, protfilter=2, quitonerror=0) if m is not None]
    pvt = [UBXMessage("NAV", "NAV-PVT", GET, iTOW=1000 * k, fixType=3, gnssFixOk=1, lat=57.0, lon=9.9).serialize()
           for k in range(3)]
    p = tmp_path / "esf.ubx"
    p.write_bytes(pvt[0] + b"".join(raw for raw, _ in frames) + pvt[1] + pvt[2])
    log = read_ubx(p)
    assert log.summary.read["ESF-MEAS"] + log.summary.skipped.get("ESF-MEAS", 0) == len(frames) == 19
    # pyubx2's fields: gyro x (data type 14) in 2^-12 deg/s as a signed 24-bit integer, first of each time tag kept.
    ref, last = [], -1
    for _, m in frames:
        for i in range(1, m.numMeas + 1):
            if getattr(m, f"dataType_{i:02d}") == 14 and m.timeTag > last:
                v = getattr(m, f"dataField_{i:02d}")
                ref.append((v - (1 << 24) if v & 0x800000 else v) * 2.0**-12 * np.pi / 180)
                last = m.timeTag
    np.testing.assert_allclose(log.channels["p@esf"].values, ref)
    assert np.all(np.diff(log.channels["p@esf"].t) > 0)


def test_rtcm_only_and_unknown_content_say_what_they_found():
    from pyrtcm import RTCMReader

    path = DATA / "pyrtcm" / "pygpsdata-1230.bin"
    with open(path, "rb") as fh:
        n = sum(1 for _, m in RTCMReader(fh) if m is not None)
    with pytest.raises(IngestError, match=rf"found RTCM 3 correction frames only \(1230 x{n}\)"):
        read_log(path)
    with pytest.raises(IngestError, match=r"content in a known format .* found '.log' holding binary data .* beginning 23 20 4e"):
        read_log(DATA / "gpsd" / "trimble-smtx.log")


# ----------------------------------------------------------------------------- DataFlash
def _fmt(type_id: int, name: str, fmt: str, cols: str) -> bytes:
    length = 3 + struct.calcsize("<" + fmt.replace("c", "h").replace("n", "4s").replace("Q", "Q"))
    return (b"\xa3\x95\x80" + struct.pack("<BB4s16s64s", type_id, length, name.encode(), fmt.encode(),
                                          cols.encode()))


def _rec(type_id: int, fmt: str, *values) -> bytes:
    return b"\xa3\x95" + bytes([type_id]) + struct.pack("<" + fmt.replace("c", "h"), *values)


def test_dataflash_timems_log(tmp_path):
    # A pre-2015 layout: records stamped in milliseconds, no instance field.
    att, imu = "Iccc", "Iffffff"
    body = _fmt(1, "ATT", att, "TimeMS,Roll,Pitch,Yaw") + _fmt(2, "IMU", imu, "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ")
    for k in range(50):
        body += _rec(1, att, 1000 + 100 * k, 150, -20, 9000) + _rec(2, imu, 1000 + 100 * k, 0.01, 0.0, 0.02,
                                                                    0.1, 0.0, -9.8)
    p = tmp_path / "old.bin"
    p.write_bytes(body)
    log = read_log(p)
    assert log.summary.read == {"ATT": 50, "IMU": 50}
    np.testing.assert_allclose(log.channels["phi"].t, 1.0 + 0.1 * np.arange(50))
    np.testing.assert_allclose(log.channels["phi"].values, np.radians(1.5))
    assert any("TimeMS" in w for w in log.summary.warnings)


def test_dataflash_corrupt_record_cannot_stretch_the_grid(tmp_path):
    imu = "QBffffff"
    body = _fmt(2, "IMU", imu, "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ")
    for k in range(200):
        body += _rec(2, imu, 10_000_000 + 20_000 * k, 0, 0.01 * np.sin(k / 5), 0.0, 0.0, 0.1, 0.0, -9.8)
    body += _rec(2, imu, 5_200_000_000_000_000_000 // 1000, 37, 0.0, 0.0, 0.0, 0.0, 0.0, -9.8)  # t = 5.2e12 s
    body += _rec(2, imu, 14_100_000, 0, 1e30, 0.0, 0.0, 0.1, 0.0, -9.8)                       # impossible rate
    body += _rec(2, imu, 5_200_000_000_000_000, 0, 0.0, 0.0, 0.0, 0.0, 0.0, -9.8)  # last record, t = 5.2e9 s
    p = tmp_path / "corrupt.bin"
    p.write_bytes(body)
    log = read_dataflash(p)
    assert set(log.channels) == {"p", "q", "r", "ax", "ay", "az"}
    # The far-future record (instance 37) is dropped; the one with GyrX = 1e30 still gives its other fields.
    assert log.summary.read["IMU"] == 201 and log.summary.skipped["IMU"] == 2
    assert len(log.channels["p"].t) == 200 and np.max(np.abs(log.channels["p"].values)) < 1.0
    assert len(log.channels["q"].t) == 201 and log.channels["q"].t[-1] == pytest.approx(14.1)
    assert any("corrupted records dropped" in w and "IMU instance 37 1" in w and "IMU p value 1" in w and "IMU time 1" in w
               for w in log.summary.warnings)
    trial = align([log])
    assert len(trial.data) < 500


# ----------------------------------------------------------------------------- short logs
def test_single_epoch_and_one_second_logs_stop_with_the_duration(tmp_path):
    one = tmp_path / "one.nmea"
    one.write_text(_line("GPRMC,120000.00,A,5703.0,N,00955.0,E,5.0,090.0,050524,,,A") + "\n")
    with pytest.raises(AlignError, match=r"expected a log of at least two samples.*found 1 sample\(s\) per channel "
                                         r"spanning 0 s"):
        align([read_log(one)])
    with pytest.raises(SegmentError, match=r"expected a trial of at least 2 s.*found 0\.9"):
        detect_segments(align([read_log(DATA / "pymavlink" / "test.BIN")]))
