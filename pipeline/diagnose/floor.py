"""The held-out gap a correct model would leave: sensor noise plus what noise does to the fit.

A gap of 1 noise unit is what a model with exactly known parameters leaves. A held-out window is
predicted with parameters fitted on other windows, and those carry the noise of their training
data. In the response channel that costs little; in a heading, which integrates the rate over a
whole window, a gain 1.6 % off (the jackknife error of a clean Nomoto ship, T = 22 s, at high noise)
is a drift of many compass-noise units by the end of a one-minute window. Measured on clean
simulated Nomoto ships logged at 10 Hz: a heading gap of 6.7-6.8 noise units at every noise level
(0.3 to 3 times nominal), so a clean trial was reported with an "unexplained" heading.

:func:`heldout_floor` measures that floor on the trial itself, by a parametric bootstrap (Efron and
Tibshirani 1993, ch. 6): the baseline fitted on every window is taken as the truth, white noise at
each channel's measured floor is added to its outputs, and the same cross-validation is run on
those synthetic data, ``REPLICATES`` times. The RMS of the replicates' held-out gaps is the floor of
each channel. It is used where the question is "is anything left beyond what a correct model would
leave": the unexplained test (:func:`pipeline.diagnose.selection.unexplained`). The candidates'
significance tests compare two held-out fits on the same data and need no floor.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Mapping, Sequence

import numpy as np

from ..parallel import ordered_map
from .candidates import Candidate
from .crossval import cross_validate
from .gridfit import GridData, LinearSpec, initial_states
from .problem import DofProblem

#: Synthetic replicates per DOF.
REPLICATES = 3
#: Seed of the replicates' noise (the floor of a trial is reproducible).
SEED = 20261125


def _start(y: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """First in-window value of each row (the synthetic measured start where the model's own
    initial states are not given)."""
    first = np.argmax(mask, axis=1)
    return np.where(mask.any(axis=1), y[np.arange(len(y)), first], 0.0)


def with_start(full: Mapping[str, np.ndarray] | None, run) -> dict | None:
    """The baseline's outputs on every window with its initial state of each window (``"x0"``), the
    start the synthetic replicates' measured start values are drawn around (:func:`heldout_floor`).

    The first block mean of the outputs is not the start: it is the response averaged over the
    first analysis step, and where a window opens with a transient (an input switched at its start)
    at a slow log rate, one step is a large part of the time constant. Randomised seed 42 r013
    (AAUSHIP's yaw at 2.1 Hz, low noise): the first block means missed the model's initial states by
    up to 62 noise units, the replicates' fits were pulled to a time constant of 4.36 s instead of the
    4.20 s they were made with, and the floor came out at 8.8 (r) and 19.8 (psi) noise units where
    replicates started at the model's initial states give 1.1 and 1.5-1.8.

    Parameters
    ----------
    full : Mapping[str, numpy.ndarray] or None
        Outputs of the baseline fitted on every window.
    run : pipeline.diagnose.crossval.CandidateRun
        The baseline's run (a linear baseline: its fit's state is ``(spec, theta)``).

    Returns
    -------
    dict or None
        ``full`` with ``"x0"`` added (unchanged where the baseline's initial states cannot be had).
    """
    if full is None:
        return None
    state = getattr(getattr(run, "full", None), "state", None)
    data = getattr(getattr(run, "candidate", None), "data", None)
    if not (isinstance(state, tuple) and len(state) == 2 and isinstance(state[0], LinearSpec) and data is not None):
        return dict(full)
    try:
        x0 = initial_states(data, state[0], float(run.full.params["T"]), np.asarray(state[1], float))
    except (KeyError, ValueError, ArithmeticError, np.linalg.LinAlgError):
        return dict(full)
    return {**full, "x0": x0} if x0.shape == (data.y.shape[0],) and np.all(np.isfinite(x0)) else dict(full)


def heldout_floor(p: DofProblem, d: GridData, full: Mapping[str, np.ndarray],
                  replicates: int = REPLICATES) -> dict[str, float]:
    """Held-out gap per output channel [noise units, >= 1] that a correct model leaves.

    Parameters
    ----------
    p : DofProblem
        The DOF problem.
    d : GridData
        Its data (noise floors, windows, inputs).
    full : Mapping[str, numpy.ndarray]
        Outputs of the baseline fitted on every window (``"y"``, ``"angle"``), and where known its
        initial state of each window (``"x0"``, :func:`with_start`), the synthetic starts' centre.
    replicates : int
        Synthetic trials.

    Returns
    -------
    dict[str, float]
        Channel -> floor; empty when the noise floor is unknown or a replicate cannot be fitted.
    """
    return heldout_floors([(p, d, full)], replicates)[0]


def heldout_floors(dofs: Sequence[tuple[DofProblem, GridData, Mapping[str, np.ndarray] | None]],
                   replicates: int = REPLICATES) -> list[dict[str, float]]:
    """:func:`heldout_floor` of several DOFs, every replicate of every DOF in one :func:`ordered_map`.

    One call for all the DOFs' replicates keeps both workers busy where one call per DOF (3 units
    on 2 workers) runs its third unit with the other worker idle. Each DOF's noise is drawn with its own
    generator seeded :data:`SEED`, so its floor is the same as :func:`heldout_floor` of it alone.

    Parameters
    ----------
    dofs : Sequence[tuple]
        ``(problem, data, full)`` per DOF; ``full`` (the baseline's outputs on every window, as in
        :func:`heldout_floor`) None where there is none.
    replicates : int
        Synthetic trials per DOF.

    Returns
    -------
    list of dict[str, float]
        Per DOF, in order: channel -> floor [noise units]; empty where ``full`` is None, the noise
        floor is unknown or a replicate cannot be fitted.
    """
    contexts, units = [], []
    for k, (p, d, full) in enumerate(dofs):
        contexts.append((p, d, {"y": p.channel, "angle": p.angle}))
        if full is not None:
            units += [(k, kw) for kw in _synthetic(d, full, replicates)]
    # The largest DOFs' replicates first (cost taken as the size of the DOF's window grid), so that
    # the small ones fill in at the end rather than one large unit running alone; the results are
    # put back in unit order (each unit's result does not depend on when it runs).
    order = sorted(range(len(units)), key=lambda i: -int(np.size(dofs[units[i][0]][1].y)))
    gaps_sorted = ordered_map(_replicate_gaps, [units[i] for i in order], context=contexts)
    gaps: list = [None] * len(units)
    for i, g in zip(order, gaps_sorted):
        gaps[i] = g
    per_dof: list[list] = [[] for _ in dofs]
    for (k, _), g in zip(units, gaps):
        per_dof[k].append(g)
    return [_floor(g) for g in per_dof]


def _synthetic(d: GridData, full: Mapping[str, np.ndarray], replicates: int) -> list[dict]:
    """The replicates' synthetic outputs (``y``, ``y0``, ``angle``) of one DOF; none when its noise
    floor is unknown."""
    if not (np.isfinite(d.sigma_y) and d.sigma_y > 0):
        return []
    rng = np.random.default_rng(SEED)
    # The replicates' noise is drawn here, in turn (the same draws whatever runs them); each
    # replicate's cross-validation is independent (worker processes when the cores allow).
    synthetic = []
    for _ in range(replicates):
        y = np.where(d.mask, np.nan_to_num(full["y"]) + rng.normal(0.0, d.sigma_y, d.y.shape), np.nan)
        # The measured start of each window is a line's end through a few samples: about twice a
        # block mean's noise variance (see grid_data), about the model's own initial state (``x0``,
        # :func:`with_start`; else the first block mean).
        start = full["x0"] if "x0" in full else _start(np.nan_to_num(full["y"]), d.mask)
        y0 = start + rng.normal(0.0, np.sqrt(2.0) * d.sigma_y, len(d.y0))
        kw = {"y": y, "y0": y0}
        if d.angle is not None and "angle" in full and np.isfinite(d.sigma_angle) and d.sigma_angle > 0:
            am = d.angle_mask
            kw["angle"] = np.where(am, np.nan_to_num(full["angle"]) + rng.normal(0.0, d.sigma_angle, d.y.shape),
                                   np.nan)
        elif d.angle is not None:
            kw["angle"] = None
        synthetic.append(kw)
    return synthetic


def _floor(gaps: list) -> dict[str, float]:
    """Channel -> floor from one DOF's replicate gaps; empty when there are none or one failed."""
    if not gaps or any(g is None for g in gaps):
        return {}
    sums: dict[str, list[float]] = {}
    for g in gaps:
        for channel, gap in g:
            sums.setdefault(channel, []).append(float(gap) ** 2)
    return {ch: float(max(np.sqrt(np.mean(v)), 1.0)) for ch, v in sums.items() if np.all(np.isfinite(v))}


def _replicate_gaps(contexts: list, unit: tuple) -> list[tuple[str, float]] | None:
    """Held-out gap per channel of one synthetic replicate (``contexts``: problem, data, channel
    names per DOF; ``unit``: the DOF's index and the replicate's outputs); None when it cannot be
    fitted."""
    from . import significance as sig

    k, kw = unit
    p, d, names = contexts[k]
    ds = replace(d, **kw)
    try:
        runs = cross_validate(p, ds, [Candidate(p, ds)])
    except (ValueError, ArithmeticError, np.linalg.LinAlgError):
        return None
    if not runs:
        return None
    sc = sig.score(ds, runs[0].heldout, runs[0].heldout, 1, {c: v for c, v in names.items() if v})
    return [(c.channel, c.gap_before) for c in sc.channels]


__all__ = ["heldout_floor", "heldout_floors", "with_start", "REPLICATES"]
