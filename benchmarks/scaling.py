"""Long trials in bounded memory and time: wall time and peak memory of every stage against trial length.

    python benchmarks/scaling.py [--minutes 10 30 60 120] [--out DIR] [--baseline-max 30] [--stages-max 60]
                                 [--compare-root /path/to/other/checkout --compare-max 30]

For each length, one continuous AAUSHIP sea trial is simulated (the identification programme of
``pipeline.sim.sea_trial`` repeated with varied amplitudes, zig-zag angles and signs, as a day of
trials would be: real manoeuvres, no concatenation, no jumps) and written as canonical CSV through
the real writer. Then, each in a fresh process so that each peak is its own:

- the stages, in one worker process through the flow's functions: ``load_trial`` (ingest + align),
  ``segment_trial``, ``fit_trial(extend=False)`` (single-DOF fits), ``extend_fits`` (the joint
  grey-box stage), ``design_autopilot`` (with its closed-loop check), ``diagnose`` and
  ``write_outputs`` (the report folder) — wall time, CPU time and peak resident memory per stage
  (the peak is reset between stages through Linux's ``/proc/self/clear_refs``, so it includes the
  interpreter, the libraries and the records the earlier stages hand on; a child process's peak,
  the C compiler of the grey-box JIT, is reported beside it);
- ``vesselid run trial.toml`` (every stage from the raw log, report included: the issue's target):
  wall time, CPU time and peak resident memory (``os.wait4``: the largest of the process and each
  child it waited for), and each of its stages timed inside it by ``benchmarks/stage_timer.py``
  (``run_stages.json``; slopes and the plot include them).

Both processes are also sampled every 0.1 s from outside (``/proc``): the largest sum of the
resident memory of the process and its children, when it happened, and the largest per command
name — which locates a transient that ``wait4`` reports but no stage's own peak shows.

With ``--compare-root``, the same ``vesselid run`` is made with another checkout's ``pipeline`` (the code
before a speed change) on the trials up to ``--compare-max`` minutes: its CPU time beside the new one, and
every coefficient's difference in the other run's standard errors (``compare`` in ``scaling.json``).

A straight line through each quantity gives its cost per trial hour. The machine may be shared:
CPU time is the figure that does not depend on what else runs. Baseline in the same run: the
previous grey-box implementation (``git show <--baseline-rev>:pipeline/fit/greybox.py``, loaded
beside the new one) fitted to the same records for lengths up to ``--baseline-max`` minutes: its
time, its Python peak memory and every coefficient's difference in standard errors.

Targets (issue 14): a 2-hour trial ``vesselid run`` < 60 s and < 1.5 GB; memory per extra trial
hour < 0.5 GB; every coefficient as before within its standard error. Exit status 1 when a target
is missed. Writes ``scaling.json`` and ``scaling.png`` into ``--out``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.sim import chain, free_decay, rudder_step, simulate, step_and_coast, zigzag  # noqa: E402
from pipeline.sim.sensors import default_sensors  # noqa: E402
from pipeline.sim.writers import write_log  # noqa: E402
from pipeline.vessel import load_vessel  # noqa: E402

VESSEL = ROOT / "vessel_configs" / "aauship.toml"
STAGES = ("align", "segment", "fit_single_dof", "fit_greybox", "autopilot", "diagnose", "report")


def programme(vessel, minutes: float, seed: int = 0):
    """A continuous trial of at least ``minutes``: the sea-trial programme repeated with variations."""
    rng = np.random.default_rng(seed)
    d = np.diag(vessel.damping)
    m = np.diag(vessel.mass_matrix())
    tc = m / d
    speeds = {"surge": 1.5, "sway": 0.3, "yaw": 0.5}
    rest_s = float(max(5.0, 3 * np.max(tc)))
    items, total = [], 0.0
    cycle = 0
    while total < minutes * 60.0:
        a = float(rng.uniform(0.6, 1.3))
        sign = 1.0 if cycle % 2 == 0 else -1.0
        block = []
        for dof, i in (("surge", 0), ("sway", 1), ("yaw", 4)):
            hold = max(6 * tc[i], 3.0)
            block.append(step_and_coast(dof, sign * a * float(d[i] * speeds[dof]) if dof != "surge"
                                        else a * float(d[i] * speeds[dof]), hold, hold))
        for dof, i, angle in (("roll", 2, np.radians(20)), ("pitch", 3, np.radians(6))):
            g = vessel.restoring.get(dof, 0.0)
            wn = np.sqrt(g / m[i])
            zeta = d[i] / (2 * np.sqrt(g * m[i]))
            length = min(max(4.0 / max(zeta * wn, 1e-3), 2.0), 60.0)
            block += [free_decay(dof, a * angle, length), free_decay(dof, -a * angle, length)]
        t_yaw = max(8 * tc[4], 5.0)
        thrust = {"tau_x": float(d[0] * a)}
        z = np.radians(float(rng.choice([10.0, 15.0, 20.0])))
        block += [rudder_step(sign * a * np.radians(10), t_yaw, t_yaw, thrust),
                  rudder_step(-sign * a * np.radians(10), t_yaw, t_yaw, thrust),
                  zigzag(z, z, 12 * tc[4] + 10, thrust)]
        for man in block:
            if total >= minutes * 60.0:
                break
            items.append(man)
            total += man.duration + rest_s
        cycle += 1
    return chain(*items, rest_s=rest_s)


def write_trial(vessel, minutes: float, folder: Path, seed: int) -> tuple[Path, Path, float]:
    sensors = tuple(s if s.rate <= 50 else type(s)(s.name, s.channels, 50.0, s.noise, s.bias, s.suffix)
                    for s in default_sensors("nominal"))
    res = simulate(vessel, programme(vessel, minutes, seed), sensors=sensors, seed=seed)
    log = write_log(res.log, folder / "log.csv", vessel=vessel)
    manifest = folder / "trial.toml"
    manifest.write_text(f'name = "scaling{int(minutes)}"\nvessel = "{VESSEL}"\nlogs = ["log.csv"]\n')
    return log, manifest, float(res.truth["t"].iloc[-1])


def rss_of(pid: int) -> tuple[float, str]:
    """Resident memory [bytes] and command name of one process (Linux ``/proc``); (0, "") when gone."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return 0.0, ""
    rss, name = 0.0, ""
    for line in status.splitlines():
        if line.startswith("VmRSS:"):
            rss = float(line.split()[1]) * 1024
        elif line.startswith("Name:"):
            name = line.split(None, 1)[1].strip()
    return rss, name


