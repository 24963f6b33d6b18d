"""Trial manifests: one TOML per trial in ``trials/`` naming the vessel, the logs and options.

```toml
name = "sample"
vessel = "../../vessel_configs/aauship.toml"   # relative to this file
logs = ["sample.csv"]                          # relative to this file; a folder means every log in it
fs = 100.0                                     # optional resample rate [Hz]
segments_mode = "replace"                      # how [[segments]] combine with detection: replace | add
[columns]                                      # optional CSV column map: raw name -> canonical
heading_deg = "psi"
[units]                                        # optional raw units: raw name -> deg, deg/s, km/h, knots, ...
heading_deg = "deg"
[inputs]                                       # optional: input channel -> command (held, default) | measured
delta = "measured"                             # a rudder-angle sensor: interpolated like a state
[[runs]]                                       # optional: state the runs (recordings) instead of
name = "rudder steps"                          # letting align group the logs; each log (or folder)
logs = ["steps.bin"]                           # in exactly one run; then top-level logs may be left out
[[segments]]                                   # optional hand-named segments (override detection)
kind = "coast_down"
dof = "surge"
t_start = 40.9
t_end = 70.0
input_channel = "tau_x"
```
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from .config_schema import MANIFEST_SCHEMA, read_toml, validate
from .errors import ConfigError

@dataclass(frozen=True)
class Manifest:
    """A parsed trial manifest; paths are absolute.

    Attributes
    ----------
    name : str
        Trial name.
    vessel : Path
        Vessel TOML.
    logs : tuple[Path, ...]
        Log files (and ROS 2 bag folders); folders named in the manifest are expanded to the logs
        in them (:func:`expand_logs`). With ``[[runs]]``, every run's logs in run order.
    fs : float or None
        Resample rate [Hz].
    segments : tuple[Mapping, ...]
        Hand-named segments.
    segments_mode : str
        ``replace`` or ``add``.
    columns, units : Mapping[str, str]
        CSV column map and raw units.
    options : Mapping[str, Any]
        Stage options (the ``autopilot`` table; a ``[waves]`` table is refused: no stage reads it).
    path : Path
        The manifest file.
    runs : tuple[tuple[str, tuple[Path, ...]], ...] or None
        Stated runs ``(name, logs)``; None lets align group the logs.
    inputs : Mapping[str, str]
        Input channel -> ``command`` or ``measured`` (``[inputs]``).
    """

    name: str
    vessel: Path
    logs: tuple[Path, ...]
    fs: float | None = None
    segments: tuple[Mapping[str, Any], ...] = ()
    segments_mode: str = "replace"
    columns: Mapping[str, str] = field(default_factory=dict)
    units: Mapping[str, str] = field(default_factory=dict)
    options: Mapping[str, Any] = field(default_factory=dict)
    path: Path = Path(".")
    runs: tuple[tuple[str, tuple[Path, ...]], ...] | None = None
    inputs: Mapping[str, str] = field(default_factory=dict)

    @property
    def run_sources(self) -> list[list[str]] | None:
        """Stated runs as lists of source strings (``RawLog.source``), for :func:`pipeline.align.align`."""
        return None if self.runs is None else [[str(p) for p in logs] for _, logs in self.runs]

    @property
    def run_names(self) -> list[str] | None:
        """Names of the stated runs, or None."""
        return None if self.runs is None else [n for n, _ in self.runs]


#: File extensions :func:`expand_logs` takes from a folder (the formats the ingest reads).
LOG_EXTENSIONS = (".csv", ".tlog", ".bin", ".ubx", ".nmea", ".bag", ".db3", ".mcap", ".txt", ".log", ".ulg")


def expand_logs(paths) -> list[Path]:
    """Log files from files and folders: a folder gives every log in it, sorted by name.

    A ROS 2 bag folder (it holds ``metadata.yaml``) is one log, not a folder of logs; ``.txt``
    and ``.log`` files are taken only when their content is a log (NMEA sentences, UBX frames,
    MAVLink, DataFlash, ULog; :func:`pipeline.ingest.sniff.sniff`); subfolders that are bags are
    taken, other subfolders are not searched. :func:`scan_logs` also says what each folder left out.

    Parameters
    ----------
    paths : Iterable[str or Path]
        Files and folders.

    Returns
    -------
    list[Path]
        Files (and bag folders) in the order given, each folder's content sorted by name.

    Raises
    ------
    ConfigError
        A folder with no log in it (naming what it holds and why each was not taken).
    """
    return scan_logs(paths)[0]


def scan_logs(paths) -> tuple[list[Path], list[str]]:
    """:func:`expand_logs`, and what it left out of each folder (nothing is dropped unsaid).

    Parameters
    ----------
    paths : Iterable[str or Path]
        Files and folders.

    Returns
    -------
    files : list[Path]
        As :func:`expand_logs`.
    notes : list[str]
        For every folder that holds entries that are not logs: the folder, how many logs were
        taken, and each entry left out with the reason (at most 12 named, then a count).

    Raises
    ------
    ConfigError
        A folder with no log in it (naming what it holds and why each was not taken).
    """
    out: list[Path] = []
    notes: list[str] = []
    for raw in paths:
        p = Path(raw)
        if not _is_folder_of_logs(p):
            out.append(p)
            continue
        found, left = _scan_folder(p)
        if not found:
            what = "an empty folder" if not left else (
                f"{len(left)} entr{'y' if len(left) == 1 else 'ies'}, none a log: " + "; ".join(left[:6])
                + (f"; and {len(left) - 6} more" if len(left) > 6 else ""))
            raise ConfigError(f"{p}: expected log files ({', '.join(LOG_EXTENSIONS)}; .txt and .log holding NMEA "
                              f"or another log format) in the folder, found {what}")
        if left:
            named = "; ".join(left[:12]) + (f"; and {len(left) - 12} more" if len(left) > 12 else "")
            notes.append(f"folder {p}: {len(found)} log(s) read, {len(left)} entr{'y' if len(left) == 1 else 'ies'} "
                         f"left out (not logs): {named}")
        out += found
    return out, notes


def _is_folder_of_logs(p: Path) -> bool:
    """True for a folder whose entries are the logs (a ROS 2 bag folder is one log)."""
    return p.is_dir() and not (p / "metadata.yaml").is_file()


def _scan_folder(p: Path) -> tuple[list[Path], list[str]]:
    """The logs of one folder (sorted by name) and every other entry with why it was not taken."""
    found, left = [], []
    for child in sorted(p.iterdir()):
        if child.is_dir():
            if (child / "metadata.yaml").is_file():
                found.append(child)
            else:
                left.append(f"{child.name}/ (a subfolder: not searched)")
            continue
        ext = child.suffix.lower()
        if ext in (".txt", ".log"):
            if _holds_log(child):
                found.append(child)
            else:
                left.append(f"{child.name} (text without NMEA sentences or another log format)")
        elif ext in LOG_EXTENSIONS:
            found.append(child)
        else:
            left.append(f"{child.name} (not a log extension)")
    return found, left


def _holds_log(p: Path) -> bool:
    """True when ``p`` holds a log format the ingest reads (RTCM corrections alone are not a log)."""
    from .ingest.sniff import sniff

    try:
        fmt, _ = sniff(p)
    except OSError:
        return False
    return (fmt is not None and fmt != "rtcm3") or _holds_nmea(p)


def _holds_nmea(p: Path) -> bool:
    try:
        with open(p, "rb") as fh:
            head = fh.read(4096)
    except OSError:
        return False
    return b"$GP" in head or b"$GN" in head or b"$II" in head or b"$HE" in head


def load_manifest(path: str | Path) -> Manifest:
    """Read and check a trial manifest.

    Every table is checked first by the one schema (:data:`pipeline.config_schema.MANIFEST_SCHEMA`);
    what remains here is what a schema cannot say: logs that exist, and runs that hold every log once.

    Parameters
    ----------
    path : str or Path
        The TOML manifest; ``vessel`` and ``logs`` in it are relative to its folder.

    Raises
    ------
    ConfigError
        Missing file, invalid TOML, unknown keys, missing vessel or logs, logs that do not exist.
    """
    p, doc = read_toml(path, "trial manifest")
    validate(doc, MANIFEST_SCHEMA, str(p))  # every table ([autopilot], [[segments]], ...; [waves] refused), before any work
    if "logs" not in doc and "runs" not in doc:
        raise ConfigError(f"{p}: expected key 'logs' (or [[runs]] tables with logs), found keys {sorted(doc)}")
    base = p.parent
    runs = _runs(p, doc["runs"], base) if "runs" in doc else None
    log_paths = tuple(_existing(p, base, doc["logs"])) if "logs" in doc else ()
    if runs is not None:
        in_runs = [x for _, r in runs for x in r]
        outside = [str(x) for x in log_paths if x not in in_runs]
        if outside:
            raise ConfigError(f"{p}: expected every log in one of the [[runs]], found {outside} in 'logs' only")
        twice = sorted({str(x) for x in in_runs if in_runs.count(x) > 1})
        if twice:
            raise ConfigError(f"{p}: expected each log in one run only, found {twice} in more than one")
        log_paths = tuple(in_runs)
    fs = doc.get("fs")
    return Manifest(name=str(doc.get("name", p.stem)), vessel=(base / doc["vessel"]).resolve(), logs=log_paths,
                    fs=float(fs) if fs is not None else None, segments=tuple(doc.get("segments", [])),
                    segments_mode=str(doc.get("segments_mode", "replace")), columns=dict(doc.get("columns", {})),
                    units=dict(doc.get("units", {})),
                    options={k: doc[k] for k in ("autopilot",) if k in doc}, path=p.resolve(),
                    runs=runs, inputs=dict(doc.get("inputs", {})))


def _existing(p: Path, base: Path, names) -> list[Path]:
    paths = [(base / x).resolve() for x in names]
    missing = [str(x) for x in paths if not x.exists()]
    if missing:
        raise ConfigError(f"{p}: expected log files, found none at {missing}")
    return expand_logs(paths)


def _runs(p: Path, runs: list[Mapping[str, Any]], base: Path) -> tuple[tuple[str, tuple[Path, ...]], ...]:
    """The stated runs ``(name, logs)`` of a manifest whose ``[[runs]]`` passed the schema."""
    out = []
    for r in runs:
        files = tuple(_existing(p, base, r["logs"]))
        out.append((str(r.get("name", files[0].stem)), files))
    names = [n for n, _ in out]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ConfigError(f"{p}: expected distinct run names, found {dup} more than once")
    return tuple(out)
