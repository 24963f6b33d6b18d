"""benchmarks/independent.py's coverage table: per row and pooled, covered / count with its Clopper-Pearson
interval and the z rms (no simulator needed: rows built from summarised estimates)."""

from __future__ import annotations

import math

import pytest

from benchmarks import independent as bench


def test_clopper_pearson_matches_the_exact_binomial_tails():
    from scipy import stats

    lo, hi = bench.clopper_pearson(18, 20)
    # The exact interval's ends: P(X >= 18 | lo) = 0.025 and P(X <= 18 | hi) = 0.025.
    assert stats.binom.sf(17, 20, lo) == pytest.approx(0.025, rel=1e-6)
    assert stats.binom.cdf(18, 20, hi) == pytest.approx(0.025, rel=1e-6)
    # 20 / 20 cannot rule out 95 %: its lower end is 0.025 ** (1 / 20) = 83.2 %.
    lo, hi = bench.clopper_pearson(20, 20)
    assert hi == 1.0 and lo == pytest.approx(0.025 ** (1 / 20))
    assert bench.clopper_pearson(0, 5)[0] == 0.0
    assert all(math.isnan(x) for x in bench.clopper_pearson(0, 0))


def _row(ship, covered_k, z_k, covered_t=(0, 0), z_t=()):
    return {"ship": ship, "man": "steps", "rudder": "measured", "waves": "no",
            "covered": {"K": list(covered_k), "T": list(covered_t)}, "z": {"K": list(z_k), "T": list(z_t)}}


def test_coverage_table_flags_a_row_only_where_its_interval_excludes_95_and_pools_the_rows():
    rows = [_row("a", (20, 20), [0.2] * 20),             # a bound: covers all, z rms 0.2, not flagged
            _row("b", (12, 20), [3.0] * 8 + [0.5] * 12),  # misses: 60 % (36-81), flagged below
            _row("c", (0, 0), [])]                        # nothing marked success
    lines = bench.coverage_table(rows)
    a, b, c, pooled = lines[-4:]
    assert "20/20 (83-100) | 0.20" in a and "**" not in a
    assert "12/20 (36-81) **below 95**" in b
    assert "| c | steps | measured | no | - | - |" in c
    zr = math.sqrt((20 * 0.04 + 8 * 9 + 12 * 0.25) / 40)
    assert pooled.startswith("| all rows |") and f"32/40 (" in pooled and f"{zr:.2f}" in pooled
    assert "**below 95**" in pooled


def test_summarise_records_coverage_and_z_of_the_estimates_marked_success():
    truth = {"K": 0.1, "T": 10.0, "attainable": []}

    def run(k, se, ok=True):
        est = {"value": k, "stderr": se, "ci": [k - 1.96 * se, k + 1.96 * se], "success": ok, "message": ""}
        return {"seed": 0, "vesselid": {"segments": [], "K": est, "T": None}, "oe": [math.nan, math.nan]}

    r = bench.summarise({"ship": "s", "man": "steps", "rudder": "measured", "waves": "no", "truth": truth,
                         "runs": [run(0.101, 0.001), run(0.105, 0.001), run(0.2, 0.001, ok=False)]})
    assert r["covered"]["K"] == [1, 2] and r["covered"]["T"] == [0, 0]
    assert r["z"]["K"] == pytest.approx([1.0, 5.0])
