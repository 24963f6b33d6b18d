"""Every real third-party file (tests/data): read + skipped = the format library's own count.

The libraries are the independent reference: pynmeagps for NMEA text (the sentences it finds,
those it rejects included, plus lines whose header it does not take at all: AIS ``!AIVDM``,
``$QZ``, numeric talkers), pyubx2 for UBX streams (NMEA and RTCM inside them included), pymavlink
for DataFlash and tlog, pyulog for ULog, rosbags for ROS bags. Lines and bytes that hold no
message (``garbage``) are counted by the readers but by no library, so they are left out.
Also: the u-blox ESF axes measured on a real drive, and the ArduPilot and ROS files.
"""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import IngestError
from pipeline.ingest import read_log
from pipeline.ingest.sniff import sniff

DATA = Path(__file__).parent / "data"
ALL = sorted(p for p in DATA.glob("*/*") if p.name != "SOURCE.md")
EXC_NAME = re.compile(r"\b[A-Z][A-Za-z]*(Error|Exception)\b")
#: Known, explained differences (reader - library).
KNOWN: dict[str, int] = {
    # None left: the damaged u-blox streams (pygpsdata-BADCK2.log, pygpsdata-MIXED-RTCM3BADCRC.log)
    # differed by one until a damaged frame whose length leads to the next frame counted as one
    # frame (tests/test_ingest_ubx.py, test_damaged_frames_counted_once_...).
}


def library_count(path: Path, fmt: str | None) -> int | None:
    """Messages in ``path`` as the format's own library counts them; None when it has no count."""
    if fmt == "nmea":
        from pynmeagps import NMEAReader
        from pynmeagps.nmeatypes_core import NMEA_HDR

        n, errors = 0, []
        with open(path, "rb") as fh:
            for raw, _ in NMEAReader(fh, quitonerror=1, validate=1, errorhandler=errors.append):
                n += raw is not None
        others = sum(1 for ln in path.read_bytes().splitlines()
                     if ln.strip()[:1] in (b"$", b"!") and ln.strip()[:2] not in NMEA_HDR)
        return n + len(errors) + others
    if fmt in ("ubx", "rtcm3"):
        from pyubx2 import UBXReader

        with open(path, "rb") as fh:
            return sum(raw is not None for raw, _ in UBXReader(fh, protfilter=7, quitonerror=0, validate=0,
                                                               msgmode=0, parsing=False))
    if fmt == "dataflash":
        from pymavlink.DFReader import DFReader_binary

        r, n = DFReader_binary(str(path)), 0
        while r.recv_msg() is not None:
            n += 1
        return n
    if fmt == "tlog":
        from pymavlink import mavutil

        m, n = mavutil.mavlink_connection(str(path)), 0
        while m.recv_match() is not None:
            n += 1
        return n
    if fmt == "ulog":
        from pyulog import ULog

        return sum(len(d.data["timestamp"]) for d in ULog(str(path)).data_list)
    return None


