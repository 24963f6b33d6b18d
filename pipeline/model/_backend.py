"""Pick numpy or casadi for a right-hand side, so one function serves both."""

from __future__ import annotations

import types

import numpy as np


def is_symbolic(x) -> bool:
    """True when ``x`` is a casadi SX/MX/DM expression."""
    return type(x).__module__.startswith("casadi")


def ops(x) -> types.SimpleNamespace:
    """Elementary functions for the type of ``x``: numpy for arrays, casadi for symbols."""
    if is_symbolic(x):
        import casadi as ca

        return types.SimpleNamespace(sin=ca.sin, cos=ca.cos, tan=ca.tan, fabs=ca.fabs, sqrt=ca.sqrt,
                                     stack=lambda items: ca.vertcat(*items), mtimes=ca.mtimes)
    return types.SimpleNamespace(sin=np.sin, cos=np.cos, tan=np.tan, fabs=np.abs, sqrt=np.sqrt,
                                 stack=lambda items: np.array(items, dtype=float), mtimes=np.dot)
