"""Independent work units on the cores this process may use: how many workers, and an ordered map.

The pipeline's long stages hold units that do not depend on each other (the whole-record Nomoto fit
of each yaw segment's window, the report's figures). :func:`ordered_map` runs them in worker
processes (``concurrent.futures.ProcessPoolExecutor``) and returns their results in input order, so
that what follows is the same as a serial loop: each unit is computed by the same code on the same
inputs, only in another process.

How many workers: ``VESSELID_JOBS`` when set (``1`` forces every unit into this process), otherwise
the cores this process may run on (``os.sched_getaffinity``), at most :data:`MAX_JOBS`. Workers are
forked (Linux): the large inputs every unit reads (a trial) are handed to them through the fork,
not pickled per unit. Where fork is not available, inside a worker, in a daemonic process (which
may not have children: a Dask worker of ``vesselid batch``) or from a thread other than the main
one, the units run here, one after the other.
"""

from __future__ import annotations

import gc
import multiprocessing
import os
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Callable, Iterable, TypeVar

from .errors import ConfigError

T = TypeVar("T")
R = TypeVar("R")

#: Environment variable that sets the number of worker processes (``1``: no workers).
JOBS_ENV = "VESSELID_JOBS"
#: Most worker processes by default (each forked worker adds the pages it writes to the memory).
MAX_JOBS = 2

#: When a list (set by a benchmark, ``benchmarks/stage_timer.py``), every :func:`ordered_map` call appends
#: ``{"jobs": workers, "unit_cpu_s": [CPU time of each unit, s]}``: what an idle machine's wall time of
#: the call would be follows from it. None: nothing is measured.
TRACE: list | None = None

#: Freeze the collector's view of the parent's objects while workers run (see :func:`ordered_map`).
FREEZE_GC = True

_CONTEXT: Any = None
_IN_WORKER = False


def available_cores() -> int:
    """Cores this process may run on (``os.sched_getaffinity``; ``os.cpu_count`` where it is missing)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def worker_count(jobs: int | None = None) -> int:
    """Number of worker processes to use.

    Parameters
    ----------
    jobs : int, optional
        Asked for explicitly; default ``VESSELID_JOBS``, else the available cores up to
        :data:`MAX_JOBS`.

    Returns
    -------
    int
        At least 1 (1: run in this process).

    Raises
    ------
    ConfigError
        ``jobs`` or ``VESSELID_JOBS`` is not a positive whole number.
    """
    if jobs is None:
        text = os.environ.get(JOBS_ENV, "").strip()
        if not text:
            return min(available_cores(), MAX_JOBS)
        try:
            jobs = int(text)
        except ValueError:
            raise ConfigError(f"{JOBS_ENV}: expected a positive whole number of worker processes, "
                             f"found {text!r}") from None
    if int(jobs) != jobs or jobs < 1:
        raise ConfigError(f"jobs: expected a positive whole number of worker processes, found {jobs!r}")
    return int(jobs)


def _can_fork() -> bool:
    # Not from a thread other than the main one (a Dask worker thread of `vesselid batch --workers 1`):
    # a fork there copies locks other threads may hold. Not in a daemonic process (Dask's worker
    # processes): it may not have children, and the batch spreads its trials over the cores already.
    return ("fork" in multiprocessing.get_all_start_methods() and not _IN_WORKER
            and not multiprocessing.current_process().daemon
            and threading.current_thread() is threading.main_thread())


def _init(context: Any) -> None:
    global _CONTEXT, _IN_WORKER
    _CONTEXT, _IN_WORKER = context, True


def _call(fn: Callable[[Any, T], R], item: T):
    if TRACE is None:
        return fn(_CONTEXT, item)
    c0 = time.process_time()
    out = fn(_CONTEXT, item)
    return out, time.process_time() - c0


def _serial(fn: Callable[[Any, T], R], items: list, context: Any) -> list[R]:
    if TRACE is None:
        return [fn(context, x) for x in items]
    out, cpu = [], []
    for x in items:
        c0 = time.process_time()
        out.append(fn(context, x))
        cpu.append(time.process_time() - c0)
    TRACE.append({"jobs": 1, "unit_cpu_s": cpu})
    return out


def ordered_map(fn: Callable[[Any, T], R], items: Iterable[T], context: Any = None,
                jobs: int | None = None) -> list[R]:
    """``[fn(context, item) for item in items]``, the items spread over worker processes.

    Parameters
    ----------
    fn : callable
        ``fn(context, item)``; a module-level function (it is sent to the workers by name). It
        should catch the errors it expects and return them as results: an exception raised in a
        worker is raised here as it would be in a serial loop, but only after the units already
        started have finished.
    items : iterable
        The units; each is pickled to its worker, so keep them small.
    context : object, optional
        What every unit reads (a trial): inherited by the forked workers, never pickled.
    jobs : int, optional
        Number of workers (:func:`worker_count`).

    Returns
    -------
    list
        The results in the order of ``items``.
    """
    items = list(items)
    n = min(worker_count(jobs), len(items))
    if n <= 1 or not _can_fork():
        return _serial(fn, items, context)
    # The objects alive now are moved out of the collector's reach (gc.freeze) while the workers run: a
    # forked worker's collections would otherwise walk, and so copy, every page of the inherited heap.
    freeze = FREEZE_GC
    if freeze:
        gc.freeze()
    try:
        with ProcessPoolExecutor(max_workers=n, mp_context=multiprocessing.get_context("fork"),
                                 initializer=_init, initargs=(context,)) as pool:
            out = list(pool.map(_call, [fn] * len(items), items))
    except BrokenProcessPool:
        # A worker died (killed for memory, say): the same units in this process, one after the other.
        return _serial(fn, items, context)
    finally:
        if freeze:
            gc.unfreeze()
    if TRACE is None:
        return out
    TRACE.append({"jobs": n, "unit_cpu_s": [c for _, c in out]})
    return [r for r, _ in out]


def makespan(unit_cpu_s: list[float], jobs: int) -> float:
    """Wall time [s] of units of the given CPU times on ``jobs`` idle cores, handed out in order to
    whichever worker is free first (as :func:`ordered_map`'s pool does).

    Parameters
    ----------
    unit_cpu_s : list of float
        CPU time of each unit, in order [s].
    jobs : int
        Workers.
    """
    free = [0.0] * max(1, int(jobs))
    for c in unit_cpu_s:
        k = free.index(min(free))
        free[k] += c
    return max(free)
