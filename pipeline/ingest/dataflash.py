"""ArduPilot DataFlash binary logs (``.bin``), as the autopilot writes them to its SD card.

A DataFlash log is a sequence of records ``A3 95 <type id> <fields>``, self-described by FMT
records (type 128, format ``BBnNZ``: Type, Length, Name, Format, Columns). There is no checksum:
a record is found by its header and its length comes from its FMT.

The file is opened through pymavlink's ``DFReader_binary``. Its record index (``offsets``,
``counts``, ``formats``, ``name_to_id``/``id_to_name``) is built here, vectorised and
fault-tolerant, by overriding ``init_arrays_fast``/``init_arrays``: pymavlink 2.4.50's own
indexers (the Cython one and the Python fallback) stop at the first record with an unknown type
id or an FMT with an impossible length, so one corrupted byte would silently drop the rest of the
log. The index walks the header chain the way ``DFReader_binary._parse_next`` does (a record's
length from its FMT, byte-wise resynchronisation to the next ``A3 95`` with a known type), and
counts garbage and a truncated tail instead of printing them.

:func:`read_dataflash` then decodes each used message type in bulk: the records at the indexed
offsets are gathered with numpy and viewed through a structured dtype built from the FMT format
string, with pymavlink's scaling (``DFReader.FORMAT_TO_STRUCT``: ``c``/``C``/``e``/``E`` x0.01,
``L`` x1e-7). :func:`read_dataflash_slow` is the reference: the same index, then one
``DFMessage`` per record from ``recv_match``; the two give identical channels.

Mapping (``VARIABLE_MAP``; SI units, radians, Fossen frames: NED world, body x fwd, y stbd, z down)
-------------------------------------------------------------------------------------------------
ATT    Roll, Pitch, Yaw [deg]            -> phi, theta, psi [rad] (psi wrapped to (-pi, pi])
IMU    GyrX/Y/Z [rad/s], AccX/Y/Z [m/s^2] -> p q r ax ay az from instance I=0; ``p@imu1`` ... from I=1
       (``@imu<I>`` for instance I >= 1; legacy IMU2/IMU3 messages are instances 1/2)
GPS    Lat, Lng [deg], Spd [m/s], GCrs [deg] -> lat lon sog cog from instance I=0, ``lat@gps2`` ... from
       I=1 (``@gps<I+1>``; legacy GPS2 message is instance 1). Samples with Status < 2 (no fix) dropped.
POS    Lat, Lng [deg]                    -> lat@ekf, lon@ekf (the navigation filter's position)
XKF1   VN, VE [m/s] (EKF3 core C)         -> sog@ekf = |v|, cog@ekf = atan2(VE, VN) for core 0
       (``@ekf<C>`` for core C >= 1); NKF1 (EKF2) is read the same way when the log has no XKF1
RCOU   C1..C14 [us]                      -> inputs through the vessel's ``[[actuators]]`` (source servo)
RCIN   C1..C14 [us]                      -> inputs through the actuator maps with source rc; an input
       that a servo map also gives is named ``<input>@rc``

Time: ``time_reference='boot'``; ``t`` [s] = TimeUS * 1e-6 of each record (autopilot boot clock);
logs before 2015 stamp records with TimeMS [ms], read as TimeUS = 1000 TimeMS.

Corrupted records (DataFlash has no checksum) are dropped and counted per type in a warning:
a TimeUS far outside the span the bulk of the log lies in (:func:`plausible_span`), an instance
number above ``MAX_INSTANCE``, a value beyond ``VALUE_LIMITS`` (40 rad/s, 40 g, |lat| > 90 deg
...). So one bad record can never stretch the log to 5e12 s.
``RawLog.start_time`` is the UTC of boot [s, Unix]: the median over GPS records with a fix of
(GWk, GMS as GPS time) - TimeUS, less the leap seconds; it carries the receiver-to-autopilot
latency of the GPS record's TimeUS (tens of ms on real autopilots). NaN without such records.
"""

from __future__ import annotations

import contextlib
import math
import struct
import sys
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
from pymavlink.DFReader import FORMAT_TO_STRUCT, DFFormat, DFReader_binary, null_term

from ..errors import IngestError
from ..geo import wrap_pi
from ..records import Channel, IngestSummary, RawLog
from ..terminal import want_progress
from ..vessel import ActuatorMap, Vessel
from ._common import actuators_reading, check_file, describe_failure
from ._gpstime import GPS_EPOCH_UNIX, WEEK_S, leap_seconds, unix_text

HEAD1, HEAD2 = 0xA3, 0x95
FMT_TYPE = 0x80
FMT_LENGTH = 89
_DEG = math.pi / 180.0

#: (message, field) -> (canonical base name, scale to SI after pymavlink's format scaling).
#: ``v_n``/``v_e`` (NED velocity [m/s]) are intermediate: they become ``sog`` and ``cog``.
#: The instance suffix (``INSTANCES``) is appended to the base name.
VARIABLE_MAP: dict[tuple[str, str], tuple[str, float]] = {
    ("ATT", "Roll"): ("phi", _DEG),
    ("ATT", "Pitch"): ("theta", _DEG),
    ("ATT", "Yaw"): ("psi", _DEG),
    ("IMU", "GyrX"): ("p", 1.0),
    ("IMU", "GyrY"): ("q", 1.0),
    ("IMU", "GyrZ"): ("r", 1.0),
    ("IMU", "AccX"): ("ax", 1.0),
    ("IMU", "AccY"): ("ay", 1.0),
    ("IMU", "AccZ"): ("az", 1.0),
    ("GPS", "Lat"): ("lat", 1.0),
    ("GPS", "Lng"): ("lon", 1.0),
    ("GPS", "Spd"): ("sog", 1.0),
    ("GPS", "GCrs"): ("cog", _DEG),
    ("POS", "Lat"): ("lat", 1.0),
    ("POS", "Lng"): ("lon", 1.0),
    ("XKF1", "VN"): ("v_n", 1.0),
    ("XKF1", "VE"): ("v_e", 1.0),
}

