"""Norrbin (T r' + r + n3 r^3 = K delta) against the linear Nomoto model (pipeline.fit.norrbin)."""

import math

import numpy as np
import pytest

from pipeline.errors import FitError
from pipeline.fit.nomoto_records import NomotoRecord
from pipeline.fit.norrbin import select_norrbin
from pipeline.model.nomoto import NomotoParams, nomoto_rhs


def _simulate(K, T, n3, delta, h, sub=10):
    p = NomotoParams(K=K, T=T, n3=n3)
    x = np.zeros(2)
    out = np.empty((delta.size, 2))
    for j, d in enumerate(delta):
        out[j] = x
        hh = h / sub
        for _ in range(sub):
            k1 = nomoto_rhs(0, x, (d,), p)
            k2 = nomoto_rhs(0, x + hh / 2 * k1, (d,), p)
            k3 = nomoto_rhs(0, x + hh / 2 * k2, (d,), p)
            k4 = nomoto_rhs(0, x + hh * k3, (d,), p)
            x = x + hh / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return out


def _records(n3, seed, K=0.5, T=6.0, h=1.25):
    rng = np.random.default_rng(seed)
    out = []
    for deg in (10, 20, 35):
        t = np.arange(0, 70, h)
        amp = math.radians(deg)
        delta = np.where(t < 3, 0.0, np.where(t < 35, amp, -amp))
        x = _simulate(K, T, n3, delta, h)
        out.append(NomotoRecord(t=t, delta=delta, psi=x[:, 0] + rng.normal(0, math.radians(0.5), t.size),
                                r=x[:, 1] + rng.normal(0, math.radians(0.2), t.size), name=f"{deg} deg"))
    return out


def test_norrbin_selected_and_n3_recovered_on_norrbin_truth():
    ch = select_norrbin(_records(30.0, 0))
    f = ch.fits["norrbin"]
    assert ch.selected == "norrbin" and ch.significant
    assert abs(f.value("n3") - 30.0) < 3 * f.error("n3") and f.error("n3") < 3.0
    assert abs(f.value("K") - 0.5) < 3 * f.error("K")
    assert abs(f.value("T") - 6.0) < 3 * f.error("T")
    # The linear model's held-out error is far above the noise; Norrbin's is at the noise (weighted RMS ~ 1).
    assert ch.heldout_rmse["nomoto"] > 3 * ch.heldout_rmse["norrbin"]
    assert ch.heldout_rmse["norrbin"] < 1.5
    assert ch.nomoto_api.K > 0 and "n3 significant" in ch.message


def test_linear_nomoto_kept_on_linear_truth():
    ch = select_norrbin(_records(0.0, 1))
    f = ch.fits["norrbin"]
    assert ch.selected == "nomoto" and not ch.significant
    assert abs(f.value("n3")) < 3 * f.error("n3")
    lin = ch.fits["nomoto"]
    assert abs(lin.value("K") - 0.5) < 3 * lin.error("K") and abs(lin.value("T") - 6.0) < 3 * lin.error("T")
    assert lin.value("n3") == 0.0 and "not significant" in ch.message


def test_bad_model_name_and_no_records_are_clear_errors():
    with pytest.raises(FitError, match="expected one of"):
        select_norrbin(_records(0.0, 2)[:1], model="cubic")
    with pytest.raises(FitError, match="at least one record"):
        select_norrbin([])
