"""Thruster maps: logged command -> thrust [N] (or yaw moment [N m]), read from the vessel config.

The vessel TOML's ``[thrusters]`` table is passed through untouched by :mod:`pipeline.vessel`
(``Vessel.extra['thrusters']``); it is validated here. One sub-table per DOF it drives::

    [thrusters.surge]               # DOF: surge, sway or yaw
    input = "tau_x"                 # logged channel holding the command (default: the DOF's force channel)
    gain = 0.2746                   # N (N m for yaw) per unit command ...
    offset = 97.7                   # ... above this command (zero thrust; default 0): F = gain (c - offset)
    relative_stderr = 0.05          # optional 1-sigma relative uncertainty of the thrust (default 0)

    [thrusters.surge]               # or a bollard-pull table: command -> N, piecewise linear
    input = "tau_x"
    table = [[60, 0.0], [100, 7.0], [140, 18.0], [180, 36.0]]

``gain`` (with ``offset``) and ``table`` are exclusive. A table's commands must increase strictly;
commands outside its range are refused (the map is not known there), not extrapolated. When the
log already holds the generalised force in newtons, ``gain = 1.0`` states that thrust is known.

A bollard-pull map overstates the thrust at speed (thrust deduction, advance ratio); the fits that
use it say so in their method text.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..errors import ConfigError, FitError
from ..records import DOF_CHANNELS, INPUT_UNITS

#: DOFs a thruster map may drive.
THRUSTER_DOFS = ("surge", "sway", "yaw")
_KEYS = {"input", "gain", "offset", "table", "relative_stderr"}


@dataclass(frozen=True)
class ThrusterMap:
    """Command -> generalised force of one DOF.

    Attributes
    ----------
    dof : str
        ``surge``, ``sway`` or ``yaw``.
    input : str
        Logged channel holding the command.
    gain : float or None
        Thrust per unit command [N or N m per command unit] (linear map).
    offset : float
        Command at zero thrust (linear map) [command unit].
    table : tuple[tuple[float, float], ...]
        ``(command, thrust)`` points (piecewise-linear map), commands strictly increasing.
    relative_stderr : float
        1-sigma relative uncertainty of the thrust [-].
    """

    dof: str
    input: str
    gain: float | None = None
    offset: float = 0.0
    table: tuple[tuple[float, float], ...] = ()
    relative_stderr: float = 0.0

    @property
    def kind(self) -> str:
        """``gain`` or ``table``."""
        return "table" if self.table else "gain"

    @property
    def unit(self) -> str:
        """Unit of the thrust: N, or N m for yaw."""
        return "N m" if self.dof == "yaw" else "N"

    def thrust(self, command: np.ndarray | float) -> np.ndarray:
        """Thrust [N or N m] for commands [command unit].

        Parameters
        ----------
        command : numpy.ndarray or float
            Logged command(s) [command unit].

        Raises
        ------
        FitError
            A command outside a table's range.
        """
        c = np.asarray(command, float)
        if not self.table:
            return float(self.gain) * (c - self.offset)
        x = np.array([p[0] for p in self.table])
        y = np.array([p[1] for p in self.table])
        finite = c[np.isfinite(c)]
        if finite.size and (finite.min() < x[0] or finite.max() > x[-1]):
            raise FitError(f"thrusters.{self.dof}: expected commands within the table's range "
                           f"[{x[0]:g}, {x[-1]:g}], found {finite.min():g} to {finite.max():g}")
        return np.interp(c, x, y)

    def describe(self) -> str:
        """Short text for method strings."""
        if self.table:
            (c0, f0), (c1, f1) = self.table[0], self.table[-1]
            return (f"thruster table of {len(self.table)} points on {self.input} "
                    f"({c0:g}..{c1:g} -> {f0:g}..{f1:g} {self.unit})")
        off = f" (c - {self.offset:g})" if self.offset else " c"
        return f"thruster gain F = {self.gain:g}{off} {self.unit} on {self.input}"


def _number(where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{where}: expected a finite number, found {value!r}")
    return float(value)


def parse_thrusters(section: Mapping[str, Any] | None, where: str = "[thrusters]") -> dict[str, ThrusterMap]:
    """Validate a ``[thrusters]`` table (``Vessel.extra['thrusters']``).

    Parameters
    ----------
    section : Mapping or None
        The parsed TOML table; None or empty gives no maps.
    where : str
        Config location for error messages.

    Returns
    -------
    dict[str, ThrusterMap]
        By DOF.

    Raises
    ------
    ConfigError
        Unknown DOF or key, gain and table both or neither, a malformed or non-increasing table,
        a negative ``relative_stderr``, an input that is not a canonical input channel.
    """
    if not section:
        return {}
    if not isinstance(section, Mapping):
        raise ConfigError(f"{where}: expected a table of DOFs ({', '.join(THRUSTER_DOFS)}), found "
                          f"{type(section).__name__}")
    out = {}
    for dof, spec in section.items():
        here = f"{where[:-1]}.{dof}]" if where.endswith("]") else f"{where}.{dof}"
        if dof not in THRUSTER_DOFS:
            raise ConfigError(f"{here}: unknown DOF {dof!r}; expected one of {list(THRUSTER_DOFS)}")
        if not isinstance(spec, Mapping):
            raise ConfigError(f"{here}: expected a table with gain or table, found {spec!r}")
        unknown = sorted(set(spec) - _KEYS)
        if unknown:
            raise ConfigError(f"{here}: unknown key(s) {unknown}; allowed: {sorted(_KEYS)}")
        has_gain, has_table = "gain" in spec, "table" in spec
        if has_gain == has_table:
            raise ConfigError(f"{here}: expected exactly one of 'gain' or 'table', found "
                              f"{'both' if has_gain else 'neither'}")
        if "offset" in spec and not has_gain:
            raise ConfigError(f"{here}: 'offset' belongs to a linear 'gain' map, found it with a 'table'")
        channel = spec.get("input", DOF_CHANNELS[dof][1])
        if channel not in INPUT_UNITS:
            raise ConfigError(f"{here}.input: expected a canonical input channel {sorted(INPUT_UNITS)}, "
                              f"found {channel!r}")
        rel = _number(f"{here}.relative_stderr", spec.get("relative_stderr", 0.0))
        if rel < 0:
            raise ConfigError(f"{here}.relative_stderr: expected >= 0, found {rel}")
        if has_gain:
            gain = _number(f"{here}.gain", spec["gain"])
            if gain == 0:
                raise ConfigError(f"{here}.gain: expected a non-zero thrust per command unit, found 0")
            out[dof] = ThrusterMap(dof, channel, gain=gain, offset=_number(f"{here}.offset", spec.get("offset", 0.0)),
                                   relative_stderr=rel)
            continue
        table = spec["table"]
        try:
            pts = tuple((float(a), float(b)) for a, b in table)
        except (TypeError, ValueError):
            raise ConfigError(f"{here}.table: expected [[command, thrust], ...] pairs of numbers, "
                              f"found {table!r}") from None
        if len(pts) < 2 or not all(math.isfinite(a) and math.isfinite(b) for a, b in pts):
            raise ConfigError(f"{here}.table: expected at least 2 finite [command, thrust] points, found {table!r}")
        cmds = np.array([a for a, _ in pts])
        if np.any(np.diff(cmds) <= 0):
            raise ConfigError(f"{here}.table: expected strictly increasing commands, found {cmds.tolist()}")
        out[dof] = ThrusterMap(dof, channel, table=pts, relative_stderr=rel)
    return out
