"""NMEA 0183 reader and simulator writer: round trips, known sentences, bad input, fuzz, real data.

pynmeagps is the independent reference: it checks every checksum the writer produces and the
reader's decoding of real sentences.
"""

from __future__ import annotations

import hashlib
import re
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st
from pynmeagps import VALCKSUM, NMEAReader

from pipeline.errors import IngestError, SimError
from pipeline.ingest.csv_log import read_csv_log
from pipeline.ingest.nmea import VARIABLE_MAP, looks_like_nmea, nmea_checksum, read_nmea
from pipeline.sim.manoeuvres import chain, step_and_coast
from pipeline.sim.simulate import simulate
from pipeline.sim.writers.nmea import write_nmea
from pipeline.vessel import load_vessel

REPO = Path(__file__).resolve().parents[1]
CE6 = REPO.parent / "shared" / "realdata" / "ce6-boat-limfjord-2022"
KNOT = 1852.0 / 3600.0


def _wrap(a):
    return np.angle(np.exp(1j * np.asarray(a)))


def _line(body: str) -> str:
    return f"${body}*{nmea_checksum(body.encode()):02X}"


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def sim(aauship):
    vessel = aauship
    return simulate(vessel, chain(step_and_coast("surge", 4.0, 6.0, 6.0), step_and_coast("yaw", 0.1, 6.0, 6.0),
                                  rest_s=2.0), seed=3)


# ------------------------------------------------------------------------------ round trips
@pytest.mark.parametrize("with_pc_time", [False, True])
def test_round_trip_sim_gps(sim, tmp_path, with_pc_time):
    path = write_nmea(sim.log, tmp_path / "gps.nmea", sensor="gps", with_pc_time=with_pc_time)
    log = read_nmea(path, sensor="gps", progress=with_pc_time)   # progress bar on stderr: same result
    assert log.format == "nmea" and log.time_reference == "gps"
    assert set(log.channels) == {"lat@gps", "lon@gps", "sog@gps", "cog@gps", "psi@gps"}
    for name, tol in (("lat@gps", 2e-9), ("lon@gps", 2e-9), ("sog@gps", 0.0005 / 3.6 + 1e-12),
                      ("cog@gps", np.radians(0.005) + 1e-12)):
        got, want = log.channels[name], sim.log.channels[name]
        np.testing.assert_allclose(got.t, want.t - want.t[0], atol=1e-9)
        diff = _wrap(got.values - want.values) if name.startswith("cog") else got.values - want.values
        assert np.max(np.abs(diff)) <= tol, name
    # Heading comes from the attitude sensor (100 Hz), interpolated onto the 10 Hz GPS epochs.
    psi = log.channels["psi@gps"]
    truth = sim.log.channels["psi"]
    want = np.interp(psi.t, truth.t, np.unwrap(truth.values))
    assert np.max(np.abs(_wrap(psi.values - want))) <= np.radians(0.0005) + 1e-9
    n = len(sim.log.channels["lat@gps"].t)
    assert log.summary.read == {"GGA": n, "RMC": n, "VTG": n, "HDT": n}
    assert not log.summary.skipped


def test_writer_checksums_and_fields_agree_with_pynmeagps(sim, tmp_path):
    path = write_nmea(sim.log, tmp_path / "nav.nmea", talker="GN", rate_hz=5.0)
    lines = path.read_bytes().splitlines()
    assert lines and all(line.startswith(b"$GN") for line in lines)
    n_gga = 0
    for raw in lines:
        msg = NMEAReader.parse(raw + b"\r\n", validate=VALCKSUM)   # raises on a bad checksum
        if msg.msgID == "GGA":
            n_gga += 1
    assert n_gga == int(np.floor(sim.log.channels["lat"].t[-1] * 5.0 + 1e-9)) + 1
    log = read_nmea(path)
    first = next(NMEAReader.parse(r + b"\r\n") for r in lines if r[3:6] == b"GGA")
    assert log.channels["lat"].values[0] == pytest.approx(first.lat, abs=1e-9)
    assert log.channels["lon"].values[0] == pytest.approx(first.lon, abs=1e-9)
    assert np.allclose(np.diff(log.channels["lat"].t), 0.2)