#: (message, field) -> FMTU unit labels (ArduPilot's UNIT records) the scale above assumes. A log
#: whose FMTU declares another unit for a field that is read is rejected.
RAW_UNITS: dict[tuple[str, str], tuple[str, ...]] = {
    ("ATT", "Roll"): ("deg",), ("ATT", "Pitch"): ("deg",), ("ATT", "Yaw"): ("deg", "degheading"),
    **{("IMU", f"Gyr{a}"): ("rad/s",) for a in "XYZ"},
    **{("IMU", f"Acc{a}"): ("m/s/s", "m/s^2") for a in "XYZ"},
    ("GPS", "Lat"): ("deglatitude", "deg"), ("GPS", "Lng"): ("deglongitude", "deg"), ("GPS", "Spd"): ("m/s",),
    ("GPS", "GCrs"): ("deg", "degheading"), ("POS", "Lat"): ("deglatitude", "deg"),
    ("POS", "Lng"): ("deglongitude", "deg"), ("XKF1", "VN"): ("m/s",), ("XKF1", "VE"): ("m/s",),
}

#: Message -> (instance field or None, instance number -> channel suffix).
INSTANCES: dict[str, tuple[str | None, Callable[[int], str]]] = {
    "ATT": (None, lambda k: ""),
    "IMU": ("I", lambda k: "" if k == 0 else f"@imu{k}"),
    "GPS": ("I", lambda k: "" if k == 0 else f"@gps{k + 1}"),
    "POS": (None, lambda k: "@ekf"),
    "XKF1": ("C", lambda k: "@ekf" if k == 0 else f"@ekf{k}"),
}

#: Legacy or alternative message names -> (message they are read as, instance number or None).
ALIASES: dict[str, tuple[str, int | None]] = {
    "IMU2": ("IMU", 1), "IMU3": ("IMU", 2), "GPS2": ("GPS", 1), "NKF1": ("XKF1", None),
}

#: Input messages: message -> (ActuatorMap.source, field name patterns tried in order, channels).
INPUT_MESSAGES: dict[str, tuple[str, tuple[str, ...], int]] = {
    "RCOU": ("servo", ("C{}", "Ch{}", "Chan{}"), 14),
    "RCIN": ("rc", ("C{}", "Ch{}", "Chan{}"), 14),
}

#: Fields read only to judge validity (Status) or to put the boot clock on UTC (GMS, GWk).
_EXTRA_FIELDS: dict[str, tuple[str, ...]] = {"GPS": ("Status", "GMS", "GWk")}
#: A boot-to-UTC offset whose GPS records disagree by more than this is reported [s].
_CLOCK_SPREAD_WARN_S = 0.5

#: struct code (pymavlink's FORMAT_TO_STRUCT) -> little-endian numpy type.
_NUMPY_OF_STRUCT = {"b": "i1", "B": "u1", "h": "<i2", "H": "<u2", "i": "<i4", "I": "<u4", "q": "<i8",
                    "Q": "<u8", "f": "<f4", "d": "<f8", "e": "<f2", "4s": "S4", "16s": "S16", "64s": "S64"}
_PROGRESS_DELAY_S = 1.0
#: Rows gathered per numpy fancy-index call, bounding the temporary index array [bytes / 8].
_GATHER_CHUNK = 1 << 22


# ----------------------------------------------------------------------------- index
@dataclass
class _Index:
    """Where the records are: on-chain offsets per type, and what was not a record."""

    offsets: dict[int, np.ndarray] = field(default_factory=dict)
    lengths: np.ndarray = field(default_factory=lambda: np.zeros(256, np.int64))
    names: dict[int, str] = field(default_factory=dict)
    formats: dict[int, DFFormat] = field(default_factory=dict)
    undecodable: dict[int, str] = field(default_factory=dict)
    garbage_bytes: int = 0
    garbage_runs: int = 0
    truncated: int = 0
    bad_fmt: int = 0
    redefined: list[str] = field(default_factory=list)
    size: int = 0


def _parse_fmt(buf: np.ndarray, pos: int) -> tuple[int, int, str, str, str] | None:
    """Type, length, name, format and columns of the FMT record at ``pos``, or None when implausible."""
    body = bytes(buf[pos + 3:pos + FMT_LENGTH])
    ftype, flen, name_b, fmt_b, cols_b = struct.unpack("<BB4s16s64s", body)
    try:
        name = null_term(name_b.decode("ascii"))
        fmt = null_term(fmt_b.decode("ascii"))
        cols = null_term(cols_b.decode("ascii"))
    except UnicodeDecodeError:
        return None
    if flen < 3 or not name or not name.isprintable() or " " in name or not fmt.isprintable() \
            or not cols.isprintable():
        return None
    return ftype, flen, name, fmt, cols


def _decodable(flen: int, fmt: str, cols: str) -> str:
    """Empty string when numpy and pymavlink can decode the format, else why not."""
    bad = [c for c in fmt if c not in FORMAT_TO_STRUCT]
    if bad:
        return f"format characters {bad} unknown to pymavlink"
    size = struct.calcsize("<" + "".join(FORMAT_TO_STRUCT[c][0] for c in fmt))
    if size + 3 != flen:
        return f"format {fmt!r} packs {size + 3} bytes, FMT says {flen}"
    names = cols.split(",") if cols else []
    if len(names) != len(fmt) or len(set(names)) != len(names) or not all(names):
        return f"{len(fmt)} format characters but columns {cols!r}"
    return ""