def pss_of(pid: int) -> float:
    """Proportional set size [bytes] of one process (Linux ``/proc/<pid>/smaps_rollup``): pages shared with
    other processes (a forked worker's copy-on-write pages of its parent) counted once over them; 0 when gone."""
    try:
        for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
            if line.startswith("Pss:"):
                return float(line.split()[1]) * 1024
    except OSError:
        pass
    return 0.0


def descendants(pid: int) -> list[int]:
    """Child processes of ``pid``, recursively (Linux ``/proc/<pid>/task/*/children``)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                kids = [int(k) for k in (task / "children").read_text().split()]
            except (OSError, ValueError):
                continue
            out += kids
            todo += kids
    return out


class TreeSampler:
    """Samples the resident memory of a process and its descendants every ``interval`` s.

    ``wait4``'s ``ru_maxrss`` is the largest of the process and each child it waited for (a C
    compiler, say), not their sum, and does not say when; this says both: the largest sum over the
    tree, when it happened (s after start), and the largest RSS seen per command name.
    """

    def __init__(self, pid: int, interval: float = 0.1) -> None:
        import threading

        self.pid, self.interval = pid, interval
        self.t0 = time.perf_counter()
        self.peak_sum, self.peak_at = 0.0, math.nan
        self.peak_pss = 0.0
        self.by_name: dict[str, float] = {}
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self) -> None:
        while not self.stop.wait(self.interval):
            total = pss = 0.0
            for p in [self.pid, *descendants(self.pid)]:
                rss, name = rss_of(p)
                total += rss
                pss += pss_of(p)
                if name:
                    self.by_name[name] = max(self.by_name.get(name, 0.0), rss)
            if total > self.peak_sum:
                self.peak_sum, self.peak_at = total, time.perf_counter() - self.t0
            self.peak_pss = max(self.peak_pss, pss)

    def result(self) -> dict:
        self.stop.set()
        self.thread.join()
        return {"tree_peak_gb": round(self.peak_sum / 1e9, 3), "tree_peak_at_s": round(self.peak_at, 1),
                "tree_peak_pss_gb": round(self.peak_pss / 1e9, 3),
                "peak_gb_by_command": {k: round(v / 1e9, 3) for k, v in sorted(self.by_name.items())}}


def measure_wait4(argv: list[str], cwd: Path, root: Path = ROOT) -> dict:
    """Wall time [s], CPU time [s] and peak RSS [GB] of one process (``os.wait4``), and its tree's sampled peak
    (``root``: the checkout whose ``pipeline`` package the process imports)."""
    env = dict(os.environ, CI="1", PYTHONPATH=str(root))
    with tempfile.TemporaryFile() as errf, tempfile.TemporaryFile() as outf:
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, *argv], cwd=cwd, env=env, stdout=outf, stderr=errf)
        sampler = TreeSampler(proc.pid)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        tree = sampler.result()
        proc.returncode = os.waitstatus_to_exitcode(status)
        errf.seek(0)
        outf.seek(0)
        err = errf.read().decode(errors="replace")
        out = outf.read().decode(errors="replace")
    return {"wall_s": round(wall, 2), "cpu_s": round(usage.ru_utime + usage.ru_stime, 2),
            "peak_gb": round(usage.ru_maxrss / 1e6, 3), "rc": proc.returncode,
            "stderr": err[-600:] if proc.returncode else "", "stdout": out, **tree}


def reset_peak_rss() -> bool:
    """Reset this process's peak RSS (Linux ``/proc/self/clear_refs``); False where not possible."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def peak_rss() -> float:
    """Peak RSS since the last reset [bytes] (``VmHWM``)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return float(line.split()[1]) * 1024
    return math.nan


def cpu_with_children() -> float:
    """CPU time [s] of this process and of the child processes it waited for (the workers of
    :mod:`pipeline.parallel`)."""
    import resource

    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + kids.ru_utime + kids.ru_stime


def stage_worker(log: Path, out_json: Path) -> None:
    """Run the stages in this process, one after the other, and write their costs to ``out_json``."""
    import resource

    from pipeline.diagnose import diagnose
    from pipeline.errors import AutopilotError
    from pipeline.fit import fit_trial
    from pipeline.fit.extend import extend_fits
    from pipeline.flow import design_autopilot, load_trial, segment_trial, write_outputs

    vessel = load_vessel(VESSEL)
    stages = {}
    state: dict = {}

    def timed(name, fn):
        # Linux: writing 5 to clear_refs resets the peak RSS (VmHWM), so each stage gets its own peak
        # without tracemalloc's overhead; elsewhere the process's running peak is reported. The
        # children's peak (a C compiler the grey-box JIT runs) is the largest child waited for so
        # far: reported when a stage raised it.
        own = reset_peak_rss()
        kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        t0, c0 = time.perf_counter(), cpu_with_children()
        value = fn()
        kids_after = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        stages[name] = {"wall_s": round(time.perf_counter() - t0, 2), "cpu_s": round(cpu_with_children() - c0, 2),
                        "peak_gb": round((peak_rss() if own else
                                          resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1e3) / 1e9, 3),
                        "children_peak_gb": round(kids_after / 1e6, 3) if kids_after > kids else 0.0,
                        "own_peak": own}
        return value

    state["trial"] = timed("align", lambda: load_trial([log], vessel))
    state["segments"] = timed("segment", lambda: segment_trial(state["trial"]))
    state["single"] = timed("fit_single_dof", lambda: fit_trial(state["trial"], state["segments"], vessel, extend=False))
    state["fits"] = timed("fit_greybox", lambda: extend_fits(state["single"], state["trial"], state["segments"], vessel))
    skipped = {}

    def autopilot():
        try:
            return design_autopilot(state["fits"], vessel)
        except AutopilotError as exc:  # as the flow: no Nomoto K, T in a short trial
            skipped["autopilot"] = str(exc)
            return None

    state["autopilot"] = timed("autopilot", autopilot)
    state["diagnosis"] = timed("diagnose", lambda: diagnose(state["trial"], vessel, fits=state["fits"]))
    with tempfile.TemporaryDirectory() as tmp:
        timed("report", lambda: write_outputs(Path(tmp) / "report", state["trial"], state["segments"], state["fits"],
                                              state["autopilot"], state["diagnosis"], skipped, None, vessel))
    est = {n: [e.value, e.stderr, e.success] for n, e in state["fits"].estimates.items()}
    out_json.write_text(json.dumps({"stages": stages, "rows": len(state["trial"].data),
                                    "segments": len(state["segments"].items), "estimates": est}))


def load_baseline(rev: str):
    """The grey-box module as it was at ``rev``, importable beside the current one."""
    src = subprocess.run(["git", "show", f"{rev}:pipeline/fit/greybox.py"], cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout
    path = Path(tempfile.mkdtemp(prefix="scaling-baseline-")) / "greybox_baseline.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location("pipeline.fit.greybox_baseline", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def compare_with_baseline(baseline, log: Path, vessel) -> dict:
    """Current and baseline grey-box fits of the same records: time, Python peak, coefficients."""
    from pipeline.fit import fit_trial
    from pipeline.fit.greybox import fit_coupled_damping
    from pipeline.flow import load_trial, segment_trial

    trial = load_trial([log], vessel)
    segs = segment_trial(trial)
    single = fit_trial(trial, segs, vessel, extend=False)
    out = {}
    for name, fn in (("current", fit_coupled_damping), ("baseline", baseline.fit_coupled_damping)):
        tracemalloc.start()
        t0, c0 = time.perf_counter(), time.process_time()
        gb = fn(trial, segs, vessel, single.damping_matrix)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        out[name] = {"wall_s": round(wall, 2), "cpu_s": round(cpu, 2), "python_peak_gb": round(peak / 1e9, 3),
                     "values": dict(zip(gb.names, map(float, gb.values))),
                     "stderr": dict(zip(gb.names, map(float, gb.stderr))), "converged": bool(gb.converged)}
    cur, base = out["current"], out["baseline"]
    out["max_diff_in_se"] = max(abs(cur["values"][n] - base["values"][n]) / cur["stderr"][n]
                                for n in cur["values"] if math.isfinite(cur["stderr"][n]) and cur["stderr"][n] > 0)
    return out


def coefficient_differences(new: Path, old: Path) -> dict:
    """Every coefficient of two ``coefficients.json`` files: the difference in the old one's standard errors."""
    a = json.loads(new.read_text())["coefficients"]
    b = json.loads(old.read_text())["coefficients"]
    out = {}
    for name, cb in b.items():
        ca = a.get(name)
        if ca is None or ca.get("value") is None or cb.get("value") is None:
            continue
        se = cb.get("stderr")
        if se and math.isfinite(se) and se > 0:
            out[name] = round(abs(ca["value"] - cb["value"]) / se, 4)
    return {"by_coefficient_in_se": out, "max_diff_in_se": max(out.values(), default=math.nan),
            "only_in_compare": sorted(set(b) - set(a)), "only_in_new": sorted(set(a) - set(b))}