def test_midnight_rollover_and_rmc_date(sim, tmp_path):
    start = datetime(2024, 12, 31, 23, 59, 50, tzinfo=timezone.utc)
    path = write_nmea(sim.log, tmp_path / "midnight.nmea", sensor="gps", start=start)
    text = path.read_text()
    assert "311224" in text and "010125" in text          # RMC dates on both sides of midnight
    log = read_nmea(path, sensor="gps")
    want = sim.log.channels["lat@gps"].t
    np.testing.assert_allclose(log.channels["lat@gps"].t, want - want[0], atol=1e-9)
    assert any("rollover" in w for w in log.summary.warnings)
    assert "2024-12-31T23:59:50" in log.summary.warnings[0]


def test_midnight_rollover_without_date(tmp_path):
    lines = [_line(f"GPGGA,{hms},5703.0,N,00955.0,E,1,08,0.9,1.0,M,,M,,") for hms in
             ("235959.50", "235959.75", "000000.00", "000000.25")]
    p = tmp_path / "gga.nmea"
    p.write_text("\n".join(lines) + "\n")
    log = read_nmea(p)
    np.testing.assert_allclose(log.channels["lat"].t, [0.0, 0.25, 0.5, 0.75])
    assert "no RMC date" in log.summary.warnings[0]


# ------------------------------------------------------------------------------ known sentences
def test_known_sentences_values_and_talkers(tmp_path):
    # The classic NMEA examples (checksums as published), plus a heading sensor and GN/GL talkers.
    lines = [
        "$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47",
        "$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A",
        _line("GPVTG,084.4,T,,M,022.4,N,041.5,K,A"),
        _line("HEHDT,274.07,T"),
        _line("GNGGA,123520,4807.040,S,01131.010,W,2,12,0.7,545.4,M,46.9,M,,"),
        _line("GLVTG,084.5,T,,M,022.0,N,,K,A"),            # knots only
        _line("HETHS,275.00,A"),
        _line("GPGSV,3,1,11,03,03,111,00,04,15,270,00,06,01,010,00,13,06,292,00"),   # unused id
    ]
    p = tmp_path / "known.nmea"
    p.write_text("\r\n".join(lines) + "\r\n")
    log = read_nmea(p)
    lat, lon = log.channels["lat"], log.channels["lon"]
    np.testing.assert_allclose(lat.values, [48 + 7.038 / 60, -(48 + 7.040 / 60)], atol=1e-12)
    np.testing.assert_allclose(lon.values, [11 + 31.0 / 60, -(11 + 31.010 / 60)], atol=1e-12)
    np.testing.assert_allclose(lat.t, [0.0, 1.0])
    sog = log.channels["sog"]
    # VTG km/h wins over RMC knots at the same epoch; the second epoch has knots only.
    np.testing.assert_allclose(sog.values, [41.5 / 3.6, 22.0 * KNOT], rtol=1e-12)
    np.testing.assert_allclose(log.channels["cog"].values, _wrap(np.radians([84.4, 84.5])), atol=1e-12)
    np.testing.assert_allclose(log.channels["psi"].values, _wrap(np.radians([274.07, 275.0])), atol=1e-12)
    assert log.summary.skipped == {"GSV": 1}
    assert "DGPS 50.0%" in log.summary.warnings[1] and "satellites 8-12" in log.summary.warnings[1]
    assert VARIABLE_MAP[("VTG", "sogk")] == ("sog", pytest.approx(1 / 3.6))


def test_bad_checksum_garbage_pc_time_and_invalid_heading_are_counted(tmp_path):
    good = [_line(f"GPGGA,1000{s:02d}.00,5703.0,N,00955.0,E,1,08,0.9,1.0,M,,M,,") for s in range(5)]
    bad = good[2][:-2] + ("00" if not good[2].endswith("00") else "01")
    lines = [
        "2024-05-05 10:00:00.050\t" + good[0],     # PC-time column
        "t" + good[1],                              # stray byte before '$'
        bad,                                        # checksum wrong -> skipped
        "c&&IbrErbZE\"%U$x" + good[3],             # serial noise, then a sentence
        "-2.285,M,40.592,M,3.5,0123*51",            # fragment, no '$'
        "$GPGGA,100004.00,5703.0,N,009",            # truncated sentence
        good[4],
        _line("HETHS,120.0,V"),                     # heading flagged invalid
        _line("HETHS,121.0,A"),
        "",
    ]
    p = tmp_path / "messy.log"
    p.write_text("\n".join(lines))
    log = read_nmea(p, sensor="gps2")
    assert set(log.channels) == {"lat@gps2", "lon@gps2", "psi@gps2"}
    np.testing.assert_allclose(log.channels["lat@gps2"].t, [0.0, 1.0, 3.0, 4.0])
    sk = log.summary.skipped
    assert sk["bad checksum"] == 1 and sk["garbage line"] == 1 and sk["incomplete sentence"] == 1
    assert sk["THS invalid"] == 1
    text = " | ".join(log.summary.warnings)
    assert "bad checksum: 1 of" in text and "THS: 1 heading" in text and "unreadable lines" in text