def build_index(buf: np.ndarray) -> _Index:
    """Index the DataFlash records in ``buf`` (uint8), vectorised, tolerant of corruption.

    The chain of records is the one ``DFReader_binary._parse_next`` follows: from a record at
    ``pos`` of a known type, the next one starts at ``pos + length``; where no header is there
    (or the type is unknown), the scan resynchronises on the next ``A3 95``. Candidates where the
    next header follows exactly form runs that are accepted in one numpy step; only the
    irregular candidates (spurious headers inside payloads, garbage, unknown types) are walked in
    Python. A type counts as known from its FMT record on (ArduPilot writes FMT before first use).

    Parameters
    ----------
    buf : numpy.ndarray
        The whole log as uint8.

    Returns
    -------
    _Index
        Offsets of the records per type id (on the chain only), lengths, names and decodable
        ``DFFormat`` per type, garbage bytes and stretches, and the truncated tail [bytes].
    """
    n = len(buf)
    idx = _Index(size=n)
    idx.lengths[FMT_TYPE] = FMT_LENGTH
    idx.names[FMT_TYPE] = "FMT"
    idx.formats[FMT_TYPE] = DFFormat(FMT_TYPE, "FMT", FMT_LENGTH, "BBnNZ", "Type,Length,Name,Format,Columns")
    if n < 3:
        idx.garbage_bytes, idx.garbage_runs = n, int(n > 0)
        return idx
    cand = np.flatnonzero((buf[:-2] == HEAD1) & (buf[1:-1] == HEAD2))
    ctype = buf[cand + 2].astype(np.int64)
    never = np.iinfo(np.int64).max
    defined_at = np.full(256, never, np.int64)
    defined_at[FMT_TYPE] = -1
    definitions: dict[int, tuple[str, str, str, int]] = {}
    for pos in cand[(ctype == FMT_TYPE) & (cand + FMT_LENGTH <= n)].tolist():
        parsed = _parse_fmt(buf, pos)
        if parsed is None:
            idx.bad_fmt += 1
            continue
        ftype, flen, name, fmt, cols = parsed
        if ftype == FMT_TYPE:
            continue  # the FMT of FMT repeats the built-in definition
        if ftype in definitions:
            if definitions[ftype][:3] != (name, fmt, cols) or definitions[ftype][3] != flen:
                idx.redefined.append(f"{name} (type {ftype})")
            continue
        definitions[ftype] = (name, fmt, cols, flen)
        defined_at[ftype] = pos
        idx.lengths[ftype] = flen
        idx.names[ftype] = name
        why = _decodable(flen, fmt, cols)
        if why:
            idx.undecodable[ftype] = why
        else:
            idx.formats[ftype] = DFFormat(ftype, name, flen, fmt, cols)

    m = len(cand)
    length = idx.lengths[ctype]
    known = (length > 0) & (cand > defined_at[ctype])
    end = cand + length
    complete = known & (end <= n)
    succ = np.searchsorted(cand, end)  # first candidate at or after the record's end
    nxt = np.minimum(succ, m - 1) if m else succ
    regular = complete & (succ < m) & (cand[nxt] == end) & (succ == np.arange(m) + 1)
    irregular = np.flatnonzero(~regular)
    on = np.zeros(m, bool)
    truncated_at = -1
    k = 0
    while k < m:
        if regular[k]:
            # A run of records each followed exactly by the next: accept it in one step.
            j = int(np.searchsorted(irregular, k))
            stop = int(irregular[j]) if j < len(irregular) else m
            on[k:stop] = True
            k = stop
            continue
        if not known[k]:
            k += 1  # unknown type: resynchronise from the next header byte on
            continue
        if not complete[k]:
            truncated_at = int(cand[k])
            break
        on[k] = True
        k = int(succ[k])

    starts, ends = cand[on], end[on]
    covered = int((ends - starts).sum())
    tail_from = int(ends[-1]) if len(ends) else 0
    if truncated_at >= 0:
        idx.truncated = n - truncated_at
    else:
        tail = bytes(buf[tail_from:])
        # A cut inside a header leaves a prefix of A3 95 <type>.
        if tail and bytes((HEAD1, HEAD2)).startswith(tail[:2]) and len(tail) < 3:
            idx.truncated = len(tail)
    idx.garbage_bytes = n - covered - idx.truncated
    if len(starts):
        idx.garbage_runs = (int((starts[1:] > ends[:-1]).sum()) + int(starts[0] > 0)
                            + int(n - idx.truncated > tail_from))
    else:
        idx.garbage_runs = int(idx.garbage_bytes > 0)
    types_on = ctype[on]
    order = np.argsort(types_on, kind="stable")
    sorted_types = types_on[order]
    bounds = np.flatnonzero(np.diff(sorted_types)) + 1
    for grp in np.split(order, bounds):
        if len(grp):
            idx.offsets[int(types_on[grp[0]])] = starts[grp]
    return idx


