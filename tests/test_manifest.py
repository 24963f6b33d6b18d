"""Trial manifests: paths resolved against the manifest, options kept, and every error named."""

from __future__ import annotations


import pytest

from pipeline.errors import ConfigError
from pipeline.manifest import Manifest, load_manifest


@pytest.fixture
def folder(tmp_path):
    (tmp_path / "logs").mkdir()
    (tmp_path / "logs" / "a.csv").write_text("t,u\n0,1\n")
    (tmp_path / "logs" / "b.csv").write_text("t,r\n0,0\n")
    return tmp_path


def _manifest(folder, body, name="trial.toml"):
    p = folder / name
    p.write_text(body)
    return p


GOOD = '''
name = "harbour"
vessel = "../vessel_configs/aauship.toml"
logs = ["logs/a.csv", "logs/b.csv"]
fs = 50
segments_mode = "add"
[columns]
heading_deg = "psi"
[units]
heading_deg = "deg"
[autopilot]
crossover = 0.3
[[segments]]
kind = "coast_down"
dof = "surge"
t_start = 40.9
t_end = 70.0
'''


def test_load_good_manifest(folder):
    p = _manifest(folder, GOOD)
    m = load_manifest(p)
    assert isinstance(m, Manifest)
    assert m.name == "harbour" and m.path == p.resolve()
    assert m.vessel == (folder.parent / "vessel_configs" / "aauship.toml").resolve()
    assert m.logs == ((folder / "logs" / "a.csv").resolve(), (folder / "logs" / "b.csv").resolve())
    assert all(x.is_absolute() for x in m.logs)
    assert m.fs == 50.0 and isinstance(m.fs, float)
    assert m.segments_mode == "add"
    assert m.columns == {"heading_deg": "psi"} and m.units == {"heading_deg": "deg"}
    assert m.options == {"autopilot": {"crossover": 0.3}}
    assert m.segments == ({"kind": "coast_down", "dof": "surge", "t_start": 40.9, "t_end": 70.0},)


def test_defaults(folder):
    m = load_manifest(_manifest(folder, 'vessel = "v.toml"\nlogs = ["logs/a.csv"]\n', "quiet_day.toml"))
    assert m.name == "quiet_day"  # the file's stem
    assert m.fs is None and m.segments == () and m.segments_mode == "replace"
    assert m.columns == {} and m.units == {} and m.options == {}


def test_relative_to_the_manifest_not_the_cwd(folder, monkeypatch):
    sub = folder / "trials"
    sub.mkdir()
    p = _manifest(sub, 'vessel = "../v.toml"\nlogs = ["../logs/a.csv"]\n')
    monkeypatch.chdir(folder / "logs")
    assert load_manifest(p).logs == ((folder / "logs" / "a.csv").resolve(),)


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match=r"trial manifest: expected a TOML file, found nothing at .*nope.toml"):
        load_manifest(tmp_path / "nope.toml")
    with pytest.raises(ConfigError, match=r"trial manifest: expected a TOML file, found nothing at"):
        load_manifest(tmp_path)  # a folder is not a manifest


def test_invalid_toml(folder):
    with pytest.raises(ConfigError, match=r"expected valid TOML, found a parse error"):
        load_manifest(_manifest(folder, 'vessel = "v.toml"\nlogs = ["a.csv"\n'))


def test_unknown_key_names_key_and_allowed(folder):
    p = _manifest(folder, 'vessel = "v.toml"\nlogs = ["logs/a.csv"]\nsample_rate = 50\nweather = "calm"\n')
    with pytest.raises(ConfigError) as exc:
        load_manifest(p)
    msg = str(exc.value)
    assert str(p) in msg and "unknown key(s) ['sample_rate', 'weather']" in msg
    for allowed in ("name", "vessel", "logs", "fs", "segments_mode", "segments", "columns", "units"):
        assert f"'{allowed}'" in msg


@pytest.mark.parametrize("body, message", [('vessel = "v.toml"\n', r"expected key 'logs' \(or \[\[runs\]\] tables"),
                                           ('logs = ["logs/a.csv"]\n', r"missing key\(s\) \['vessel'\]; found \['logs'\]")])