def test_repeats_and_steps_back_are_dropped_and_counted(tmp_path):
    times = ["100000.00", "100000.05", "100000.05", "100000.10", "100000.00", "100000.15"]
    lines = []
    for hms in times:
        lines.append(_line(f"GPGGA,{hms},5703.0,N,00955.0,E,2,08,0.9,1.0,M,,M,,"))
        lines.append(_line("GPVTG,010.0,T,,M,1.0,N,1.852,K,D"))
    p = tmp_path / "dup.nmea"
    p.write_text("\n".join(lines))
    log = read_nmea(p)
    np.testing.assert_allclose(log.channels["lat"].t, [0.0, 0.05, 0.10, 0.15], atol=1e-9)
    np.testing.assert_allclose(log.channels["sog"].t, [0.0, 0.05, 0.10, 0.15], atol=1e-9)
    assert log.summary.skipped["GGA repeated or out of order"] == 2
    assert log.summary.skipped["VTG repeated or out of order"] == 2
    assert np.all(np.diff(log.channels["lat"].t) > 0)


def test_no_fix_void_and_empty_sentences_are_skipped(tmp_path):
    lines = [
        _line("GPGGA,100000.00,,,,,0,00,99.9,,,,,,"),
        _line("GPRMC,100000.00,V,,,,,,,050524,,,N"),
        _line("GPVTG,,T,,M,,N,,K,N"),
        _line("GPGGA,100001.00,5703.0,N,00955.0,E,1,08,0.9,1.0,M,,M,,"),
        _line("GPVTG,,T,,M,,N,,K,A"),
    ]
    p = tmp_path / "nofix.nmea"
    p.write_text("\n".join(lines))
    log = read_nmea(p)
    assert list(log.channels) == ["lat", "lon"]
    assert log.summary.skipped == {"GGA no fix": 1, "RMC void": 1, "VTG not valid": 1, "VTG empty": 1}
    assert "invalid 50.0%" in log.summary.warnings[1]


# ------------------------------------------------------------------------------ bad input
def test_errors_name_expected_and_found(tmp_path):
    with pytest.raises(IngestError, match="expected a file, found nothing"):
        read_nmea(tmp_path / "missing.nmea")
    empty = tmp_path / "empty.nmea"
    empty.write_bytes(b"")
    with pytest.raises(IngestError, match="found an empty file"):
        read_nmea(empty)
    binary = tmp_path / "noise.nmea"
    binary.write_bytes(bytes(np.random.default_rng(0).integers(0, 256, 4000, dtype=np.uint8)))
    with pytest.raises(IngestError, match=r"expected NMEA 0183 sentences .* found none"):
        read_nmea(binary)
    gsv = tmp_path / "gsv.nmea"
    gsv.write_text(_line("GPGSV,1,1,01,03,03,111,00") + "\n")
    with pytest.raises(IngestError, match=r"expected usable GGA/RMC/.*HDG/HDM/VHW/ROT.*GSV 1"):
        read_nmea(gsv)
    untimed = tmp_path / "vtg.nmea"
    untimed.write_text(_line("GPVTG,010.0,T,,M,1.0,N,1.852,K,A") + "\n" + _line("HEHDT,10.0,T") + "\n")
    with pytest.raises(IngestError, match="with a time"):
        read_nmea(untimed)
    allbad = tmp_path / "allbad.nmea"
    allbad.write_text("$GPGGA,100000.00,5703.0,N,00955.0,E,1,08,0.9,1.0,M,,M,,*00\n")
    with pytest.raises(IngestError, match="bad checksum 1"):
        read_nmea(allbad)
    assert not looks_like_nmea(binary) and not looks_like_nmea(tmp_path / "missing.nmea")
    assert not looks_like_nmea(allbad) and looks_like_nmea(gsv)
    ok = tmp_path / "ok.nmea"
    ok.write_text(_line("GPGGA,100000.00,5703.0,N,00955.0,E,1,08,0.9,1.0,M,,M,,") + "\n")
    with pytest.raises(IngestError, match="sensor: expected letters"):
        read_nmea(ok, sensor="gps 2")


