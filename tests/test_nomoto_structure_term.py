"""The model-structure term when the first- and second-order values' difference is not measured.

Where the held-out errors leave the Nomoto structure undecided, the difference between the two
structures' K or T is added to the combined error (pipeline/fit/nomoto_structure.py ``StructureGap.term``).
Fitted with both structures on one segment only, that difference can be smaller than its own error:
PythonVehicleSimulator's tanker at 20 m, commanded rudder steps, seed 5 of 0-7, T +0.31 +- 2.3 s, and T
-4.3 +- 7.1 % was marked success with the 0.31 s as its term. The per-segment values below are that seed's.
"""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from pipeline.fit.nomoto_quality import judge_nomoto
from pipeline.fit.nomoto_structure import STRUCTURE_TERM_PREFIX, structure_gaps, structure_term_notes
from pipeline.fit.segment_fit import failed_segment_fit
from pipeline.records import Estimate, Segment

#: Seed 5's five successful steps: K [1/s], its error, T [s], its error; levels before and after [deg].
STEPS = [(-0.00582, 2e-5, 8.964, 1.024, 0, 10), (-0.00573, 2e-5, 9.194, 0.849, 10, 0),
         (-0.00584, 2e-5, 8.247, 0.882, 0, -10), (-0.00562, 4e-5, 9.230, 0.855, -10, 0),
         (-0.00581, 5e-5, 9.006, 1.823, 0, 5)]
#: The one segment fitted with both structures: K and T, first order then second, each with its error.
PAIR = {"K": (-0.005731, 2.2e-5, -0.005707, 3.1e-5), "T": (9.194, 0.849, 9.502, 2.14)}
#: The linearisation's T (first-order equivalent T1 + T2 - T3) [s].
T_TRUE = 9.3205


def _step_fit(k, sk, t, st, before, after, message):
    seg = Segment("rudder_step", "yaw", 0.0, 500.0, "delta", math.radians(before), math.radians(after))
    return replace(failed_segment_fit(seg, "nomoto_oe", "", ""), success=True, params={"K": k, "T": t},
                   stderr={"K": sk, "T": st}, message=message)


def test_a_structure_difference_below_its_error_gives_that_error_as_the_term():
    gaps = {g.name: g for g in structure_gaps([PAIR])}
    t_gap = gaps["T"]
    assert t_gap.diff == pytest.approx(0.308, abs=1e-3) and t_gap.diff_se == pytest.approx(2.30, abs=0.01)
    assert t_gap.term == pytest.approx(t_gap.diff_se)
    # A difference above its error stays the term.
    measured = structure_gaps([{"T": (10.70, 0.10, 9.00, 0.20)}])[0]
    assert measured.term == pytest.approx(1.70)
    notes = structure_term_notes(gaps.values(), "weak", "the held-out segments do not decide between the structures")
    assert any(n.startswith(f"{STRUCTURE_TERM_PREFIX} T: +-2.3") for n in notes), notes

    fits = [_step_fit(*s, message="; ".join(["OE"] + notes)) for s in STEPS]
    est = {"K_nomoto": Estimate("K_nomoto", -0.0057659, 2.186e-4, (-0.0062, -0.0053), "1/s", 5, "m",
                                per_segment=tuple(s[0] for s in STEPS)),
           "T_nomoto": Estimate("T_nomoto", 8.920, 0.5895, (7.76, 10.08), "s", 5, "m",
                                per_segment=tuple(s[2] for s in STEPS))}
    out = judge_nomoto(est, fits)
    t = out["T_nomoto"]
    # T's structure effect is not measured: the 95 % interval spans about +-50 %, and T is unsure.
    assert t.stderr == pytest.approx(math.hypot(0.5895, t_gap.diff_se), rel=1e-3)
    assert t.ci95[0] < T_TRUE < t.ci95[1]
    assert not t.success and "relative standard error" in t.message, t.message
    # K's difference (+2.4e-5 +- 3.8e-5) is below its error too, but that error is a sixth of K's own.
    assert out["K_nomoto"].success, out["K_nomoto"].message
