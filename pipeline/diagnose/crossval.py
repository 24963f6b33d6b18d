"""K-fold cross-validation over windows: every candidate refitted on training windows, every
window predicted once while held out.

Folds are dealt round-robin in time order, the DOF's own windows first and the bystander windows
after, so each training set holds some of every kind of manoeuvre and the blocks of one long
window land in different folds. The baseline is refitted per fold too, so a candidate is always
compared with a baseline that saw the same data.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from .candidates import Candidate, Fitted, candidate_label
from .gridfit import GridData
from .problem import DofProblem

#: Largest number of folds.
MAX_FOLDS = 5


@dataclass(frozen=True)
class CandidateRun:
    """A candidate's cross-validated predictions and its fit on all windows.

    Attributes
    ----------
    label : str
        ``effect`` or ``effect[input]``.
    candidate : Candidate
        The candidate.
    heldout : Mapping[str, numpy.ndarray]
        Held-out outputs per window (``"y"`` and ``"angle"``), each (W, n).
    fold_params : tuple[Mapping[str, float], ...]
        Parameters fitted in each fold.
    full : Fitted
        Fit on every window (the parameters reported).
    fold_of : numpy.ndarray
        Fold index of each window.
    """

    label: str
    candidate: Candidate
    heldout: Mapping[str, np.ndarray]
    fold_params: tuple[Mapping[str, float], ...]
    full: Fitted
    fold_of: np.ndarray = field(repr=False, default=None)


def signature(problem: DofProblem, i: int) -> frozenset[str]:
    """Inputs (with their sign) that drive window ``i``: ``{"tau_x+", "delta-"}``.

    A held-out window can only be predicted when the training windows saw the same inputs in
    the same direction (a gain astern cannot be learnt from runs ahead).

    Parameters
    ----------
    problem : DofProblem
        The DOF problem.
    i : int
        Window index.
    """
    w = problem.windows[i]
    out = set()
    for c in problem.inputs:
        u = problem.raw[c]
        amp = float(np.max(np.abs(u))) if len(u) else 0.0
        seg = u[w.i0:w.i1]
        if amp <= 0 or len(seg) == 0:
            continue
        if np.mean(seg > 0.05 * amp) > 0.2:
            out.add(c + "+")
        if np.mean(seg < -0.05 * amp) > 0.2:
            out.add(c + "-")
    return frozenset(out)


def excitation(problem: DofProblem, i: int) -> float:
    """How much the inputs move in window ``i``: summed absolute changes over each input's range.

    Parameters
    ----------
    problem : DofProblem
        The DOF problem.
    i : int
        Window index.
    """
    w = problem.windows[i]
    total = 0.0
    for c in problem.inputs:
        u = problem.raw[c]
        span = float(np.ptp(u)) if len(u) else 0.0
        if span <= 0:
            continue
        seg = u[max(w.i0 - 1, 0):w.i1]
        total += float(np.sum(np.abs(np.diff(seg)))) / span
    return total


def assign_folds(problem: DofProblem, k_max: int = MAX_FOLDS) -> np.ndarray:
    """Fold index of each window.

    The DOF's own windows are dealt round-robin, the most excited first (most input change, then
    by input signature and time), so the few windows that pin a gain down (the rudder steps from
    rest of a slow ship) land in different folds and no training set lacks them all; bystander
    windows follow in time order.

    Parameters
    ----------
    problem : DofProblem
        The DOF problem.
    k_max : int
        Largest number of folds (fewer when there are fewer windows).
    """
    n = len(problem.windows)
    sigs = [signature(problem, i) for i in range(n)]
    exc = [round(excitation(problem, i), 3) for i in range(n)]
    own = [i for i, w in enumerate(problem.windows) if problem.dof in w.dofs]
    own.sort(key=lambda i: (-exc[i], sorted(sigs[i]), problem.windows[i].t0))
    other = [i for i in range(n) if i not in own]
    k = int(min(k_max, max(len(own), 2), n))
    folds = np.empty(n, int)
    for j, i in enumerate(own):
        folds[i] = j % k
    for j, i in enumerate(other):
        folds[i] = (j + len(own)) % k
    return folds


def supported(problem: DofProblem, train: np.ndarray, test: np.ndarray) -> np.ndarray:
    """Test windows whose inputs (and signs) all appear in some training window.

    Parameters
    ----------
    problem : DofProblem
        The DOF problem.
    train, test : numpy.ndarray
        Window indices.
    """
    seen = set().union(*(signature(problem, i) for i in train)) if len(train) else set()
    return np.array([signature(problem, i) <= seen for i in test], bool)


def cross_validate(problem: DofProblem, data: GridData, candidates: list[Candidate],
                   tick: Callable[[], None] | None = None) -> list[CandidateRun]:
    """Cross-validate the baseline (``candidates[0]``) and every candidate.

    Parameters
    ----------
    problem : DofProblem
        The DOF problem.
    data : GridData
        Its analysis-grid data.
    candidates : list[Candidate]
        Baseline first.
    tick : callable, optional
        Called once per fold and once for the final fits (progress).

    Returns
    -------
    list[CandidateRun]
        In the order of ``candidates``.
    """
    folds = assign_folds(problem)
    k = int(folds.max()) + 1
    shape = data.y.shape
    failed: set[int] = set()
    keys = ("y", "angle") if data.angle is not None else ("y",)
    held = [{key: np.full(shape, np.nan) for key in keys} for _ in candidates]
    fparams: list[list[Mapping[str, float]]] = [[] for _ in candidates]
    for f in range(k):
        train = np.flatnonzero(folds != f)
        test = np.flatnonzero(folds == f)
        if len(train) == 0:
            continue
        # Windows driven by an input the training set never saw are not scored for anyone.
        test = test[supported(problem, train, test)]
        base = candidates[0].fit(train)
        for j, c in enumerate(candidates):
            if j in failed:
                continue
            try:
                fitted = base if j == 0 else c.fit(train, start=base)
                if len(test):
                    pred = c.simulate(fitted, test)
                    for key in keys:
                        held[j][key][test] = pred[key]
            except (ValueError, ArithmeticError, np.linalg.LinAlgError):
                # A candidate that cannot be fitted on these data (degenerate windows, no
                # excitation) is dropped; it must not cost the user the other candidates.
                failed.add(j)
                continue
            fparams[j].append(dict(fitted.params))
        if tick:
            tick()
    everything = np.arange(len(problem.windows))
    base_full = candidates[0].fit(everything)
    runs = []
    for j, c in enumerate(candidates):
        if j in failed:
            continue
        try:
            full = base_full if j == 0 else c.fit(everything, start=base_full)
        except (ValueError, ArithmeticError, np.linalg.LinAlgError):
            continue
        runs.append(CandidateRun(candidate_label(c), c, held[j], tuple(fparams[j]), full, folds))
    if tick:
        tick()
    return runs


def jackknife_stderr(full: Mapping[str, float], folds: tuple[Mapping[str, float], ...]) -> dict[str, float]:
    """Delete-a-group jackknife standard errors [unit of each parameter].

    ``se^2 = (K - 1) / K sum_f (theta_f - mean theta)^2`` over the K fold fits (each leaves one
    group of windows out); NaN with fewer than two folds.

    Parameters
    ----------
    full : Mapping[str, float]
        Parameters fitted on every window (their names are used).
    folds : tuple[Mapping[str, float], ...]
        Parameters fitted in each fold.
    """
    out = {}
    k = len(folds)
    for name in full:
        vals = np.array([f.get(name, np.nan) for f in folds], float)
        vals = vals[np.isfinite(vals)]
        if len(vals) < 2:
            out[name] = float("nan")
            continue
        out[name] = float(np.sqrt((len(vals) - 1) / len(vals) * np.sum((vals - vals.mean()) ** 2)))
    return out
