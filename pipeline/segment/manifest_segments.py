"""Segments named by hand in a trial manifest, which override or add to detection."""

from __future__ import annotations

from typing import Any, Mapping, Sequence

from ..errors import SegmentError
from ..records import SEGMENT_DOFS, SEGMENT_KINDS, INPUT_UNITS, Segment, Segments, Trial

_KEYS = {"kind", "dof", "t_start", "t_end", "input_channel", "input_before", "input_after", "label"}


def parse_segment(entry: Mapping[str, Any], where: str) -> Segment:
    """One ``[[segments]]`` table of a manifest -> Segment (``origin='manifest'``).

    Parameters
    ----------
    entry : Mapping[str, Any]
        The table: ``kind``, ``dof``, ``t_start``, ``t_end`` [s] required; ``input_channel``,
        ``input_before``, ``input_after`` [SI unit of the input] and ``label`` optional.
    where : str
        Where the table is (``segments[2]``), for the error message.

    Raises
    ------
    SegmentError
        Unknown or missing keys, unknown kind, DOF or input channel, non-numeric bounds, or
        ``t_end <= t_start``.
    """
    unknown = sorted(set(entry) - _KEYS)
    if unknown:
        raise SegmentError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(_KEYS)}")
    for req in ("kind", "dof", "t_start", "t_end"):
        if req not in entry:
            raise SegmentError(f"{where}: expected key {req!r}, found keys {sorted(entry)}")
    if entry["kind"] not in SEGMENT_KINDS:
        raise SegmentError(f"{where}.kind: expected one of {SEGMENT_KINDS}, found {entry['kind']!r}")
    if entry["dof"] not in SEGMENT_DOFS:
        raise SegmentError(f"{where}.dof: expected one of {SEGMENT_DOFS}, found {entry['dof']!r}")
    ch = entry.get("input_channel")
    if ch is not None and ch not in INPUT_UNITS:
        raise SegmentError(f"{where}.input_channel: expected one of {sorted(INPUT_UNITS)}, found {ch!r}")
    try:
        t0, t1 = float(entry["t_start"]), float(entry["t_end"])
    except (TypeError, ValueError):
        raise SegmentError(f"{where}: expected numbers for t_start/t_end [s], found "
                           f"{entry['t_start']!r}, {entry['t_end']!r}") from None
    if not t1 > t0:
        raise SegmentError(f"{where}: expected t_end > t_start, found {t0} .. {t1}")
    return Segment(kind=entry["kind"], dof=entry["dof"], t_start=t0, t_end=t1, input_channel=ch,
                   input_before=float(entry.get("input_before", 0.0)), input_after=float(entry.get("input_after", 0.0)),
                   quality=1.0, origin="manifest", label=str(entry.get("label", "")))


def apply_manifest_segments(trial: Trial, detected: Segments, entries: Sequence[Mapping[str, Any]],
                            mode: str = "replace") -> Segments:
    """Combine detected segments with those a manifest names.

    Parameters
    ----------
    trial : Trial
        The trial (segment bounds are checked against its time span).
    detected : Segments
        Detector output.
    entries : Sequence[Mapping]
        The manifest's ``[[segments]]`` tables.
    mode : str
        ``replace`` (only the manifest's segments) or ``add`` (manifest segments, plus detected ones
        that do not overlap them).
    """
    if mode not in ("replace", "add"):
        raise SegmentError(f"segments mode: expected 'replace' or 'add', found {mode!r}")
    manual = [parse_segment(e, f"segments[{i}]") for i, e in enumerate(entries)]
    t_end = float(trial.t[-1]) if len(trial.t) else 0.0
    for i, s in enumerate(manual):
        if s.t_start < -1e-9 or s.t_end > t_end + 1e-6:
            raise SegmentError(f"segments[{i}]: expected bounds within the trial 0 .. {t_end:.2f} s, "
                               f"found {s.t_start} .. {s.t_end}")
    if not manual:
        return detected
    items = list(manual)
    if mode == "add":
        items += [d for d in detected.items
                  if not any(d.dof == m.dof and d.t_start < m.t_end and m.t_start < d.t_end for m in manual)]
    items.sort(key=lambda s: s.t_start)
    return Segments(detected.trial, tuple(items), detected.notes if mode == "add" else ())