class _IndexedDFReader(DFReader_binary):
    """``DFReader_binary`` with the fault-tolerant vectorised index of :func:`build_index`.

    ``init_clock`` is skipped: this module stamps samples with TimeUS directly, and pymavlink's
    clock search reads the whole log message by message when it has no GPS week.
    """

    index: _Index

    def init_arrays_fast(self, progress_callback=None) -> None:  # noqa: D102 - pymavlink hook
        buf = np.frombuffer(self.data_map, np.uint8)
        try:
            self.index = build_index(buf)
        finally:
            del buf  # the mmap cannot be closed while a numpy view of it exists
        self.formats = dict(self.index.formats)
        self.name_to_id = {name: t for t, name in self.index.names.items() if t in self.formats}
        self.id_to_name = {t: name for name, t in self.name_to_id.items()}
        empty = np.zeros(0, np.int64)
        self.offsets = [self.index.offsets.get(t, empty) if t in self.formats else empty for t in range(256)]
        self.counts = [len(o) for o in self.offsets]
        self._count = sum(self.counts)
        self.offset = 0

    init_arrays = init_arrays_fast

    def init_clock(self) -> None:  # noqa: D102 - pymavlink hook
        self.clock = None
        self._rewind(keep_messages=True)


def _open(p: Path) -> _IndexedDFReader:
    try:
        return _IndexedDFReader(str(p))
    except (OSError, ValueError) as exc:
        raise IngestError(f"{p}: expected a readable DataFlash log, found an error opening it ({describe_failure(exc)})") from None


# ----------------------------------------------------------------------------- decode
def _wanted() -> dict[str, tuple[str, ...]]:
    """Message -> fields to decode (TimeUS first)."""
    out: dict[str, list[str]] = defaultdict(lambda: ["TimeUS"])
    for (msg, f) in VARIABLE_MAP:
        out[msg].append(f)
    for msg, (inst, _) in INSTANCES.items():
        if inst:
            out[msg].append(inst)
    for msg, extra in _EXTRA_FIELDS.items():
        out[msg] += list(extra)
    for msg, (_, patterns, count) in INPUT_MESSAGES.items():
        out[msg] += [p.format(i) for p in patterns for i in range(1, count + 1)]
    return {k: tuple(dict.fromkeys(v)) for k, v in out.items()}


def _message_types(reader: _IndexedDFReader) -> dict[str, tuple[str, tuple[str, ...]]]:
    """Message names present in the log that are decoded -> (canonical message, present fields)."""
    wanted = _wanted()
    present = {name: reader.formats[t] for name, t in reader.name_to_id.items()}
    out: dict[str, tuple[str, tuple[str, ...]]] = {}
    for name, fmt in present.items():
        canon = ALIASES.get(name, (name, None))[0]
        if not len(reader.offsets[reader.name_to_id[name]]):
            continue
        if canon not in wanted:
            continue
        if name == "NKF1" and "XKF1" in present:
            continue  # EKF3 is the one ArduPilot flies on when both are logged
        # Only numeric fields: a corrupted FMT may declare a wanted column as a string.
        fields = tuple(f for f in wanted[canon] if f in fmt.colhash and fmt.format[fmt.colhash[f]] not in "nNZa")
        if "TimeUS" in fields:
            out[name] = (canon, fields)
        elif "TimeMS" in fmt.colhash and fmt.format[fmt.colhash["TimeMS"]] not in "nNZa":
            # Logs before ArduPilot 3.3 (2015) stamp records in milliseconds (TimeMS).
            out[name] = (canon, ("TimeMS",) + fields)
    return out


def _scale(values: np.ndarray, fmt_char: str) -> np.ndarray:
    """pymavlink's ``DFMessage.__getattr__`` scaling, bit for bit (it divides for multipliers < 1)."""
    mul = FORMAT_TO_STRUCT[fmt_char][1]
    # A corrupted record can hold a NaN or infinite float: it is dropped later as non-finite,
    # so the cast need not warn on the terminal.
    with np.errstate(invalid="ignore", over="ignore"):
        v = values.astype(np.float64)
    if mul is None:
        return v
    if 0.0 < mul < 1.0:
        return v / (1 / mul)
    return v * mul