def test_missing_required_key(folder, body, message):
    with pytest.raises(ConfigError, match=message):
        load_manifest(_manifest(folder, body))


@pytest.mark.parametrize("logs", ['[]', '"logs/a.csv"', '[1, 2]', '["logs/a.csv", 3]'])
def test_logs_must_be_a_list_of_names(folder, logs):
    with pytest.raises(ConfigError, match=r"logs(\[\d\])?: expected a (list of one or more strings|string), found"):
        load_manifest(_manifest(folder, f'vessel = "v.toml"\nlogs = {logs}\n'))


def test_missing_log_file_is_named(folder):
    p = _manifest(folder, 'vessel = "v.toml"\nlogs = ["logs/a.csv", "logs/missing.csv"]\n')
    with pytest.raises(ConfigError) as exc:
        load_manifest(p)
    msg = str(exc.value)
    assert "expected log files, found none at" in msg and "missing.csv" in msg and "a.csv" not in msg.split("at")[-1]


@pytest.mark.parametrize("fs", ["0", "-10", '"fast"', "true", "[100]", "nan"])
def test_bad_fs(folder, fs):
    with pytest.raises(ConfigError, match=r"fs: expected a positive number, found"):
        load_manifest(_manifest(folder, f'vessel = "v.toml"\nlogs = ["logs/a.csv"]\nfs = {fs}\n'))


@pytest.mark.parametrize("key, value", [("columns", '"psi"'), ("units", "[1, 2]"), ("columns", "{ heading = 3 }")])
def test_column_map_and_units_must_be_tables_of_names(folder, key, value):
    with pytest.raises(ConfigError, match=rf"{key}(.heading)?: expected a (table of name = a string|string), found"):
        load_manifest(_manifest(folder, f'vessel = "v.toml"\nlogs = ["logs/a.csv"]\n{key} = {value}\n'))


# --------------------------------------------------------------------------- runs, inputs, folders
def test_a_folder_gives_every_log_in_it(folder):
    (folder / "logs" / "notes.md").write_text("not a log")
    (folder / "logs" / "gps.txt").write_text("$GPGGA,094701.10,5703.49,N,00952.33,E,2,6,1.8,0,M,40,M,2.6,0123*5C\n")
    (folder / "logs" / "readme.txt").write_text("hello")
    m = load_manifest(_manifest(folder, 'vessel = "v.toml"\nlogs = ["logs"]\n'))
    assert [p.name for p in m.logs] == ["a.csv", "b.csv", "gps.txt"]
    assert m.runs is None and m.run_sources is None


def test_empty_folder_is_named(folder):
    (folder / "empty").mkdir()
    with pytest.raises(ConfigError, match=r"empty: expected log files \(.csv, .tlog, .*\) in the folder, found an empty folder"):
        load_manifest(_manifest(folder, 'vessel = "v.toml"\nlogs = ["empty"]\n'))


def test_a_folder_without_logs_names_each_entry_and_why():
    # Like the CE6 actuator-test folders: text tables of encoder values, notes, a spreadsheet.
    import tempfile
    from pathlib import Path

    from pipeline.manifest import expand_logs

    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        (d / "step5000.txt").write_text("5000 0\n5100 10\n")
        (d / "results.xlsx").write_bytes(b"PK\x03\x04")
        (d / "old").mkdir()
        with pytest.raises(ConfigError) as err:
            expand_logs([d])
    msg = str(err.value)
    assert "found 3 entries, none a log" in msg
    assert "step5000.txt (text without NMEA sentences or another log format)" in msg
    assert "results.xlsx (not a log extension)" in msg and "old/ (a subfolder: not searched)" in msg


def test_a_folder_takes_a_ubx_capture_saved_as_log_and_leaves_corrections_alone(tmp_path):
    # The reader goes by content, so a folder does too (before: only .txt/.log with "$GP" and the
    # like were taken, and a u-blox capture named .log was silently left out of the trial).
    import shutil
    from pathlib import Path

    from pipeline.manifest import expand_logs

    data = Path(__file__).parent / "data"
    shutil.copy(data / "pyubx2" / "pygpsdata-ALL.log", tmp_path / "receiver.log")
    shutil.copy(data / "pyrtcm" / "pygpsdata-MT1023.log", tmp_path / "corrections.log")
    assert [p.name for p in expand_logs([tmp_path])] == ["receiver.log"]


