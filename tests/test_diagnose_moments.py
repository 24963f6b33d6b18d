"""The held input's block moments (:func:`pipeline.diagnose.problem.input_moments`) and their reuse."""

import numpy as np
import pytest

from pipeline.diagnose import problem
from pipeline.diagnose.problem import Window, input_moments


def _windows():
    return (Window(3, 3 + 7 * 4, 0.0, 1.0, ("step",), ("yaw",), "a"),
            Window(40, 40 + 5 * 4 + 3, 2.0, 3.0, ("step",), ("yaw",), "b"),
            Window(70, 72, 4.0, 4.1, ("step",), ("yaw",), "c"))


def _reference(u, windows, m, n):
    out = np.zeros((3, len(windows), n))
    for k, w in enumerate(windows):
        for b in range((w.i1 - w.i0) // m):
            seg = np.nan_to_num(u[w.i0 + b * m:w.i0 + (b + 1) * m], nan=0.0)
            lag = m - 1 - np.arange(m)
            out[:, k, b] = [seg.sum(), (seg * lag).sum(), (seg * lag**2).sum()]
    return out


def test_moments_match_their_definition_and_are_reused_only_for_the_same_array():
    rng = np.random.default_rng(3)
    u = rng.normal(size=100)
    u[45] = np.nan
    w = _windows()
    first = input_moments(u, w, 4, 7)
    np.testing.assert_allclose(first, _reference(u, w, 4, 7), rtol=1e-12, atol=1e-12)
    assert input_moments(u, w, 4, 7) is first  # the same array and windows: kept
    with pytest.raises(ValueError):
        first[0, 0, 0] = 1.0  # read-only, so a caller cannot spoil the kept result
    changed = u.copy()
    changed[5] += 1.0
    other = input_moments(changed, w, 4, 7)  # another array: computed afresh
    assert other is not first
    np.testing.assert_allclose(other, _reference(changed, w, 4, 7), rtol=1e-12, atol=1e-12)
    assert other[0, 0, 0] == pytest.approx(first[0, 0, 0] + 1.0)
    # Only window 0 differs, so only it was recomputed: the same bits as computed from scratch.
    problem._MOMENTS.clear()
    alone = input_moments(changed.copy(), w, 4, 7)
    assert np.array_equal(other.view(np.int64), alone.view(np.int64))
    assert problem._windows_differing(changed, u, w, 4) == [0]
    # Other windows or another block length: not the kept result either.
    assert input_moments(u, w[:2], 4, 7).shape == (3, 2, 7)
    np.testing.assert_allclose(input_moments(u, w, 2, 14), _reference(u, w, 2, 14), rtol=1e-12, atol=1e-12)
