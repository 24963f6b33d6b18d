"""u-blox UBX: simulator writer -> reader round trip, pyubx2 reference, iTOW wrap, receivers, bad input, fuzz."""

from __future__ import annotations

import dataclasses
import hashlib
import io
import re
import time
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest
from fuzz import fuzz_reader
from pyubx2 import GET, UBX_PROTOCOL, UBXMessage, UBXReader

from pipeline.errors import IngestError, SimError
from pipeline.ingest.ubx import read_ubx
from pipeline.records import Channel, IngestSummary, RawLog
from pipeline.sim import chain, default_sensors, free_decay, rudder_step, simulate, step_and_coast
from pipeline.sim.sensors import SensorSpec
from pipeline.sim.writers.ubx import GPS_LEAP_S, write_ubx, write_ubx_base

START = datetime(2024, 5, 5, 10, 0, tzinfo=timezone.utc)
GPS_EPOCH = datetime(1980, 1, 6, tzinfo=timezone.utc)


def _tow(when: datetime) -> float:
    """GPS time of week [s] of a UTC instant."""
    return ((when - GPS_EPOCH).total_seconds() + GPS_LEAP_S) % 604800


def _wrap(a):
    return np.angle(np.exp(1j * np.asarray(a)))


@pytest.fixture(scope="module")
def sim(aauship):
    v = aauship
    sched = chain(step_and_coast("surge", 5.0, 3.0, 3.0), free_decay("roll", 0.3, 3.0),
                  rudder_step(0.17, 3.0, 3.0, {"tau_x": 3.0}), rest_s=1.0)
    sensors = default_sensors() + (SensorSpec("gps2", ("lat", "lon", "sog", "cog"), 5.0,
                                              noise={"lat": 0.5, "lon": 0.5, "sog": 0.03}, suffix="@gps2"),)
    return simulate(v, sched, sensors=sensors, seed=4)


@pytest.fixture(scope="module")
def files(sim, tmp_path_factory):
    d = tmp_path_factory.mktemp("ubx")
    return {
        "rover": write_ubx(sim.log, d / "rover.ubx", receiver="gps", include_relposned=True, include_esf=True,
                           week_start=START),
        "plain": write_ubx(sim.log, d / "plain.ubx", week_start=START),
        "rover2": write_ubx(sim.log, d / "rover2.ubx", receiver="gps2", week_start=START),
        "base": write_ubx_base(d / "base.ubx", 30.0, 57.0501, 9.9201, height_m=42.0, week_start=START),
    }


# ----------------------------------------------------------------------------- round trip
def test_nav_pvt_round_trip(files, sim):
    log = read_ubx(files["rover"], sensor="gps")
    w = sim.log.channels
    t0 = _tow(START)
    assert log.format == "ubx" and log.time_reference == "gps"
    for q in ("lat", "lon", "sog", "cog"):
        c = log.channels[f"{q}@gps"]
        assert len(c.t) == len(w[f"{q}@gps"].t)
        np.testing.assert_allclose(c.t - t0, w[f"{q}@gps"].t, atol=1e-6)  # iTOW in ms; sim epochs are whole ms
        assert "GPS week 2313" in c.source
    assert np.max(np.abs(log.channels["lat@gps"].values - w["lat@gps"].values)) <= 0.5e-7 + 1e-12
    assert np.max(np.abs(log.channels["lon@gps"].values - w["lon@gps"].values)) <= 0.5e-7 + 1e-12
    assert np.max(np.abs(log.channels["sog@gps"].values - w["sog@gps"].values)) <= 0.5e-3 + 1e-9  # mm/s
    assert np.max(np.abs(_wrap(log.channels["cog@gps"].values - w["cog@gps"].values))) <= np.radians(0.5e-5) + 1e-12
    assert np.all(np.abs(log.channels["cog@gps"].values) <= np.pi)
    assert any(w_.startswith("t = 0 is the start of GPS week 2313 (2024-05-05") for w_ in log.summary.warnings)
    assert "NAV-PVT fix types: 3D" in " ".join(log.summary.warnings)
    assert "carrier solution: fixed" in " ".join(log.summary.warnings)


def test_relposned_heading(files, sim):
    log = read_ubx(files["rover"], sensor="gps")
    psi = log.channels["psi@gps"]
    truth = np.interp(psi.t - _tow(START), sim.log.channels["psi"].t, np.unwrap(sim.log.channels["psi"].values))
    assert np.max(np.abs(_wrap(psi.values - truth))) <= np.radians(0.5e-5) + 1e-9
    assert log.summary.read["NAV-RELPOSNED"] == len(psi.t)
    assert read_ubx(files["rover"]).channels.keys() >= {"psi@dual", "lat", "p@esf"}


