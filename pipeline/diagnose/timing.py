"""When a logged command switched: the log's own timing of the inputs, a nuisance of the baseline.

A command written by periodic sampling (a controller or autopilot that runs faster than its log)
is recorded at the first log sample after it changed: on average half a log sample late, at most
one. Held from the sample that records it, every switch then starts late, which a clean trial's
baseline cannot fit and a candidate then "explains" (at 2 Hz the transients after each switch were
taken for waves). Recorded by an event logger at the instant it was issued, the command is on
time. The log does not say which, so the diagnosis estimates it: once per DOF, on all its windows,
the advance ``s`` in ``[0, 1]`` trial sample of every input against the outputs that fits the
baseline best (on a grid of tenths of a sample, at the baseline's time constant), and analyses the
inputs advanced by it. The advance is shared by the baseline and every candidate, so it favours
none of them; a true actuator delay or a lagging sensor puts the optimum at 0 and is then tested as
before. A delay of less than one log sample cannot be told from this timing, and none is claimed.

When a constant force (a nuisance, ``"__one"``) removes at least ``BIAS_DOMINANT`` of the
baseline's misfit, the advance is chosen with it beside the inputs: a steady moment or rudder bias
is the commonest gap, and left out it dominates the misfit, so the sum of squares hardly depends
on the advance and its minimum lands anywhere (a Nomoto ship with a 1.4 deg rudder bias, logged on
time at 10 Hz, was advanced by 0.9 samples; once the bias was selected, the undone advance came
back as a second effect, a 0.1 s actuator delay). Otherwise the baseline alone chooses: a free
constant it does not need blunts the choice (a clean twin-thruster boat's surge at 2.2 Hz moved
from 0.3 to 0.2 samples, and the transients left by that tenth of a sample were taken for waves).

The advance is applied only where the data pin it: the best advance must fit better than the worst
by more than ``PINNED`` (the 95 % point of chi-square with one degree of freedom) residual variances
``sigma^2 = SSE_min / n_eff`` (``n_eff`` the residual's samples corrected for their lag-1
autocorrelation, per channel, as the significance test counts them; at least the number of
windows). A clean trial's timing shapes the fit by hundreds of ``sigma^2``; where an unmodelled
effect dominates the misfit the sum of squares hardly depends on the advance, its minimum lands
anywhere, at the end of the range as often as not, and an arbitrary full sample was left for the
candidates to take back: a true surge rate limit at 7.1 Hz, its ramp lasting 3.8 s, changed the
sum of squares by 0.03 % over the range, the advance went to one sample, and a delay of 0.13-0.2 s
"behind the rate limit" was selected at 62 % shrink (randomised seed 22, r036); a thrust asymmetry
at 2.3 Hz left 0.9 samples, which a rate limit on top of it took back at 26 % (r011). There the
inputs are taken as logged.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..fit.heldout_test import lag1
from .gridfit import LinearSpec, fit_linear, grid_data, predict_linear, solve_linear
from .actuators import actuator_key
from .problem import DofProblem

#: Advances searched [trial samples].
ADVANCES = np.linspace(0.0, 1.0, 11)
#: Share of the baseline's sum of squares a constant force must remove to join the timing model.
BIAS_DOMINANT = 0.5
#: Least improvement of the best advance over the worst, in residual variances, for the data to
#: pin the advance (the 95 % point of chi-square with one degree of freedom).
PINNED = 3.84


def advance_input(u: np.ndarray, samples: float) -> np.ndarray:
    """``u(t + s)`` on the trial grid for ``s = samples / fs``; fractions blend neighbours.

    After the end of the record the last value is held.

    Parameters
    ----------
    u : numpy.ndarray
        Held input on the trial grid [SI].
    samples : float
        Advance [trial samples], not negative.
    """
    u = np.asarray(u, float)
    n = len(u)
    i = int(np.floor(samples))
    f = samples - i

    def shift(k: int) -> np.ndarray:
        if k <= 0:
            return u
        if k >= n:
            return np.full(n, u[-1])
        return np.concatenate([u[k:], np.full(k, u[-1])])

    return shift(i) if f < 1e-9 else (1 - f) * shift(i) + f * shift(i + 1)


def n_effective(d, theta: np.ndarray, spec: LinearSpec, t_const: float) -> float:
    """Independent samples in a fit's residual: per channel ``n (1 - rho) / (1 + rho)`` with ``rho``
    its lag-1 autocorrelation (:func:`pipeline.fit.heldout_test.lag1`), summed; at least the number
    of windows (each window's residual counts once however smooth it is).

    Parameters
    ----------
    d : pipeline.diagnose.gridfit.GridData
        The windows fitted.
    theta : numpy.ndarray
        Linear parameters of ``spec``.
    spec : LinearSpec
        Regressors.
    t_const : float
        Time constant [s].
    """
    out = predict_linear(d, spec, t_const, theta)
    total = 0.0
    for meas, key in ((d.y, "y"), (d.angle, "angle")):
        if meas is None or key not in out:
            continue
        r = np.where(d.mask & np.isfinite(meas), meas - out[key], np.nan)
        n = int(np.isfinite(r).sum())
        rho = float(np.clip(lag1(r), 0.0, 0.999))
        total += n * (1 - rho) / (1 + rho)
    return max(total, float(d.y.shape[0]))


def pinned_advance(sse: np.ndarray, n_eff: float, advances: np.ndarray = ADVANCES) -> float:
    """The best-fitting advance where the data pin it, else 0 (module docstring) [trial samples].

    Parameters
    ----------
    sse : numpy.ndarray
        Weighted sum of squares at each of ``advances``.
    n_eff : float
        Independent samples of the residual at the best advance.
    advances : numpy.ndarray
        Advances searched [trial samples].
    """
    lo, hi = float(np.min(sse)), float(np.max(sse))
    best = float(advances[int(np.argmin(sse))])
    if lo > 0 and np.isfinite(hi) and n_eff > 0 and (hi - lo) / (lo / n_eff) < PINNED:
        return 0.0
    return best


def input_timing(p: DofProblem) -> tuple[DofProblem, float]:
    """The problem with its inputs advanced by the best-fitting log timing (module docstring).

    Parameters
    ----------
    p : DofProblem
        A DOF problem with inputs.

    Returns
    -------
    (DofProblem, float)
        The problem (unchanged when the best advance is 0 or it has no input) and the advance [s].
    """
    if not p.inputs:
        return p, 0.0
    plain = LinearSpec(tuple(p.inputs))
    biased = LinearSpec(tuple(p.inputs) + ("__one",))

    def data(inputs=None):
        d = grid_data(p, inputs=inputs)
        return d.with_forcing(__one=np.where(d.mask, 1.0, 0.0))

    d0 = data()
    t_plain, _, sse_plain = fit_linear(d0, plain, p.t_guess)
    t_biased, _, sse_biased = fit_linear(d0, biased, p.t_guess)
    spec, t_const = (biased, t_biased) if sse_biased < (1.0 - BIAS_DOMINANT) * sse_plain else (plain, t_plain)
    sse, top = [], None
    for s in ADVANCES:
        d = data({c: advance_input(p.raw[c], float(s)) for c in p.inputs})
        theta, v = solve_linear(d, spec, t_const)
        sse.append(v)
        if top is None or v < top[0]:
            top = (v, d, theta)
    best = pinned_advance(np.array(sse), n_effective(top[1], top[2], spec, t_const))
    if best == 0.0:
        return p, 0.0
    raw = dict(p.raw)
    for c in tuple(p.inputs) + tuple(actuator_key(a.name) for a in p.actuators):
        raw[c] = advance_input(p.raw[c], best)
    return replace(p, raw=raw), best / p.fs


__all__ = ["advance_input", "input_timing", "pinned_advance", "n_effective", "ADVANCES", "BIAS_DOMINANT", "PINNED"]