def idle_wall_estimate(run: dict) -> float:
    """Wall time [s] ``vesselid run`` would take on 2 idle cores: its CPU time less, for every top-level
    stage that ran units side by side (``benchmarks/stage_timer.py``), its CPU time minus its 2-core
    estimate. Everything else is taken as serial (one core)."""
    top = ("ingest + align", "segment", "fit", "autopilot", "diagnose", "report (write_outputs)")
    saved = sum(st["cpu_s"] - st["idle_2core_wall_s"] for label, st in run.get("stages", {}).items()
                if label in top and "idle_2core_wall_s" in st)
    return round(run["cpu_s"] - saved, 1)


def slope(x: list[float], y: list[float]) -> tuple[float, float]:
    """Least-squares line ``y = a + b x``: (b, a)."""
    b, a = np.polyfit(np.asarray(x, float), np.asarray(y, float), 1)
    return float(b), float(a)


def series(results: list[dict], name: str, key: str) -> tuple[list[float], list[float]]:
    """Trial hours and one quantity of a stage (or ``run``), over the lengths where it was measured."""
    rows = [r for r in results if (name == "run" and "run" in r) or name in r.get("stages", {})]
    return [r["hours"] for r in rows], [(r["run"] if name == "run" else r["stages"][name])[key] for r in rows]


