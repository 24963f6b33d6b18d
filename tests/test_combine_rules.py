"""The stated rules for combining per-segment values, side by side (benchmarks/independent.py measures their coverage)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.fit.combine import COMBINATION_RULES, Contribution, combination_rules, combine


@pytest.mark.parametrize("values", [[1.0, 1.01, 0.99, 1.02], [1.0, 1.1, 0.9, 1.3]])
def test_dersimonian_laird_rule_is_what_combine_reports(values):
    se = [0.01, 0.02, 0.01, 0.05]
    est = combine("K", "1/s", "m", [Contribution(v, s, f"s{i}") for i, (v, s) in enumerate(zip(values, se))])
    value, stderr, ci = combination_rules(values, se)["dersimonian_laird"]
    assert value == pytest.approx(est.value) and stderr == pytest.approx(est.stderr)
    assert ci == pytest.approx(est.ci95)


def test_rules_widen_with_the_spread_and_agree_on_one_segment():
    rules = combination_rules([1.0, 1.1, 0.9, 1.3], [0.01, 0.02, 0.01, 0.05])
    assert set(rules) == set(COMBINATION_RULES)
    fixed = rules["fixed_effect"][1]
    assert rules["birge_ratio"][1] > 3 * fixed and rules["dersimonian_laird"][1] > 3 * fixed
    lo, hi = rules["hartung_knapp"][2]
    assert hi - lo > 2 * 1.96 * rules["hartung_knapp"][1]  # t with 3 dof is wider than normal
    one = combination_rules([2.0, math.nan], [0.1, 0.1], dof=10)
    assert {v[0] for v in one.values()} == {2.0} and len({v[2] for v in one.values()}) == 1


def test_coverage_of_the_rules_under_a_between_segment_spread():
    # Segments scattered by tau beyond their own errors: the fixed-effect interval under-covers,
    # the random-effects and Hartung-Knapp ones come near 95 % (k = 6).
    rng = np.random.default_rng(0)
    hits = {r: 0 for r in COMBINATION_RULES}
    n = 400
    for _ in range(n):
        se = rng.uniform(0.01, 0.03, 6)
        x = 1.0 + 0.04 * rng.standard_normal(6) + se * rng.standard_normal(6)
        for r, (_, _, (lo, hi)) in combination_rules(x, se).items():
            hits[r] += lo <= 1.0 <= hi
    cover = {r: h / n for r, h in hits.items()}
    assert cover["fixed_effect"] < 0.6
    assert cover["hartung_knapp"] > 0.9 and cover["dersimonian_laird"] > 0.8


def test_values_from_overlapping_windows_are_combined_as_correlated():
    # Four estimates, each the mean of 100 white samples, consecutive windows sharing 50 samples
    # (rudder steps sharing the hold between them). Combined as independent, their mean's z spreads
    # by about 1.4 over draws; with the windows given, the correlated error of the mean holds it.
    from pipeline.fit.combine import overlap_correlation

    windows = [(50.0 * i, 50.0 * i + 100.0) for i in range(4)]
    rho = overlap_correlation(windows + [None])
    assert rho[0, 1] == pytest.approx(0.5) and rho[0, 2] == 0.0 and rho[0, 4] == 0.0 and rho[4, 4] == 1.0
    rng = np.random.default_rng(3)
    z_indep, z_windows = [], []
    for _ in range(800):
        samples = rng.standard_normal(250)
        values = [float(samples[50 * i:50 * i + 100].mean()) for i in range(4)]
        se = [0.1] * 4
        plain = combine("K", "1/s", "m", [Contribution(v, s, f"s{i}") for i, (v, s) in enumerate(zip(values, se))])
        with_w = combine("K", "1/s", "m", [Contribution(v, s, f"s{i}", window=w)
                                           for i, (v, s, w) in enumerate(zip(values, se, windows))])
        z_indep.append(plain.value / plain.stderr)
        z_windows.append(with_w.value / with_w.stderr)
    assert np.std(z_indep) > 1.25
    assert 0.93 < np.std(z_windows) < 1.07
    assert "share samples" in with_w.message and "overlapping windows correlated" in with_w.method


def test_prediction_error_keeps_the_spread_of_disagreeing_segments():
    # Segments that disagree beyond their errors: with prediction=True the combined error is
    # sqrt(se_re^2 + tau^2) (the spread is not averaged down by the number of segments); segments
    # that agree are combined as before.
    values, se = [1.0, 1.1, 0.9, 1.3, 1.05, 0.95], [0.01] * 6
    items = [Contribution(v, s, f"s{i}") for i, (v, s) in enumerate(zip(values, se))]
    plain = combine("K", "1/s", "m", items)
    pred = combine("K", "1/s", "m", items, prediction=True)
    rules = combination_rules(values, se)
    assert pred.value == pytest.approx(plain.value)
    assert pred.stderr == pytest.approx(rules["dl_prediction"][1])
    assert pred.stderr > 2 * plain.stderr and pred.stderr > 0.8 * np.std(values, ddof=1)
    assert "prediction error" in pred.method and "not averaged down" in pred.message
    agree = [Contribution(v, 0.1, f"s{i}") for i, v in enumerate(values)]
    assert combine("K", "1/s", "m", agree, prediction=True).stderr == pytest.approx(combine("K", "1/s", "m", agree).stderr)
