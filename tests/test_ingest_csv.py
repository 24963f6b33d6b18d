"""Canonical CSV logs: simulator -> write_csv_log -> read_csv_log round trip, and bad input.

Every file is written into ``tmp_path``, by the real writer or by hand for the malformed ones.
"""

from __future__ import annotations

import math
import os
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import IngestError, OutputError
from pipeline.flow import load_trial
from pipeline.ingest import read_csv_log, read_log
from pipeline.records import ANGLE_CHANNELS, Channel, IngestSummary, RawLog
from pipeline.sim import chain, rudder_step, simulate, step_and_coast
from pipeline.sim.writers.csv_writer import write_csv_log
from pipeline.vessel import load_vessel

from conftest import AAUSHIP  # noqa: E402 - the vessel, loaded once per session


@pytest.fixture(scope="module")
def sim():
    sched = chain(step_and_coast("surge", 4.0, 10.0, 10.0), rudder_step(np.radians(-20), 8.0, 8.0), rest_s=2.0)
    return simulate(AAUSHIP, sched, seed=8)


@pytest.fixture(scope="module")
def written(sim, tmp_path_factory):
    path = tmp_path_factory.mktemp("csv") / "trial.csv"
    write_csv_log(sim.log, path)
    return path


def _write(tmp_path, text, name="log.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


# --------------------------------------------------------------------------- round trip
def test_round_trip_channels_times_and_values(sim, written):
    log = read_csv_log(written)
    assert log.format == "csv" and log.source == str(written) and log.time_reference == "trial"
    assert set(log.channels) == set(sim.log.channels)
    for name, ch in sim.log.channels.items():
        back = log.channels[name]
        assert back.name == name and back.source == f"csv:{name}"
        # Each channel keeps its own timestamps (sensors at 100, 50 and 10 Hz share one file).
        assert len(back.t) == len(ch.t), name
        np.testing.assert_allclose(back.t, ch.t, rtol=0, atol=1e-6)
        if name.split("@")[0] in ("lat", "lon"):
            np.testing.assert_allclose(back.values, ch.values, rtol=0, atol=5.1e-10)  # 9 decimals
        elif name.split("@")[0] in ANGLE_CHANNELS:
            err = np.angle(np.exp(1j * (back.values - ch.values)))
            np.testing.assert_allclose(err, 0, atol=5e-7 * np.pi)  # 7 significant digits
        else:
            np.testing.assert_allclose(back.values, ch.values, rtol=5.1e-7, atol=1e-300)
    rates = {n: 1 / np.median(np.diff(c.t)) for n, c in log.channels.items()}
    assert rates["r"] == pytest.approx(100) and rates["sog"] == pytest.approx(50)
    assert rates["sog@gps"] == pytest.approx(10) and rates["delta"] == pytest.approx(50)
    assert log.summary.read["r"] == len(sim.log.channels["r"].t)
    assert log.summary.skipped == {} and log.summary.warnings == ()


def test_round_trip_file_layout(sim, written):
    lines = written.read_text().splitlines()
    header = lines[0].split(",")
    assert header[0] == "t" and set(header[1:]) == set(sim.log.channels)
    # One row per distinct sample time; empty cells where a sensor did not sample.
    n_times = len(np.unique(np.concatenate([c.t for c in sim.log.channels.values()]).round(6)))
    assert len(lines) == 1 + n_times
    gps = header.index("sog@gps")
    row = lines[2].split(",")  # t = 0.01: the 10 Hz GPS has no sample there
    assert float(row[0]) == pytest.approx(0.01) and row[gps] == ""


def test_read_log_dispatches_on_extension(written, tmp_path):
    log = read_log(written)
    assert log.format == "csv" and "r" in log.channels
    other = _write(tmp_path, "t,u\n0,1\n", "log.xyz")
    with pytest.raises(IngestError, match=r"expected a log with extension \[.*'.csv'.*found '.xyz'"):
        read_log(other)


def test_round_trip_keeps_microsecond_times_far_from_zero(tmp_path):
    # A log on another clock (autopilot boot, hours in): times must survive to the microsecond.
    t = 12345.678901 + np.arange(50) * 0.0100003
    src = RawLog("hand", "sim", {"u": Channel("u", t, np.linspace(0, 1, 50)),
                                 "psi": Channel("psi", t[::2], np.linspace(-3.1, 3.1, 25))},
                 IngestSummary("hand", "sim"))
    back = read_csv_log(write_csv_log(src, tmp_path / "late.csv"))
    np.testing.assert_allclose(back.channels["u"].t, t, rtol=0, atol=1.01e-6)
    np.testing.assert_allclose(back.channels["psi"].t, t[::2], rtol=0, atol=1.01e-6)
    np.testing.assert_allclose(back.channels["psi"].values, np.linspace(-3.1, 3.1, 25), atol=1e-6)


def test_reading_leaves_the_file_untouched(written):
    before = written.read_bytes()
    st = os.stat(written)
    read_csv_log(written)
    read_csv_log(written, columns={"r": "r"}, units={"r": "rad/s"})
    assert written.read_bytes() == before
    after = os.stat(written)
    assert after.st_mtime_ns == st.st_mtime_ns and after.st_size == st.st_size


def test_write_is_atomic_and_leaves_no_temp_files(sim, tmp_path):
    target = tmp_path / "out" / "trial.csv"  # the folder is created
    write_csv_log(sim.log, target)
    assert sorted(p.name for p in target.parent.iterdir()) == ["trial.csv"]
    first = target.read_bytes()
    # Overwriting replaces the whole file in one rename.
    small = RawLog("x", "sim", {"u": Channel("u", np.array([0.0, 0.1]), np.array([1.0, 2.0]))},
                   IngestSummary("x", "sim"))
    write_csv_log(small, target)
    assert target.read_text() == "t,u\n0.000000,1\n0.100000,2\n"
    assert sorted(p.name for p in target.parent.iterdir()) == ["trial.csv"]
    assert first != target.read_bytes()


def test_failed_write_leaves_target_and_no_temp_files(sim, tmp_path):
    # The target is a folder: the final rename fails after the data were written to a temp file.
    target = tmp_path / "trial.csv"
    target.mkdir()
    (target / "keep").write_text("x")
    with pytest.raises(OutputError, match="cannot write"):
        write_csv_log(sim.log, target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["trial.csv"]
    assert target.is_dir() and (target / "keep").read_text() == "x"


# --------------------------------------------------------------------------- bad input
def test_missing_file(tmp_path):
    with pytest.raises(IngestError, match=r"CSV log: expected a file, found nothing at .*nope.csv"):
        read_csv_log(tmp_path / "nope.csv")


def test_empty_file(tmp_path):
    with pytest.raises(IngestError, match=r"expected a CSV log, found an empty file \(0 bytes\)"):
        read_csv_log(_write(tmp_path, ""))


def test_blank_file(tmp_path):
    with pytest.raises(IngestError, match=r"expected a header row and data rows, found no columns"):
        read_csv_log(_write(tmp_path, "\n\n"))


def test_header_only(tmp_path):
    with pytest.raises(IngestError, match=r"expected data rows after the header, found none"):
        read_csv_log(_write(tmp_path, "t,u,r\n"))


def test_no_time_column(tmp_path):
    with pytest.raises(IngestError, match=r"expected a time column 't' \(or a column map entry naming one, e.g. "
                                         r"\[columns\] t_s = \"t\"\), found columns \['clock', 'u'\]"):
        read_csv_log(_write(tmp_path, "clock,u\n0,1\n0.1,2\n"))


def test_non_numeric_cell(tmp_path):
    p = _write(tmp_path, "t,u,r\n0,1,0.1\n0.1,abc,0.2\n0.2,1.1,0.3\n0.3,x,0.3\n")
    with pytest.raises(IngestError, match=r"expected numbers in column 'u', found 'abc' \(2 non-numeric cells\)"):
        read_csv_log(p)


def test_non_numeric_time(tmp_path):
    with pytest.raises(IngestError, match=r"expected a number in 't' on every row, found '0.2s' on data row 3"):
        read_csv_log(_write(tmp_path, "t,u\n0,1\n0.1,1\n0.2s,1\n"))


@pytest.mark.parametrize("times, row, found", [(["0", "0.1", "0.05", "0.2"], 3, "0.05 after 0.1"),
                                               (["0", "0.1", "0.2", "0.2", "0.3"], 4, "0.2 after 0.2")])
def test_non_monotonic_time_names_the_row(tmp_path, times, row, found):
    p = _write(tmp_path, "t,u\n" + "".join(f"{t},1\n" for t in times))
    with pytest.raises(IngestError) as exc:
        read_csv_log(p)
    msg = str(exc.value)
    assert "expected strictly increasing time in 't'" in msg
    assert f"on data row {row}" in msg and f"found {found}" in msg


def test_truncated_row(tmp_path):
    # A file cut mid-write: the last row has fewer fields (missing cells are "not sampled").
    log = read_csv_log(_write(tmp_path, "t,u,r\n0,1,0.1\n0.01,1.1,0.2\n0.02,1.2"))
    np.testing.assert_array_equal(log.channels["u"].t, [0, 0.01, 0.02])
    np.testing.assert_array_equal(log.channels["r"].t, [0, 0.01])
    # A row with too many fields is not a log row at all.
    with pytest.raises(IngestError, match=r"expected comma-separated values, found unparsable content"):
        read_csv_log(_write(tmp_path, "t,u\n0,1\n0.1,2,3,4\n", "wide.csv"))


@pytest.mark.parametrize("column, values", [("psi", [10.0, 90.0, 180.0, 270.0]), ("phi", [0.0, 5.0, -12.0, 4.0]),
                                            ("r", [0.0, 30.0, 45.0, 10.0]), ("delta", [0.0, 20.0, -20.0, 0.0])])
def test_degrees_in_a_radian_column(tmp_path, column, values):
    p = _write(tmp_path, f"t,{column}\n" + "".join(f"{i * 0.1},{v}\n" for i, v in enumerate(values)))
    with pytest.raises(IngestError) as exc:
        read_csv_log(p)
    msg = str(exc.value)
    assert f"column {column!r}" in msg and f"found {max(abs(v) for v in values):.4g}" in msg
    assert "degrees or another unit?" in msg


def test_unknown_column_is_reported_not_silently_dropped(tmp_path):
    p = _write(tmp_path, "t,u,battery_v,r\n0,1,12.1,0\n0.1,1,12.0,\n0.2,1,,0.1\n")
    log = read_csv_log(p)
    assert set(log.channels) == {"u", "r"}
    assert log.summary.skipped == {"battery_v": 2}
    (w,) = log.summary.warnings
    assert "'battery_v'" in w and "2 values not used" in w
    text = log.summary.text()
    assert "skipped battery_v 2" in text and "warning: column 'battery_v'" in text


def test_only_unknown_columns(tmp_path):
    with pytest.raises(IngestError, match=r"expected at least one canonical channel .*found only \['t', 'foo'\]"):
        read_csv_log(_write(tmp_path, "t,foo\n0,1\n0.1,2\n"))


def test_empty_column_warns(tmp_path):
    log = read_csv_log(_write(tmp_path, "t,u,r\n0,1,\n0.1,2,\n"))
    assert set(log.channels) == {"u"}
    assert log.summary.warnings == ("column 'r' has no values",)


def test_column_map_and_units_convert(tmp_path):
    rows = [(0, 350.0, 10.0, 2.0, 7.2, 1.0), (500, 10.0, -20.0, 4.0, 36.0, 1.5), (1000, 90.0, 0.0, 0.0, 0.0, 2.0)]
    text = "time_ms,heading_deg,yaw_rate_dps,speed_kn,gps_speed_kmh,u\n" + "".join(
        ",".join(str(x) for x in r) + "\n" for r in rows)
    p = _write(tmp_path, text)
    log = read_csv_log(p, columns={"heading_deg": "psi", "yaw_rate_dps": "r", "speed_kn": "sog",
                                   "gps_speed_kmh": "sog@gps"},
                       units={"time_ms": "ms", "heading_deg": "deg", "yaw_rate_dps": "deg/s", "speed_kn": "knots",
                              "gps_speed_kmh": "km/h"}, time_column="time_ms")
    assert set(log.channels) == {"psi", "r", "sog", "sog@gps", "u"}
    np.testing.assert_allclose(log.channels["psi"].t, [0.0, 0.5, 1.0])
    # 350 deg is -10 deg in (-pi, pi].
    np.testing.assert_allclose(log.channels["psi"].values, np.radians([-10.0, 10.0, 90.0]), atol=1e-12)
    np.testing.assert_allclose(log.channels["r"].values, np.radians([10.0, -20.0, 0.0]), atol=1e-15)
    np.testing.assert_allclose(log.channels["sog"].values, np.array([2.0, 4.0, 0.0]) * 1852 / 3600)
    np.testing.assert_allclose(log.channels["sog@gps"].values, [2.0, 10.0, 0.0])
    np.testing.assert_allclose(log.channels["u"].values, [1.0, 1.5, 2.0])
    assert log.channels["psi"].source == "csv:heading_deg"
    assert log.summary.read == {"heading_deg": 3, "yaw_rate_dps": 3, "speed_kn": 3, "gps_speed_kmh": 3, "u": 3}


def test_unknown_unit(tmp_path):
    p = _write(tmp_path, "t,heading\n0,1\n")
    with pytest.raises(IngestError, match=r"unit of column 'heading': expected one of .*'deg'.*found 'grad'"):
        read_csv_log(p, columns={"heading": "psi"}, units={"heading": "grad"})


def test_infinite_cells_are_counted_not_mistaken_for_units(tmp_path):
    # pandas reads 'inf' as a number; it is not a sample, and not a sign of a unit mix-up.
    log = read_csv_log(_write(tmp_path, "t,u,x_n\n0,1,0\n0.1,inf,1\n0.2,-inf,inf\n0.3,2,3\n"))
    np.testing.assert_array_equal(log.channels["u"].t, [0.0, 0.3])
    np.testing.assert_array_equal(log.channels["x_n"].values, [0.0, 1.0, 3.0])
    assert log.summary.skipped == {"u": 2, "x_n": 1}
    assert "column 'u': 2 infinite values not used" in log.summary.warnings
    assert "column 'x_n': 1 infinite values not used" in log.summary.warnings


# --------------------------------------------------------------------------- CSV as people write it
def test_column_map_renames_the_time_column(tmp_path):
    log = read_csv_log(_write(tmp_path, "t_s,u\n0,1\n0.1,2\n0.2,3\n"), columns={"t_s": "t"})
    np.testing.assert_allclose(log.channels["u"].t, [0, 0.1, 0.2])
    assert "time: column 't_s' is the time column" in log.summary.warnings


@pytest.mark.parametrize("header, scale, unit", [("t_ms", 1e3, None), ("time_us", 1e6, None), ("t_ns", 1e9, None),
                                                 ("stamp", 1e3, "ms")])
def test_time_in_ms_us_ns_by_suffix_or_unit(tmp_path, header, scale, unit):
    rows = "".join(f"{int(round(k * 0.1 * scale))},{k}\n" for k in range(5))
    p = _write(tmp_path, f"{header},u\n{rows}")
    log = read_csv_log(p, columns={"stamp": "t"} if unit else None, units={"stamp": unit} if unit else None)
    np.testing.assert_allclose(log.channels["u"].t, np.arange(5) * 0.1, atol=1e-12)
    assert math.isnan(log.start_time)


def test_time_in_ms_through_align(tmp_path):
    """Milliseconds once ended in 'ValueError: v cannot be empty'; now a 10 Hz trial."""
    rows = "".join(f"{k * 100},{0.01 * k},{0.5}\n" for k in range(50))
    trial = load_trial([_write(tmp_path, "t_ms,r,u\n" + rows)])
    assert trial.fs == pytest.approx(10.0) and trial.t[-1] == pytest.approx(4.9)


def test_iso_timestamps_give_absolute_time(tmp_path):
    p = _write(tmp_path, "timestamp,u\n2022-05-18T09:47:01.10Z,1\n2022-05-18T09:47:01.20Z,2\n"
                         "2022-05-18T09:47:01.30Z,3\n")
    log = read_csv_log(p)
    np.testing.assert_allclose(log.channels["u"].t, [0, 0.1, 0.2], atol=1e-9)
    assert log.start_time == pytest.approx(datetime(2022, 5, 18, 9, 47, 1, 100000, tzinfo=timezone.utc).timestamp())
    assert log.time_reference == "unix"
    naive = read_csv_log(_write(tmp_path, "time,u\n2022-05-18 09:47:01.1,1\n2022-05-18 09:47:01.2,2\n", "n.csv"))
    assert naive.start_time == pytest.approx(log.start_time)
    assert any("no time zone; taken as UTC" in w for w in naive.summary.warnings)
    with pytest.raises(IngestError, match=r"expected an ISO 8601 timestamp in 'time' on every row, found 'soon' on "
                                          r"data row 2|expected numbers or ISO 8601 timestamps in time column 'time'"):
        read_csv_log(_write(tmp_path, "time,u\n2022-05-18T09:47:01Z,1\nsoon,2\n", "bad.csv"))


def test_unix_epoch_seconds_give_absolute_time(tmp_path):
    log = read_csv_log(_write(tmp_path, "t,u\n1652867221.1,1\n1652867221.2,2\n"))
    assert log.start_time == pytest.approx(1652867221.1)
    np.testing.assert_allclose(log.channels["u"].t, [0.0, 0.1], atol=1e-6)


def test_semicolons_and_decimal_commas(tmp_path):
    log = read_csv_log(_write(tmp_path, "t;u;psi_deg\n0,0;1,5;10\n0,1;1,6;20,5\n"))
    np.testing.assert_allclose(log.channels["u"].values, [1.5, 1.6])
    np.testing.assert_allclose(log.channels["psi"].values, np.radians([10, 20.5]))
    assert "format: separator ';', decimal ','" in log.summary.warnings
    plain = read_csv_log(_write(tmp_path, "t;u\n0.0;1.5\n0.1;1.6\n", "dot.csv"))
    np.testing.assert_allclose(plain.channels["u"].values, [1.5, 1.6])


def test_units_by_suffix_are_converted_and_named(tmp_path):
    p = _write(tmp_path, "t,psi_deg,r_degs,sog_kn,u_ms,phi_rad,heading_deg\n0,90,10,2,1.5,0.1,45\n0.1,91,10,2,1.5,0.1,46\n")
    log = read_csv_log(p, columns={"heading_deg": "psi@compass"})
    assert log.channels["psi"].values[0] == pytest.approx(np.pi / 2)
    assert log.channels["r"].values[0] == pytest.approx(np.radians(10))
    assert log.channels["sog"].values[0] == pytest.approx(2 * 1852 / 3600)
    assert log.channels["u"].values[0] == pytest.approx(1.5)
    assert log.channels["psi@compass"].values[0] == pytest.approx(np.radians(45))
    for text in ("'psi_deg' read as psi in deg", "'r_degs' read as r in deg/s", "'sog_kn' read as sog in knots",
                 "'u_ms' read as u in m/s", "'heading_deg' read as psi@compass in deg"):
        assert any(text in w for w in log.summary.warnings), text
    # A declared unit wins over the suffix (and 90 rad is then refused as implausible).
    with pytest.raises(IngestError, match=r"column 'psi_deg' \(psi\) expected in rad"):
        read_csv_log(p, units={"psi_deg": "rad"}, columns={"heading_deg": "psi@c"})


def test_two_columns_for_one_channel_and_bad_time_unit(tmp_path):
    with pytest.raises(IngestError, match=r"two columns give channel 'psi' \(one of them 'psi_deg'\)"):
        read_csv_log(_write(tmp_path, "t,psi,psi_deg\n0,0.1,5\n0.1,0.1,5\n"))
    with pytest.raises(IngestError, match=r"unit of time column 't': expected one of \['s', 'ms', 'us', 'ns'\], "
                                          r"found 'deg'"):
        read_csv_log(_write(tmp_path, "t,u\n0,1\n1,1\n", "b.csv"), units={"t": "deg"})


def test_input_kinds(tmp_path):
    p = _write(tmp_path, "t,delta,tau_x,r\n0,0,0,0\n1,0.2,4,0\n2,0.2,4,0\n")
    log = read_csv_log(p, input_kinds={"delta": "measured"})
    assert log.channels["delta"].input_kind == "measured" and not log.channels["delta"].held
    assert log.channels["tau_x"].held  # the documented default: a command
    with pytest.raises(IngestError, match=r"input kind of 'delta': expected one of \['command', 'measured'\], found 'x'"):
        read_csv_log(p, input_kinds={"delta": "x"})
    with pytest.raises(IngestError, match=r"input kind given for 'r' \(r\), but it is a state"):
        read_csv_log(p, input_kinds={"r": "measured"})