def run_stage_labels(results: list[dict]) -> list[str]:
    """Stage labels timed inside ``vesselid run`` (top level and nested), in the order first seen."""
    labels: dict[str, None] = {}
    for r in results:
        for label in r.get("run", {}).get("stages", {}):
            labels.setdefault(label, None)
    return list(labels)


def run_stage_series(results: list[dict], label: str):
    """Trial hours, CPU [s], wall [s] and peak [GB, NaN when not its own] of one stage of vesselid run."""
    rows = [r for r in results if label in r.get("run", {}).get("stages", {})]
    st = [r["run"]["stages"][label] for r in rows]
    return ([r["hours"] for r in rows], [x["cpu_s"] for x in st], [x["wall_s"] for x in st],
            [x.get("peak_gb", math.nan) for x in st])


def plot(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 7))
    for name in STAGES + ("run",):
        label = "vesselid run" if name == "run" else name
        x, y = series(results, name, "cpu_s")
        if not x:
            continue
        axes[0].plot(x, y, "ko-" if name == "run" else "o-", label=label)
        axes[1].plot(*series(results, name, "wall_s"), "ko-" if name == "run" else "o-", label=label)
        axes[2].plot(*series(results, name, "peak_gb"), "ko-" if name == "run" else "o-", label=label)
    # The stages of vesselid run itself (benchmarks/stage_timer.py), dashed.
    for label in run_stage_labels(results):
        x, cpu, wall, peak = run_stage_series(results, label)
        axes[0].plot(x, cpu, "s--", label=f"run: {label}")
        axes[1].plot(x, wall, "s--", label=f"run: {label}")
        if all(v == v for v in peak):
            axes[2].plot(x, peak, "s--", label=f"run: {label}")
    # The run's memory sampled from outside (wait4 also counts the benchmark's own image at the fork).
    tree = [(r["hours"], r["run"]["tree_peak_gb"]) for r in results if "tree_peak_gb" in r.get("run", {})]
    if tree:
        axes[2].plot(*zip(*tree), "k^-", label="vesselid run, sampled process tree")
    axes[1].axhline(60, color="k", ls=":", lw=1, label="run target at 2 h")
    axes[2].axhline(1.5, color="k", ls=":", lw=1, label="run target at 2 h")
    axes[0].set(xlabel="trial length [h]", ylabel="CPU time [s]", title="CPU time")
    axes[1].set(xlabel="trial length [h]", ylabel="wall time [s]", title="wall time (shared machine)")
    axes[2].set(xlabel="trial length [h]", ylabel="peak RSS [GB]", title="peak resident memory per stage")
    for ax in axes:
        ax.grid(alpha=0.3)
        # Below the axes: inside, the legend of many stages hid the data.
        ax.legend(fontsize=6, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=1)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, nargs="+", default=[10, 30, 60, 120])
    ap.add_argument("--out", default=str(ROOT / "reports" / "scaling"))
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--baseline-rev", default="930a812", help="git revision of the previous grey-box")
    ap.add_argument("--baseline-max", type=float, default=30, help="longest trial the baseline is run on [min]")
    ap.add_argument("--run-max", type=float, default=math.inf,
                    help="longest trial vesselid run is measured on [min] (it repeats every stage)")
    ap.add_argument("--stages-max", type=float, default=math.inf,
                    help="longest trial the per-stage worker is run on [min] (it repeats what vesselid run does)")
    ap.add_argument("--reuse", action="store_true",
                    help="use a trial log already simulated into --out (same lengths and seed) instead of simulating again")
    ap.add_argument("--keep", action="store_true", help="keep other lengths from an earlier run in --out")
    ap.add_argument("--compare-root", default=None,
                    help="another checkout (e.g. the main branch before a change): its vesselid run is measured on "
                         "the same trials and its coefficients compared")
    ap.add_argument("--compare-max", type=float, default=30, help="longest trial the --compare-root run is made on [min]")
    ap.add_argument("--stage-worker", nargs=2, metavar=("LOG", "OUT_JSON"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.stage_worker:
        stage_worker(Path(args.stage_worker[0]), Path(args.stage_worker[1]))
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    vessel = load_vessel(VESSEL)
    baseline = None
    try:
        baseline = load_baseline(args.baseline_rev)
    except (subprocess.CalledProcessError, OSError) as exc:
        print(f"baseline grey-box at {args.baseline_rev} not available ({exc}): no baseline comparison")
    results = []
    previous = out / "scaling.json"
    if args.keep and previous.exists():
        # Lengths measured by an earlier run into the same folder and not repeated now are kept.
        results = [r for r in json.loads(previous.read_text())["results"] if r["minutes"] not in args.minutes]
    for minutes in args.minutes:
        folder = out / f"{int(minutes)}min"
        folder.mkdir(exist_ok=True)
        t0 = time.perf_counter()
        if args.reuse and (folder / "log.csv").exists() and (folder / "duration.txt").exists():
            log, manifest = folder / "log.csv", folder / "trial.toml"
            manifest.write_text(f'name = "scaling{int(minutes)}"\nvessel = "{VESSEL}"\nlogs = ["log.csv"]\n')
            duration = float((folder / "duration.txt").read_text())
        else:
            log, manifest, duration = write_trial(vessel, minutes, folder, args.seed)
            (folder / "duration.txt").write_text(repr(duration))
        sim_s = time.perf_counter() - t0
        row = {"minutes": minutes, "hours": duration / 3600.0, "simulated_s": round(sim_s, 1)}
        worker = {"rc": 0}
        if minutes <= args.stages_max:
            worker = measure_wait4([__file__, "--stage-worker", str(log), str(folder / "stages.json")], folder)
            if worker["rc"] == 0:
                row.update(json.loads((folder / "stages.json").read_text()))
            row["stage_process"] = {k: worker[k] for k in ("wall_s", "cpu_s", "peak_gb", "rc", "stderr",
                                                            "tree_peak_gb", "tree_peak_at_s", "peak_gb_by_command")}
        for name, st in row.get("stages", {}).items():
            print(f"{minutes:5.0f} min  {name:15s} {st['wall_s']:7.1f} s wall {st['cpu_s']:7.1f} s cpu  "
                  f"{st['peak_gb']:6.3f} GB peak RSS"
                  + (f" (a child process: {st['children_peak_gb']:.3f} GB)" if st.get("children_peak_gb") else ""),
                  flush=True)
        if "stage_process" in row:
            print(f"{minutes:5.0f} min  stages process peak RSS {worker['peak_gb']:.2f} GB (wait4), sampled tree "
                  f"peak {worker['tree_peak_gb']:.2f} GB at {worker['tree_peak_at_s']} s, by command "
                  f"{worker['peak_gb_by_command']} rc={worker['rc']} {worker['stderr'][-300:]}", flush=True)
        if minutes <= args.run_max:
            # vesselid's own main, with the stages timed from outside (benchmarks/stage_timer.py).
            run = measure_wait4([str(ROOT / "benchmarks" / "stage_timer.py"), str(folder / "run_stages.json"),
                                 "run", str(manifest), "--out", str(folder / "report")], folder)
            row["run"] = {k: run[k] for k in ("wall_s", "cpu_s", "peak_gb", "rc", "stderr", "tree_peak_gb",
                                              "tree_peak_at_s", "tree_peak_pss_gb", "peak_gb_by_command")}
            if (folder / "run_stages.json").exists():
                row["run"]["stages"] = json.loads((folder / "run_stages.json").read_text())
                row["run"]["idle_2core_wall_s"] = idle_wall_estimate(row["run"])
                for label, st in row["run"]["stages"].items():
                    print(f"{minutes:5.0f} min    run: {label:50s} {st['wall_s']:7.1f} s wall {st['cpu_s']:7.1f} s cpu"
                          + (f"  {st['peak_gb']:.3f} GB peak RSS" if "peak_gb" in st else ""), flush=True)
            if "idle_2core_wall_s" in row["run"]:
                print(f"{minutes:5.0f} min  vesselid run: estimated wall on 2 idle cores "
                      f"{row['run']['idle_2core_wall_s']:.1f} s (CPU time less what the units run side by side save)",
                      flush=True)
            print(f"{minutes:5.0f} min  vesselid run    {run['wall_s']:7.1f} s wall {run['cpu_s']:7.1f} s cpu  "
                  f"{run['peak_gb']:6.2f} GB peak RSS (wait4), sampled tree peak {run['tree_peak_gb']:.2f} GB at "
                  f"{run['tree_peak_at_s']} s (proportional set size of the tree: {run['tree_peak_pss_gb']:.2f} GB), by command "
                  f"{run['peak_gb_by_command']}  rc={run['rc']} "
                  f"{run['stderr'][-300:]}", flush=True)
        if args.compare_root and minutes <= args.compare_max and "run" in row:
            # The same vesselid run with another checkout's pipeline (the baseline of a speed change).
            cmp = measure_wait4([str(ROOT / "benchmarks" / "stage_timer.py"), str(folder / "compare_stages.json"),
                                 "run", str(manifest), "--out", str(folder / "report_compare")], folder,
                                Path(args.compare_root))
            row["compare"] = {k: cmp[k] for k in ("wall_s", "cpu_s", "peak_gb", "rc", "stderr", "tree_peak_gb",
                                                  "tree_peak_pss_gb")}
            row["compare"]["root"] = str(args.compare_root)
            if (folder / "compare_stages.json").exists():
                row["compare"]["stages"] = json.loads((folder / "compare_stages.json").read_text())
            if cmp["rc"] == 0 and row["run"]["rc"] == 0:
                row["compare"]["coefficients"] = coefficient_differences(folder / "report" / "coefficients.json",
                                                                         folder / "report_compare" / "coefficients.json")
            c = row["compare"]
            print(f"{minutes:5.0f} min  compare run ({args.compare_root}) {c['wall_s']:7.1f} s wall {c['cpu_s']:7.1f} s "
                  f"cpu {c['peak_gb']:6.2f} GB; CPU ratio new/compare {row['run']['cpu_s'] / max(c['cpu_s'], 1e-9):.2f}; "
                  f"largest coefficient difference "
                  f"{c.get('coefficients', {}).get('max_diff_in_se', math.nan):.4f} standard errors rc={c['rc']}",
                  flush=True)
        if baseline is not None and minutes <= args.baseline_max:
            row["baseline"] = compare_with_baseline(baseline, log, vessel)
            b = row["baseline"]
            print(f"{minutes:5.0f} min  grey-box current {b['current']['cpu_s']} s cpu {b['current']['python_peak_gb']} GB"
                  f" | baseline {b['baseline']['cpu_s']} s cpu {b['baseline']['python_peak_gb']} GB | largest "
                  f"difference {b['max_diff_in_se']:.3f} standard errors", flush=True)
        results.append(row)
        (out / "scaling.json").write_text(json.dumps({"results": results}, indent=1, default=str))
    results.sort(key=lambda r: r["hours"])
    fits = {}
    for name in STAGES + ("run",):
        if len(series(results, name, "cpu_s")[0]) > 1:
            fits[name] = {"cpu_s_per_hour": slope(*series(results, name, "cpu_s"))[0],
                          "wall_s_per_hour": slope(*series(results, name, "wall_s"))[0],
                          "gb_per_hour": slope(*series(results, name, "peak_gb"))[0]}
            f = fits[name]
            print(f"slope {name:15s} {f['cpu_s_per_hour']:7.1f} s/h cpu  {f['wall_s_per_hour']:7.1f} s/h wall  "
                  f"{f['gb_per_hour']:6.3f} GB/h peak RSS")
    for label in run_stage_labels(results):
        x, cpu, wall, peak = run_stage_series(results, label)
        if len(x) > 1:
            fits[f"run: {label}"] = {"cpu_s_per_hour": slope(x, cpu)[0], "wall_s_per_hour": slope(x, wall)[0],
                                     "gb_per_hour": slope(x, peak)[0] if all(v == v for v in peak) else math.nan}
            f = fits[f"run: {label}"]
            print(f"slope run: {label:50s} {f['cpu_s_per_hour']:7.1f} s/h cpu  {f['wall_s_per_hour']:7.1f} s/h wall  "
                  f"{f['gb_per_hour']:6.3f} GB/h peak RSS")
    (out / "scaling.json").write_text(json.dumps({"results": results, "slopes": fits}, indent=1, default=str))
    plot(results, out / "scaling.png")
    longest = max(results, key=lambda r: r["hours"])
    ok = all(r.get("run", {}).get("rc", 0) == 0 and r.get("stage_process", {}).get("rc", 0) == 0 for r in results)
    if longest["hours"] >= 1.9 and "run" in longest:
        run = longest["run"]
        # On a shared machine the measured wall time says little: the estimate for 2 idle cores counts too.
        met = min(run["wall_s"], run.get("idle_2core_wall_s", math.inf)) < 60 and run["peak_gb"] < 1.5
        print(f"2-hour vesselid run: {run['wall_s']:.1f} s wall, {run['cpu_s']:.1f} s CPU, estimated "
              f"{run.get('idle_2core_wall_s', math.nan):.1f} s wall on 2 idle cores, {run['peak_gb']:.2f} GB "
              f"(target < 60 s, < 1.5 GB): {'met' if met else 'missed'}")
        ok &= met
    else:
        print("2-hour target not measured (no vesselid run on a trial of 2 hours)")
    if "run" in fits:
        ok &= fits["run"]["gb_per_hour"] < 0.5
    ok &= all(r.get("baseline", {}).get("max_diff_in_se", 0.0) < 1.0 for r in results)
    print("targets met" if ok else "targets missed (see above)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
