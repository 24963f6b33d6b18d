"""``vesselid waves`` and ``vesselid autopilot``: parsers and handlers for the main CLI.

Handlers return 0 on success and raise :class:`pipeline.errors.AutopilotError` on bad input; the
main CLI prints ``error: <message>`` and exits non-zero. Degrees appear only in flags that say so
(``--phase-margin DEG``, ``--noise-std-deg``); everything written is SI and radians.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from ..atomic import atomic_write_bytes
from ..errors import AutopilotError, VesselidError
from .defaults import CROSSOVER_TIMES_T, DEFAULT_Q, DEFAULT_TS

# The design modules (numpy, scipy, casadi) load in the handlers, so ``--help`` stays fast.


# --------------------------------------------------------------------------- waves
def add_waves_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``waves LOG --json OUT.json [--column C] [--unit rad|deg] [--nperseg N] [--band LO HI] [--plot PNG]``.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``vesselid`` subcommand group (``ArgumentParser.add_subparsers()``).

    Returns
    -------
    argparse.ArgumentParser
        The ``waves`` subparser.
    """
    p = subparsers.add_parser(
        "waves", help="fit the second-order wave model to a wave-induced heading record",
        description="Fit omega0, lambda and K_w of psi_w(s) = K_w s/(s^2 + 2 lambda omega0 s + omega0^2) "
                    "by least squares to the Welch PSD of a heading record, with standard errors. "
                    "sigma^2 is the PSD peak and K_w = 2 lambda omega0 sigma (two-sided PSD per rad/s for "
                    "unit-intensity noise; the course convention, sigma/sqrt(pi), is also written).")
    p.add_argument("log", metavar="LOG", help="CSV (t [s] and a heading column) or .mat holding psi_w "
                                              "as 2 x N [time; heading in degrees] like the course's wave.mat")
    p.add_argument("--json", required=True, metavar="OUT.json", help="where to write the fit")
    p.add_argument("--column", metavar="NAME", help="CSV column or MAT variable (default psi_w, then psi)")
    p.add_argument("--unit", choices=("rad", "deg"),
                   help="heading unit (default deg for .mat and *_deg columns, else rad)")
    p.add_argument("--nperseg", type=int, metavar="N", help="Welch segment length [samples] (default <= 4096)")
    p.add_argument("--band", type=float, nargs=2, metavar=("LOW", "HIGH"),
                   help="frequency band fitted [rad/s] (default a factor 3 either side of the PSD peak)")
    p.add_argument("--plot", metavar="OUT.png", help="also write the PSD and fit as a PNG")
    p.set_defaults(func=cmd_waves)
    return p


def cmd_waves(args: argparse.Namespace) -> int:
    """Fit the wave model to ``args.log`` and write ``args.json``.

    Parameters
    ----------
    args : argparse.Namespace
        ``log``, ``json``, ``column``, ``unit``, ``nperseg``, ``band``, ``plot``.

    Returns
    -------
    int
        0.

    Raises
    ------
    AutopilotError
        Unreadable record, failed fit, unwritable output.
    """
    from .config import source_file
    from .waves_fit import course_kw, course_sigma, fit_wave_record, read_heading_record, wave_fit_to_dict

    rec = read_heading_record(args.log, column=getattr(args, "column", None), unit=getattr(args, "unit", None))
    band = tuple(args.band) if getattr(args, "band", None) else None
    fit = fit_wave_record(rec, nperseg=getattr(args, "nperseg", None), band=band)
    doc = wave_fit_to_dict(fit)
    doc["source"] = {"path": str(args.log), "sha256": source_file("waves_record", args.log).sha256,
                     "series": rec.source}
    try:
        atomic_write_bytes(Path(args.json), (json.dumps(doc, indent=2, allow_nan=False) + "\n").encode())
    except OSError as exc:
        raise AutopilotError(f"{args.json}: expected a writable JSON path, found: {exc}") from None
    if getattr(args, "plot", None):
        from .figures import wave_fit_figure

        try:
            atomic_write_bytes(Path(args.plot), wave_fit_figure(fit))
        except OSError as exc:
            raise AutopilotError(f"{args.plot}: expected a writable PNG path, found: {exc}") from None
    par, st = fit.params, fit.statistics
    print(f"omega0 = {par['omega0'].value:.4f} +- {par['omega0'].stderr:.2g} rad/s, "
          f"lambda = {par['lam'].value:.4f} +- {par['lam'].stderr:.2g}, "
          f"kw = {par['kw'].value:.4g} +- {par['kw'].stderr:.2g} rad s^-1/2, sigma = {st['sigma']:.4g} +- {st['sigma_se']:.2g} "
          f"(course convention: sigma {course_sigma(fit):.4g}, kw {course_kw(fit):.4g})")
    if fit.message:
        print(f"note: {fit.message}")
    if not fit.success:
        raise AutopilotError(f"{args.log}: expected a resonant wave spectrum, found a failed fit "
                             f"({fit.message}); the JSON was written for inspection")
    return 0