def test_writer_rejects_bad_arguments(sim, tmp_path):
    with pytest.raises(SimError, match="talker"):
        write_nmea(sim.log, tmp_path / "x.nmea", talker="GPS")
    with pytest.raises(SimError, match="rate_hz"):
        write_nmea(sim.log, tmp_path / "x.nmea", rate_hz=0)
    with pytest.raises(SimError, match="timezone-aware"):
        write_nmea(sim.log, tmp_path / "x.nmea", start=datetime(2024, 1, 1))
    with pytest.raises(SimError, match=r"expected lat@nope/lon@nope or sog@nope"):
        write_nmea(sim.log, tmp_path / "x.nmea", sensor="nope")
    assert not (tmp_path / "x.nmea").exists()


# ------------------------------------------------------------------------------ fuzz
def _mutate(data: bytes, rng: np.random.Generator) -> bytes:
    kind = rng.integers(0, 4)
    if kind == 0:                                   # truncate
        return data[: int(rng.integers(0, len(data)))]
    buf = bytearray(data)
    if kind == 1:                                   # flip bytes
        for i in rng.integers(0, len(buf), int(rng.integers(1, 50))):
            buf[i] = int(rng.integers(0, 256))
        return bytes(buf)
    if kind == 2:                                   # insert garbage
        for _ in range(int(rng.integers(1, 20))):
            i = int(rng.integers(0, len(buf)))
            buf[i:i] = bytes(rng.integers(0, 256, int(rng.integers(1, 40)), dtype=np.uint8))
        return bytes(buf)
    lines = data.split(b"\n")                        # shuffle lines (clock steps back)
    rng.shuffle(lines)
    return b"\n".join(lines)


def test_fuzz_corrupted_files_give_ingest_error_or_warnings(sim, tmp_path):
    src = write_nmea(sim.log, tmp_path / "src.nmea", sensor="gps", with_pc_time=True)
    data = src.read_bytes()[:20000]
    rng = np.random.default_rng(20240505)
    outcomes = {"ok": 0, "error": 0}
    for k in range(60):
        p = tmp_path / f"fuzz{k}.nmea"
        p.write_bytes(_mutate(data, rng))
        before = _sha(p)
        try:
            log = read_nmea(p)
        except IngestError as exc:
            assert "expected" in str(exc)
            outcomes["error"] += 1
        else:
            outcomes["ok"] += 1
            for ch in log.channels.values():
                assert np.all(np.diff(ch.t) > 0) and np.all(np.isfinite(ch.values))
        assert _sha(p) == before, "the reader must not change its input"
    assert outcomes["ok"] > 0


@settings(max_examples=150, derandomize=True, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.one_of(st.binary(max_size=90),
                          st.sampled_from([b"$GPGGA,", b"$GPRMC,", b"$GPVTG,", b"$HEHDT,", b"$HETHS,", b",", b"*",
                                           b"N", b"E", b"A", b"V", b"T", b"K", b"\r\n", b".", b"99"]),
                          st.text(alphabet="0123456789.,NSEWATVKMN*$", max_size=40).map(str.encode)),
                max_size=40))
def test_fuzz_arbitrary_bytes(tmp_path_factory, parts):
    # Random bytes that look a little like NMEA: the checksum is fixed up half the time so the
    # field parsers see garbage too, not only the checksum test.
    data = b"".join(parts)
    fixed = re.sub(rb"\$([^$*\r\n]*)\*", lambda m: b"$" + m.group(1) + b"*%02X" % nmea_checksum(m.group(1)), data)
    for variant in (data, fixed):
        p = tmp_path_factory.mktemp("hyp") / "x.nmea"
        p.write_bytes(variant)
        try:
            log = read_nmea(p)
        except IngestError:
            continue
        for ch in log.channels.values():
            assert np.all(np.diff(ch.t) > 0) and np.all(np.isfinite(ch.values))


