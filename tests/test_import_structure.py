"""The package's import structure: no import cycle, no private name imported across modules, no
stage importing a later stage, and no third-party import that pyproject.toml does not declare for
it (read from the source with ``ast``, nothing imported)."""

from __future__ import annotations

import ast
import importlib.metadata
import re
import sys
import tomllib
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "pipeline"
#: Stages in flow order (ARCHITECTURE.md); a stage may import earlier ones and top-level modules.
STAGES = ("model", "ingest", "align", "segment", "fit", "autopilot", "diagnose", "report", "export", "catalog")
#: Known private imports in files another change owns (remove an entry once fixed there).
KNOWN_PRIVATE: set[tuple[str, str]] = set()


def _modules() -> dict[str, Path]:
    out = {}
    for f in PKG.rglob("*.py"):
        parts = list(f.relative_to(PKG.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = f
    return out


def _imports(mod: str, path: Path, module_level: bool):
    """``(target module, imported names)`` of every ``pipeline`` import in ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    nodes = tree.body if module_level else list(ast.walk(tree))
    base = mod.split(".") if path.name == "__init__.py" else mod.split(".")[:-1]
    for node in nodes:
        if isinstance(node, ast.ImportFrom):
            if node.level:
                target = ".".join(base[:len(base) - node.level + 1] + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] == "pipeline":
                yield target, [a.name for a in node.names]
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == "pipeline":
                    yield a.name, []


def _relative(package: str, spec: str) -> str:
    """``..records`` relative to ``pipeline.diagnose`` -> ``pipeline.records``."""
    level = len(spec) - len(spec.lstrip("."))
    base = package.split(".")[:len(package.split(".")) - level + 1]
    return ".".join(base + ([spec.lstrip(".")] if spec.lstrip(".") else []))


def _reexports(mods: dict[str, Path]) -> dict[tuple[str, str], str]:
    """``(package, name) -> module`` for every name a package's ``__init__`` takes from a module: its
    module-level imports and its lazy ``_EXPORTS`` table (:func:`pipeline.lazy.lazy_exports`)."""
    out = {}
    for m, path in mods.items():
        if path.name != "__init__.py":
            continue
        for target, names in _imports(m, path, module_level=True):
            for n in names:
                out[(m, n)] = f"{target}.{n}" if f"{target}.{n}" in mods else target
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if (isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "_EXPORTS" for t in node.targets)):
                for n, spec in ast.literal_eval(node.value).items():
                    out[(m, n)] = _relative(m, spec)
    return out


def _graph() -> dict[str, set[str]]:
    """Module -> modules it imports, at module level or inside a function (a deferred import that closes
    a loop is still a cycle: it only hides it from the interpreter). A name imported from a package is
    followed to the module the package's ``__init__`` takes it from, so a loop through a package's
    re-exports is seen."""
    mods = _modules()
    again = _reexports(mods)
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for m, path in mods.items():
        for target, names in _imports(m, path, module_level=False):
            for name in names or [""]:
                full = f"{target}.{name}" if name else target
                dest = full if full in mods else target
                for _ in range(5):  # a re-export of a re-export
                    dest = again.get((dest, name), dest) if name else dest
                if dest in mods and dest != m:
                    graph[m].add(dest)
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return out


def test_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def _package_graph() -> dict[str, set[str]]:
    """:func:`_graph` without a module's edge to its own enclosing package: a name the package defines
    itself (``pipeline.__version__``) is no loop. The package's own edges to its submodules stay, so a
    submodule that reaches its package again through another package is a cycle."""
    return {m: {t for t in ts if not m.startswith(t + ".")} for m, ts in _graph().items()}


def test_no_import_cycle_in_the_package():
    assert _cycles(_package_graph()) == []


def test_graph_follows_names_a_package_re_exports():
    graph = _graph()
    # segment_trial imported from the segment package is segment.trial's (an __init__ import) ...
    assert "pipeline.segment.trial" in graph["pipeline.diagnose.segments"]
    # ... and diagnose imported from the diagnose package is verdict's (a lazy _EXPORTS entry).
    assert "pipeline.diagnose.verdict" in graph["pipeline.flow"]
    # A loop closed through such a re-export is a cycle.
    looped = {**_package_graph(), "pipeline.segment.quality": {"pipeline.diagnose.segments"}}
    assert any("pipeline.segment.quality" in c and "pipeline.segment.trial" in c for c in _cycles(looped))


def test_no_private_name_imported_across_modules():
    found = set()
    for m, path in _modules().items():
        for target, names in _imports(m, path, module_level=False):
            found |= {(m, n) for n in names if n.startswith("_") and not n.startswith("__")}
    assert found <= KNOWN_PRIVATE, sorted(found - KNOWN_PRIVATE)


def test_no_stage_imports_a_later_stage():
    later = []
    for m, path in _modules().items():
        parts = m.split(".")
        if len(parts) < 2 or parts[1] not in STAGES:
            continue
        here = STAGES.index(parts[1])
        for target, _ in _imports(m, path, module_level=False):
            tparts = target.split(".")
            if len(tparts) > 1 and tparts[1] in STAGES and STAGES.index(tparts[1]) > here:
                later.append(f"{m} imports {target}")
    assert later == []


def _dist_name(requirement: str) -> set[str]:
    """``dask[distributed]>=2024.8`` -> ``{"dask", "distributed"}`` (PEP 503 names; an extra named after
    a distribution pulls that distribution in)."""
    m = re.match(r"\s*([A-Za-z0-9_.-]+)(?:\[([^\]]*)\])?", requirement)
    names = {m.group(1)} | {e.strip() for e in (m.group(2) or "").split(",") if e.strip()}
    return {re.sub(r"[-_.]+", "-", n).lower() for n in names}


def test_package_imports_only_what_pyproject_declares_for_it():
    # Runtime dependencies and the "review" extra (plotly, loaded only for the optional review page);
    # not the "test" extra: what only the tests and benchmarks use (pynmeagps) is no runtime dependency.
    project = tomllib.loads((PKG.parent / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    declared = set().union(*(_dist_name(r) for r in project["dependencies"] + project["optional-dependencies"]["review"]))
    test_only = set().union(*(_dist_name(r) for r in project["optional-dependencies"]["test"])) - declared
    assert "pynmeagps" in test_only
    dists = importlib.metadata.packages_distributions()
    undeclared = []
    for m, path in _modules().items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            tops = ([a.name.split(".")[0] for a in node.names] if isinstance(node, ast.Import) else
                    [node.module.split(".")[0]] if isinstance(node, ast.ImportFrom) and not node.level else [])
            for top in tops:
                if top == "pipeline" or top in sys.stdlib_module_names:
                    continue
                names = {re.sub(r"[-_.]+", "-", d).lower() for d in dists.get(top, [top])}
                if not names & declared:
                    undeclared.append(f"{m} imports {top}")
    assert undeclared == []

