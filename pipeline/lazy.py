"""Package namespaces whose names load on first use (PEP 562), so that ``vesselid X --help`` is fast.

A stage package's ``__init__`` names what it offers and the submodule that defines each name;
the submodule (and numpy, scipy, casadi behind it) is imported only when a name is first used,
``from pipeline.autopilot import build_autopilot`` included.
"""

from __future__ import annotations

import importlib
import sys
from typing import Any, Callable, Mapping


def lazy_exports(package: str, exports: Mapping[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]], list[str]]:
    """The ``__getattr__``, ``__dir__`` and ``__all__`` of a package that loads its names on first use.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    exports : mapping of str to str
        Public name -> module defining it, relative to the package (``".design"``, ``"..records"``).

    Returns
    -------
    tuple
        ``(__getattr__, __dir__, __all__)`` to assign in the package's ``__init__``.

    Examples
    --------
    >>> __getattr__, __dir__, __all__ = lazy_exports(__name__, {"build_autopilot": ".design"})  # doctest: +SKIP
    """
    exports = dict(exports)

    def __getattr__(name: str) -> Any:
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(exports[name], package), name)
        setattr(sys.modules[package], name, value)  # later look-ups skip this function
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(exports))

    return __getattr__, __dir__, list(exports)