def _decode_vectorised(reader: _IndexedDFReader, types: Mapping[str, tuple[str, tuple[str, ...]]],
                       tick: Callable[[int], None]) -> dict[str, dict[str, np.ndarray]]:
    """Decode every record of the wanted types in bulk: gather rows at the offsets, view as a struct."""
    buf = np.frombuffer(reader.data_map, np.uint8)
    try:
        out: dict[str, dict[str, np.ndarray]] = {}
        for name, (_, fields) in types.items():
            t = reader.name_to_id[name]
            fmt = reader.formats[t]
            offs = reader.offsets[t]
            width = fmt.len - 3
            dtype = np.dtype({"names": fmt.columns,
                              "formats": [_NUMPY_OF_STRUCT[FORMAT_TO_STRUCT[c][0]] for c in fmt.format]})
            rows = np.empty((len(offs), width), np.uint8)
            step = max(1, _GATHER_CHUNK // max(width, 1))
            cols = np.arange(width)
            for i in range(0, len(offs), step):
                rows[i:i + step] = buf[(offs[i:i + step] + 3)[:, None] + cols]
            rec = rows.view(dtype).reshape(len(offs))
            out[name] = {f: (rec[f].astype(np.int64) if f in ("TimeUS", "TimeMS")
                             else _scale(rec[f], fmt.format[fmt.colhash[f]]))
                         for f in fields}
            _time_us(out[name])
            tick(len(offs))
    finally:
        del buf
    return out


def _decode_slow(reader: _IndexedDFReader, types: Mapping[str, tuple[str, tuple[str, ...]]],
                 tick: Callable[[int], None]) -> dict[str, dict[str, np.ndarray]]:
    """Reference decoder: one pymavlink ``DFMessage`` per record through ``recv_match``."""
    rows: dict[str, list] = {name: [] for name in types}
    reader.rewind()
    while True:
        m = reader.recv_match(type=list(types), strict=True)
        if m is None:
            break
        name = m.get_type()
        rows[name].append(tuple(getattr(m, f) for f in types[name][1]))
        tick(1)
    out: dict[str, dict[str, np.ndarray]] = {}
    for name, (_, fields) in types.items():
        arr = rows[name]
        # TimeUS through uint64 so a corrupted stamp wraps exactly as in the vectorised path.
        out[name] = {f: (np.array([r[i] for r in arr], dtype=np.uint64).astype(np.int64) if f in ("TimeUS", "TimeMS")
                         else np.array([r[i] for r in arr], dtype=np.float64))
                     for i, f in enumerate(fields)}
        _time_us(out[name])
    return out


def _time_us(cols: dict[str, np.ndarray]) -> None:
    """Put a TimeMS column on the TimeUS scale (in place), so one code path serves both eras."""
    if "TimeMS" in cols:
        cols["TimeUS"] = cols.pop("TimeMS") * 1000


#: Largest instance number of a message that real autopilots log (IMU, GPS, EKF cores); a larger
#: one is a corrupted instance byte and its records are dropped.
MAX_INSTANCE = 9
#: Physical limits beyond which a value is a corrupted record, not a measurement [SI].
VALUE_LIMITS: dict[str, float] = {"p": 40.0, "q": 40.0, "r": 40.0,                  # rad/s (> 2000 deg/s)
                                  "ax": 400.0, "ay": 400.0, "az": 400.0,            # m/s^2 (> 40 g)
                                  "lat": 90.0, "lon": 180.0, "sog": 400.0,          # deg, deg, m/s
                                  "phi": 2 * math.pi, "theta": 2 * math.pi, "psi": 4 * math.pi,
                                  "cog": 4 * math.pi}


def plausible_span(times_us: list[np.ndarray]) -> tuple[float, float]:
    """The span of the log's boot clock [us] that its records can lie in.

    DataFlash has no checksum: a corrupted TimeUS (5e12 s where the log lasts an hour) would
    stretch any grid built over the log. From the 10th and 90th percentiles of every record
    time pooled (which hold 80 % of a uniformly logged flight), the span reaches five times
    their distance plus 60 s beyond each: a real record is never that far out, a corrupted one
    almost always is, and fewer than 10 % of corrupted records cannot move the percentiles.

    Parameters
    ----------
    times_us : list of numpy.ndarray
        TimeUS of every decoded message type [us].

    Returns
    -------
    (float, float)
        Lowest and highest plausible TimeUS [us].
    """
    parts = [np.asarray(t, float) for t in times_us if len(t)]
    if not parts:
        return -math.inf, math.inf
    p10, p90 = np.percentile(np.concatenate(parts), [10.0, 90.0])
    margin = 5.0 * (p90 - p10) + 60e6
    return float(max(p10 - margin, 0.0)), float(p90 + margin)


def _check_units(p: Path, reader: _IndexedDFReader, types: Mapping[str, tuple[str, tuple[str, ...]]]) -> None:
    """Raise when FMTU declares a unit other than ``RAW_UNITS`` for a field that is read.

    UNIT records map unit ids to labels and FMTU records give each message's unit ids; both are
    few, so pymavlink decodes them. Logs without FMTU (older firmware) are not checked.
    """
    if "UNIT" not in reader.name_to_id or "FMTU" not in reader.name_to_id:
        return
    labels: dict[str, str] = {}
    unit_ids: dict[int, str] = {}
    for kind in ("UNIT", "FMTU"):
        reader.rewind()
        while True:
            m = reader.recv_match(type=[kind], strict=True)
            if m is None:
                break
            try:
                if kind == "UNIT":
                    labels[chr(int(m.Id) & 0xFF)] = str(m.Label)
                else:
                    unit_ids.setdefault(int(m.FmtType), str(m.UnitIds))
            except (AttributeError, ValueError, TypeError):
                continue  # a damaged definition record: no unit to check against
    reader.rewind()
    for name, (canon, fields) in types.items():
        t = reader.name_to_id[name]
        ids = unit_ids.get(t)
        if ids is None:
            continue
        fmt = reader.formats[t]
        for f in fields:
            accepted = RAW_UNITS.get((canon, f))
            i = fmt.colhash[f]
            if accepted is None or i >= len(ids) or ids[i] in "-?":
                continue
            label = labels.get(ids[i])
            if label is not None and label not in accepted:
                raise IngestError(f"{p}: {name}.{f} expected in {' or '.join(accepted)} (FMTU unit), found unit "
                                  f"{ids[i]!r} = {label!r}; this reader's scaling would be wrong")


# ----------------------------------------------------------------------------- build


def _bar(p: Path, total: int, progress: bool | None) -> Any:
    if not want_progress(progress):
        return None
    from tqdm import tqdm

    # Auto mode shows the bar only when the read takes longer than a second.
    return tqdm(total=total, unit="msg", unit_scale=True, desc=p.name, file=sys.stderr, leave=False,
                delay=0.0 if progress else _PROGRESS_DELAY_S)


def _clean_times(tus: np.ndarray) -> np.ndarray:
    """Mask of records kept: isolated forward spikes removed, then strictly increasing (first kept).

    DataFlash has no checksum, so a corrupted TimeUS far in the future would otherwise make every
    later record of the type look out of order; a stamp above both of the next two is dropped.
    """
    t = tus.astype(np.int64)
    keep = np.ones(len(t), bool)
    if len(t) >= 3:
        keep[:-2] = ~((t[:-2] > t[1:-1]) & (t[:-2] > t[2:]))
    idx = np.flatnonzero(keep)
    tk = t[idx]
    ok = np.ones(len(tk), bool)
    if len(tk) > 1:
        ok[1:] = tk[1:] > np.maximum.accumulate(tk)[:-1]
    out = np.zeros(len(t), bool)
    out[idx[ok]] = True
    return out




def _split_instances(name: str, canon: str, cols: Mapping[str, np.ndarray]) -> list[tuple[int, np.ndarray]]:
    """(instance number, row mask) pairs of one message type."""
    n = len(cols["TimeUS"])
    alias_inst = ALIASES.get(name, (canon, None))[1]
    inst_field = INSTANCES.get(canon, (None, None))[0]
    if alias_inst is not None:
        return [(alias_inst, np.ones(n, bool))]
    if inst_field is None or inst_field not in cols:
        return [(0, np.ones(n, bool))]
    inst = cols[inst_field]
    return [(int(k), inst == k) for k in np.unique(inst)]


def _build(p: Path, decoded: Mapping[str, Mapping[str, np.ndarray]],
           types: Mapping[str, tuple[str, tuple[str, ...]]], reader: _IndexedDFReader,
           vessel: Vessel | None) -> RawLog:
    idx = reader.index
    warnings: list[str] = []
    read: Counter = Counter()
    skipped: Counter = Counter()
    for t, offs in idx.offsets.items():
        name = idx.names.get(t, f"TYPE_{t}")
        if name not in types:
            skipped[name] += len(offs)
    if idx.truncated:
        warnings.append(f"truncated: {idx.truncated} trailing bytes (an incomplete last record) ignored")
    if idx.garbage_bytes:
        skipped["GARBAGE_BYTES"] += idx.garbage_bytes
        warnings.append(f"garbage: {idx.garbage_bytes} byte(s) in {idx.garbage_runs} stretch(es) between records "
                        "skipped (no A3 95 header, or a type without FMT)")
    if idx.bad_fmt:
        warnings.append(f"{idx.bad_fmt} FMT record(s) with an impossible definition ignored")
    if idx.redefined:
        warnings.append(f"message type(s) defined twice with different FMT, first definition kept: "
                        f"{', '.join(sorted(set(idx.redefined)))}")
    for t, why in idx.undecodable.items():
        name = idx.names[t]
        count = len(idx.offsets.get(t, ()))
        if count:
            warnings.append(f"{name}: {count} record(s) not decodable ({why})")

    maps = tuple(vessel.actuators) if vessel is not None else ()
    produced: dict[str, Channel] = {}
    lo_us, hi_us = plausible_span([decoded[name]["TimeUS"] for name in types])
    impossible: Counter = Counter()
    if any("TimeMS" in decoded_fields for _, decoded_fields in types.values()):
        warnings.append("time stamps: TimeMS (milliseconds, logs before 2015) read as TimeUS = 1000 TimeMS")
    for name, (canon, _) in types.items():
        cols = decoded[name]
        n_msgs = len(cols["TimeUS"])
        used = np.zeros(n_msgs, bool)
        for inst, rows in _split_instances(name, canon, cols):
            if inst > MAX_INSTANCE or inst < 0:
                impossible[f"{name} instance {inst}"] += int(rows.sum())
                continue
            sub = {f: v[rows] for f, v in cols.items()}
            in_span = (sub["TimeUS"] >= lo_us) & (sub["TimeUS"] <= hi_us)
            if (~in_span).any():
                impossible[f"{name} time"] += int((~in_span).sum())
            keep = _clean_times(sub["TimeUS"]) & in_span
            bad = int((~keep).sum())
            if bad:
                warnings.append(f"{name}{'' if inst == 0 and canon == name else f'[{inst}]'}: {bad} record(s) with a "
                                "duplicate, out-of-order or isolated out-of-range TimeUS skipped (first kept)")
            t = sub["TimeUS"] * 1e-6
            chans, ok = _channels(name, canon, inst, t, sub, keep, maps, warnings, impossible)
            used[np.flatnonzero(rows)[ok]] = True
            for ch_name, ch in chans.items():
                if ch_name in produced:
                    warnings.append(f"{ch_name} is already read from {produced[ch_name].source}; "
                                    f"{name} not used for it")
                    continue
                produced[ch_name] = ch
        read[name] += int(used.sum())
        skipped[name] += int(n_msgs - used.sum())
    if impossible:
        warnings.append("corrupted records dropped (no checksum in DataFlash): "
                        + ", ".join(f"{k} {v}" for k, v in sorted(impossible.items()))
                        + f" (plausible TimeUS span {lo_us * 1e-6:.1f}-{hi_us * 1e-6:.1f} s; instance <= "
                        f"{MAX_INSTANCE}; values within physical limits)")
    for msg, (src, _, _) in INPUT_MESSAGES.items():
        if msg in types or not any(a.source == src for a in maps):
            continue
        wanted = ", ".join(f"{a.target} (channel {a.channel})" for a in maps if a.source == src)
        warnings.append(f"actuator map expects {msg} for {wanted}, found no {msg} records")

    start_time = _start_time(decoded, types, warnings)
    if not produced:
        found = ", ".join(f"{k} {v}" for k, v in sorted(skipped.items()) if k != "GARBAGE_BYTES") or "none"
        raise IngestError(f"{p}: expected usable ATT, IMU, GPS, POS, XKF1, RCOU or RCIN records, found none "
                          f"(records: {found})")
    summary = IngestSummary(path=str(p), format="dataflash", read=dict(read),
                            skipped={k: v for k, v in skipped.items() if v}, warnings=tuple(warnings))
    return RawLog(source=str(p), format="dataflash", channels=produced, summary=summary, time_reference="boot",
                  start_time=start_time)


def _start_time(decoded: Mapping[str, Mapping[str, np.ndarray]], types: Mapping[str, tuple[str, tuple[str, ...]]],
                warnings: list[str]) -> float:
    """UTC of boot (TimeUS = 0) [s, Unix] from the GPS records' week and time of week, NaN without.

    Each GPS record with a fix carries both clocks: TimeUS (boot) and GWk/GMS (GPS). The median
    of their difference over all such records is robust to a corrupted record or two; the spread
    is reported because it includes the receiver-to-autopilot latency jitter.
    """
    offsets = []
    for name, (canon, fields) in types.items():
        cols = decoded.get(name, {})
        if canon != "GPS" or not {"GMS", "GWk", "Status"} <= set(fields):
            continue
        ok = (cols["Status"] >= 2) & (cols["GWk"] > 0) & (cols["GMS"] >= 0) & (cols["GMS"] < WEEK_S * 1000) \
            & (cols["TimeUS"] > 0)
        if ok.any():
            gps = GPS_EPOCH_UNIX + cols["GWk"][ok] * WEEK_S + cols["GMS"][ok] * 1e-3
            offsets.append(gps - cols["TimeUS"][ok] * 1e-6)
    if not offsets:
        warnings.append("no GPS record with a fix and a GPS week: the boot clock has no absolute time (start_time NaN)")
        return math.nan
    off = np.concatenate(offsets)
    gps_boot = float(np.median(off))
    leap = leap_seconds(gps_boot - leap_seconds(gps_boot))
    start = gps_boot - leap
    q1, q3 = np.percentile(off, [25, 75])
    warnings.append(f"t = 0 (boot) is {unix_text(start)} UTC, from GPS week/time of week (GWk/GMS) against "
                    f"TimeUS of {len(off)} GPS record(s); interquartile spread {1e3 * (q3 - q1):.1f} ms, "
                    f"GPS - UTC = {leap} s")
    spread = float(np.max(off) - np.min(off))
    if spread > _CLOCK_SPREAD_WARN_S:
        warnings.append(f"GPS records disagree on the boot-to-GPS offset by up to {spread:.3f} s (a GPS time "
                        "jump or a reboot); the median is used")
    return start


def _channels(name: str, canon: str, inst: int, t: np.ndarray, cols: Mapping[str, np.ndarray], keep: np.ndarray,
              maps: tuple[ActuatorMap, ...], warnings: list[str], impossible: Counter | None = None
              ) -> tuple[dict[str, Channel], np.ndarray]:
    """Channels of one message type and instance; returns them and which records gave a sample."""
    where = name if canon == name and inst == 0 else f"{name}[{inst}]"
    if canon in INPUT_MESSAGES:
        values, valid = _inputs(name, cols, keep, maps, warnings)
    else:
        values = {}
        valid = {}
        for (m, f), (base, scale) in VARIABLE_MAP.items():
            if m == canon and f in cols:
                values[base] = cols[f] * scale
                valid[base] = keep & np.isfinite(values[base])
        if canon == "ATT":
            for a in ("phi", "theta", "psi"):
                if a in values:
                    values[a] = wrap_pi(values[a])
        elif canon == "GPS":
            if "Status" in cols:
                nofix = keep & (cols["Status"] < 2)
                if nofix.any():
                    warnings.append(f"{where}: {int(nofix.sum())} record(s) without a fix (Status < 2) not used")
                    valid = {k: v & ~nofix for k, v in valid.items()}
            if "lat" in values and "lon" in values:
                zero = keep & (values["lat"] == 0) & (values["lon"] == 0)
                if zero.any():
                    warnings.append(f"{where}: {int(zero.sum())} record(s) with position 0/0 not used for lat/lon")
                    valid["lat"] = valid["lat"] & ~zero
                    valid["lon"] = valid["lon"] & ~zero
            if "cog" in values:
                values["cog"] = wrap_pi(values["cog"])
        elif canon == "POS" and "lat" in values and "lon" in values:
            zero = keep & (values["lat"] == 0) & (values["lon"] == 0)
            valid["lat"] = valid["lat"] & ~zero
            valid["lon"] = valid["lon"] & ~zero
        elif canon == "XKF1" and "v_n" in values and "v_e" in values:
            vn, ve = values.pop("v_n"), values.pop("v_e")
            ok = valid.pop("v_n") & valid.pop("v_e")
            values = {"sog": np.hypot(vn, ve), "cog": np.arctan2(ve, vn)}
            valid = {"sog": ok, "cog": ok}
        suffix = INSTANCES[canon][1](inst)
        values = {b + suffix: v for b, v in values.items()}
        valid = {b + suffix: v for b, v in valid.items()}

    chans: dict[str, Channel] = {}
    used = np.zeros(len(t), bool)
    for ch_name, v in values.items():
        limit = VALUE_LIMITS.get(ch_name.split("@")[0])
        ok = valid[ch_name] & np.isfinite(v)
        if limit is not None:
            wild = ok & (np.abs(v) > limit)
            if wild.any():
                ok &= ~wild
                if impossible is not None:
                    impossible[f"{where} {ch_name.split('@')[0]} value"] += int(wild.sum())
        if not ok.any():
            continue
        used |= ok
        chans[ch_name] = Channel(name=ch_name, t=t[ok], values=np.asarray(v[ok], float), source=where)
    return chans, used


def _inputs(name: str, cols: Mapping[str, np.ndarray], keep: np.ndarray, maps: tuple[ActuatorMap, ...],
            warnings: list[str]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    src, patterns, count = INPUT_MESSAGES[name]
    mine = actuators_reading(maps, src, int(keep.sum()), f"{name} record(s)", warnings)
    if not mine:
        return {}, {}
    out: dict[str, np.ndarray] = {}
    valid: dict[str, np.ndarray] = {}
    for a in mine:
        field_name = next((pat.format(a.channel) for pat in patterns if pat.format(a.channel) in cols), None)
        if field_name is None:
            warnings.append(f"actuator map {src} channel {a.channel} ({a.target}): {name} has no such channel; "
                            "not read")
            continue
        pwm = cols[field_name]
        undriven = keep & ((pwm == 0) | (pwm == 65535))
        if undriven.any():
            warnings.append(f"{int(undriven.sum())} sample(s) of {a.target} ({name}.{field_name}) not used: PWM 0 "
                            "or 65535 (channel not driven)")
        ok = keep & ~undriven
        value = a.to_input(pwm)
        if a.target in out:
            # Several channels on one target (twin thrusters) add up to the generalised force.
            out[a.target] = out[a.target] + value
            valid[a.target] = valid[a.target] & ok
        else:
            out[a.target], valid[a.target] = value, ok
    if src == "rc":
        servo_targets = {a.target for a in maps if a.source == "servo"}
        out = {(f"{k}@rc" if k in servo_targets else k): v for k, v in out.items()}
        valid = {(f"{k}@rc" if k in servo_targets else k): v for k, v in valid.items()}
    return out, valid


# ----------------------------------------------------------------------------- public
def _read(path: str | Path, vessel: Vessel | None, progress: bool | None, slow: bool) -> RawLog:
    p = check_file(path, "DataFlash log")
    reader = _open(p)
    try:
        idx = reader.index
        if len(idx.names) <= 1:
            head = bytes(reader.data_map[:16])
            cut = " (the file is cut inside its first FMT record)" if head[:3] == b"\xa3\x95\x80" and \
                idx.size < FMT_LENGTH else ""
            raise IngestError(f"{p}: expected a DataFlash log (A3 95 records defined by FMT records), found no "
                              f"valid FMT record in {idx.size} bytes{cut}; starts with {head!r}")
        types = _message_types(reader)
        _check_units(p, reader, types)
        total = sum(len(reader.offsets[reader.name_to_id[n]]) for n in types)
        bar = _bar(p, total, progress)
        tick = bar.update if bar is not None else (lambda k: None)
        try:
            decoded = (_decode_slow if slow else _decode_vectorised)(reader, types, tick)
        finally:
            if bar is not None:
                bar.close()
        return _build(p, decoded, types, reader, vessel)
    finally:
        # A numpy view still referenced from a traceback would make close() fail; the mmap then
        # closes when the reader is collected.
        with contextlib.suppress(BufferError):
            reader.close()


def read_dataflash(path: str | Path, vessel: Vessel | None = None, progress: bool | None = None) -> RawLog:
    """Read an ArduPilot DataFlash ``.bin`` log into canonical channels on the autopilot boot clock.

    Parameters
    ----------
    path : str or Path
        The log. Opened read-only (memory-mapped) and never modified.
    vessel : Vessel, optional
        Supplies ``actuators``, the map from RCOU / RCIN PWM [us] to canonical inputs
        (``ActuatorMap.to_input``). Several maps on one target add up (twin thrusters). Without
        it inputs are not read and the summary says so.
    progress : bool, optional
        tqdm bar over the records decoded. ``None``: shown on a terminal when the read takes
        longer than 1 s, never when the ``CI`` environment variable is set or stderr is not a TTY.

    Returns
    -------
    RawLog
        ``format='dataflash'``, ``time_reference='boot'``: ``t`` [s] = TimeUS * 1e-6. Channels
        (module docstring): ``phi theta psi`` [rad], ``p q r`` [rad/s] and ``ax ay az`` [m/s^2]
        (IMU 0), ``p@imu1``... (IMU 1), ``lat lon`` [deg] ``sog`` [m/s] ``cog`` [rad] (GPS 0),
        ``lat@gps2``... (GPS 1), ``lat@ekf lon@ekf`` (POS), ``sog@ekf cog@ekf`` (XKF1), inputs.
        ``Channel.source`` is the message (``IMU[1]`` for an instance).

    Raises
    ------
    IngestError
        Missing or empty file, no FMT record (not a DataFlash log), a field whose FMTU unit differs
        from the one assumed (``RAW_UNITS``: gyro in deg/s instead of rad/s, ...), or no usable record.

    Notes
    -----
    Counted in ``summary`` rather than raised: a truncated tail (``truncated: N trailing
    bytes``), garbage bytes between records, records of a type without FMT, duplicate or
    out-of-order TimeUS within a message type and instance (the first is kept), GPS without a
    fix, undriven PWM channels. Types not used (FMT, PARM, MSG, BARO, ...) are counted in
    ``summary.skipped``.
    """
    return _read(path, vessel, progress, slow=False)


def read_dataflash_slow(path: str | Path, vessel: Vessel | None = None, progress: bool | None = None) -> RawLog:
    """Reference reader for tests and benchmarks: :func:`read_dataflash` through pymavlink's ``recv_match``.

    The same index and channel building, but every record is decoded by pymavlink as one
    ``DFMessage`` (``DFReader_binary._parse_next`` and ``DFMessage.__getattr__``). Return value and
    errors as :func:`read_dataflash`; the channels are identical.

    Parameters
    ----------
    path : str or Path
        The log. Opened read-only and never modified.
    vessel : Vessel, optional
        Supplies ``actuators``, the map from RCOU / RCIN PWM [us] to canonical inputs; without it
        inputs are not read.
    progress : bool, optional
        tqdm bar over the records decoded; ``None`` decides as :func:`read_dataflash` does.
    """
    return _read(path, vessel, progress, slow=True)


__all__ = ["read_dataflash", "read_dataflash_slow", "build_index", "VARIABLE_MAP", "INSTANCES", "ALIASES"]
