"""Trial manifests: one TOML per trial in ``trials/`` naming the vessel, the logs and options.

```toml
name = "sample"
vessel = "../../vessel_configs/aauship.toml"   # relative to this file
logs = ["sample.csv"]                          # relative to this file
fs = 100.0                                     # optional resample rate [Hz]
segments_mode = "replace"                      # how [[segments]] combine with detection: replace | add
[columns]                                      # optional CSV column map: raw name -> canonical
heading_deg = "psi"
[units]                                        # optional raw units: raw name -> deg, deg/s, km/h, knots, ...
heading_deg = "deg"
[[segments]]                                   # optional hand-named segments (override detection)
kind = "coast_down"
dof = "surge"
t_start = 40.9
t_end = 70.0
input_channel = "tau_x"
```
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from .errors import ConfigError

_KEYS = {"name", "vessel", "logs", "fs", "segments_mode", "segments", "columns", "units", "autopilot", "waves"}


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
        Log files.
    fs : float or None
        Resample rate [Hz].
    segments : tuple[Mapping, ...]
        Hand-named segments.
    segments_mode : str
        ``replace`` or ``add``.
    columns, units : Mapping[str, str]
        CSV column map and raw units.
    options : Mapping[str, Any]
        Stage options (``autopilot``, ``waves`` tables).
    path : Path
        The manifest file.
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


def load_manifest(path: str | Path) -> Manifest:
    """Read and check a trial manifest.

    Parameters
    ----------
    path : str or Path
        The TOML manifest; ``vessel`` and ``logs`` in it are relative to its folder.

    Raises
    ------
    ConfigError
        Missing file, invalid TOML, unknown keys, missing vessel or logs, logs that do not exist.
    """
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"trial manifest: expected a TOML file, found nothing at {p}")
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: expected valid TOML, found a parse error: {exc}") from None
    unknown = sorted(set(doc) - _KEYS)
    if unknown:
        raise ConfigError(f"{p}: unknown key(s) {unknown}; allowed: {sorted(_KEYS)}")
    for req in ("vessel", "logs"):
        if req not in doc:
            raise ConfigError(f"{p}: expected key {req!r}, found keys {sorted(doc)}")
    logs = doc["logs"]
    if not isinstance(logs, list) or not logs or not all(isinstance(x, str) for x in logs):
        raise ConfigError(f"{p}: 'logs' expected a non-empty list of file names, found {logs!r}")
    base = p.parent
    log_paths = tuple((base / x).resolve() for x in logs)
    missing = [str(x) for x in log_paths if not x.is_file()]
    if missing:
        raise ConfigError(f"{p}: expected log files, found none at {missing}")
    fs = doc.get("fs")
    # bool is an int to Python (fs = true would be 1 Hz), and nan passes "not <= 0".
    if fs is not None and (isinstance(fs, bool) or not isinstance(fs, (int, float)) or not math.isfinite(fs)
                           or fs <= 0):
        raise ConfigError(f"{p}: 'fs' expected a positive rate [Hz], found {fs!r}")
    for key in ("columns", "units"):
        table = doc.get(key, {})
        if not isinstance(table, dict) or not all(isinstance(v, str) for v in table.values()):
            raise ConfigError(f"{p}: '{key}' expected a table of raw column name = \"name\", found {table!r}")
    return Manifest(name=str(doc.get("name", p.stem)), vessel=(base / doc["vessel"]).resolve(), logs=log_paths,
                    fs=float(fs) if fs is not None else None, segments=tuple(doc.get("segments", [])),
                    segments_mode=str(doc.get("segments_mode", "replace")), columns=dict(doc.get("columns", {})),
                    units=dict(doc.get("units", {})),
                    options={k: doc[k] for k in ("autopilot", "waves") if k in doc}, path=p.resolve())
