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
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .gridfit import LinearSpec, fit_linear, grid_data, solve_linear
from .actuators import actuator_key
from .problem import DofProblem

#: Advances searched [trial samples].
ADVANCES = np.linspace(0.0, 1.0, 11)
#: Share of the baseline's sum of squares a constant force must remove to join the timing model.
BIAS_DOMINANT = 0.5


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
    sse = []
    for s in ADVANCES:
        d = data({c: advance_input(p.raw[c], float(s)) for c in p.inputs})
        sse.append(solve_linear(d, spec, t_const)[1])
    best = float(ADVANCES[int(np.argmin(sse))])
    if best == 0.0:
        return p, 0.0
    raw = dict(p.raw)
    for c in tuple(p.inputs) + tuple(actuator_key(a.name) for a in p.actuators):
        raw[c] = advance_input(p.raw[c], best)
    return replace(p, raw=raw), best / p.fs


__all__ = ["advance_input", "input_timing", "ADVANCES", "BIAS_DOMINANT"]
