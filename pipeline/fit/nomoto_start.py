"""Closed-form start values of the whole-record Nomoto fit (integral regression on the heading)."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy.integrate import cumulative_trapezoid

from .nomoto_problem import Prepared


def guess_nomoto(t: np.ndarray, delta: np.ndarray, psi: np.ndarray, bias: bool = True) -> dict[str, float]:
    """Closed-form start for the first-order model by integral regression on the heading.

    Integrating ``T psi_ddot + psi_dot = K (delta - b)`` twice from 0 to t::

        int psi = -T psi(t) + T psi0 + (T r0 + psi0) t + K int int delta - (K b / 2) t^2

    is linear in ``(-T, T psi0, T r0 + psi0, K, -K b/2)``; the integrals average the noise, so
    a least-squares solve gives usable starts even under waves.

    Parameters
    ----------
    t : numpy.ndarray
        Uniform sample times [s].
    delta : numpy.ndarray
        Rudder angle [rad].
    psi : numpy.ndarray
        Heading [rad] (unwrapped, finite).
    bias : bool
        Include the rudder bias term.

    Returns
    -------
    dict
        ``K`` [1/s], ``T`` [s], ``b`` [rad], ``psi0`` [rad], ``r0`` [rad/s].
    """
    t = np.asarray(t, float) - float(t[0])
    psi = np.asarray(psi, float)
    delta = np.asarray(delta, float)
    h = float(t[1] - t[0])
    # The ZOH input integrated exactly: int delta is piecewise linear between samples.
    i1 = np.concatenate([[0.0], np.cumsum(delta[:-1]) * h])
    i2 = cumulative_trapezoid(i1, t, initial=0.0)
    ipsi = cumulative_trapezoid(psi, t, initial=0.0)
    cols = [psi, np.ones_like(t), t, i2] + ([t**2] if bias else [])
    c, *_ = np.linalg.lstsq(np.column_stack(cols), ipsi, rcond=None)
    T, K = -float(c[0]), float(c[3])
    duration = float(t[-1])
    if not (math.isfinite(T) and 2 * h < T < 50 * duration) or K == 0 or not math.isfinite(K):
        # Fall back to a mid-range time constant and the gain that fits best with it.
        T = max(duration / 5, 10 * h)
        cols = [np.ones_like(t), t, i2] + ([t**2] if bias else [])
        c2, *_ = np.linalg.lstsq(np.column_stack(cols), ipsi + T * psi, rcond=None)
        K = float(c2[2])
        c = np.array([-T, c2[0], c2[1], c2[2]] + ([c2[3]] if bias else []))
    psi0 = float(c[1]) / T
    r0 = (float(c[2]) - psi0) / T
    b = -2.0 * float(c[4]) / K if bias and K != 0 else 0.0
    return {"K": K, "T": T, "b": b if math.isfinite(b) else 0.0, "psi0": psi0, "r0": r0}


def first_order_start(preps: Sequence[Prepared], bias: bool,
                       channels: tuple[str, ...]) -> tuple[list[float], float, list[list[float]]]:
    """First-order start values shared by all records (medians of :func:`guess_nomoto`).

    Parameters
    ----------
    preps : sequence of Prepared
        Prepared records.
    bias : bool
        Estimate the rudder bias.
    channels : tuple of str
        Fitted outputs (the initial heading is a parameter only with ``psi``).

    Returns
    -------
    dyn : list of float
        ``[K, T]`` [1/s, s].
    b : float
        Rudder bias [rad].
    ics : list of list of float
        Initial states per record.
    """
    gs = []
    for prep in preps:
        t = np.arange(prep.u.size) * prep.h
        if "psi" in prep.y:
            m = prep.mask["psi"]
            psi = np.interp(t, t[m], prep.y["psi"][m])
            gs.append(guess_nomoto(t, prep.u, psi, bias))
        else:
            # Yaw rate only: integrate it into a heading and use the same regression.
            m = prep.mask["r"]
            r = np.interp(t, t[m], prep.y["r"][m])
            gs.append(guess_nomoto(t, prep.u, cumulative_trapezoid(r, t, initial=0.0), bias))
    K = float(np.median([g["K"] for g in gs]))
    T = float(np.median([g["T"] for g in gs]))
    b = float(np.mean([g["b"] for g in gs])) if bias else 0.0
    ics = []
    for g, prep in zip(gs, preps):
        ic = []
        if "psi" in channels:
            ic.append(g["psi0"])
        ic.append(g["r0"])
        ics.append(ic)
    return [K, T], b, ics