# ------------------------------------------------------------------------------ real data
def _ce6_logs() -> list[Path]:
    """Every NMEA log of the CE6 set: files whose first kilobytes hold a $GPGGA sentence."""
    out = []
    for f in sorted((CE6 / "Estimations").rglob("*")):
        if f.is_file() and f.suffix in (".txt", ".log"):
            with open(f, "rb") as fh:
                if b"$GPGGA," in fh.read(4096):
                    out.append(f)
    return out


#: Column map and units of the curated CSV exports in ``csv/`` (parsed from the same NMEA files):
#: ``t_s`` [s from first fix], ``lat``/``lon`` [deg], ``sog_mps`` [m/s], ``cog_deg`` [deg true];
#: ``utc_s``, ``fix``, ``nsat``, ``hdop`` are not canonical channels and are skipped.
CE6_CSV_COLUMNS = {"lat": "lat", "lon": "lon", "sog_mps": "sog", "cog_deg": "cog"}
CE6_CSV_UNITS = {"cog_deg": "deg", "t_s": "s"}


@pytest.mark.realdata
@pytest.mark.skipif(not CE6.is_dir(), reason="real data folder ../shared/realdata/ce6-boat-limfjord-2022 absent")
def test_ce6_limfjord_logs_ingest_with_sane_values():
    logs = _ce6_logs()
    assert len(logs) == 79
    others = [f for f in (CE6 / "Estimations").rglob("*") if f.is_file() and f not in logs]
    assert all(looks_like_nmea(f) for f in logs) and not any(looks_like_nmea(f) for f in others)
    samples = 0
    for f in logs:
        log = read_nmea(f)
        lat, lon, sog, cog = (log.channels[n] for n in ("lat", "lon", "sog", "cog"))
        samples += len(lat.t)
        assert 57.03 < lat.values.min() and lat.values.max() < 57.08, f      # Limfjord at Aalborg
        assert 9.78 < lon.values.min() and lon.values.max() < 9.92, f
        assert 0.0 <= sog.values.min() and sog.values.max() < 6.0, f         # a small outboard boat
        assert np.all(np.abs(cog.values) <= np.pi)
        for ch in (lat, sog):
            assert ch.t[0] >= 0 and np.all(np.diff(ch.t) > 0), f
            assert np.median(np.diff(ch.t)) == pytest.approx(0.05, abs=1e-6), f   # 20 Hz
        assert log.summary.skipped.get("bad checksum", 0) <= 1
        assert any(w.startswith("fix stats (GGA): quality") for w in log.summary.warnings)
    assert samples > 49000


@pytest.mark.realdata
@pytest.mark.skipif(not CE6.is_dir(), reason="real data folder ../shared/realdata/ce6-boat-limfjord-2022 absent")
def test_ce6_reader_agrees_with_pynmeagps_and_curated_csv():
    f = CE6 / "Estimations" / "Boat test 2" / "VirtualMass" / "throt11866E.txt"
    log = read_nmea(f)
    ref_lat, ref_sog = [], []
    for raw in f.read_bytes().splitlines():
        i = raw.find(b"$")
        if i < 0:
            continue
        try:
            msg = NMEAReader.parse(raw[i:] + b"\r\n", validate=VALCKSUM)
        except Exception:       # fragments: the reader skips them too
            continue
        if msg is not None and msg.msgID == "GGA":
            ref_lat.append(msg.lat)
        elif msg is not None and msg.msgID == "VTG":
            ref_sog.append(msg.sogk / 3.6)
    np.testing.assert_allclose(log.channels["lat"].values, ref_lat, atol=1e-9)   # pynmeagps rounds to 1e-10
    np.testing.assert_allclose(log.channels["sog"].values, ref_sog, atol=1e-12)
    # The curated CSV export of the same file, through the CSV reader with its column map.
    csv = read_csv_log(CE6 / "csv" / "Boat_test_2_VirtualMass_throt11866E.csv", columns=CE6_CSV_COLUMNS,
                       units=CE6_CSV_UNITS, time_column="t_s")
    np.testing.assert_allclose(csv.channels["lat"].t, log.channels["lat"].t, atol=1e-6)
    np.testing.assert_allclose(csv.channels["lat"].values, log.channels["lat"].values, atol=1e-8)
    np.testing.assert_allclose(csv.channels["sog"].values, log.channels["sog"].values, atol=1e-4)
    np.testing.assert_allclose(_wrap(csv.channels["cog"].values - log.channels["cog"].values), 0, atol=1e-6)
