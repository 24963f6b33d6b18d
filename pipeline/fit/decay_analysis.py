"""Roll and pitch free-decay analysis as naval architects do it: extinction curves.

From each free decay the successive extreme angles ``phi_n`` (peaks and troughs about the
equilibrium) give, per half cycle, the decrement ``dphi = |phi_n| - |phi_n+1|`` and the mean
amplitude ``phi_m = (|phi_n| + |phi_n+1|) / 2``. The extinction curve ``dphi = a phi_m + b phi_m^2``
is fitted by least squares (ITTC 7.5-02-07-04.5, "Numerical estimation of roll damping"; Himeno 1981).
For ``I phi'' + B1 phi' + B2 |phi'| phi' + C phi = 0``, the energy lost per half cycle gives
(equivalent linearisation, Himeno 1981)::

    a = pi B1 / (2 I wn)          ->  B1 = 2 I wn a / pi
    b = 4 B2 / (3 I)              ->  B2 = 3 I b / 4
    B_eq(phi_a) = B1 + (8 / (3 pi)) wn phi_a B2

``wn`` comes from the extrema times (half period = slope of ``t_n`` against ``n``), corrected for
damping; ``I`` is the config's ``M_ii`` when given, else ``C / wn^2``. The effective inertia
``I_fit = C / wn^2`` from the restoring and the fitted frequency is reported beside the config's
(sway-roll coupling lowers it on some hulls). Decays are analysed per release direction
(roll: port or starboard down; pitch: bow up or down) and pooled, with a Wald test that the
directions share ``(a, b)``.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy import signal, stats

from ..records import DOF_ANGLE, DecayAnalysis, Extinction, Segment, Trial
from ..vessel import Vessel
from .data import noise_sigma

#: Amplitude at which the equivalent linear damping is stated, as a fraction of the largest
#: analysed amplitude (a stated amplitude can also be passed).
DEFAULT_AMPLITUDE_FRACTION = 0.5
#: Extrema must stand this many noise standard deviations above the equilibrium.
MIN_PEAK_SNR = 5.0
#: p-value below which the two directions are called inconsistent.
CONSISTENCY_ALPHA = 0.01


def extrema(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Alternating extreme values about the equilibrium, refined by a parabola through 3 samples.

    Parameters
    ----------
    t : numpy.ndarray
        Time [s], uniform.
    y : numpy.ndarray
        Angle [rad].

    Returns
    -------
    tuple
        Extremum times [s], signed values about the equilibrium [rad], and the equilibrium [rad]
        (mean of the last quarter of the record).
    """
    ok = np.isfinite(y)
    t, y = t[ok], y[ok]
    if y.size < 10:
        return np.zeros(0), np.zeros(0), math.nan
    offset = float(np.mean(y[-max(y.size // 4, 3):]))
    z = y - offset
    sigma = noise_sigma(y)
    h = MIN_PEAK_SNR * (sigma if math.isfinite(sigma) and sigma > 0 else 1e-12)
    idx = np.sort(np.concatenate([signal.find_peaks(z, height=h, prominence=h)[0],
                                  signal.find_peaks(-z, height=h, prominence=h)[0]]))
    times, vals = [], []
    for i in idx:
        if 0 < i < z.size - 1:
            y0, y1, y2 = z[i - 1], z[i], z[i + 1]
            den = y0 - 2 * y1 + y2
            dx = 0.5 * (y0 - y2) / den if den != 0 else 0.0
            dx = float(np.clip(dx, -0.5, 0.5))
            times.append(t[i] + dx * (t[1] - t[0]))
            vals.append(y1 - 0.25 * (y0 - y2) * dx)
    times, vals = np.array(times), np.array(vals)
    # Keep strictly alternating signs (a noise bump between two peaks of one sign is dropped).
    keep = [0] if vals.size else []
    for k in range(1, vals.size):
        if np.sign(vals[k]) != np.sign(vals[keep[-1]]):
            keep.append(k)
        elif abs(vals[k]) > abs(vals[keep[-1]]):
            keep[-1] = k
    return times[keep], vals[keep], offset


def _half_period(times: Sequence[np.ndarray]) -> tuple[float, float]:
    """Half period [s] and its standard error from ``t_n = t_0 + n T/2`` pooled over decays."""
    rows, ys = [], []
    for j, tt in enumerate(times):
        for n, tn in enumerate(tt):
            r = np.zeros(len(times) + 1)
            r[j] = 1.0
            r[-1] = n
            rows.append(r)
            ys.append(tn)
    X, y = np.array(rows), np.array(ys)
    if y.size < len(times) + 2:
        return math.nan, math.nan
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    res = y - X @ coef
    s2 = float(res @ res) / max(y.size - X.shape[1], 1)
    cov = s2 * np.linalg.pinv(X.T @ X)
    return float(coef[-1]), float(math.sqrt(max(cov[-1, -1], 0.0)))


def extinction_curve(label: str, decays: Sequence[tuple[np.ndarray, np.ndarray]], inertia: float,
                     restoring: float, amplitude: float | None = None) -> Extinction:
    """Fit the extinction curve of one set of decays.

    Parameters
    ----------
    label : str
        Name of the set.
    decays : Sequence[tuple[numpy.ndarray, numpy.ndarray]]
        Per decay the extrema times [s] and signed values [rad] from :func:`extrema`.
    inertia : float
        ``M_ii`` [kg m^2]; NaN: ``C / wn^2`` is used.
    restoring : float
        ``C`` [N m/rad]; NaN when unknown.
    amplitude : float, optional
        Amplitude for the equivalent linear damping [rad]; default half the largest mean amplitude.

    Returns
    -------
    Extinction
    """
    pm, dp = [], []
    for _, v in decays:
        a = np.abs(v)
        pm += list(0.5 * (a[:-1] + a[1:]))
        dp += list(a[:-1] - a[1:])
    pm, dp = np.array(pm), np.array(dp)
    nan = math.nan
    T_half, T_half_se = _half_period([t for t, _ in decays])
    wd = math.pi / T_half if T_half > 0 else nan
    wd_se = math.pi * T_half_se / T_half**2 if T_half > 0 else nan
    a_lin = a_lin_se = nan
    a = b = nan
    cov = np.full((2, 2), nan)
    if pm.size >= 2:
        x = pm[:, None]
        c, *_ = np.linalg.lstsq(x, dp, rcond=None)
        r = dp - x @ c
        a_lin = float(c[0])
        a_lin_se = float(math.sqrt(float(r @ r) / max(pm.size - 1, 1) / float(pm @ pm)))
    if pm.size >= 3:
        X = np.column_stack([pm, pm**2])
        c, *_ = np.linalg.lstsq(X, dp, rcond=None)
        r = dp - X @ c
        cov = float(r @ r) / max(pm.size - 2, 1) * np.linalg.pinv(X.T @ X)
        a, b = float(c[0]), float(c[1])
    # Linear decrement a = pi zeta per half cycle: wn = wd / sqrt(1 - zeta^2).
    zeta = (a if math.isfinite(a) else a_lin) / math.pi
    wn = wd / math.sqrt(max(1 - zeta**2, 1e-6)) if math.isfinite(zeta) else wd
    wn_se = wd_se / math.sqrt(max(1 - zeta**2, 1e-6)) if math.isfinite(zeta) else wd_se
    i_fit = restoring / wn**2 if math.isfinite(restoring) and wn > 0 else nan
    i_fit_se = 2 * restoring * wn_se / wn**3 if math.isfinite(i_fit) else nan
    inertia_used = inertia if math.isfinite(inertia) else i_fit
    amp = float(amplitude) if amplitude is not None else (DEFAULT_AMPLITUDE_FRACTION * float(pm.max()) if pm.size else nan)
    # B1 = 2 I wn a / pi and B2 = 3 I b / 4 (the wn error is small next to a's and is left out).
    B1, B2 = 2 * inertia_used * wn * a / math.pi, 0.75 * inertia_used * b
    J = np.array([[2 * inertia_used * wn / math.pi, 0.0], [0.0, 0.75 * inertia_used]])
    cov_B = J @ cov @ J.T
    g = np.array([1.0, 8.0 / (3.0 * math.pi) * wn * amp])
    B_eq = B1 + g[1] * B2
    return Extinction(label, pm, dp, a, b, cov, a_lin, a_lin_se, wn, wn_se, B1,
                      float(math.sqrt(max(cov_B[0, 0], 0))), B2, float(math.sqrt(max(cov_B[1, 1], 0))), B_eq,
                      float(math.sqrt(max(g @ cov_B @ g, 0))), amp, i_fit, i_fit_se, len(decays))


def _direction(dof: str, first: float) -> str:
    # Fossen: positive roll is starboard down, positive pitch is bow up.
    if dof == "roll":
        return "starboard down" if first > 0 else "port down"
    return "bow up" if first > 0 else "bow down"


def analyse_decays(trial: Trial, segments: Sequence[Segment], vessel: Vessel | None, dof: str,
                   amplitude: float | None = None) -> DecayAnalysis | None:
    """Extinction analysis of every free decay of ``dof`` in the trial, per direction and pooled.

    Parameters
    ----------
    trial : Trial
        The trial (needs the angle channel ``phi`` or ``theta``).
    segments : Sequence[Segment]
        Its segments; ``free_decay`` segments of ``dof`` are used.
    vessel : Vessel, optional
        ``M_ii`` and restoring.
    dof : str
        ``roll`` or ``pitch``.
    amplitude : float, optional
        Amplitude for the equivalent linear damping [rad].

    Returns
    -------
    DecayAnalysis or None
        None when no decay of ``dof`` has at least three extrema above the noise.
    """
    channel = DOF_ANGLE[dof]
    if not trial.has(channel):
        return None
    groups: dict[str, list] = {}
    for seg in segments:
        if seg.kind != "free_decay" or seg.dof != dof:
            continue
        rows = trial.window(seg.t_start, seg.t_end)
        times, vals, _ = extrema(rows["t"].to_numpy(float), rows[channel].to_numpy(float))
        if vals.size >= 3:
            groups.setdefault(_direction(dof, vals[0]), []).append((times, vals))
    if not groups:
        return None
    inertia = vessel.effective_mass(dof) if vessel is not None and vessel.has_rigid_body else math.nan
    restoring = float(vessel.restoring.get(dof, math.nan)) if vessel is not None else math.nan
    everything = [d for g in groups.values() for d in g]
    combined = extinction_curve("combined", everything, inertia, restoring, amplitude)
    amp = combined.amplitude
    curves = {k: extinction_curve(k, v, inertia, restoring, amp) for k, v in groups.items()}
    curves["combined"] = combined
    p, msg = math.nan, []
    dirs = [c for k, c in curves.items() if k != "combined"]
    if len(dirs) == 2 and all(np.all(np.isfinite(c.cov_ab)) for c in dirs):
        d = np.array([dirs[0].a - dirs[1].a, dirs[0].b - dirs[1].b])
        chi2 = float(d @ np.linalg.pinv(dirs[0].cov_ab + dirs[1].cov_ab) @ d)
        p = float(stats.chi2.sf(chi2, 2))
        verdict = "disagree" if p < CONSISTENCY_ALPHA else "agree"
        msg.append(f"{dirs[0].label} and {dirs[1].label} extinction curves {verdict} (Wald chi2 = {chi2:.3g} on 2 dof, "
                   f"p = {p:.2g}); B_eq at {math.degrees(amp):.3g} deg: {dirs[0].B_eq:.4g} +- {dirs[0].B_eq_se:.2g} vs "
                   f"{dirs[1].B_eq:.4g} +- {dirs[1].B_eq_se:.2g}")
    elif len(dirs) == 1:
        msg.append(f"decays released one way only ({dirs[0].label}): no direction check")
    if math.isfinite(combined.inertia_fit) and math.isfinite(inertia):
        ratio = combined.inertia_fit / inertia
        msg.append(f"effective inertia C/wn^2 = {combined.inertia_fit:.4g} +- {combined.inertia_fit_se:.2g} kg m^2 "
                   f"against the config's {inertia:.4g} ({ratio:.3g} x)")
    return DecayAnalysis(dof, curves, inertia, restoring, p, "; ".join(msg))
