"""A damping fit says when the start of its segments holds a fast change the model does not describe
(a throttle cut that is not logged), and stays silent on records the model describes."""

from __future__ import annotations

import numpy as np

from pipeline.fit.quadratic import DofRecord
from pipeline.fit.start_transient import START_RATIO, start_misfit, start_transient_note
from pipeline.fit.structure import select_structure

DT = 0.05


def coasts(extra_drop: float, seed: int = 0) -> list[DofRecord]:
    """Two 15 s coast-downs (T = 6 s) at 20 Hz with 0.01 m/s noise; ``extra_drop`` [m/s] is lost in the
    first 0.5 s on top of the exponential (a fast transient after an unlogged cut)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, 15, DT)
    out = []
    for i, u0 in enumerate((2.0, 3.0)):
        y = u0 * np.exp(-t / 6.0) - extra_drop * np.minimum(t / 0.5, 1.0) * np.exp(-t / 6.0)
        out.append(DofRecord(f"coast {i}", "coast_down", y + rng.normal(0, 0.01, t.size), {}, 0.01, "rate", "sog"))
    return out


def test_fast_drop_after_the_cut_is_named():
    recs = coasts(0.8)
    choice = select_structure(recs, "surge", DT, float("nan"))
    ratio, share, n_share, window = start_misfit(choice, recs, DT)
    assert ratio >= START_RATIO and share > n_share
    note = start_transient_note(choice, recs, DT)
    assert note.startswith("unsure: the first 1 s of the surge segments holds"), note
    assert recs[0].y.size == 300  # records are not modified


def test_model_that_describes_the_records_gives_no_note():
    for seed in range(3):
        recs = coasts(0.0, seed)
        choice = select_structure(recs, "surge", DT, float("nan"))
        assert start_misfit(choice, recs, DT)[0] < 2.0
        assert start_transient_note(choice, recs, DT) == ""
