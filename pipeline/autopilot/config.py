"""The autopilot configuration (:class:`pipeline.records.AutopilotConfig`): its design, TOML file, input
readers and an ArduPilot export.

``AUTOPILOT.toml`` holds every number a controller needs, SI units and radians::

    ts = 0.1                                   # filter and controller sample time [s]
    states = ["xi_w", "psi_w", "psi", "r", "b"]
    [model]   K, T (+ K_stderr, T_stderr)      # Nomoto [1/s], [s]
    [wave]    omega0, lambda, kw (+ _stderr), source
    [pd]      kpd, td, tf, crossover, phase_margin
    [rudder]  max_angle, max_rate, source
    [kalman]  ad (5x5), bd (5), ed (5x2), c (5), qd (5x5), r, p0 (5x5), x0 (5), q (2x2), layout
    [provenance] version, generator, sources = [{role, path, sha256}], notes

Matrices are lists of rows; ``bd`` is the input column and ``c`` the measurement row, flattened.
A value that could not be identified (a standard error) is left out rather than written as NaN.
"""

from __future__ import annotations

import hashlib
import json
import math
import tomllib
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import tomli_w

from ..atomic import atomic_write_bytes
from ..errors import AutopilotError
from ..model.waves import WaveParams
from ..records import ArduPilotExport, AutopilotConfig, KalmanModel, NomotoCoefficients, PDGains, SourceFile
from .defaults import DEFAULT_TS  # the default lives where the CLI's --help can read it
from .kalman import DEFAULT_P0, DEFAULT_Q, DEFAULT_R, KALMAN_STATES, kalman_model
from .pd import DEFAULT_PHASE_MARGIN, pd_gains

#: Default rudder limit [rad]: 35 deg hard over (SOLAS II-1 reg. 29; the seed's +-35 deg).
DEFAULT_MAX_ANGLE = math.radians(35.0)
#: Default rudder rate [rad/s]: SOLAS II-1 reg. 29 minimum, 35 deg one side to 30 deg the other in
#: 28 s, i.e. 65/28 = 2.32 deg/s. A small craft's servo is much faster; give ``[rudder] max_rate``.
DEFAULT_MAX_RATE = math.radians(65.0 / 28.0)
#: Default wave model when no wave record is given: our fit to the TTK4115 course record
#: (omega0 = 0.785 rad/s, lambda = 0.090, K_w = 0.00938 rad s^-1/2 in this package's convention).
DEFAULT_WAVES = WaveParams(omega0=0.7848, lam=0.0896, kw=0.00938)


def source_file(role: str, path: str | Path) -> SourceFile:
    """:class:`~pipeline.records.SourceFile` with the SHA-256 of ``path``.

    Parameters
    ----------
    role : str
        What the file is to the configuration (``coefficients``, ``waves``, ``vessel``, ``still``).
    path : str or Path
        The file; read in 1 MiB blocks, recorded as given.
    """
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return SourceFile(role=role, path=str(path), sha256=h.hexdigest())