def test_esf_raw_imu(files, sim):
    log = read_ubx(files["rover"], sensor="gps")
    w = sim.log.channels
    for name in ("p", "q", "r"):
        c = log.channels[f"{name}@esf_gps"]
        np.testing.assert_allclose(c.t - _tow(START), w[name].t, atol=1.5e-3)  # offset estimated from order
        assert np.max(np.abs(c.values - w[name].values)) <= np.radians(2.0**-13) + 1e-12
    for name in ("ax", "ay", "az"):
        c = log.channels[f"{name}@esf_gps"]
        assert np.max(np.abs(c.values - w[name].values)) <= 2.0**-11 + 1e-12
    assert any("ESF-RAW: sensor time tags put on GPS time" in x for x in log.summary.warnings)


def test_vectorised_nav_pvt_equals_pyubx2(files):
    rows = []
    with open(files["plain"], "rb") as fh:
        for _, m in UBXReader(fh, protfilter=UBX_PROTOCOL):
            rows.append((m.iTOW, m.lat, m.lon, m.gSpeed, m.headMot))
    ref = np.array(rows, float)
    log = read_ubx(files["plain"])
    tow = _tow(START)
    np.testing.assert_allclose(log.channels["lat"].t, ref[:, 0] / 1000, atol=1e-9)
    np.testing.assert_allclose(log.channels["lat"].values, ref[:, 1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(log.channels["lon"].values, ref[:, 2], rtol=0, atol=1e-12)
    np.testing.assert_allclose(log.channels["sog"].values, ref[:, 3] / 1000, rtol=0, atol=1e-12)
    np.testing.assert_allclose(log.channels["cog"].values, _wrap(np.radians(ref[:, 4])), rtol=0, atol=1e-9)
    assert log.channels["lat"].t[0] == pytest.approx(tow)


def test_two_receivers_and_a_base_as_three_logs(files, sim):
    logs = [read_ubx(files["plain"]), read_ubx(files["rover2"], sensor="gps2"), read_ubx(files["base"], sensor="base")]
    names = [set(lg.channels) for lg in logs]
    assert names[0] == {"lat", "lon", "sog", "cog"}
    assert names[1] == {"lat@gps2", "lon@gps2", "sog@gps2", "cog@gps2"}
    assert names[2] == {"lat@base", "lon@base", "sog@base", "cog@base"}
    assert not (names[0] & names[1]) and not (names[0] & names[2]) and not (names[1] & names[2])
    # All three on the same GPS clock: they overlap in time and agree on the week.
    spans = [(lg.channels[sorted(lg.channels)[0]].t[0], lg.channels[sorted(lg.channels)[0]].t[-1]) for lg in logs]
    assert max(s[0] for s in spans) < min(s[1] for s in spans)
    assert all(lg.summary.warnings[0] == logs[0].summary.warnings[0] for lg in logs)
    base = logs[2].channels
    np.testing.assert_allclose(base["lat@base"].values, 57.0501, atol=1e-7)
    np.testing.assert_allclose(base["sog@base"].values, 0.0)
    assert len(base["lat@base"].t) == 31
    np.testing.assert_allclose(np.diff(base["lat@base"].t), 1.0)
    w = sim.log.channels
    assert np.max(np.abs(logs[1].channels["lat@gps2"].values - w["lat@gps2"].values)) <= 0.5e-7 + 1e-12


def test_itow_week_rollover_is_unwrapped(sim, tmp_path):
    # 10 s before the end of GPS week 2313 (Saturday 23:59:50 GPS is 23:59:32 UTC).
    end_of_week = GPS_EPOCH + timedelta(weeks=2314) - timedelta(seconds=GPS_LEAP_S)
    start = end_of_week - timedelta(seconds=10)
    p = write_ubx(sim.log, tmp_path / "wrap.ubx", receiver="gps", include_relposned=True, week_start=start)
    raw = [m.iTOW for _, m in UBXReader(open(p, "rb"), protfilter=UBX_PROTOCOL) if m.identity == "NAV-PVT"]
    assert min(raw) < 1000 and max(raw) > 604_790_000  # the file really wraps
    log = read_ubx(p, sensor="gps")
    for c in log.channels.values():
        assert np.all(np.diff(c.t) > 0)
    t = log.channels["lat@gps"].t
    np.testing.assert_allclose(t - 604790.0, sim.log.channels["lat@gps"].t, atol=1e-6)
    assert t[-1] > 604800.0
    assert log.channels["psi@gps"].t[-1] > 604800.0
    assert "GPS week 2313" in log.summary.warnings[0]


def test_heading_without_valid_flag_is_rejected_and_counted(sim, tmp_path):
    t = sim.log.channels["lat@gps"].t
    half = float(t[len(t) // 2])

    def part(lo, hi):
        return RawLog("hand", "sim", {k: Channel(k, c.t[(c.t >= lo) & (c.t < hi)], c.values[(c.t >= lo) & (c.t < hi)])
                                      for k, c in sim.log.channels.items()}, IngestSummary("hand", "sim"))

    a = write_ubx(part(0, half), tmp_path / "a.ubx", receiver="gps", include_relposned=True, week_start=START)
    b = write_ubx(part(half, 1e9), tmp_path / "b.ubx", receiver="gps", include_relposned=True, carr_soln="none",
                  week_start=START)
    p = tmp_path / "ab.ubx"
    p.write_bytes(a.read_bytes() + b.read_bytes())
    log = read_ubx(p)
    n_bad = int((t >= half).sum())
    assert len(log.channels["psi@dual"].t) == len(t) - n_bad
    assert log.summary.skipped["NAV-RELPOSNED"] == n_bad
    assert any(f"NAV-RELPOSNED: {n_bad} heading(s) without relPosHeadingValid" in w for w in log.summary.warnings)
    assert "carrier solution: none" in " ".join(log.summary.warnings)
    assert len(log.channels["lat"].t) == len(t)


# ----------------------------------------------------------------------------- damaged files
def _rtcm_frame(msg_no: int, payload_len: int = 19) -> bytes:
    from pipeline.ingest.sniff import crc24q

    body = bytes([msg_no >> 4, (msg_no & 0x0F) << 4]) + bytes(range(payload_len - 2))
    head = b"\xd3" + bytes([payload_len >> 8, payload_len & 0xFF]) + body
    return head + crc24q(head).to_bytes(3, "big")


def test_damaged_frames_counted_once_where_their_length_leads_to_the_next_frame(files, tmp_path):
    # pyubx2 (validation off) yields a frame whose checksum fails as one message and resumes after
    # its declared length; a "b5 62" inside its payload is not a second frame. Same for an RTCM 3
    # frame with a broken CRC that ends where the next frame starts. Junk elsewhere stays garbage.
    data = files["plain"].read_bytes()
    size = 100
    frames = [data[i:i + size] for i in range(0, len(data), size)]
    bad = bytearray(frames[10])
    bad[40:42] = b"\xb5\x62"  # a sync pair inside the payload; the checksum no longer matches
    rtcm_bad = bytearray(_rtcm_frame(1077))
    rtcm_bad[10] ^= 0xFF
    junk = b"\xd3\x00\x13junk"  # an RTCM-like header whose length leads nowhere
    body = (b"".join(frames[:10]) + bytes(bad) + b"".join(frames[11:20]) + _rtcm_frame(1005) + bytes(rtcm_bad)
            + b"".join(frames[20:30]) + junk + b"".join(frames[30:]))
    p = tmp_path / "damaged.ubx"
    p.write_bytes(body)
    s = read_ubx(p).summary
    assert s.skipped["BAD_CHECKSUM"] == 1
    assert s.skipped["RTCM3-1005"] == 1 and s.skipped["RTCM3_BAD_CRC"] == 1
    assert s.skipped["GARBAGE_BYTES"] == size + len(junk)  # the bad UBX frame's bytes and the junk
    assert any(w == "bad CRC: 1 RTCM 3 frame(s) skipped" for w in s.warnings)
    with open(p, "rb") as fh:
        lib = sum(raw is not None for raw, _ in UBXReader(fh, protfilter=7, quitonerror=0, validate=0,
                                                           msgmode=0, parsing=False))
    ours = sum(s.read.values()) + sum(v for k, v in s.skipped.items() if k != "GARBAGE_BYTES")
    assert ours == lib


def test_crc_error_garbage_nmea_duplicate_and_truncation(files, tmp_path):
    data = files["plain"].read_bytes()
    clean = read_ubx(files["plain"])
    n = len(clean.channels["lat"].t)
    size = 100  # NAV-PVT frame: 6 + 92 + 2
    assert len(data) == n * size
    frames = [data[i:i + size] for i in range(0, len(data), size)]
    bad = bytearray(frames[10])
    bad[40] ^= 0xFF  # payload byte: checksum no longer matches
    nmea = b"$GNGGA,100000.00,5703.0,N,00955.2,E,1,12,0.8,10.0,M,40.0,M,,*47\r\n"
    body = (b"".join(frames[:10]) + bytes(bad) + b"\x00\x01garbage" + b"".join(frames[11:30]) + nmea
            + frames[29] + b"".join(frames[30:]))
    p = tmp_path / "bad.ubx"
    p.write_bytes(body[:-37])  # cut inside the last frame
    log = read_ubx(p)
    s = log.summary
    assert s.skipped["BAD_CHECKSUM"] == 1
    # A GGA has no date: it cannot be put on the UBX (GPS week) clock, so it is counted, not used.
    assert s.skipped["NMEA GGA (no date to place it on the UBX clock)"] == 1
    assert s.skipped["GARBAGE_BYTES"] == size + 9  # the bad frame's bytes and the junk
    assert any(w == "truncated: 63 trailing bytes (an incomplete last frame) ignored" for w in s.warnings)
    assert any("1 message(s) with a duplicate or out-of-order iTOW" in w for w in s.warnings)
    assert len(log.channels["lat"].t) == n - 2  # the bad frame and the cut one
    keep = np.ones(n, bool)
    keep[[10, n - 1]] = False
    np.testing.assert_array_equal(log.channels["lat"].values, clean.channels["lat"].values[keep])


def test_no_fix_samples_are_counted(tmp_path):
    frames = [UBXMessage("NAV", "NAV-PVT", GET, iTOW=1000 * k, fixType=3 if k > 2 else 0, gnssFixOk=int(k > 2),
                         lat=57.0, lon=9.9).serialize() for k in range(6)]
    p = tmp_path / "nofix.ubx"
    p.write_bytes(b"".join(frames))
    log = read_ubx(p)
    assert len(log.channels["lat"].t) == 3
    assert log.summary.skipped["NAV-PVT"] == 3
    assert any("fix types: no fix 3, 3D 3" in w for w in log.summary.warnings)
    p.write_bytes(b"".join(frames[:3]))
    with pytest.raises(IngestError, match="expected UBX NAV-PVT, NAV-PVAT, NAV-ATT, HNR-PVT, NAV-RELPOSNED, ESF-RAW/MEAS messages or NMEA fixes with usable samples"):
        read_ubx(p)


@pytest.mark.parametrize("content, expected", [
    (b"", "empty file"),
    (b"$GPGGA,hello*00\r\n" * 40, "found no valid UBX frame"),
    (bytes(range(256)) * 10, "found no valid UBX frame"),
    (b"\xb5\x62\x01\x07\x5c\x00" + bytes(40), r"found no valid UBX frame in 46 bytes \(truncated"),
])
def test_not_a_ubx_file(tmp_path, content, expected):
    p = tmp_path / "x.ubx"
    p.write_bytes(content)
    with pytest.raises(IngestError, match=expected) as err:
        read_ubx(p)
    assert "expected" in str(err.value) and "found" in str(err.value)


def test_missing_file_and_no_usable_message(tmp_path):
    with pytest.raises(IngestError, match="expected a file, found nothing"):
        read_ubx(tmp_path / "nope.ubx")
    p = tmp_path / "clock.ubx"
    p.write_bytes(UBXMessage("NAV", "NAV-CLOCK", GET, iTOW=5).serialize() * 3)
    with pytest.raises(IngestError, match=r"found none \(messages: NAV-CLOCK 3\)"):
        read_ubx(p)


def test_reading_leaves_the_file_unchanged(files):
    before = hashlib.sha256(files["rover"].read_bytes()).hexdigest()
    read_ubx(files["rover"], sensor="gps")
    assert hashlib.sha256(files["rover"].read_bytes()).hexdigest() == before


def test_fuzz_truncation_and_byte_flips(files, tmp_path):
    data = files["rover"].read_bytes()[:30_000]
    outcomes = fuzz_reader(data, lambda p: read_ubx(p, sensor="gps"), tmp_path, ".ubx", seed=7)
    assert outcomes["read"] >= 25
    print(f"\nUBX fuzz: {outcomes}")


# ----------------------------------------------------------------------------- speed
def _retimed(block: bytes, add_ms: int) -> bytes:
    """NAV-PVT frames (100 bytes each) with ``add_ms`` added to iTOW and the checksums redone."""
    f = np.frombuffer(block, np.uint8).reshape(-1, 100).copy()
    itow = f[:, 6:10].copy().view("<u4")[:, 0] + np.uint32(add_ms)
    f[:, 6:10] = itow.astype("<u4").view(np.uint8).reshape(-1, 4)
    run = np.cumsum(f[:, 2:98], axis=1, dtype=np.uint8)
    f[:, 98] = run[:, -1]
    f[:, 99] = np.cumsum(run, axis=1, dtype=np.uint8)[:, -1]
    return f.tobytes()


def test_nav_pvt_vectorised_is_much_faster_than_a_pyubx2_loop(tmp_path):
    # 500 epochs through the writer (pyubx2 builds ~1 ms per message), repeated 10 times later
    # in the week: 5,000 distinct NAV-PVT messages (benchmarks/ingest.py times the long files).
    n_block, n = 500, 5_000
    t = np.arange(n_block) * 0.1
    rng = np.random.default_rng(1)
    chans = {"lat": Channel("lat", t, 57.05 + 1e-5 * np.cumsum(rng.standard_normal(n_block))),
             "lon": Channel("lon", t, 9.92 + 1e-5 * np.cumsum(rng.standard_normal(n_block))),
             "sog": Channel("sog", t, np.abs(2.0 + rng.standard_normal(n_block))),
             "cog": Channel("cog", t, _wrap(rng.uniform(-4, 4, n_block)))}
    block = write_ubx(RawLog("hand", "sim", chans, IngestSummary("hand", "sim")), tmp_path / "block.ubx",
                      week_start=START).read_bytes()
    p = tmp_path / "long.ubx"
    p.write_bytes(b"".join(_retimed(block, k * n_block * 100) for k in range(n // n_block)))
    data = p.read_bytes()

    t0 = time.perf_counter()
    rows = []
    for _, m in UBXReader(io.BytesIO(data), protfilter=UBX_PROTOCOL):
        if m.identity == "NAV-PVT":
            rows.append((m.iTOW, m.lat, m.lon, m.gSpeed, m.headMot))
    t1 = time.perf_counter()
    log = read_ubx(p)
    t2 = time.perf_counter()
    assert len(rows) == n == len(log.channels["lat"].t)
    np.testing.assert_allclose(log.channels["lat"].values, [r[1] for r in rows], rtol=0, atol=1e-12)
    ratio = (t1 - t0) / (t2 - t1)
    print(f"\nNAV-PVT {n} messages: vectorised {n / (t2 - t1):,.0f} msg/s, pyubx2 UBXReader loop "
          f"{n / (t1 - t0):,.0f} msg/s, ratio {ratio:.0f}x")
    assert ratio >= 5.0


# ----------------------------------------------------------------------------- writer errors
def test_writer_errors(sim, tmp_path):
    with pytest.raises(SimError, match=r"receiver 'gps9' needs channels \['lat@gps9', 'lon@gps9'\]"):
        write_ubx(sim.log, tmp_path / "x.ubx", receiver="gps9")
    with pytest.raises(SimError, match="timezone-aware"):
        write_ubx(sim.log, tmp_path / "x.ubx", week_start=datetime(2024, 5, 5))
    no_psi = dataclasses.replace(sim.log, channels={k: v for k, v in sim.log.channels.items() if k != "psi"})
    with pytest.raises(SimError, match="NAV-RELPOSNED needs a heading channel 'psi'"):
        write_ubx(no_psi, tmp_path / "x.ubx", include_relposned=True)
    with pytest.raises(SimError, match="carr_soln expected one of"):
        write_ubx(sim.log, tmp_path / "x.ubx", carr_soln="rtk")
    assert not (tmp_path / "x.ubx").exists()
    with pytest.raises(SimError, match="positive duration"):
        write_ubx_base(tmp_path / "b.ubx", 0.0, 57.0, 9.9)


def test_progress_bar_only_when_asked(files, capsys, monkeypatch):
    read_ubx(files["rover"], sensor="gps", progress=True)
    assert re.search(r"rover\.ubx", capsys.readouterr().err)
    monkeypatch.setenv("CI", "1")
    read_ubx(files["rover"], sensor="gps")
    assert capsys.readouterr().err == ""