@pytest.mark.parametrize("path", ALL, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_read_plus_skipped_is_the_library_count(path):
    try:
        log = read_log(path)
    except IngestError as exc:  # a file that stops: one line, expected and found, no class name
        msg = str(exc)
        assert "expected" in msg and "found" in msg and "\n" not in msg and not EXC_NAME.search(msg), msg
        return
    fmt, _ = sniff(path)
    lib = library_count(path, fmt)
    assert lib is not None, f"no library count for {fmt}"
    s = log.summary
    ours = sum(s.read.values()) + sum(v for k, v in s.skipped.items() if "garbage" not in k.lower())
    assert ours - lib == KNOWN.get(path.name, 0), (ours, lib, dict(s.read), dict(s.skipped))


def test_nmea_sentences_pynmeagps_does_not_take_are_counted():
    # 37 QZSS ($QZGSV) sentences pynmeagps skips without a word, and AIS (!AIVDM) in a chartplotter log.
    log = read_log(DATA / "gpsd" / "quectelLC79D.log")
    assert log.summary.skipped["GSV"] == 250
    log = read_log(DATA / "signalk-server" / "gofree-merrimac.log")
    assert log.summary.skipped["VDM"] == 1507
    assert log.summary.skipped["bad checksum"] == 142  # garbled $SDVLW lines; pynmeagps rejects them too


# ----------------------------------------------------------------------------- u-blox ESF axes
def test_esf_axes_on_a_real_drive_against_the_receivers_own_vehicle_frame():
    """NEO-M8L drive (gpsd): gravity on -z in the body frame, and r has the sign of the heading rate.

    The receiver's own outputs are the reference: HNR-ATT heading (NED, clockwise) turns at about
    +4.3 deg/s over the 19 s, and its pitch is +10.8 deg (nose up), so at near-constant speed the
    body-frame specific force is about (+g sin(theta), 0, -g cos(theta)).
    """
    log = read_log(DATA / "gpsd" / "ublox-neo-m8l.log")
    ch = log.channels
    psi = np.unwrap(ch["psi"].values)
    heading_rate = (psi[-1] - psi[0]) / (ch["psi"].t[-1] - ch["psi"].t[0])
    assert heading_rate > np.radians(3)
    r = ch["r@esf"].values.mean()
    assert r > 0 and abs(r - heading_rate) < np.radians(1.0)
    theta = ch["theta"].values.mean()
    g = 9.80665
    assert ch["az@esf"].values.mean() == pytest.approx(-g * np.cos(theta), abs=0.5)
    assert ch["ax@esf"].values.mean() == pytest.approx(g * np.sin(theta), abs=0.5)
    assert "y and z negated" in ch["az@esf"].source


@pytest.mark.parametrize("name", ["gpsd/ublox-neo-m8u.log", "pyubx2/pygpsdata-ESF.log"])
def test_esf_gravity_on_minus_z_on_other_receivers(name):
    from pyubx2 import UBXReader

    raw_z = []
    with open(DATA / name, "rb") as fh:
        for _, p in UBXReader(fh, protfilter=2, quitonerror=0):
            if p is not None and p.identity in ("ESF-MEAS", "ESF-RAW"):
                for i in range(1, 40):
                    if getattr(p, f"dataType_{i:02d}", None) == 18:
                        v = getattr(p, f"dataField_{i:02d}")
                        raw_z.append((v - 2**24 if v >= 2**23 else v) / 1024)
    assert np.mean(raw_z) > 9.0  # as the receiver logs it: +g on its z axis (up)
    try:
        log = read_log(DATA / name)
    except IngestError:  # pygpsdata-ESF.log has no position or time to place ESF-MEAS on
        return
    az = [c.values for k, c in log.channels.items() if k.startswith("az@")]
    assert az and all(np.mean(v) < -9.0 for v in az)


# ----------------------------------------------------------------------------- ArduPilot, ROS
def test_ardupilot_copter_log_cut_at_80_kib():
    log = read_log(DATA / "MethodicConfigurator" / "backend_log_80k.bin")
    s = log.summary
    assert sum(s.read.values()) + sum(s.skipped.values()) == library_count(
        DATA / "MethodicConfigurator" / "backend_log_80k.bin", "dataflash") == 1817
    assert any("incomplete last record" in w for w in s.warnings)
    assert {"phi", "theta", "psi", "lat", "lon", "ax", "az"} <= set(log.channels)
    assert -11 < np.mean(log.channels["az"].values) < -8.5  # a copter on the ground: gravity on -z


@pytest.mark.parametrize("path", sorted(p for d in ("rosbag2", "rosbag.js") for p in (DATA / d).iterdir()
                                        if p.name != "SOURCE.md"), ids=lambda p: p.name)
def test_ros_bags_without_vessel_topics_name_what_they_hold(path):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    with pytest.raises(IngestError) as err:
        read_log(path)
    msg = str(err.value)
    assert "\n" not in msg and not EXC_NAME.search(msg)
    store = get_typestore(Stores.ROS1_NOETIC if path.suffix == ".bag" else Stores.ROS2_HUMBLE)
    try:
        with AnyReader([path], default_typestore=store) as r:
            topics = Counter({c.topic: c.msgcount for c in r.connections})
    except Exception:  # noqa: BLE001 - rosbags cannot parse this bag's service-event definitions
        assert "test_msgs/srv/BasicTypes_Event" in msg
        return
    if sum(topics.values()) == 0:
        assert "empty bag" in msg
    else:
        assert all(t in msg for t in topics), msg
