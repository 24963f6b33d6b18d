"""casadi functions compiled to C, in bounded time and memory, or left to casadi's virtual machine.

The grey-box fit calls one small casadi ``Function`` (an RK4 step, or the step with its sensitivity)
hundreds of thousands of times; compiled, it runs about 20x faster than in casadi's virtual machine.
Only that one step is compiled, never a roll-out over the data, so the generated code grows with
the model (states, estimated coefficients) and not with the record length or the sample rate.

Bounds (a compile that breaks one of them falls back to the virtual machine, with the reason in
:attr:`Compiled.note`; the numbers are the same either way):

- generated C larger than ``MAX_SOURCE_BYTES``;
- the C compiler running longer than ``COMPILE_TIMEOUT_S`` or using more address space than
  ``COMPILE_MEMORY_BYTES`` (POSIX ``RLIMIT_AS``);
- no C compiler (``$CC``, ``cc``, ``gcc`` or ``clang`` on the PATH).

The C file and the shared object live in a ``vesselid-jit-<pid>-*`` temporary folder that is
removed as soon as the library is loaded (``finally``: on success, on a compiler error, on an
exception or ``KeyboardInterrupt``). A folder left by a process that was killed outright
(``SIGKILL``) is removed by the next compile once its process id is no longer alive.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
from functools import lru_cache
from pathlib import Path
from typing import NamedTuple

#: Largest generated C source compiled [bytes]; the RK4 step and its sensitivity of the 6-state
#: lateral model with every coupling free is about 60 kB.
MAX_SOURCE_BYTES = 2_000_000
#: Longest compile [s].
COMPILE_TIMEOUT_S = 60.0
#: Address-space limit of the compiler process [bytes].
COMPILE_MEMORY_BYTES = 2 * 1024 ** 3
#: Prefix of the temporary folders (the process id follows, so stale ones can be recognised).
FOLDER_PREFIX = "vesselid-jit-"


class Compiled(NamedTuple):
    """A function ready to call.

    Attributes
    ----------
    function : casadi.Function
        The compiled function, or the original one (virtual machine).
    compiled : bool
        Whether ``function`` runs compiled C.
    note : str
        Why it was not compiled (empty when it was, or when compilation was not asked for).
    """

    function: object
    compiled: bool
    note: str


def _compiler() -> str | None:
    for name in (os.environ.get("CC", ""), "cc", "gcc", "clang"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


def remove_stale_folders(root: str | Path | None = None) -> int:
    """Remove ``vesselid-jit-<pid>-*`` folders whose process is gone (killed before its clean-up).

    Parameters
    ----------
    root : str or Path, optional
        Folder to look in; default the system temporary folder.

    Returns
    -------
    int
        Folders removed.
    """
    root = Path(root or tempfile.gettempdir())
    removed = 0
    pattern = re.compile(re.escape(FOLDER_PREFIX) + r"(\d+)-")
    try:
        entries = list(root.iterdir())
    except OSError:
        return 0
    for entry in entries:
        m = pattern.match(entry.name)
        if m and entry.is_dir() and int(m.group(1)) != os.getpid() and not _alive(int(m.group(1))):
            shutil.rmtree(entry, ignore_errors=True)
            removed += 1
    return removed


def _limit_memory() -> None:  # pragma: no cover - runs in the compiler's child process
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (COMPILE_MEMORY_BYTES, COMPILE_MEMORY_BYTES))


def _build(fn) -> Compiled:
    """Generate C for ``fn``, compile it within the bounds, load it; the folder is always removed."""
    import casadi as ca

    cc = _compiler()
    if cc is None:
        return Compiled(fn, False, "no C compiler found ($CC, cc, gcc, clang): casadi's virtual machine was used")
    remove_stale_folders()
    folder = tempfile.mkdtemp(prefix=f"{FOLDER_PREFIX}{os.getpid()}-")
    try:
        name = f"vesselid_{fn.name()}"
        source = Path(folder) / f"{name}.c"
        gen = ca.CodeGenerator(source.name, {"with_header": False})
        gen.add(fn)
        gen.generate(folder + os.sep)
        size = source.stat().st_size
        if size > MAX_SOURCE_BYTES:
            return Compiled(fn, False, f"generated code of {fn.name()} is {size / 1e6:.1f} MB (limit "
                            f"{MAX_SOURCE_BYTES / 1e6:.1f} MB): casadi's virtual machine was used")
        library = Path(folder) / f"{name}.so"
        try:
            proc = subprocess.run([cc, "-O1", "-fPIC", "-shared", str(source), "-o", str(library), "-lm"],
                                  capture_output=True, text=True, timeout=COMPILE_TIMEOUT_S,
                                  preexec_fn=_limit_memory if os.name == "posix" else None)
        except subprocess.TimeoutExpired:
            return Compiled(fn, False, f"compiling {fn.name()} took longer than {COMPILE_TIMEOUT_S:g} s: "
                            f"casadi's virtual machine was used")
        if proc.returncode != 0 or not library.exists():
            last = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no message"]
            return Compiled(fn, False, f"the C compiler failed on {fn.name()} ({last[0][:200]}): casadi's "
                            f"virtual machine was used")
        # dlopen maps the library; the file can go right after.
        return Compiled(ca.external(fn.name(), str(library)), True, "")
    finally:
        shutil.rmtree(folder, ignore_errors=True)


@lru_cache(maxsize=32)
def _cached(serialized: str) -> Compiled:
    import casadi as ca

    return _build(ca.Function.deserialize(serialized))


def compile_function(fn, jit: bool = True) -> Compiled:
    """``fn`` compiled to C when a compiler works within the bounds, else ``fn`` itself (see the module notes).

    Parameters
    ----------
    fn : casadi.Function
        Function to compile (one model step, not a roll-out: see the module notes).
    jit : bool
        False returns ``fn`` unchanged.

    Returns
    -------
    Compiled
        ``(function, compiled, note)``; one compile per distinct function and process.
    """
    if not jit:
        return Compiled(fn, False, "")
    try:
        return _cached(fn.serialize())
    except (RuntimeError, OSError, ValueError) as exc:  # casadi raises RuntimeError on a failed load
        return Compiled(fn, False, f"compiling {fn.name()} failed ({exc}): casadi's virtual machine was used")


__all__ = ["Compiled", "compile_function", "remove_stale_folders"]
