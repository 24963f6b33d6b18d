"""Meta-test (python-control style): every public function of the package documents its parameters.

A parameter counts as documented when its name starts a line of the docstring's Parameters section
(numpydoc: ``name : type`` or ``a, b : type``). Dataclass-generated methods and private names
(leading underscore) are exempt, and so are overrides: a method that a base class already defines
shares the base's documented contract (lmfit's ``guess.__doc__ = COMMON_GUESS_DOC``), so its
Parameters block is not copied. This is the package's one docstring meta-test.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re

import pipeline

EXEMPT_PARAMS = {"self", "cls", "args", "kwargs", "_"}


def _public_functions():
    for mod_info in pkgutil.walk_packages(pipeline.__path__, "pipeline."):
        if any(part.startswith("_") for part in mod_info.name.split(".")[1:]):
            continue
        mod = importlib.import_module(mod_info.name)
        for name, obj in vars(mod).items():
            if name.startswith("_"):
                continue
            if inspect.isfunction(obj) and obj.__module__ == mod.__name__:
                yield f"{mod.__name__}.{name}", obj
            elif inspect.isclass(obj) and obj.__module__ == mod.__name__:
                for mname, meth in vars(obj).items():
                    if inspect.isfunction(meth) and not mname.startswith("_") and not _is_override(obj, mname):
                        yield f"{mod.__name__}.{name}.{mname}", meth


def _is_override(cls: type, name: str) -> bool:
    """A base class (other than ``object``) defines ``name``: the override shares its contract."""
    return any(name in vars(base) for base in cls.__mro__[1:] if base is not object)


def _public_classes():
    for mod_info in pkgutil.walk_packages(pipeline.__path__, "pipeline."):
        if any(part.startswith("_") for part in mod_info.name.split(".")[1:]):
            continue
        mod = importlib.import_module(mod_info.name)
        for name, obj in vars(mod).items():
            if not name.startswith("_") and inspect.isclass(obj) and obj.__module__ == mod.__name__:
                yield f"{mod.__name__}.{name}", obj


def _documented(doc: str) -> set[str]:
    names: set[str] = set()
    m = re.search(r"Parameters\n\s*-+\n(.*?)(\n\s*\n\s*[A-Z][A-Za-z ]+\n\s*-+\n|\Z)", doc, re.S)
    if not m:
        return names
    for line in m.group(1).splitlines():
        head = re.match(r"\s*([\*\w, ]+?)\s*(:|$)", line)
        if head:
            names.update(n.strip().lstrip("*") for n in head.group(1).split(","))
    return names


def test_every_public_function_has_a_docstring():
    missing = [q for q, f in _public_functions() if not (f.__doc__ or "").strip()]
    assert not missing, missing


def test_every_public_class_has_a_docstring():
    missing = [q for q, c in _public_classes() if not (c.__doc__ or "").strip()]
    assert not missing, missing


def test_overrides_are_exempt_and_new_methods_are_not():
    """The exemption covers only methods a base class defines."""

    class Base:
        def guess(self, data):
            """Start values.

            Parameters
            ----------
            data : array
                Data.
            """

    class Child(Base):
        def guess(self, data):
            return data

        def extra(self, x):
            return x

    assert _is_override(Child, "guess") and not _is_override(Child, "extra") and not _is_override(Base, "guess")


def test_every_public_function_documents_its_parameters():
    missing = []
    for qual, func in _public_functions():
        params = [p for p in inspect.signature(func).parameters if p not in EXEMPT_PARAMS]
        if not params:
            continue
        documented = _documented(inspect.getdoc(func) or "")
        missing += [f"{qual}: {p}" for p in params if p not in documented]
    assert not missing, f"{len(missing)} undocumented parameters:\n" + "\n".join(missing)
