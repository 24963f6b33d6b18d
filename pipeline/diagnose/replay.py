"""Where the identified model disagrees with the boat.

The baseline's held-out residuals (every window predicted by a model that did not see it), in
units of each channel's sensor noise, are split by channel, by segment kind, by frequency band
(below, in and above the wave band) and by operating regime (speed and input-amplitude bins).
Each place gets its share of the trial's total *excess* squared error (what is left after the
sensor noise its samples would show anyway), so the places can be ranked: a place that holds
only noise has no share. The baseline is also replayed over the whole
trial from its first sample (re-initialised only after dropouts), the plainest sim-to-real picture.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..records import Trial
from . import waves as wave_model
from .gridfit import GridData, grid_data
from .problem import DofProblem, Window, block_average
from ..records import Place, Spectrum, Trace

#: Bins of the operating-regime split.
N_BINS = 3


def _bins(x: np.ndarray, e2: np.ndarray, unit: str, lo: float, hi: float) -> list[tuple[str, float, int]]:
    """(name, summed e^2, count) per equal-width bin of ``x`` between ``lo`` and ``hi``."""
    out = []
    if not hi > lo:
        return out
    edges = np.linspace(lo, hi, N_BINS + 1)
    which = np.clip(np.digitize(x, edges[1:-1]), 0, N_BINS - 1)
    for b in range(N_BINS):
        sel = which == b
        if sel.any():
            out.append((f"{edges[b]:.3g}-{edges[b + 1]:.3g} {unit}".strip(), float(np.sum(e2[sel])), int(sel.sum())))
    return out


def band_split(resid: np.ndarray, dt: float, band: tuple[float, float]) -> dict[str, float]:
    """Sum of squares of residual rows below, in and above ``band`` [rad/s] (Parseval per window).

    The mean of a window counts as "below": a constant offset is the lowest frequency there is.

    Parameters
    ----------
    resid : numpy.ndarray
        Residual rows (W, n), NaN outside windows.
    dt : float
        Step [s].
    band : tuple[float, float]
        Wave band [rad/s].
    """
    out = {"below wave band": 0.0, "in wave band": 0.0, "above wave band": 0.0}
    for row in resid:
        x = row[np.isfinite(row)]
        if len(x) < 2:
            continue
        spec = np.fft.rfft(x)
        om = 2 * np.pi * np.fft.rfftfreq(len(x), dt)
        p = np.abs(spec) ** 2
        # One-sided: double every bin but DC (and Nyquist for even lengths), then Parseval.
        p[1:] *= 2
        if len(x) % 2 == 0:
            p[-1] /= 2
        p /= len(x)
        out["below wave band"] += float(p[om < band[0]].sum())
        out["in wave band"] += float(p[(om >= band[0]) & (om <= band[1])].sum())
        out["above wave band"] += float(p[om > band[1]].sum())
    return out


def pooled_psd(resid: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """PSD [1/(rad/s)] of residual rows pooled over windows (Welch, segments up to 1024 samples,
    windows of at least 16 samples).

    Parameters
    ----------
    resid : numpy.ndarray
        Residual rows (W, n), NaN outside windows.
    dt : float
        Step [s].
    """
    lengths = [int(np.isfinite(r).sum()) for r in resid]
    usable = [n for n in lengths if n >= 16]
    if not usable:
        return np.zeros(0), np.zeros(0)
    nper = int(min(2 ** int(np.log2(max(usable))), 1024))
    acc, cnt, freqs = None, 0, None
    for r in resid:
        x = r[np.isfinite(r)]
        if len(x) < nper:
            continue
        import scipy.signal

        f, g = scipy.signal.welch(x, fs=1.0 / dt, nperseg=nper, detrend=False)
        acc = g if acc is None else acc + g
        cnt += 1
        freqs = f
    if acc is None:
        return np.zeros(0), np.zeros(0)
    return 2 * np.pi * freqs, acc / cnt / (2 * np.pi)


def where(problem: DofProblem, data: GridData, resid: dict[str, np.ndarray], trial: Trial,
          band: tuple[float, float], names: dict[str, str]) -> tuple[list[tuple[str, str, float, int]], list[Spectrum]]:
    """Split a DOF's held-out residuals into places.

    Parameters
    ----------
    problem : DofProblem
        The DOF problem.
    data : GridData
        Its data.
    resid : dict
        Held-out residual rows per output key (``"y"``, ``"angle"``) in noise units.
    trial : Trial
        The trial (speed and inputs for the regime split).
    band : tuple[float, float]
        Wave band [rad/s].
    names : dict
        Output key -> channel name.

    Returns
    -------
    places, spectra
        Places as ``(category, name, summed squared error, samples)`` (noise units) and the
        residual spectra.
    """
    out: list[tuple[str, str, float, int]] = []
    spectra = []
    for key, r in resid.items():
        ok = np.isfinite(r)
        out.append(("channel", names[key], float(np.sum(r[ok] ** 2)), int(ok.sum())))
        for name, ss in band_split(r, data.dt, band).items():
            out.append(("frequency band", f"{names[key]} {name}", ss, int(ok.sum())))
        om, psd = pooled_psd(r, data.dt)
        spectra.append(Spectrum(problem.dof, names[key], om, psd, band))
    # Kinds and regimes pool the DOF's channels.
    e2 = sum(np.where(np.isfinite(r), r**2, 0.0) for r in resid.values())
    valid = np.zeros_like(e2, bool)
    for r in resid.values():
        valid |= np.isfinite(r)
    kinds: dict[str, list[float]] = {}
    for k, w in enumerate(problem.windows):
        label = w.label.split(" (")[0]
        acc = kinds.setdefault(label, [0.0, 0])
        acc[0] += float(e2[k][valid[k]].sum())
        acc[1] += int(valid[k].sum())
    out += [("segment kind", name, ss, n) for name, (ss, n) in kinds.items()]
    speed_ch = "u" if trial.has("u") else ("sog" if trial.has("sog") else None)
    if speed_ch:
        sp = np.abs(block_average(trial.data[speed_ch].to_numpy(float), problem.windows, problem.m, data.y.shape[1]))
        ok = valid & np.isfinite(sp)
        if ok.any():
            out += [("speed", n, ss, c) for n, ss, c in _bins(sp[ok], e2[ok], "m/s", 0.0, float(np.max(sp[ok])))]
    if problem.inputs:
        amp = np.zeros_like(e2)
        for c in problem.inputs:
            u = problem.raw[c]
            scale = max(float(np.max(np.abs(u))), 1e-12)
            amp = np.maximum(amp, np.abs(block_average(u, problem.windows, problem.m, data.y.shape[1])) / scale)
        ok = valid & np.isfinite(amp)
        if ok.any():
            out += [("input amplitude", f"{n} of max {'/'.join(problem.inputs)}", ss, c)
                    for n, ss, c in _bins(amp[ok], e2[ok], "", 0.0, 1.0)]
    return out, spectra


def rank_places(raw: list[tuple[str, str, str, float, int]]) -> tuple[Place, ...]:
    """Places with their share of the trial's excess, largest share first.

    ``raw`` holds ``(dof, category, name, summed squared error, samples)`` in noise units; a
    place's excess is ``sum e^2 - n`` (the noise's own contribution removed), floored at zero.
    Each category (channel, segment kind, frequency band, speed, input amplitude) splits the same
    excess its own way, so shares are taken within the category and sum to one there.

    Parameters
    ----------
    raw : list of tuples
        Places as described above.
    """
    totals: dict[str, float] = {}
    for _, cat, _, ss, n in raw:
        totals[cat] = totals.get(cat, 0.0) + max(ss - n, 0.0)
    places = [Place(cat, dof, name, max(ss - n, 0.0) / totals[cat] if totals[cat] > 0 else 0.0,
                    float(np.sqrt(ss / n)) if n else np.nan, n)
              for dof, cat, name, ss, n in raw]
    return tuple(sorted(places, key=lambda p: -p.share))


def whole_trial_windows(problem: DofProblem, trial: Trial) -> tuple[Window, ...]:
    """The whole trial as windows, split only at dropouts of the response.

    Parameters
    ----------
    problem : DofProblem
        The DOF problem (its response and analysis step).
    trial : Trial
        The trial.
    """
    y = problem.raw[problem.channel]
    ok = np.isfinite(y)
    t = trial.t
    out = []
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        return ()
    breaks = np.flatnonzero(np.diff(idx) > max(int(0.5 * trial.fs), 1))
    starts = np.concatenate([[idx[0]], idx[breaks + 1]])
    ends = np.concatenate([idx[breaks] + 1, [idx[-1] + 1]])
    for a, b in zip(starts, ends):
        if (b - a) // problem.m >= 4:
            out.append(Window(int(a), int(b), float(t[a]), float(t[b - 1]), ("replay",), (problem.dof,), "replay"))
    return tuple(out)


def replay(problem: DofProblem, trial: Trial, simulate) -> tuple[GridData, dict[str, np.ndarray], DofProblem]:
    """Replay a model over the whole trial.

    Parameters
    ----------
    problem : DofProblem
        The DOF problem.
    trial : Trial
        The trial.
    simulate : callable
        ``simulate(data) -> outputs`` for a :class:`GridData` of the whole-trial windows.

    Returns
    -------
    data, outputs, problem
        The whole-trial data, the model outputs and the whole-trial problem.
    """
    wins = whole_trial_windows(problem, trial)
    if not wins:
        return None, {}, problem
    p = replace(problem, windows=wins)
    d = grid_data(p)
    return d, simulate(d), p


def traces(problem: DofProblem, data: GridData, base: dict[str, np.ndarray], effect: dict[str, np.ndarray] | None,
           label: str | None, kind: str, names: dict[str, str]) -> list[Trace]:
    """Overlay series of each output channel: windows joined in time with a NaN between them.

    Parameters
    ----------
    problem : DofProblem
        The DOF problem.
    data : GridData
        Its data (the measurements).
    base : dict
        Baseline outputs (``"y"``, ``"angle"``).
    effect : dict or None
        Outputs of the model with the effect.
    label : str or None
        The effect's label.
    kind : str
        ``heldout`` or ``replay``.
    names : dict
        Output key -> channel name.
    """
    out = []
    for key in base:
        meas = data.y if key == "y" else data.angle
        if meas is None:
            continue
        ts, ms, bs, es = [], [], [], []
        for k, w in enumerate(problem.windows):
            ok = data.mask[k]
            n = int(ok.sum())
            if n == 0:
                continue
            tk = w.t0 + (np.arange(data.y.shape[1]) + 0.5) * data.dt
            ts += [tk[ok], [np.nan]]
            ms += [meas[k][ok], [np.nan]]
            bs += [base[key][k][ok], [np.nan]]
            es += [(effect[key][k][ok] if effect is not None else np.full(n, np.nan)), [np.nan]]
        if not ts:
            continue
        order = np.concatenate(ts)
        out.append(Trace(problem.dof, names[key], kind, label, order, np.concatenate(ms), np.concatenate(bs),
                         np.concatenate(es)))
    return out


def default_band(problem: DofProblem) -> tuple[float, float]:
    """Wave band used for the frequency split when no wave peak was fitted [rad/s].

    Parameters
    ----------
    problem : DofProblem
        The DOF problem (its time constant and step).
    """
    return wave_model.search_band(problem.t_guess, problem.dt)
