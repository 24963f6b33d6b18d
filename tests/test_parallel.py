"""Tests of pipeline.parallel: worker count, ordered results equal to a serial loop, forced serial runs."""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest

from pipeline.errors import ConfigError

from pipeline import parallel


def _square_and_pid(context, x):
    return context["scale"] * x * x, os.getpid()


def _nested(context, x):
    # A unit that maps again: inside a worker it runs in that worker, one after the other.
    return parallel.ordered_map(_square_and_pid, [x, x + 1], context=context)


def _fails_on_three(context, x):
    if x == 3:
        raise ValueError("three")
    return x


def _solve(context, seed):
    rng = np.random.default_rng(seed)
    a = context + rng.normal(size=context.shape)
    return np.linalg.solve(a @ a.T + np.eye(len(a)), rng.normal(size=len(a)))


def test_results_in_input_order_and_equal_to_serial(monkeypatch):
    monkeypatch.delenv(parallel.JOBS_ENV, raising=False)
    # The context holds a lock (not picklable): it reaches the workers through the fork only.
    ctx = {"scale": 3, "lock": threading.Lock()}
    out = parallel.ordered_map(_square_and_pid, range(7), context=ctx, jobs=2)
    assert [v for v, _ in out] == [3 * x * x for x in range(7)]
    if "fork" in __import__("multiprocessing").get_all_start_methods():
        assert {pid for _, pid in out} - {os.getpid()}, "no unit ran in a worker process"


def test_floating_point_results_are_bit_identical_to_serial():
    base = np.random.default_rng(1).normal(size=(40, 40))
    serial = parallel.ordered_map(_solve, range(6), context=base, jobs=1)
    par = parallel.ordered_map(_solve, range(6), context=base, jobs=2)
    for a, b in zip(serial, par):
        assert np.array_equal(a, b)


def test_environment_forces_one_process(monkeypatch):
    monkeypatch.setenv(parallel.JOBS_ENV, "1")
    assert parallel.worker_count() == 1
    out = parallel.ordered_map(_square_and_pid, range(4), context={"scale": 1})
    assert {pid for _, pid in out} == {os.getpid()}


def test_default_follows_available_cores(monkeypatch):
    monkeypatch.delenv(parallel.JOBS_ENV, raising=False)
    assert parallel.worker_count() == min(parallel.available_cores(), parallel.MAX_JOBS)
    monkeypatch.setattr(parallel.os, "sched_getaffinity", lambda pid: {0}, raising=False)
    assert parallel.worker_count() == 1


@pytest.mark.parametrize("text", ["0", "-2", "two", "1.5"])
def test_bad_job_count_is_a_clear_error(monkeypatch, text):
    monkeypatch.setenv(parallel.JOBS_ENV, text)
    with pytest.raises(ConfigError, match="VESSELID_JOBS|jobs"):
        parallel.worker_count()


def test_nested_maps_run_inside_the_worker(monkeypatch):
    monkeypatch.delenv(parallel.JOBS_ENV, raising=False)
    out = parallel.ordered_map(_nested, [1, 5], context={"scale": 1}, jobs=2)
    assert [[v for v, _ in inner] for inner in out] == [[1, 4], [25, 36]]
    for inner in out:
        assert len({pid for _, pid in inner}) == 1


def test_a_unit_error_is_raised_as_in_a_serial_loop():
    with pytest.raises(ValueError, match="three"):
        parallel.ordered_map(_fails_on_three, range(5), jobs=2)


def test_units_stay_in_this_process_from_another_thread(monkeypatch):
    monkeypatch.delenv(parallel.JOBS_ENV, raising=False)
    out = []
    th = threading.Thread(target=lambda: out.extend(parallel.ordered_map(_square_and_pid, range(3),
                                                                         context={"scale": 1}, jobs=2)))
    th.start()
    th.join()
    assert [v for v, _ in out] == [0, 1, 4] and {pid for _, pid in out} == {os.getpid()}


def test_makespan_hands_units_out_in_order():
    assert parallel.makespan([4.0, 1.0, 1.0, 1.0, 1.0], 2) == 4.0
    assert parallel.makespan([1.0, 1.0, 4.0], 2) == 5.0
    assert parallel.makespan([2.0, 3.0], 1) == 5.0
