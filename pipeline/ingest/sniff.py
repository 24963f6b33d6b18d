"""Which reader a log file needs, decided by its content (the extension only breaks ties).

Loggers and people name files freely: a UBX capture saved as ``.log``, NMEA as ``.txt``, RTCM
corrections as ``.bin``. :func:`sniff` looks at the first bytes for each format's signature and
answers the format name, or ``None`` with a description of what the bytes look like, so the
error can say what was found rather than repeating the extension.

| format | signature |
|---|---|
| ulog | ``ULog`` + ``01 12 35`` magic at byte 0 |
| dataflash | ``A3 95 80`` (a FMT record) at byte 0 |
| rosbag | ``#ROSBAG V2.0``, ``SQLite format 3``, ``\\x89MCAP`` at byte 0 |
| tlog | 8-byte big-endian microsecond stamp (years 2000-2100) followed by a MAVLink 1/2 start byte |
| ubx | at least one UBX frame (``B5 62``) with a valid checksum in the first 256 kB |
| nmea | at least one checksummed NMEA sentence in the first 256 kB |
| rtcm3 | RTCM 3 frames (``D3``, 10-bit length, CRC-24Q) and nothing else known: corrections only |
"""

from __future__ import annotations

import re
import struct
from pathlib import Path

import numpy as np

#: Bytes looked at [bytes].
HEAD_BYTES = 256 * 1024
_ULOG = b"ULog\x01\x12\x35"
_NMEA_RE = re.compile(rb"[$!]([A-Z0-9]{2,10})(?:,([\x20-\x23\x25-\x29\x2b-\x7e]*))?\*([0-9A-Fa-f]{2})")


def _crc24q_table() -> list[int]:
    table = []
    for i in range(256):
        crc = i << 16
        for _ in range(8):
            crc <<= 1
            if crc & 0x1000000:
                crc ^= 0x1864CFB
        table.append(crc & 0xFFFFFF)
    return table


_CRC24Q = _crc24q_table()


def crc24q(data: bytes) -> int:
    """CRC-24Q of ``data`` (the RTCM 3 frame check).

    Parameters
    ----------
    data : bytes
        Frame from the ``D3`` preamble to the end of the payload.

    Returns
    -------
    int
        24-bit checksum.
    """
    crc = 0
    for b in data:
        crc = ((crc << 8) & 0xFFFFFF) ^ _CRC24Q[((crc >> 16) ^ b) & 0xFF]
    return crc


def rtcm3_frames(data: bytes) -> dict[int, int]:
    """RTCM 3 frames with a valid CRC in ``data``, counted by message number.

    Parameters
    ----------
    data : bytes
        Any byte stream (frames may be mixed with UBX or NMEA).

    Returns
    -------
    dict
        Message number -> count.
    """
    out: dict[int, int] = {}
    i = data.find(b"\xd3")
    n = len(data)
    while 0 <= i < n - 5:
        if data[i + 1] & 0xFC == 0:
            length = ((data[i + 1] & 0x03) << 8) | data[i + 2]
            end = i + 3 + length + 3
            if length >= 2 and end <= n and crc24q(data[i:end - 3]) == int.from_bytes(data[end - 3:end], "big"):
                msg = (data[i + 3] << 4) | (data[i + 4] >> 4)
                out[msg] = out.get(msg, 0) + 1
                i = data.find(b"\xd3", end)
                continue
        i = data.find(b"\xd3", i + 1)
    return out


def has_ubx_frame(head: bytes) -> bool:
    """True when ``head`` holds at least one UBX frame with a valid Fletcher checksum.

    Parameters
    ----------
    head : bytes
        The first bytes of a file.
    """
    i = head.find(b"\xb5\x62")
    while 0 <= i < len(head) - 8:
        length = head[i + 4] | (head[i + 5] << 8)
        end = i + 6 + length
        if end + 2 <= len(head):
            ck_a = ck_b = 0
            for b in head[i + 2:end]:
                ck_a = (ck_a + b) & 0xFF
                ck_b = (ck_b + ck_a) & 0xFF
            if ck_a == head[end] and ck_b == head[end + 1]:
                return True
        i = head.find(b"\xb5\x62", i + 2)
    return False


def _nmea_ok(head: bytes) -> bool:
    from functools import reduce
    from operator import xor

    return any(reduce(xor, m.group(0)[1:-3], 0) == int(m.group(3), 16) for m in _NMEA_RE.finditer(head))


def _tlog(head: bytes) -> bool:
    if len(head) < 9 or head[8] not in (0xFE, 0xFD):
        return False
    (stamp,) = struct.unpack(">Q", head[:8])
    return 946_684_800e6 <= stamp <= 4_102_444_800e6


def describe(head: bytes) -> str:
    """What the first bytes of a file look like, for an error message.

    Parameters
    ----------
    head : bytes
        The first bytes.
    """
    if not head:
        return "an empty file"
    sample = head[:4096]
    printable = np.frombuffer(sample, np.uint8)
    text_share = float(np.mean(((printable >= 0x20) & (printable < 0x7F)) | np.isin(printable, (9, 10, 13))))
    first = head[:16].hex(" ")
    if text_share > 0.95:
        line = sample.split(b"\n", 1)[0][:60].decode("ascii", "replace").strip()
        return f"text ({100 * text_share:.0f}% printable) beginning {line!r}"
    hints = []
    if head[:2] == b"\xa0\xa2" or b"\xa0\xa2" in head[:64]:
        hints.append("SiRF binary (A0 A2)")
    if head[:1] == b"\x10":
        hints.append("possibly Trimble TSIP (DLE 10)")
    hint = f", {'; '.join(hints)}" if hints else ""
    return f"binary data ({100 * text_share:.0f}% printable) beginning {first}{hint}"


def sniff(path: str | Path) -> tuple[str | None, str]:
    """Format of a log file from its content.

    Parameters
    ----------
    path : str or Path
        A file.

    Returns
    -------
    (str or None, str)
        Format (``ulog``, ``dataflash``, ``rosbag``, ``tlog``, ``ubx``, ``nmea``, ``rtcm3``) or
        None, and a description of the first bytes (for error messages).
    """
    with open(path, "rb") as fh:
        head = fh.read(HEAD_BYTES)
    if head.startswith(_ULOG):
        return "ulog", "ULog header"
    if head.startswith(b"\xa3\x95\x80"):
        return "dataflash", "DataFlash FMT record"
    if head.startswith((b"#ROSBAG V2.0", b"SQLite format 3\x00", b"\x89MCAP")):
        return "rosbag", "ROS bag header"
    if _tlog(head):
        return "tlog", "MAVLink telemetry with 8-byte time stamps"
    if has_ubx_frame(head):
        return "ubx", "UBX frames"
    if _nmea_ok(head):
        return "nmea", "NMEA 0183 sentences"
    frames = rtcm3_frames(head)
    if frames:
        kinds = ", ".join(f"{k} x{v}" for k, v in sorted(frames.items()))
        return "rtcm3", f"RTCM 3 correction frames only ({kinds})"
    return None, describe(head)
