"""Dispatch: one export format -> its text, written atomically."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping

from ..atomic import atomic_write_text
from .ardupilot import ardupilot_text
from .errors import ExportError
from .formats import FORMATS
from .model import ExportModel
from .pvs import pvs_module
from .ros2 import ros2_yaml
from .vrx import vrx_sdf



def export_text(model: ExportModel, coefficients: Mapping[str, Any], target: str) -> str:
    """The file text for ``target``.

    Parameters
    ----------
    model : ExportModel
        The identified model.
    coefficients : Mapping
        The loaded ``coefficients.json``.
    target : str
        One of ``FORMATS``.

    Raises
    ------
    ExportError
        Unknown target or a model lacking what the target needs.
    """
    if target == "vrx":
        model.require("damping", (0, 1, 4), "vrx")
        return vrx_sdf(model)
    if target == "pvs":
        model.require("damping", (0,), "pvs")
        model.require("inertia", (0,), "pvs")
        return pvs_module(model)
    if target == "ardupilot":
        return ardupilot_text(model)
    if target == "ros2":
        return ros2_yaml(model, coefficients)
    raise ExportError(f"--to: expected one of {list(FORMATS)}, found {target!r}")


def write_export(model: ExportModel, coefficients: Mapping[str, Any], target: str, path: str | os.PathLike) -> Path:
    """Write :func:`export_text` to ``path`` atomically.

    Parameters
    ----------
    model : ExportModel
        The identified model.
    coefficients : Mapping
        The loaded ``coefficients.json``.
    target : str
        One of ``FORMATS``.
    path : str or os.PathLike
        Output file.
    """
    text = export_text(model, coefficients, target)
    return atomic_write_text(Path(path), text)