def build_autopilot_config(K: float, T: float, *, K_stderr: float = math.nan, T_stderr: float = math.nan,
                           waves: WaveParams | None = None, waves_stderr: Mapping[str, float] | None = None,
                           wave_source: str = "", ts: float = DEFAULT_TS,
                           crossover: float | None = None, phase_margin: float = DEFAULT_PHASE_MARGIN,
                           r: float | None = None, r_source: str = "",
                           q: tuple[float, float] = DEFAULT_Q, p0: tuple[float, ...] = DEFAULT_P0,
                           rudder: Mapping[str, float] | None = None, rudder_source: str = "",
                           sources: tuple[SourceFile, ...] = ()) -> AutopilotConfig:
    """Design the PD autopilot and the Kalman filter from an identified Nomoto model.

    Parameters
    ----------
    K, T : float
        Nomoto gain [1/s] and time constant [s].
    K_stderr, T_stderr : float
        Standard errors (carried into the report's robustness table).
    waves : WaveParams, optional
        Wave model; ``DEFAULT_WAVES`` (with a note) when omitted.
    waves_stderr : Mapping, optional
        Standard errors of the wave parameters.
    wave_source : str
        Where ``waves`` came from.
    ts : float
        Sample time [s].
    crossover : float, optional
        PD crossover frequency [rad/s]; default :func:`pipeline.autopilot.pd.default_crossover`.
    phase_margin : float
        PD phase margin [rad].
    r : float, optional
        Sampled compass-noise variance [rad^2]; ``DEFAULT_R`` (with a note) when omitted.
    r_source : str
        Where ``r`` came from.
    q : pair of float
        Continuous process-noise intensities ``(q_w [-], q_b [rad^2/s])``.
    p0 : 5 floats
        Initial covariance diagonal.
    rudder : Mapping, optional
        ``max_angle`` [rad] and ``max_rate`` [rad/s] (the vessel config's ``[rudder]``); the SOLAS
        defaults fill what is missing.
    rudder_source : str
        Where ``rudder`` came from.
    sources : tuple of SourceFile
        Input files.

    Returns
    -------
    AutopilotConfig
        The configuration.

    Raises
    ------
    AutopilotError
        Non-positive K, T, ts, crossover or rudder limits; phase margin out of range.
    """
    notes = []
    gains = pd_gains(K, T, crossover, phase_margin)
    if waves is None:
        waves = DEFAULT_WAVES
        wave_source = wave_source or "default: fit to the TTK4115 course wave record (not this vessel's sea)"
        notes.append("wave model is the default (TTK4115 course record), not fitted to this vessel's sea; "
                     "give --waves WAVES.json from `vesselid waves`")
    for name, v in (("wave omega0", waves.omega0), ("wave lambda", waves.lam), ("wave kw", waves.kw)):
        if not (math.isfinite(v) and v > 0):
            raise AutopilotError(f"{name}: expected a positive number, found {v!r}")
    if r is None:
        r = DEFAULT_R
        notes.append("compass noise R is the default 0.002 deg^2 (TTK4115 course compass); measure it from "
                     "a still record (--still) or give --noise-std-deg")
    elif r_source:
        notes.append(f"compass noise R from {r_source}")
    if tuple(q) == DEFAULT_Q:
        notes.append("process noise Q = diag(30, 1e-6) is the seed's hand-out tuning: w_w of unit intensity "
                     "is the physical value in this package's convention, so 30 makes the filter follow "
                     "the wave band more closely; q_b = 1e-6 rad^2/s is a bias random walk of 0.06 deg/s^0.5")
    if tuple(p0) == DEFAULT_P0:
        notes.append("P0 = diag(1, 0.013, pi^2, 1, 2.5e-3) is the seed's hand-out value, read in radians")
    rud = dict(rudder or {})
    unknown = sorted(set(rud) - {"max_angle", "max_rate", "yaw_moment", "sway_force"})
    if unknown:
        raise AutopilotError(f"rudder limits: unknown key(s) {unknown}; expected max_angle, max_rate")
    max_angle = rud.get("max_angle", DEFAULT_MAX_ANGLE)
    max_rate = rud.get("max_rate", DEFAULT_MAX_RATE)
    if "max_angle" not in rud:
        notes.append("rudder saturation is the default 35 deg (no [rudder] max_angle in the vessel config)")
    if "max_rate" not in rud:
        notes.append("rudder rate is the default 2.32 deg/s, the SOLAS II-1/29 minimum (35 deg to 30 deg "
                     "the other side in 28 s); a small craft's servo is faster: set [rudder] max_rate")
    for name, v in (("rudder max_angle", max_angle), ("rudder max_rate", max_rate)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise AutopilotError(f"{name}: expected a positive number, found {v!r}")
    if max_angle > math.pi / 2:
        raise AutopilotError(f"rudder max_angle: expected radians below pi/2, found {max_angle!r} "
                             f"(degrees given as radians?)")
    km = kalman_model(K, T, waves, ts, r=r, q=q, p0=p0)
    return AutopilotConfig(
        ts=float(ts), K=float(K), T=float(T), K_stderr=float(K_stderr), T_stderr=float(T_stderr),
        waves=waves, waves_stderr=dict(waves_stderr or {}), wave_source=wave_source, pd=gains, kalman=km,
        rudder_max_angle=float(max_angle), rudder_max_rate=float(max_rate),
        rudder_source=rudder_source or ("vessel config" if rud else "default (SOLAS II-1/29)"),
        sources=tuple(sources), notes=tuple(notes),
    )


# --------------------------------------------------------------------------- TOML
def _finite_items(d: Mapping[str, float]) -> dict[str, float]:
    return {k: float(v) for k, v in d.items() if v is not None and math.isfinite(v)}


def config_to_dict(cfg: AutopilotConfig) -> dict[str, Any]:
    """The TOML document of a configuration (plain floats, lists of rows).

    Parameters
    ----------
    cfg : AutopilotConfig
        The configuration; standard errors that are NaN or None are left out.
    """
    km = cfg.kalman
    model = {"K": cfg.K, "T": cfg.T, **_finite_items({"K_stderr": cfg.K_stderr, "T_stderr": cfg.T_stderr})}
    wave = {"omega0": cfg.waves.omega0, "lambda": cfg.waves.lam, "kw": cfg.waves.kw,
            **_finite_items({f"{k}_stderr": v for k, v in cfg.waves_stderr.items()}),
            "source": cfg.wave_source}
    return {
        "ts": cfg.ts,
        "states": list(KALMAN_STATES),
        "units": "SI, angles in radians; psi/delta = K/(s(Ts+1)); PD delta = kpd (1+td s)/(1+tf s) (psi_r - psi)",
        "model": model,
        "wave": wave,
        "pd": {"kpd": cfg.pd.kpd, "td": cfg.pd.td, "tf": cfg.pd.tf, "crossover": cfg.pd.crossover,
               "phase_margin": cfg.pd.phase_margin},
        "rudder": {"max_angle": cfg.rudder_max_angle, "max_rate": cfg.rudder_max_rate, "source": cfg.rudder_source},
        "kalman": {
            "ad": km.ad.tolist(), "bd": km.bd[:, 0].tolist(), "ed": km.ed.tolist(), "c": km.c[0].tolist(),
            "qd": km.qd.tolist(), "r": km.r, "p0": km.p0.tolist(), "x0": km.x0.tolist(), "q": km.q.tolist(),
            "layout": ("x = [xi_w, psi_w, psi, r, b]; x[k+1] = ad x[k] + bd delta[k] + noise of covariance qd; "
                       "y[k] = c x[k] + v[k], var v = r [rad^2]; q = continuous intensity of (w_w, w_b); "
                       "ed maps a held (w_w, w_b) and is not the noise covariance"),
        },
        "provenance": {
            "version": cfg.version, "generator": "vesselid autopilot",
            "sources": [{"role": s.role, "path": s.path, "sha256": s.sha256} for s in cfg.sources],
            "notes": list(cfg.notes),
        },
    }


def write_autopilot_toml(cfg: AutopilotConfig, path: str | Path) -> Path:
    """Write ``AUTOPILOT.toml`` atomically.

    Parameters
    ----------
    cfg : AutopilotConfig
    path : str or Path
        Destination; parent folders are created.

    Returns
    -------
    Path
        The path written.
    """
    try:
        atomic_write_bytes(Path(path), tomli_w.dumps(config_to_dict(cfg)).encode())
    except OSError as exc:
        raise AutopilotError(f"{path}: expected a writable autopilot config path, found: {exc}") from None
    return Path(path)


def read_autopilot_toml(path: str | Path) -> AutopilotConfig:
    """Read an ``AUTOPILOT.toml`` back into an :class:`~pipeline.records.AutopilotConfig`.

    The discrete matrices are taken as written (not recomputed), so a hand-tuned file is honoured.

    Parameters
    ----------
    path : str or Path
        The TOML file.

    Returns
    -------
    AutopilotConfig
        The configuration (continuous matrices a, b, e are NaN: the file does not hold them).

    Raises
    ------
    AutopilotError
        Missing file, bad TOML, missing keys or wrong shapes.
    """
    p = Path(path)
    try:
        doc = tomllib.loads(p.read_text())
    except FileNotFoundError:
        raise AutopilotError(f"{p}: expected an autopilot config, found no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise AutopilotError(f"{p}: expected valid TOML, found: {exc}") from None
    try:
        m, w, pdg, rud, k = doc["model"], doc["wave"], doc["pd"], doc["rudder"], doc["kalman"]
        waves = WaveParams(omega0=float(w["omega0"]), lam=float(w["lambda"]), kw=float(w["kw"]))
        km = KalmanModel(
            ts=float(doc["ts"]), ad=np.array(k["ad"], float), bd=np.array(k["bd"], float).reshape(5, 1),
            ed=np.array(k["ed"], float), c=np.array(k["c"], float).reshape(1, 5), qd=np.array(k["qd"], float),
            r=float(k["r"]), p0=np.array(k["p0"], float), x0=np.array(k["x0"], float),
            a=np.full((5, 5), np.nan), b=np.full((5, 1), np.nan), e=np.full((5, 2), np.nan),
            q=np.array(k["q"], float))
        for name, arr, shape in (("ad", km.ad, (5, 5)), ("ed", km.ed, (5, 2)), ("qd", km.qd, (5, 5)),
                                 ("p0", km.p0, (5, 5)), ("x0", km.x0, (5,)), ("q", km.q, (2, 2))):
            if arr.shape != shape:
                raise AutopilotError(f"{p} [kalman] {name}: expected shape {shape}, found {arr.shape}")
        prov = doc.get("provenance", {})
        cfg = AutopilotConfig(
            ts=float(doc["ts"]), K=float(m["K"]), T=float(m["T"]),
            K_stderr=float(m.get("K_stderr", math.nan)), T_stderr=float(m.get("T_stderr", math.nan)),
            waves=waves,
            waves_stderr={kk: float(w[f"{kk}_stderr"]) for kk in ("omega0", "lambda", "kw") if f"{kk}_stderr" in w},
            wave_source=str(w.get("source", "")),
            pd=PDGains(kpd=float(pdg["kpd"]), td=float(pdg["td"]), tf=float(pdg["tf"]),
                       crossover=float(pdg["crossover"]), phase_margin=float(pdg["phase_margin"])),
            kalman=km, rudder_max_angle=float(rud["max_angle"]), rudder_max_rate=float(rud["max_rate"]),
            rudder_source=str(rud.get("source", "")),
            sources=tuple(SourceFile(role=s["role"], path=s["path"], sha256=s["sha256"])
                          for s in prov.get("sources", [])),
            notes=tuple(prov.get("notes", [])), version=str(prov.get("version", "")))
    except KeyError as exc:
        raise AutopilotError(f"{p}: expected key {exc.args[0]!r} in the autopilot config, not found") from None
    except (TypeError, ValueError) as exc:
        raise AutopilotError(f"{p}: expected numbers of the documented shapes, found: {exc}") from None
    return cfg


# --------------------------------------------------------------------------- inputs
def _coef(doc: Mapping, name: str, path: str) -> tuple[float, float]:
    coefs = doc.get("coefficients")
    if not isinstance(coefs, Mapping):
        raise AutopilotError(f"{path}: expected an object 'coefficients' holding K_nomoto and T_nomoto, "
                             f"found {type(coefs).__name__}")
    entry = coefs.get(name)
    if entry is None:
        raise AutopilotError(f"{path}: expected coefficients.{name}, found only {sorted(coefs)}")
    if isinstance(entry, Mapping):
        value, stderr = entry.get("value"), entry.get("stderr")
    else:
        value, stderr = entry, None
    if value is None or isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        why = entry.get("message", "") if isinstance(entry, Mapping) else ""
        raise AutopilotError(f"{path}: expected a number for coefficients.{name}.value, found {value!r}"
                             + (f" ({why})" if why else " (the fit did not identify it)"))
    se = float(stderr) if isinstance(stderr, (int, float)) and not isinstance(stderr, bool) else math.nan
    return float(value), se


def read_coefficients_json(path: str | Path) -> NomotoCoefficients:
    """Read Nomoto K and T (value, stderr) from ``coefficients.json``; other keys are ignored.

    Parameters
    ----------
    path : str or Path
        The fit stage's ``coefficients.json``.

    Returns
    -------
    NomotoCoefficients

    Raises
    ------
    AutopilotError
        Missing file, bad JSON, K_nomoto or T_nomoto missing or null.
    """
    p = Path(path)
    doc = _read_json_object(p, "coefficients.json")
    k, kse = _coef(doc, "K_nomoto", str(p))
    t, tse = _coef(doc, "T_nomoto", str(p))
    return NomotoCoefficients(K=k, K_stderr=kse, T=t, T_stderr=tse, vessel=str(doc.get("vessel", "")),
                              source=source_file("coefficients", p))


def _read_json_object(p: Path, what: str) -> Mapping:
    """The JSON object in ``p``; an AutopilotError naming ``what`` was expected and what was found."""
    try:
        doc = json.loads(p.read_text())
    except FileNotFoundError:
        raise AutopilotError(f"{p}: expected a {what}, found no such file") from None
    except IsADirectoryError:
        raise AutopilotError(f"{p}: expected a {what} file, found a folder") from None
    except OSError as exc:
        raise AutopilotError(f"{p}: expected a readable {what}, found: {exc.strerror}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise AutopilotError(f"{p}: expected JSON, found: {exc}") from None
    if not isinstance(doc, Mapping):
        raise AutopilotError(f"{p}: expected a JSON object, found {type(doc).__name__}")
    return doc


def read_waves_json(path: str | Path) -> tuple[WaveParams, dict[str, float]]:
    """Read the wave model written by ``vesselid waves`` (or a flat ``{"omega0": x, ...}``).

    Parameters
    ----------
    path : str or Path
        The JSON file.

    Returns
    -------
    params : WaveParams
    stderr : dict
        ``omega0``, ``lambda``, ``kw`` standard errors present in the file.

    Raises
    ------
    AutopilotError
        Missing file, bad JSON, missing or non-positive parameters.
    """
    p = Path(path)
    doc = _read_json_object(p, "wave-fit JSON")
    vals, ses = {}, {}
    for key in ("omega0", "lambda", "kw"):
        entry = doc.get(key)
        v = entry.get("value") if isinstance(entry, Mapping) else entry
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise AutopilotError(f"{p}: expected a positive number for {key}, found {v!r} "
                                 f"(keys present: {sorted(doc)})")
        vals[key] = float(v)
        se = entry.get("stderr") if isinstance(entry, Mapping) else None
        if isinstance(se, (int, float)) and not isinstance(se, bool) and math.isfinite(se):
            ses[key] = float(se)
    return WaveParams(omega0=vals["omega0"], lam=vals["lambda"], kw=vals["kw"]), ses


# --------------------------------------------------------------------------- ArduPilot
#: Documented ranges (AR_AttitudeControl parameter metadata), to flag values a GCS would warn about.
_AP_RANGES = {"ATC_STR_ANG_P": (1.0, 10.0), "ATC_STR_RAT_FF": (0.0, 3.0), "ATC_STR_RAT_P": (0.0, 2.0),
              "ATC_STR_RAT_I": (0.0, 2.0), "ATC_STR_RAT_MAX": (0.0, 1000.0), "ATC_STR_ACC_MAX": (0.0, 1000.0)}


def ardupilot_params(cfg: AutopilotConfig) -> ArduPilotExport:
    """Map the PD design onto ArduPilot Rover's cascaded steering controller (AR_AttitudeControl).

    ArduPilot turns the heading error into a desired turn rate (``ATC_STR_ANG_P`` [1/s]) and a rate
    controller turns the rate error into a steering output in [-1, 1] with feed-forward
    ``ATC_STR_RAT_FF`` and PID ``ATC_STR_RAT_P/I/D`` [per rad/s]. With the steering output
    proportional to rudder angle, full deflection at ``max_angle`` (``delta = max_angle * out``), the
    Nomoto ship gives ``r = K max_angle out / (T s + 1)``, and:

    * ``FF = 1 / (K max_angle)`` makes the steady turn rate equal the demand;
    * ``P = (T / T_f - 1) / (K max_angle)`` puts the closed rate loop's pole at ``1 / T_f``: the rate
      loop becomes ``1 / (1 + T_f s)``, exactly what the PD's zero-pole cancellation leaves;
    * ``ANG_P = K_pd K`` then gives the same loop transfer ``K_pd K / (s (1 + T_f s))``, hence the same
      crossover and phase margin;
    * ``I = P omega_c / 5`` (integral zero a factor five below crossover) removes a constant
      current bias, standing in for the Kalman bias feed-forward ArduPilot does not have;
    * ``ATC_STR_RAT_MAX = K max_angle`` and ``ATC_STR_ACC_MAX = K max_angle / T``, in deg/s and
      deg/s^2, the fastest turn and turn-acceleration the rudder can give.

    ArduPilot has no wave filter; the Kalman part of the config has no counterpart there.

    Parameters
    ----------
    cfg : AutopilotConfig

    Returns
    -------
    ArduPilotExport
        Parameters and notes.
    """
    k, t, dm = cfg.K, cfg.T, cfg.rudder_max_angle
    g = cfg.pd
    kd = k * dm
    p = (t / g.tf - 1.0) / kd
    params = {
        "ATC_STR_ANG_P": g.kpd * k,
        "ATC_STR_RAT_FF": 1.0 / kd,
        "ATC_STR_RAT_P": max(p, 0.0),
        "ATC_STR_RAT_I": max(p, 0.0) * g.crossover / 5.0,
        "ATC_STR_RAT_D": 0.0,
        "ATC_STR_RAT_MAX": math.degrees(kd),
        "ATC_STR_ACC_MAX": math.degrees(kd / t),
    }
    notes = ["assumes steering output proportional to rudder angle with full deflection at "
             f"{math.degrees(dm):.1f} deg, and the Nomoto model at the speed the tune is used at",
             "ArduPilot has no wave filter: with waves the rate loop will chase them as PD alone does"]
    if p < 0:
        notes.append(f"T_f = {g.tf:.3g} s exceeds T = {t:.3g} s: the rate loop needs no P; ATC_STR_RAT_P set to 0")
    for name, (lo, hi) in _AP_RANGES.items():
        v = params[name]
        if not lo <= v <= hi:
            notes.append(f"{name} = {v:.4g} is outside ArduPilot's documented range [{lo:g}, {hi:g}]: "
                         f"the vessel is slower than the small craft those ranges assume")
    return ArduPilotExport(params=params, notes=tuple(notes))


def write_ardupilot_params(cfg: AutopilotConfig, path: str | Path) -> Path:
    """Write the ArduPilot export as a ``NAME,VALUE`` parameter file (Mission Planner / MAVProxy).

    Comment lines start with ``#`` and carry the mapping's notes.

    Parameters
    ----------
    cfg : AutopilotConfig
        The configuration.
    path : str or Path
        Destination (written atomically).

    Returns
    -------
    Path
        The path written.
    """
    exp = ardupilot_params(cfg)
    lines = [f"# vesselid {cfg.version}: ArduPilot Rover steering from K={cfg.K:.6g} 1/s, T={cfg.T:.6g} s, "
             f"kpd={cfg.pd.kpd:.6g}, tf={cfg.pd.tf:.6g} s"]
    lines += [f"# {n}" for n in exp.notes]
    lines += [f"{name},{value:.6g}" for name, value in sorted(exp.params.items())]
    try:
        atomic_write_bytes(Path(path), ("\n".join(lines) + "\n").encode())
    except OSError as exc:
        raise AutopilotError(f"{path}: expected a writable parameter-file path, found: {exc}") from None
    return Path(path)
