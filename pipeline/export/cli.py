"""``vesselid export --coefficients C.json --to vrx|pvs|ardupilot|ros2 --out FILE [--vessel V.toml]``."""

from __future__ import annotations

import argparse

from .formats import FORMATS


def add_export_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``export`` on the ``vesselid`` subparsers.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        From ``ArgumentParser.add_subparsers``.
    """
    p = subparsers.add_parser("export", help="write the identified model for Gazebo/VRX, PythonVehicleSimulator, "
                                             "ArduPilot or ROS 2")
    p.add_argument("--coefficients", required=True, metavar="C.json", help="coefficients.json from fit or report")
    p.add_argument("--to", required=True, choices=list(FORMATS), help="target")
    p.add_argument("--out", required=True, metavar="FILE", help="file to write")
    p.add_argument("--vessel", metavar="V.toml",
                   help="vessel config: mass split, restoring and rudder limit (ardupilot needs [rudder] max_angle)")
    p.set_defaults(func=cmd_export)
    return p


def cmd_export(args: argparse.Namespace) -> int:
    """``vesselid export``: read coefficients.json, write one target's file, print notes.

    Parameters
    ----------
    args : argparse.Namespace
        ``coefficients``, ``to``, ``out`` and ``vessel`` (or None).

    Returns
    -------
    int
        0 (errors are raised and turned into an exit code by :func:`pipeline.cli.main`).
    """
    from ..report.coefficients_json import load_coefficients
    from ..vessel import load_vessel
    from .model import model_from_coefficients
    from .writers import export_text, write_export

    data = load_coefficients(args.coefficients)
    vessel = load_vessel(args.vessel) if args.vessel else None
    model = model_from_coefficients(data, vessel)
    write_export(model, data, args.to, args.out)
    print(f"wrote {args.out} ({args.to})")
    for note in model.notes:
        print(f"note: {note}")
    if args.to == "ardupilot":
        for line in export_text(model, data, "ardupilot").splitlines()[1:]:
            if line.startswith("# "):
                print(f"note: {line[2:]}")
    return 0
