"""The lab's regression suite: simulate the sample vessel, write real log files, read them back
through the readers a user's file would take, run the real pipeline, and recover the truth.

Truth is the simulator's own configuration (vessel_configs/aauship.toml): D diagonal and the
rudder's yaw moment, so Nomoto K = yaw_moment / D_r and T = Izz / D_r.
"""

from __future__ import annotations


import numpy as np
import pytest

from pipeline.fit import fit_trial
from pipeline.flow import load_trial, segment_trial
from pipeline.sim.writers import write_log

from conftest import AAUSHIP as VESSEL
D = np.diag(VESSEL.damping)
TRUTH = {
    "X_u": -D[0], "Y_v": -D[1], "K_p": -D[2], "M_q": -D[3], "N_r": -D[4],
    "K_nomoto": VESSEL.rudder["yaw_moment"] / D[4],
    "T_nomoto": VESSEL.inertia[2] / D[4],
}

CASES = [("csv", level, seed) for level in ("low", "nominal", "high") for seed in (11, 12, 13)]
CASES += [("tlog", level, 21) for level in ("low", "nominal", "high")]


@pytest.fixture(scope="module")
def recovered(tmp_path_factory, sea_trial_sim):
    """``recovered(case)``: the fit of one (format, noise level, seed) case, run through a real file,
    computed once per worker. Each case is its own xdist group (``make test-ci`` runs this module with
    ``--dist loadgroup``), so the 12 cases split over the workers instead of one worker fitting all.
    Only the diagonal and Nomoto K, T are checked here, so the joint grey-box stage is not run
    (test_fit_greybox)."""
    cache = {}
    folder = tmp_path_factory.mktemp("regression")

    def get(case):
        if case not in cache:
            fmt, level, seed = case
            res = sea_trial_sim(level, seed)
            path = write_log(res.log, folder / f"trial_{level}_{seed}.{fmt}", vessel=VESSEL)
            trial = load_trial([path], VESSEL)
            segments = segment_trial(trial)
            cache[case] = fit_trial(trial, segments, VESSEL, extend=False)
        return cache[case]

    return get


def _case_id(case) -> str:
    return f"{case[0]}-{case[1]}-{case[2]}"


def _grouped(cases):
    """Each case as a pytest param in its own xdist group (one fit per case per worker)."""
    return [pytest.param(c, id=_case_id(c), marks=pytest.mark.xdist_group(_case_id(c))) for c in cases]


@pytest.mark.slow
@pytest.mark.parametrize("case", _grouped(CASES))
@pytest.mark.parametrize("name", sorted(TRUTH))
def test_recovers_truth_within_three_sigma(recovered, case, name):
    est = recovered(case).estimates[name]
    assert est.success, f"{name} not identified: {est.message}"
    err = est.value - TRUTH[name]
    assert abs(err) < 3 * est.stderr, (f"{name}: {est.value:.5g} +- {est.stderr:.2g}, truth {TRUTH[name]:.5g}, "
                                       f"error {err / est.stderr:.1f} sigma ({est.method})")
    lo, hi = est.ci95
    assert lo <= est.value <= hi


@pytest.mark.slow
@pytest.mark.parametrize("case", _grouped([c for c in CASES if c[1] in ("low", "nominal")]))
@pytest.mark.parametrize("name", sorted(TRUTH))
def test_within_two_percent_at_nominal_noise(recovered, case, name):
    est = recovered(case).estimates[name]
    rel = abs(est.value / TRUTH[name] - 1)
    assert rel < 0.02, f"{name}: {est.value:.5g} vs truth {TRUTH[name]:.5g} ({100 * rel:.2f}%)"


@pytest.mark.slow
@pytest.mark.xdist_group("csv-nominal-11")
def test_damping_matrix_holds_identified_diagonal(recovered):
    fits = recovered(("csv", "nominal", 11))
    dm = fits.damping_matrix
    assert dm.shape == (5, 5)
    np.testing.assert_allclose(np.diag(dm), D, rtol=0.02)
    assert np.all(np.diag(dm) > 0), "D holds positive damping (Fossen sign convention)"