def test_runs_and_inputs(folder):
    body = ('vessel = "v.toml"\n[inputs]\ndelta = "measured"\n[[runs]]\nname = "steps"\nlogs = ["logs/a.csv"]\n'
            '[[runs]]\nlogs = ["logs/b.csv"]\n')
    m = load_manifest(_manifest(folder, body))
    assert m.run_names == ["steps", "b"]
    assert m.run_sources == [[str((folder / "logs" / "a.csv").resolve())], [str((folder / "logs" / "b.csv").resolve())]]
    assert [p.name for p in m.logs] == ["a.csv", "b.csv"]
    assert m.inputs == {"delta": "measured"}


@pytest.mark.parametrize("body, message", [
    ('[[runs]]\nlogs = []\n', r"runs\[0\].logs: expected a list of one or more strings, found \[\]"),
    ('[[runs]]\nlogs = ["logs/a.csv"]\nfs = 3\n', r"runs\[0\]: unknown key\(s\) \['fs'\]; allowed: \['name', 'logs'\]"),
    ('runs = 3\n', r"runs: expected an array of tables \[\[...\]\], found 3"),
    ('[[runs]]\nlogs = ["logs/a.csv"]\n[[runs]]\nlogs = ["logs/a.csv"]\n',
     r"expected distinct run names, found \['a'\] more than once"),
    ('[[runs]]\nname = "x"\nlogs = ["logs/a.csv"]\n[[runs]]\nname = "y"\nlogs = ["logs/a.csv"]\n',
     r"expected each log in one run only, found \[.*a.csv'\] in more than one"),
    ('logs = ["logs/a.csv", "logs/b.csv"]\n[[runs]]\nlogs = ["logs/a.csv"]\n',
     r"expected every log in one of the \[\[runs\]\], found \[.*b.csv'\] in 'logs' only"),
    ('[inputs]\ndelta = "servo"\nlogs = ["logs/a.csv"]\n', r"inputs.delta: expected one of 'command', 'measured', "
                                                           r"found 'servo'"),
])
def test_bad_runs_and_inputs_are_named(folder, body, message):
    if body.startswith("[inputs]"):
        body = 'logs = ["logs/a.csv"]\n[inputs]\ndelta = "servo"\n'
    with pytest.raises(ConfigError, match=message):
        load_manifest(_manifest(folder, 'vessel = "v.toml"\n' + body))


def test_what_a_folder_leaves_out_is_said_by_align_and_ingest(tmp_path, capsys):
    # Nothing is dropped unsaid: a folder's entries that are not logs are named in the trial's notes
    # (the report's alignment notes) and by `vesselid ingest`, with the reason for each.
    import shutil
    from pathlib import Path

    from pipeline.cli import main
    from pipeline.flow import load_trial

    root = Path(__file__).resolve().parents[1]
    shutil.copy(root / "trials" / "sample" / "sample.csv", tmp_path / "run1.csv")
    (tmp_path / "results.xlsx").write_bytes(b"PK\x03\x04")
    (tmp_path / "imu_raw.txt").write_text("5000 0\n5100 10\n")
    notes = [n for n in load_trial([tmp_path]).notes if n.startswith("folder ")]
    assert len(notes) == 1, notes
    assert "1 log(s) read, 2 entries left out (not logs)" in notes[0]
    assert "results.xlsx (not a log extension)" in notes[0]
    assert "imu_raw.txt (text without NMEA sentences or another log format)" in notes[0]
    assert main(["ingest", str(tmp_path)]) == 0
    assert "results.xlsx (not a log extension)" in capsys.readouterr().out
    # A folder of logs only, or a file given by name, adds no note.
    (tmp_path / "results.xlsx").unlink()
    (tmp_path / "imu_raw.txt").unlink()
    assert not [n for n in load_trial([tmp_path]).notes if n.startswith("folder ")]
    assert not [n for n in load_trial([tmp_path / "run1.csv"]).notes if n.startswith("folder ")]
