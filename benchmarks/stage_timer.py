"""Per-stage wall time, CPU time and peak memory of one ``vesselid run``, without changing what it runs.

:func:`install` wraps the flow's stage functions (and, inside them, the grey-box stage, the
autopilot's closed-loop check, the report writer and the diagnosis figures) with timers; at exit
the costs are written as JSON (and after each stage, so a run stopped half-way still says
where its time went). ``benchmarks/scaling.py`` runs ``vesselid run`` through
:func:`main` so that the 2-hour run, measured as a whole by ``os.wait4``, also says where its time
went. The peak resident memory of each top-level stage is its own (Linux: ``/proc/self/clear_refs``
resets it at the start of the stage). CPU times include the worker processes a stage started and
waited for (``RUSAGE_CHILDREN``), and, for a stage with units run side by side by
:func:`pipeline.parallel.ordered_map`, the CPU time of those units and the wall time the stage would
take on 2 idle cores (its other CPU time plus each call's in-order makespan on 2 workers;
``idle_2core_wall_s``: an estimate, for a machine that other work shares); a function called inside a worker (``fit_nomoto`` in the whole-record
fits when they run in workers) is timed in the worker and not reported (its stage is).
"""

from __future__ import annotations

import atexit
import functools
import json
import os
import resource
import sys
import time
from pathlib import Path

#: (module, attribute, label, top level): the functions timed.
TARGETS = (
    ("pipeline.flow", "load_trial", "ingest + align", True),
    ("pipeline.flow", "segment_trial", "segment", True),
    ("pipeline.flow", "fit_segments", "fit", True),
    ("pipeline.fit.trial", "fit_nomoto_trial", "fit: whole-record Nomoto (fit_nomoto_trial)", False),
    ("pipeline.fit.nomoto_segment", "fit_nomoto", "fit: whole-record Nomoto solves (fit_nomoto, summed)", False),
    ("pipeline.fit.structure", "select_structures", "fit: damping-structure selection (select_structures)", False),
    ("pipeline.fit.structure", "select_structure", "fit: damping-structure selection (select_structure, summed)",
     False),
    ("pipeline.fit.extend", "extend_fits", "fit: grey-box (extend_fits)", False),
    ("pipeline.flow", "design_autopilot", "autopilot", True),
    ("pipeline.autopilot.design", "closed_loop_check", "autopilot: closed-loop check", False),
    ("pipeline.flow", "diagnose_trial", "diagnose", True),
    ("pipeline.flow", "write_outputs", "report (write_outputs)", True),
    ("pipeline.report", "write_report", "report: write_report (fit figures, tables, HTML)", False),
    ("pipeline.diagnose.figures", "write_figures", "report: diagnosis figures", False),
)


def _hwm() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return float(line.split()[1]) * 1024
    return float("nan")


def _cpu() -> float:
    """CPU time [s] of this process and of the child processes it has waited for (the worker
    processes of :mod:`pipeline.parallel` are waited for when their pool closes, inside the stage)."""
    own = time.process_time()
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own + kids.ru_utime + kids.ru_stime


def _reset() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


#: The diagnosis's cross-validation job and where its workers write their CPU times (set by :func:`install`).
_UNITS: dict = {}


def _timed_cross_validate_job(args):
    """``pipeline.diagnose.verdict._cross_validate_job`` that appends its CPU time [s] to a side file when
    it runs in a worker (module level: the pool sends it to the worker by name)."""
    c0 = time.process_time()
    try:
        return _UNITS["job"](args)
    finally:
        if os.getpid() != _UNITS["pid"]:
            with _UNITS["file"].open("a") as fh:
                fh.write(f"{time.process_time() - c0}\n")


def install(out_json: str | Path) -> dict:
    """Wrap the stage functions; write ``{label: {wall_s, cpu_s, peak_gb}}`` to ``out_json`` at exit."""
    import importlib

    costs: dict = {}
    pid = os.getpid()

    try:
        from pipeline import parallel
    except ImportError:  # a checkout before pipeline.parallel (a --compare-root baseline)
        parallel = None
    else:
        parallel.TRACE = []

    def record(label: str, t0: float, c0: float, own: bool, n0: int) -> None:
        cpu = _cpu() - c0
        entry = {"wall_s": round(time.perf_counter() - t0, 2), "cpu_s": round(cpu, 2)}
        regions = parallel.TRACE[n0:] if parallel is not None else []
        if regions and "summed" not in label:
            # The units that ran side by side, and what 2 idle cores would take for them (in-order hand-out).
            units = sum(sum(r["unit_cpu_s"]) for r in regions)
            entry["parallel_units_cpu_s"] = round(units, 2)
            entry["idle_2core_wall_s"] = round(cpu - units + sum(parallel.makespan(r["unit_cpu_s"], 2)
                                                                  for r in regions), 2)
            # Each call's units in hand-out order [s CPU] (which unit sets a call's makespan).
            entry["unit_cpu_s"] = [[round(c, 2) for c in r["unit_cpu_s"]] for r in regions]
        if own:
            entry["peak_gb"] = round(_hwm() / 1e9, 3)
        if "summed" in label and label in costs:
            # Called many times inside a stage: the total over the calls.
            entry = {k: round(costs[label][k] + entry[k], 2) for k in ("wall_s", "cpu_s")}
        costs[label] = entry
        # Written after every stage too: a run stopped half-way still says where it got.
        Path(out_json).write_text(json.dumps(costs, indent=1))

    # A checkout before pipeline.diagnose.crossval.cross_validate_all (a --compare-root baseline) cross-validates
    # its DOFs in its own worker processes (pipeline.diagnose.verdict._cross_validate_job): each job's CPU time
    # is appended to a side file by the worker and read back as one region of units. Since then the folds are
    # units of pipeline.parallel.ordered_map, traced like the others (and verdict has no such job).
    units_file = Path(str(out_json) + ".units")
    units_file.write_text("")
    try:
        verdict = importlib.import_module("pipeline.diagnose.verdict")
        job = verdict._cross_validate_job
    except (ImportError, AttributeError):
        verdict = None
    if verdict is not None:
        _UNITS.update(file=units_file, pid=pid, job=job)
        verdict._cross_validate_job = _timed_cross_validate_job

    def diagnosis_units() -> None:
        text = units_file.read_text().split()
        if text and parallel is not None:
            # Submitted largest first: in decreasing order.
            parallel.TRACE.append({"jobs": 2, "unit_cpu_s": sorted(map(float, text), reverse=True)})
        units_file.write_text("")

    for module, attr, label, top in TARGETS:
        mod = importlib.import_module(module)
        fn = getattr(mod, attr)

        def wrapped(*args, _fn=fn, _label=label, _top=top, **kwargs):
            own = _reset() if _top else False
            t0, c0, n0 = time.perf_counter(), _cpu(), len(parallel.TRACE) if parallel is not None else 0
            try:
                return _fn(*args, **kwargs)
            finally:
                # Inside a forked worker (pipeline.parallel) nothing is recorded: the parent times its stage.
                if os.getpid() == pid:
                    if _label == "diagnose":
                        diagnosis_units()
                    record(_label, t0, c0, own, n0)

        setattr(mod, attr, functools.wraps(fn)(wrapped))
    atexit.register(lambda: Path(out_json).write_text(json.dumps(costs, indent=1)))
    return costs


def main(argv: list[str]) -> int:
    """``stage_timer.py OUT_JSON vesselid-arguments...``: ``vesselid`` with :func:`install` first."""
    install(argv[0])
    from pipeline.cli import main as cli_main

    return cli_main(argv[1:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
