"""Does a damping fit miss a fast change at the start of its segments?

The joint damping fit (:mod:`pipeline.fit.quadratic`) simulates each segment from its start with
the logged input. When the input change that starts a segment is not logged (a throttle cut found
from the speed alone, as in the CE6 coast-downs) or the segment starts a little off the change,
the first moments of the record hold a fast change that no damping structure describes: the CE6
boats lose about 1 m/s in the first second after the cut. That misfit then sits in the first
second of every segment, and the damping terms are a compromise between it and the rest.

:func:`start_transient_note` compares the fit's mean squared (noise-weighted) residual in the first
``START_WINDOW_S`` seconds of each record (at most ``MAX_WINDOW_SHARE`` of the record) with that of
the rest, pooled over the DOF's records; at ``START_RATIO`` times the rest or more the fit says so.
For white residuals of ``n`` start samples the ratio's spread is about ``sqrt(2 / n)``, so 4 is far
out of reach of noise (CE6: 20 samples per record at 20 Hz over 1-8 records); coloured residuals
(a navigation filter) widen it but not to 4x over a whole second of several records.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..records import StructureChoice
from .quadratic import SECOND_ORDER, decimate_records

#: Seconds at the start of each record that are compared with the rest [s].
START_WINDOW_S = 1.0
#: Largest share of a record taken as its start window [-].
MAX_WINDOW_SHARE = 0.2
#: Ratio of the start window's mean squared residual to the rest's at which the fit says so [-].
START_RATIO = 4.0


def start_misfit(choice: StructureChoice, records: Sequence, dt: float) -> tuple[float, float, float, float]:
    """Mean-square ratio of the selected fit's residuals at the records' start against the rest.

    Parameters
    ----------
    choice : StructureChoice
        The DOF's structure choice (its selected fit's ``y_fit``).
    records : Sequence[DofRecord]
        The records given to :func:`pipeline.fit.structure.select_structure` (decimated here the same way).
    dt : float
        Their sample interval [s].

    Returns
    -------
    tuple[float, float, float, float]
        Ratio [-], the start windows' share of the squared error [-], their share of the samples [-]
        and the window length [s]; NaN ratio when either part is empty.
    """
    fit = choice.fits[choice.selected]
    recs, dt_fit, _ = decimate_records(list(records), dt, choice.dof)
    early = rest = 0.0
    n_early = n_rest = 0
    window = START_WINDOW_S
    for r, yhat in zip(recs, fit.y_fit):
        e = ((np.asarray(r.y, float) - np.asarray(yhat, float)) / r.sigma)
        e = e[np.isfinite(e)]
        n = min(max(int(round(START_WINDOW_S / dt_fit)), 1), int(MAX_WINDOW_SHARE * e.size))
        if n < 1 or e.size - n < 1:
            continue
        window = min(window, n * dt_fit)
        early += float(np.sum(e[:n] ** 2))
        rest += float(np.sum(e[n:] ** 2))
        n_early += n
        n_rest += e.size - n
    if n_early == 0 or n_rest == 0 or rest <= 0:
        return math.nan, math.nan, math.nan, window
    ratio = (early / n_early) / (rest / n_rest)
    return ratio, early / (early + rest), n_early / (n_early + n_rest), window


def start_transient_note(choice: StructureChoice, records: Sequence, dt: float) -> str:
    """``unsure: ...`` when the first second of the DOF's segments holds a misfit ``START_RATIO`` times
    the rest's (first-order DOFs: coast-downs and steps); empty otherwise.

    Parameters
    ----------
    choice : StructureChoice
        The DOF's structure choice.
    records : Sequence[DofRecord]
        Its records (as given to the structure choice).
    dt : float
        Their sample interval [s].
    """
    if choice.dof in SECOND_ORDER or not records:
        return ""
    ratio, share, n_share, window = start_misfit(choice, records, dt)
    if not (math.isfinite(ratio) and ratio >= START_RATIO):
        return ""
    return (f"unsure: the first {window:.2g} s of the {choice.dof} segments holds {share:.0%} of the fit's squared "
            f"error in {n_share:.0%} of the samples ({ratio:.1f} times the rest): a fast change at the segment start "
            f"that the damping model does not describe (an input change that is not logged, such as a throttle cut "
            f"found from the speed alone, or a segment that starts off the change); the damping terms are a "
            f"compromise between it and the rest of the record")
