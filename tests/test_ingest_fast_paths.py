"""The vectorised decoders added for ingest speed (issue 3, "Performance") give exactly what the
message-by-message reference decoders give: UBX NAV-RELPOSNED and ESF-RAW against pyubx2, ROS bag
topics decoded in one step against rosbags' deserialisation of each message.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pyubx2 import GET, UBXReader

import pipeline.ingest.rosbag as rosbag_reader
from pipeline.ingest import read_log
from pipeline.ingest.rosbag import message_layout
from pipeline.ingest.ubx import _esf_rows, _frames, _relposned_vectorised
from pipeline.records import Channel, RawLog
from pipeline.sim import chain, rudder_step, simulate
from pipeline.sim.writers import write_log
from pipeline.vessel import load_vessel

from conftest import AAUSHIP as VESSEL  # noqa: E402 - loaded once per session


@pytest.fixture(scope="module")
def log():
    return simulate(VESSEL, chain(rudder_step(np.radians(10), 6.0, 4.0, {"tau_x": 2.86}), rest_s=1.0), seed=2).log


def test_ubx_relposned_and_esf_match_pyubx2(log, tmp_path):
    path = write_log(log, tmp_path / "rover.ubx", receiver="gps", include_relposned=True, include_esf=True)
    data = path.read_bytes()
    buf = np.frombuffer(data, np.uint8)
    fr = _frames(buf)
    starts, ends = fr["starts"], fr["ends"]
    rel = np.flatnonzero((fr["cls"] == 0x01) & (fr["id"] == 0x3C))
    esf = np.flatnonzero((fr["cls"] == 0x10) & (fr["id"] == 0x03))
    assert len(rel) > 50 and len(esf) > 500
    fast, slow = _relposned_vectorised(buf, starts, ends, rel)
    assert len(slow) == 0
    for m, i in zip(fast, rel.tolist()):
        ref = UBXReader.parse(data[starts[i]:ends[i]], msgmode=GET)
        assert (m.iTOW, m.relPosHeading, m.relPosHeadingValid, m.carrSoln) == (
            ref.iTOW, ref.relPosHeading, ref.relPosHeadingValid, ref.carrSoln)
    rows, ok = _esf_rows(buf, starts, ends, esf)
    assert ok.all()
    expected = []
    for j, i in enumerate(esf.tolist()):
        ref = UBXReader.parse(data[starts[i]:ends[i]], msgmode=GET)
        k = 1
        while hasattr(ref, f"data_{k:02d}"):
            word = int.from_bytes(getattr(ref, f"data_{k:02d}"), "little")
            value = word & 0xFFFFFF
            expected.append((j, (word >> 24) & 0xFF, value - (1 << 24) if value & 0x800000 else value,
                             int.from_bytes(getattr(ref, f"sTag_{k:02d}"), "little")))
            k += 1
    np.testing.assert_array_equal(rows, np.array(expected, np.int64))


@pytest.mark.parametrize("ext", [".bag", ".db3", ".mcap"])
def test_rosbag_topics_decoded_at_once_match_message_by_message(log, tmp_path, monkeypatch, ext):
    # A body-frame twist and a rudder Float64 too, so every role of the writer is covered.
    ch = dict(log.channels)
    t = ch["r"].t
    ch.update({"u": Channel("u", t, np.interp(t, ch["sog"].t, ch["sog"].values)),
               "v": Channel("v", t, np.zeros(len(t))), "x_n": Channel("x_n", t, np.zeros(len(t))),
               "y_e": Channel("y_e", t, np.zeros(len(t)))})
    path = write_log(RawLog(log.source, log.format, ch, log.summary), tmp_path / f"trial{ext}")
    fast = read_log(path)
    monkeypatch.setattr(rosbag_reader, "FAST_DECODE", False)
    slow = read_log(path)
    assert set(fast.channels) == set(slow.channels) and len(fast.channels) >= 15
    for name in fast.channels:
        a, b = fast.channels[name], slow.channels[name]
        np.testing.assert_array_equal(a.t, b.t, err_msg=name)
        np.testing.assert_array_equal(a.values, b.values, err_msg=name)
        assert a.source == b.source
    assert fast.summary == slow.summary and fast.start_time == slow.start_time


def test_message_layout_refuses_what_it_cannot_lay_out():
    defs = {"a/msg/Seq": ([], [("data", (4, ((1, ("float64", 0)), 0)))]),
            "a/msg/Two": ([], [("x", (1, ("uint8", 0))), ("y", (1, ("float64", 0)))])}
    assert message_layout(defs, "a/msg/Seq", b"\x00\x01\x00\x00" + bytes(12), ros1=False) is None
    assert message_layout(defs, "a/msg/Two", b"\x01\x01\x00\x00" + bytes(16), ros1=False) is None  # big-endian
    fields, _ = message_layout(defs, "a/msg/Two", b"\x00\x01\x00\x00" + bytes(16), ros1=False)
    assert fields == {"x": (4, "u1"), "y": (12, "<f8")}  # CDR aligns the float64 to 8 after the header
    fields, _ = message_layout(defs, "a/msg/Two", bytes(9), ros1=True)
    assert fields == {"x": (0, "u1"), "y": (1, "<f8")}  # ROS 1 packs without alignment
    assert message_layout(defs, "a/msg/Unknown", bytes(9), ros1=True) is None
