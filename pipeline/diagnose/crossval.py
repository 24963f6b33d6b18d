"""K-fold cross-validation over windows: every candidate refitted on training windows, every
window predicted once while held out.

Folds are dealt round-robin in time order, the DOF's own windows first and the bystander windows
after, so each training set holds some of every kind of manoeuvre and the blocks of one long
window land in different folds. The baseline is refitted per fold too, so a candidate is always
compared with a baseline that saw the same data.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np

from ..parallel import ordered_map
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
    return _signature(problem, i, _input_amplitudes(problem))


def signatures(problem: DofProblem) -> list[frozenset[str]]:
    """:func:`signature` of every window, in window order (each input's amplitude found once).

    Parameters
    ----------
    problem : DofProblem
        The DOF problem.
    """
    amps = _input_amplitudes(problem)
    return [_signature(problem, i, amps) for i in range(len(problem.windows))]


def _input_amplitudes(problem: DofProblem) -> dict[str, float]:
    """Largest absolute value of each input over the trial [SI] (0 for an empty signal)."""
    return {c: float(np.max(np.abs(problem.raw[c]))) if len(problem.raw[c]) else 0.0 for c in problem.inputs}


def _signature(problem: DofProblem, i: int, amps: Mapping[str, float]) -> frozenset[str]:
    """:func:`signature` with the inputs' amplitudes given."""
    w = problem.windows[i]
    out = set()
    for c in problem.inputs:
        amp = amps[c]
        seg = problem.raw[c][w.i0:w.i1]
        if amp <= 0 or len(seg) == 0:
            continue
        if np.mean(seg > 0.05 * amp) > 0.2:
            out.add(c + "+")
        if np.mean(seg < -0.05 * amp) > 0.2:
            out.add(c + "-")
    return frozenset(out)


#: Input changes up to this many time constants before a window's start still count toward its
#: excitation (the response they start is still under way in the window).
EXCITATION_BEFORE_T = 3.0


def excitation(problem: DofProblem, i: int) -> float:
    """How much transient response window ``i`` holds: the inputs' absolute changes over each
    input's range, each weighted by how much of the response it starts lies in the window.

    A change at time ``t_c`` counts ``exp(-(t_0 - t_c) / T)`` when it came before the window's start
    ``t_0`` (the response still under way) and ``min(1, (t_1 - t_c) / T)`` when it comes within
    the window ending at ``t_1`` (a change in its last sample starts nothing the window shows). A
    step's first block, cut from a window that begins just after the step, holds the whole rise
    although its input is constant; a block that ends on the next step holds none of it. Counted
    by the change alone, the two swapped places, and the two blocks holding a single sway step's
    transients (the rise and the coast-down's start) were dealt into one fold, whose training set
    then saw neither and could not pin the quadratic damping (randomised seed 18, r000).

    Parameters
    ----------
    problem : DofProblem
        The DOF problem.
    i : int
        Window index.
    """
    w = problem.windows[i]
    n_t = max(problem.t_guess * problem.fs, 1.0)  # T in trial samples
    a = max(w.i0 - int(np.ceil(EXCITATION_BEFORE_T * n_t)), 1)
    total = 0.0
    for c in problem.inputs:
        u = problem.raw[c]
        span = float(np.ptp(u)) if len(u) else 0.0
        if span <= 0 or a >= w.i1:
            continue
        # Change at sample j: u[j] - u[j - 1], acting from sample j on.
        j = np.arange(a, w.i1)
        du = np.abs(u[j] - u[j - 1]) / span
        weight = np.where(j < w.i0, np.exp(-(w.i0 - j) / n_t), np.minimum((w.i1 - j) / n_t, 1.0))
        total += float(np.sum(du * weight))
    return total


def assign_folds(problem: DofProblem, k_max: int = MAX_FOLDS,
                 sigs: Sequence[frozenset[str]] | None = None) -> np.ndarray:
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
    sigs : sequence of frozenset, optional
        :func:`signatures` of the problem, when already known.
    """
    n = len(problem.windows)
    sigs = signatures(problem) if sigs is None else sigs
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


def supported(problem: DofProblem, train: np.ndarray, test: np.ndarray,
              sigs: Sequence[frozenset[str]] | None = None) -> np.ndarray:
    """Test windows whose inputs (and signs) all appear in some training window.

    Parameters
    ----------
    problem : DofProblem
        The DOF problem.
    train, test : numpy.ndarray
        Window indices.
    sigs : sequence of frozenset, optional
        :func:`signatures` of the problem, when already known.
    """
    sigs = signatures(problem) if sigs is None else sigs
    seen = set().union(*(sigs[i] for i in train)) if len(train) else set()
    return np.array([sigs[i] <= seen for i in test], bool)


def cross_validate(problem: DofProblem, data: GridData, candidates: list[Candidate],
                   tick: Callable[[], None] | None = None, jobs: int | None = 1) -> list[CandidateRun]:
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
    jobs : int or None
        Worker processes for the folds (:func:`pipeline.parallel.ordered_map`; 1: in this process,
        None: ``VESSELID_JOBS`` or the cores). The results do not depend on it.

    Returns
    -------
    list[CandidateRun]
        In the order of ``candidates``.
    """
    return cross_validate_all([problem], [data], [candidates], tick=tick, jobs=jobs)[0]


def cross_validate_all(problems: Sequence[DofProblem], datas: Sequence[GridData],
                       candidates: Sequence[list[Candidate]], tick: Callable[[], None] | None = None,
                       jobs: int | None = None) -> list[list[CandidateRun]]:
    """:func:`cross_validate` of several DOFs, every fold of every DOF (and each DOF's fit on all its
    windows) one unit of :func:`pipeline.parallel.ordered_map`.

    A fold's unit fits the baseline on the training windows, then every candidate from it, and
    predicts the held-out windows; the last unit of a DOF fits them all on every window. The units
    do not depend on each other, so they run side by side; a candidate that fails in any unit is
    dropped, as in one loop over the folds. Units are handed out largest DOF first (samples times
    candidates), so that the last to finish is a small one.

    Parameters
    ----------
    problems, datas, candidates : sequence
        Per DOF: its problem, its analysis-grid data and its candidates (baseline first).
    tick : callable, optional
        Called once per unit as the results are gathered (progress).
    jobs : int or None
        Worker processes (1: in this process; None: ``VESSELID_JOBS`` or the cores).

    Returns
    -------
    list of list[CandidateRun]
        Per DOF, in the order of its ``candidates``.
    """
    sigs = [signatures(p) for p in problems]
    folds = [assign_folds(p, sigs=s) for p, s in zip(problems, sigs)]
    units = []
    for i, f in enumerate(folds):
        k = int(f.max()) + 1
        units += [(i, fold) for fold in range(k)] + [(i, k)]
    size = [float(np.sum(d.mask)) * len(c) for d, c in zip(datas, candidates)]
    order = sorted(range(len(units)), key=lambda u: (-size[units[u][0]], units[u][0], units[u][1]))
    context = (list(problems), list(datas), [list(c) for c in candidates], folds, sigs)
    done = ordered_map(_cross_validate_unit, [units[u] for u in order], context=context, jobs=jobs)
    result = dict(zip((units[u] for u in order), done))
    out = []
    for i, (p, d, cs, f) in enumerate(zip(problems, datas, candidates, folds)):
        k = int(f.max()) + 1
        keys = ("y", "angle") if d.angle is not None else ("y",)
        held = [{key: np.full(d.y.shape, np.nan) for key in keys} for _ in cs]
        fparams: list[list[Mapping[str, float]]] = [[] for _ in cs]
        failed: set[int] = set()
        for fold in range(k):
            part = result[(i, fold)]
            if tick:
                tick()
            if part is None:
                continue
            test, per = part
            for j, got in enumerate(per):
                if j in failed:
                    continue
                if got is None:
                    failed.add(j)
                    continue
                params, pred = got
                if pred is not None:
                    for key in keys:
                        held[j][key][test] = pred[key]
                fparams[j].append(params)
        runs = []
        for j, (c, full) in enumerate(zip(cs, result[(i, k)])):
            if j in failed or full is None:
                continue
            runs.append(CandidateRun(candidate_label(c), c, held[j], tuple(fparams[j]), full, f))
        if tick:
            tick()
        out.append(runs)
    return out


def _cross_validate_unit(context: tuple, unit: tuple[int, int]):
    """One fold of one DOF: ``(test windows, per candidate (params, held-out prediction) or None when
    it failed)``, None when the fold has no training windows; the fold index past the last: the fits
    on every window (per candidate a :class:`Fitted`, or None when it failed)."""
    problems, datas, candidates, folds, sigs = context
    i, fold = unit
    problem, cs, f = problems[i], candidates[i], folds[i]
    if fold > int(f.max()):
        everything = np.arange(len(problem.windows))
        base_full = cs[0].fit(everything)
        fulls = []
        for j, c in enumerate(cs):
            try:
                fulls.append(base_full if j == 0 else c.fit(everything, start=base_full))
            except (ValueError, ArithmeticError, np.linalg.LinAlgError):
                fulls.append(None)
        return fulls
    train = np.flatnonzero(f != fold)
    test = np.flatnonzero(f == fold)
    if len(train) == 0:
        return None
    # Windows driven by an input the training set never saw are not scored for anyone.
    test = test[supported(problem, train, test, sigs[i])]
    base = cs[0].fit(train)
    per = []
    for j, c in enumerate(cs):
        try:
            fitted = base if j == 0 else c.fit(train, start=base)
            pred = c.simulate(fitted, test) if len(test) else None
        except (ValueError, ArithmeticError, np.linalg.LinAlgError):
            # A candidate that cannot be fitted on these data (degenerate windows, no
            # excitation) is dropped; it must not cost the user the other candidates.
            per.append(None)
            continue
        keys = ("y", "angle") if datas[i].angle is not None else ("y",)
        per.append((dict(fitted.params), None if pred is None else {key: pred[key] for key in keys}))
    return test, per


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