# --------------------------------------------------------------------------- autopilot
def add_autopilot_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``autopilot --coefficients C.json [--waves W.json] [--crossover RAD_S] [--phase-margin DEG] --out A.toml``
    plus ``--vessel``, ``--ts``, ``--still``, ``--noise-std-deg``, ``--q-wave``, ``--q-bias``,
    ``--ardupilot`` and ``--report-dir``.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``vesselid`` subcommand group (``ArgumentParser.add_subparsers()``).

    Returns
    -------
    argparse.ArgumentParser
        The ``autopilot`` subparser.
    """
    p = subparsers.add_parser(
        "autopilot", help="PD heading autopilot and discrete Kalman filter from the identified Nomoto model",
        description="Design the PD autopilot (T_d = T; T_f and K_pd from a crossover frequency and a phase "
                    "margin) and the 5-state discrete Kalman filter (wave filtering and rudder-bias "
                    "estimate; Van Loan discretisation), and write every number a controller needs.")
    p.add_argument("--coefficients", required=True, metavar="COEFFICIENTS.json",
                   help="the fit stage's coefficients.json (K_nomoto and T_nomoto are read)")
    p.add_argument("--waves", metavar="WAVES.json", help="wave model from `vesselid waves` "
                                                         "(default: the course record's fit, with a note)")
    p.add_argument("--crossover", type=float, default=None, metavar="RAD_S",
                   help=f"PD crossover frequency [rad/s] (default {CROSSOVER_TIMES_T:.2f}/T, as vesselid run)")
    p.add_argument("--phase-margin", type=float, default=50.0, metavar="DEG",
                   help="PD phase margin [deg] (default 50)")
    p.add_argument("--out", required=True, metavar="AUTOPILOT.toml", help="where to write the config")
    p.add_argument("--vessel", metavar="VESSEL.toml",
                   help="vessel config: [rudder] max_angle/max_rate, and [nomoto] as the simulated truth")
    p.add_argument("--ts", type=float, default=DEFAULT_TS, metavar="S",
                   help=f"filter and controller sample time [s] (default {DEFAULT_TS})")
    noise = p.add_mutually_exclusive_group()
    noise.add_argument("--still", metavar="LOG", help="compass record at rest, at least 512 samples (CSV t and "
                                                     "psi [rad] or psi_deg): its detrended sample variance is R")
    noise.add_argument("--noise-std-deg", type=float, metavar="DEG",
                       help="compass noise standard deviation per sample [deg]; R = its square in rad^2")
    p.add_argument("--q-wave", type=float, default=DEFAULT_Q[0], metavar="Q",
                   help=f"continuous intensity of the wave noise w_w [-] (default {DEFAULT_Q[0]:g}; 1 is physical)")
    p.add_argument("--q-bias", type=float, default=DEFAULT_Q[1], metavar="Q",
                   help=f"continuous intensity of the bias random walk [rad^2/s] (default {DEFAULT_Q[1]:g})")
    p.add_argument("--ardupilot", metavar="OUT.param", help="also write ArduPilot Rover steering parameters")
    p.add_argument("--report-dir", metavar="DIR",
                   help="run the closed-loop check and write its metrics, figures and HTML section here")
    p.set_defaults(func=cmd_autopilot)
    return p


def _positive_arg(name: str, value, unit: str) -> float:
    if value is None or not math.isfinite(value) or value <= 0:
        raise AutopilotError(f"{name}: expected a positive number [{unit}], found {value!r}")
    return float(value)


def cmd_autopilot(args: argparse.Namespace) -> int:
    """Build ``AUTOPILOT.toml`` from ``args.coefficients`` (and ``args.waves``) and write it to ``args.out``.

    Parameters
    ----------
    args : argparse.Namespace
        As added by :func:`add_autopilot_parser`.

    Returns
    -------
    int
        0.

    Raises
    ------
    AutopilotError
        Missing or malformed inputs, out-of-range design values, unwritable outputs.
    """
    from .config import (read_coefficients_json, read_waves_json, source_file, write_ardupilot_params,
                         write_autopilot_toml)
    from .design import build_autopilot
    from .outputs import write_autopilot_outputs
    from .kalman import sampled_noise_variance
    from .waves_fit import read_heading_record

    crossover = None if args.crossover is None else _positive_arg("--crossover", args.crossover, "rad/s")
    pm_deg = args.phase_margin
    if pm_deg is None or not math.isfinite(pm_deg) or not 0 < pm_deg < 90:
        raise AutopilotError(f"--phase-margin: expected degrees between 0 and 90 (exclusive), found {pm_deg!r}")
    ts = _positive_arg("--ts", getattr(args, "ts", DEFAULT_TS), "s")
    q = (getattr(args, "q_wave", DEFAULT_Q[0]), getattr(args, "q_bias", DEFAULT_Q[1]))
    for name, v in zip(("--q-wave", "--q-bias"), q):
        if v is None or not math.isfinite(v) or v < 0:
            raise AutopilotError(f"{name}: expected a non-negative intensity, found {v!r}")
    coefs = read_coefficients_json(args.coefficients)
    sources = []
    waves, wse, wsrc = None, None, ""
    if getattr(args, "waves", None):
        waves, wse = read_waves_json(args.waves)
        sources.append(source_file("waves", args.waves))
        wsrc = f"fitted: {args.waves}"
    vessel = None
    if getattr(args, "vessel", None):
        from ..vessel import load_vessel

        try:
            vessel = load_vessel(args.vessel)
        except VesselidError as exc:
            raise AutopilotError(f"--vessel: {exc}") from None
        sources.append(source_file("vessel", args.vessel))
    r, r_src = None, ""
    if getattr(args, "still", None):
        rec = read_heading_record(args.still)
        r = sampled_noise_variance(rec.psi)
        r_src = f"sampled variance of the still record {args.still} ({rec.fs:.3g} Hz)"
        sources.append(source_file("still", args.still))
    elif getattr(args, "noise_std_deg", None) is not None:
        r = math.radians(_positive_arg("--noise-std-deg", args.noise_std_deg, "deg")) ** 2
        r_src = f"--noise-std-deg {args.noise_std_deg:g}"
    report_dir = getattr(args, "report_dir", None)
    result = build_autopilot(coefs, waves=waves, waves_stderr=wse, wave_source=wsrc, vessel=vessel, ts=ts,
                             crossover=crossover, phase_margin=math.radians(pm_deg), r=r, r_source=r_src,
                             q=q, sources=tuple(sources), check=bool(report_dir))
    write_autopilot_toml(result.config, args.out)
    if getattr(args, "ardupilot", None):
        write_ardupilot_params(result.config, args.ardupilot)
    cfg = result.config
    print(f"K = {cfg.K:.4g} 1/s, T = {cfg.T:.4g} s -> kpd = {cfg.pd.kpd:.4g}, td = {cfg.pd.td:.4g} s, "
          f"tf = {cfg.pd.tf:.4g} s; wrote {args.out}")
    if report_dir:
        write_autopilot_outputs(result, report_dir)
        for s in result.check.scenarios:
            for c in ("pd", "pd_kalman", "pd_kalman_ff"):
                m = result.check.run(s.name, c).metrics
                print(f"  {s.name:6s} {c:13s} steady error {math.degrees(m.steady_error):6.2f} deg, "
                      f"rudder swing in 5 s {math.degrees(m.max_swing):6.2f} deg, "
                      f"RMS rudder rate {math.degrees(m.rms_rudder_rate):6.3f} deg/s")
    for n in cfg.notes:
        print(f"note: {n}")
    return 0
