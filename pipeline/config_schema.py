"""One schema for the two configuration files: the vessel TOML and the trial manifest.

Every table of both files is declared here (``VESSEL_SCHEMA``, ``MANIFEST_SCHEMA``) and checked by
:func:`validate` before any work starts (:func:`pipeline.vessel.parse_vessel` and
:func:`pipeline.manifest.load_manifest` call it when the file is read): key names, types, lengths and allowed
words. An error names the place as a TOML key path (``aauship.toml: thrusters.surge.gain``), what was expected and
what was found, and lists every problem at once. What a schema cannot say (a positive definite
damping matrix, logs that exist, a thruster table with increasing commands, segment bounds inside
the trial) is checked by the stage that reads the table, still before the heavy work.

Why no library: jsonschema (or pydantic) would need the same declarations plus a translation of
its messages ("1.5 is not of type 'string'") into the project's "expected ..., found ..." form and
the TOML table names; TOML has six value types, and the walker below is short. The schema is
plain data, readable as the reference of both files.

Spec language
-------------
A spec is one of: ``"string"``, ``"number"`` (finite int or float, not bool), ``"positive"``
(number > 0), ``"non-negative"`` (number >= 0), ``"text"`` (a non-empty string), ``"integer>=1"``,
``"boolean"``, ``("one of", words)``, ``("list", n, spec)`` (``n`` items, None: any non-empty
length), ``("matrix", rows, cols)`` of numbers,
``("table", {key: spec}, required)`` (unknown keys refused), ``("map", spec)`` (free keys, each
value ``spec``), ``("tables", spec)`` (a TOML array of tables, each ``spec``), ``("refuse",
why)`` (a key that is recognised but not accepted) and ``("any of", spec, ...)`` (the first that
fits).
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any, Mapping

from .errors import ConfigError
from .records import DOF_NAMES, INPUT_KINDS, INPUT_UNITS, SEGMENT_DOFS, SEGMENT_KINDS, STATE_UNITS

DOF_WORDS = tuple(DOF_NAMES.values())
_NUM = "number"
_POS = "positive"

#: ``[sensors.<name>]``: an antenna (``lever_arm``) or a dual-antenna baseline (``antennas``).
SENSOR = ("any of",
          ("table", {"lever_arm": ("list", 3, _NUM), "suffix": "string"}, ("lever_arm",)),
          ("table", {"antennas": ("list", 2, "string"), "mounting_yaw": _NUM}, ("antennas",)))
#: ``[thrusters.<dof>]``: linear map (``gain``, ``offset``) or a bollard-pull ``table``.
THRUSTER = ("table", {"input": ("one of", tuple(INPUT_UNITS)), "gain": _NUM, "offset": _NUM,
                      "table": ("list", None, ("list", 2, _NUM)), "relative_stderr": _NUM}, ())

#: ``[steady_state.<dof>]``: thrust against steady speed (pipeline.fit.steady_map).
STEADY = ("table", {"speed": ("list", None, _NUM), "force": ("list", None, _NUM),
                    "speed_se": ("any of", _NUM, ("list", None, _NUM)),
                    "force_se": ("any of", _POS, ("list", None, _POS)), "source": "string"},
          ("speed", "force", "force_se"))
#: The DOFs a ``[steady_state]`` table may name, and the keys of one DOF's table (the fit reads them here).
STEADY_DOFS = ("surge", "sway", "yaw")
STEADY_KEYS = tuple(STEADY[1])

VESSEL_SCHEMA = ("table", {
    "name": "text",
    "rigid_body": ("table", {"mass": _POS, "inertia": ("list", 3, _POS), "cg": ("list", 3, _NUM)}, ()),
    "added_mass": ("table", {d: "non-negative" for d in DOF_WORDS}, ()),  # -X_udot, -Y_vdot, ...
    "restoring": ("table", {"roll": _NUM, "pitch": _NUM}, ()),
    "damping": ("table", {"matrix": ("matrix", 5, 5), "diagonal": ("list", 5, _NUM),
                          "quadratic": ("list", 5, _NUM)}, ()),
    "nomoto": ("table", {"K": _NUM, "T": _POS}, ()),
    "rudder": ("table", {"max_angle": _POS, "max_rate": _POS, "yaw_moment": _NUM, "sway_force": _NUM}, ()),
    # source: PWM (servo, rc) or PX4's normalised actuator_motors / actuator_servos (motor, servo_control).
    # Several maps of one source and channel are one actuator driving several inputs (a thruster's
    # surge force and yaw moment): the allocation; ``name`` names it (pipeline.vessel.actuator_allocation).
    "actuators": ("tables", ("table", {"source": ("one of", ("servo", "rc", "motor", "servo_control")),
                                       "channel": "integer>=1", "target": ("one of", tuple(INPUT_UNITS)), "pwm_trim": _NUM,
                                       "pwm_span": _POS, "full_scale": _NUM, "reverse_scale": _NUM,
                                       "name": "text"},
                             ("source", "channel", "target"))),
    "thrusters": ("table", {d: THRUSTER for d in ("surge", "sway", "yaw")}, ()),
    "topics": ("map", "string"),
    "sensors": ("map", SENSOR),
    "steady_state": ("table", {d: STEADY for d in STEADY_DOFS}, ()),
    # Optional: white-noise standard deviation per logged sample of a sensor channel [SI unit of the
    # channel] (pipeline.vessel docstring); the diagnosis' noise floor is at most this.
    "sensor_noise": ("table", {c: _POS for c in STATE_UNITS}, ()),
}, ("name",))

#: A manifest's hand-named segment (``[[segments]]``).
SEGMENT = ("table", {"kind": ("one of", SEGMENT_KINDS), "dof": ("one of", SEGMENT_DOFS), "t_start": _NUM, "t_end": _NUM,
                     "input_channel": "string", "input_before": _NUM, "input_after": _NUM, "label": "string"},
           ("kind", "dof", "t_start", "t_end"))

MANIFEST_SCHEMA = ("table", {
    "name": "text",
    "vessel": "string",
    "logs": ("list", None, "string"),
    "fs": _POS,
    "segments_mode": ("one of", ("replace", "add")),
    "segments": ("tables", SEGMENT),
    "columns": ("map", "string"),
    "units": ("map", "string"),
    "inputs": ("map", ("one of", INPUT_KINDS)),
    "autopilot": ("table", {"crossover": _POS, "phase_margin_deg": _POS}, ()),
    "runs": ("tables", ("table", {"name": "string", "logs": ("list", None, "string")}, ("logs",))),
    "waves": ("refuse", "no stage reads a manifest [waves] table (a wave model is fitted from a heading "
                        "record with `vesselid waves`); remove the table"),
}, ("vessel",))


def _kind(value: Any) -> str:
    if isinstance(value, bool):
        return f"{value!r}"
    if isinstance(value, Mapping):
        return f"a table with keys {sorted(value)}"
    if isinstance(value, list):
        return f"{value!r}" if len(repr(value)) <= 60 else f"a list of {len(value)}"
    return f"{value!r}"


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _describe(spec) -> str:
    if isinstance(spec, str):
        return {"string": "a string", "number": "a finite number", "positive": "a positive number",
                "integer>=1": "an integer >= 1", "boolean": "true or false",
                "non-negative": "a number >= 0", "text": "a non-empty string"}[spec]
    tag = spec[0]
    if tag == "one of":
        return "one of " + ", ".join(repr(w) for w in spec[1])
    if tag == "list":
        item = _describe(spec[2]).removeprefix("a ").removeprefix("an ")
        item = item + "s" if item.endswith(("number", "string")) else item
        return f"a list of {spec[1] if spec[1] else 'one or more'} {item}"
    if tag == "matrix":
        return f"a {spec[1]}x{spec[2]} array of numbers"
    if tag == "table":
        return "a table with keys " + ", ".join(spec[1])
    if tag == "map":
        return f"a table of name = {_describe(spec[1])}"
    if tag == "tables":
        return "an array of tables [[...]]"
    if tag == "any of":
        return " or ".join(_describe(s) for s in spec[1:])
    return str(spec)


def _child(where: str, key: str, spec) -> str:
    """TOML key path of ``key`` inside ``where`` (``thrusters.surge.gain``)."""
    return f"{where}.{key}" if where else key


def _check(where: str, value: Any, spec, errors: list[str]) -> None:
    """Append to ``errors`` every way ``value`` at ``where`` departs from ``spec``."""
    if isinstance(spec, str):
        ok = {"string": lambda v: isinstance(v, str),
              "number": _is_number,
              "positive": lambda v: _is_number(v) and v > 0,
              "non-negative": lambda v: _is_number(v) and v >= 0,
              "text": lambda v: isinstance(v, str) and bool(v.strip()),
              "integer>=1": lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 1,
              "boolean": lambda v: isinstance(v, bool)}[spec](value)
        if not ok:
            errors.append(f"{where}: expected {_describe(spec)}, found {_kind(value)}")
        return
    tag = spec[0]
    if tag == "one of":
        if value not in spec[1]:
            errors.append(f"{where}: expected {_describe(spec)}, found {_kind(value)}")
    elif tag == "list":
        n, item = spec[1], spec[2]
        if not isinstance(value, list) or (n is not None and len(value) != n) or (n is None and not value):
            errors.append(f"{where}: expected {_describe(spec)}, found {_kind(value)}")
            return
        for i, v in enumerate(value):
            _check(f"{where}[{i}]", v, item, errors)
    elif tag == "matrix":
        rows, cols = spec[1], spec[2]
        if not (isinstance(value, list) and len(value) == rows
                and all(isinstance(r, list) and len(r) == cols and all(_is_number(x) for x in r) for r in value)):
            errors.append(f"{where}: expected {_describe(spec)}, found {value!r}")
    elif tag == "table":
        if not isinstance(value, Mapping):
            errors.append(f"{where}: expected {_describe(spec)}, found {_kind(value)}")
            return
        keys, required = spec[1], spec[2]
        unknown = sorted(set(value) - set(keys))
        if unknown:
            errors.append(f"{where}: unknown key(s) {unknown}; allowed: {list(keys)}")
        missing = [k for k in required if k not in value]
        if missing:
            errors.append(f"{where}: missing key(s) {missing}; found {sorted(value)}")
        for k, sub in keys.items():
            if k in value:
                _check(_child(where, k, sub), value[k], sub, errors)
    elif tag == "map":
        if not isinstance(value, Mapping):
            errors.append(f"{where}: expected {_describe(spec)}, found {_kind(value)}")
            return
        for k, v in value.items():
            _check(_child(where, k, spec[1]), v, spec[1], errors)
    elif tag == "tables":
        if not isinstance(value, list) or not all(isinstance(v, Mapping) for v in value):
            errors.append(f"{where}: expected {_describe(spec)}, found {_kind(value)}")
            return
        for i, v in enumerate(value):
            _check(f"{where}[{i}]", v, spec[1], errors)
    elif tag == "refuse":
        errors.append(f"{where}: {spec[1]}")
    elif tag == "any of":
        for option in spec[1:]:
            trial: list[str] = []
            _check(where, value, option, trial)
            if not trial:
                return
        # A table that has an option's required keys is meant as that option: report its errors.
        meant = [o for o in spec[1:] if o[0] == "table" and o[2] and isinstance(value, Mapping)
                 and all(k in value for k in o[2])]
        if meant:
            _check(where, value, meant[0], errors)
        else:
            errors.append(f"{where}: expected {_describe(spec)}, found {_kind(value)}")
    else:  # a programming error in the schema itself
        raise ValueError(f"config_schema: unknown spec {spec!r}")


def read_toml(path: str | Path, what: str) -> tuple[Path, dict]:
    """Read a configuration TOML; a missing file or a parse error is a ConfigError naming ``what``.

    Parameters
    ----------
    path : str or Path
        The file.
    what : str
        What it should be (``vessel config``, ``trial manifest``), for the message.

    Returns
    -------
    tuple[Path, dict]
        The path and the parsed document (not yet validated).
    """
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{what}: expected a TOML file, found nothing at {p}")
    try:
        return p, tomllib.loads(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: expected valid TOML, found a parse error: {exc}") from None


def validate(doc: Mapping[str, Any], schema, source: str) -> None:
    """Check a parsed TOML document against ``schema``; raise one ConfigError listing every problem.

    Parameters
    ----------
    doc : Mapping
        The parsed TOML (``tomllib.load``); not modified.
    schema : tuple
        ``VESSEL_SCHEMA`` or ``MANIFEST_SCHEMA``.
    source : str
        The file name, for the messages.

    Raises
    ------
    ConfigError
        ``source: <place>: expected ..., found ...``, one line per problem.
    """
    if not isinstance(doc, Mapping):
        raise ConfigError(f"{source}: expected a TOML table at the top level, found {_kind(doc)}")
    errors: list[str] = []
    _check("", doc, schema, errors)
    errors = [e.removeprefix(": ") for e in errors]  # the top level has no key path
    if errors:
        head = f"{source}: " if len(errors) == 1 else f"{source}: {len(errors)} problems:\n  "
        raise ConfigError(head + "\n  ".join(errors))

