"""K from two sinusoids that fix the second order's four constants exactly carries a model-structure term
(pipeline.fit.nomoto_structure.exact_fit_k_term): tested with real joint fits of the project's linear
second-order ship (measured rudder) and of its first-order ship, which keeps its own error."""

from __future__ import annotations

import math

import pytest

from pipeline.fit.nomoto_quality import STRUCTURE_TERM
from test_fit_nomoto_structure import _fit_sine_pair

EXACT = "sinusoids fix the second order's constants exactly"


def test_k_of_an_exact_second_order_sinusoid_fit_carries_its_own_error_as_a_term():
    fits = _fit_sine_pair(order1=False, measured=True)
    k = fits.estimates["K_nomoto"]
    lead = next(sf for sf in fits.segment_fits if sf.segment.kind == "sinusoid")
    assert "T3" in lead.params
    notes = [p for p in lead.message.split("; ") if p.startswith(f"{STRUCTURE_TERM} K: +-") and EXACT in p]
    assert len(notes) == 1, lead.message
    term = float(notes[0].split("+-")[1].split(" ")[0])
    se = lead.stderr["K"]
    assert term == pytest.approx(se, rel=1e-4)
    # The combined error holds the term in quadrature (sqrt(2) times the fit's own), and the measured
    # rudder's timing term carried by K's slope on T (pipeline.fit.nomoto_quality.rudder_timing_term).
    from pipeline.fit.nomoto_quality import rudder_timing_term

    timing = rudder_timing_term([sf for sf in fits.segment_fits if sf.success and sf.segment.dof == "yaw"], "K")
    assert timing > 0
    assert k.stderr == pytest.approx(math.sqrt(se**2 + term**2 + timing**2), rel=1e-3)
    assert k.success and k.value == pytest.approx(0.09, rel=0.02), k.message


def test_first_order_sinusoids_get_no_exact_fit_term():
    fits = _fit_sine_pair(order1=True, measured=True)
    assert not any(EXACT in sf.message for sf in fits.segment_fits)
    assert fits.estimates["K_nomoto"].success
