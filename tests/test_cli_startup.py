"""``vesselid --help`` starts fast: no stage package (numpy, scipy, pandas, casadi) loads for it, and
the one-line help of the lazily registered subcommands is the one their own parsers give."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from pipeline.cli import LAZY_COMMANDS, build_parser

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("numpy", "scipy", "pandas", "casadi", "matplotlib", "duckdb", "dask")


def _python(code: str) -> tuple[float, str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    return time.perf_counter() - t0, out.stdout


def _loaded_after(argv: list[str]) -> set[str]:
    code = ("import sys\nfrom pipeline.cli import main\ntry:\n    main(%r)\nexcept SystemExit:\n    pass\n"
            "print('MODULES', ' '.join(sorted({m.split('.')[0] for m in sys.modules})))" % argv)
    _, out = _python(code)
    line = next(x for x in out.splitlines() if x.startswith("MODULES"))
    return set(line.split()[1:])


def test_help_imports_no_stage_dependency():
    loaded = _loaded_after(["--help"])
    assert not loaded & set(HEAVY), f"vesselid --help imported {sorted(loaded & set(HEAVY))}"
    # The catalogue's parser needs neither DuckDB nor pandas either.
    loaded = _loaded_after(["catalog", "--help"])
    assert not loaded & {"pandas", "duckdb", "dask", "scipy"}, sorted(loaded & set(HEAVY))


def test_every_subcommand_help_imports_no_stage_dependency():
    # The stage packages load their names on first use (pipeline/lazy.py), so `vesselid X --help`
    # builds X's parser without numpy, scipy, pandas or casadi (it took 6-8 s on a loaded machine).
    commands = [a for a in build_parser()._actions if a.__class__.__name__ == "_SubParsersAction"][0].choices
    code = ("import sys\nfrom pipeline.cli import main\nheavy = %r\nfor name in %r:\n"
            "    try:\n        main([name, '--help'])\n    except SystemExit:\n        pass\n"
            "    print('MODULES', name, ' '.join(sorted({m.split('.')[0] for m in sys.modules} & set(heavy))))")
    _, out = _python(code % (HEAVY, sorted(commands)))
    loaded = {ln.split()[1]: ln.split()[2:] for ln in out.splitlines() if ln.startswith("MODULES")}
    assert set(loaded) == set(commands)
    assert {c: m for c, m in loaded.items() if m} == {}


def test_help_start_up_is_close_to_bare_python():
    # Relative to the interpreter's own start-up in the same run, so a loaded machine does not fail it;
    # the eager imports this guards against cost 2 s or more.
    bare = min(_python("pass")[0] for _ in range(3))
    help_ = min(_python("from pipeline.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass")[0]
                for _ in range(3))
    assert help_ - bare < 0.6, f"vesselid --help took {help_:.2f} s against {bare:.2f} s for python -c pass"
    for name in LAZY_COMMANDS:
        sub = min(_python("from pipeline.cli import main\ntry:\n    main([%r, '--help'])\nexcept SystemExit:\n"
                          "    pass" % name)[0] for _ in range(2))
        assert sub - bare < 0.6, f"vesselid {name} --help took {sub:.2f} s against {bare:.2f} s for python -c pass"


def test_lazy_subcommands_list_the_help_their_parsers_give():
    def helps(parser):
        sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
        return {c.dest: c.help for c in sub._choices_actions}

    full, lazy = helps(build_parser()), helps(build_parser(""))
    assert list(full) == list(lazy)                          # same commands, same order
    for name in LAZY_COMMANDS:
        assert lazy[name] == full[name], name
