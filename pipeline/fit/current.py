"""Is a water current the larger misfit of a damping fit on speed over ground?

A speed from GNSS is speed over ground: speed through the water plus the current along the
track. The damping model describes the speed through the water, so a current shows up as a
constant offset per segment (a coast-down that levels off at the current instead of at rest).
When the surge or sway channel is over ground, the damping structure is also fitted with one
constant offset per segment (:func:`pipeline.fit.structure.select_structure` with ``drift=True``)
and the held-out errors are compared: if the offsets lower the linear model's error more than the
damping structure does, the fit says so, with both numbers, since the coefficients then carry the
current's imprint (the CE6 coast-downs: -25 % with the offsets against -9 % for the quadratic
structure).
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

from ..records import StructureChoice, Trial
from .quadratic import decimate_records, fit_dof

#: Held-out error reduction by the offsets above which the fit names the current [-].
CURRENT_SHRINK = 0.05
#: DOFs whose velocity over ground differs from the velocity through the water by the current.
CURRENT_DOFS = ("surge", "sway")


def over_ground(trial: Trial, channel: str) -> bool:
    """Whether ``channel`` is a velocity over ground: ``sog``, or ``u``/``v`` that the aligner
    derived from speed and course over ground.

    Parameters
    ----------
    trial : Trial
        The trial (its notes say what the aligner derived).
    channel : str
        The fitted channel.
    """
    if channel.split("@")[0] == "sog":
        return True
    return channel in ("u", "v") and any("u, v over ground" in n for n in trial.notes)


def current_note(choice: StructureChoice, drifted: StructureChoice) -> str:
    """The note when per-segment offsets (a current) explain more of the held-out error than the
    damping structure; empty otherwise.

    Parameters
    ----------
    choice : StructureChoice
        The fit without offsets.
    drifted : StructureChoice
        The same records fitted with one offset per segment.
    """
    lin = choice.heldout_rmse.get("linear", math.nan)
    sel = choice.heldout_rmse.get(choice.selected, math.nan)
    best = drifted.heldout_rmse.get(drifted.selected, math.nan)
    if not all(math.isfinite(x) for x in (lin, sel, best)) or lin <= 0:
        return ""
    by_structure = 1.0 - sel / lin
    by_current = 1.0 - best / lin
    if by_current < CURRENT_SHRINK or by_current <= by_structure:
        return ""
    return (f"unsure: the {choice.dof} speed is over ground, and a constant current along the track per segment "
            f"lowers the held-out error by {by_current:.0%} ({lin:.3g} -> {best:.3g}, {drifted.selected} structure) "
            f"against {max(by_structure, 0.0):.0%} by the {choice.selected} structure without it: the larger misfit is "
            f"the current, which the damping model has no term for (log the speed through the water, or run "
            f"the coast-downs both ways along the current); with the offsets the "
            f"{drifted.selected} structure is chosen")


def check_current(trial: Trial, records: Sequence, dof: str, dt: float, mass: float, choice: StructureChoice,
                  select: Callable[..., StructureChoice], steady: Sequence = ()) -> str:
    """:func:`current_note` for a DOF fitted on speed over ground (empty for others or a forced
    linear structure, which has no held-out errors).

    Parameters
    ----------
    trial : Trial
        The trial.
    records : Sequence[DofRecord]
        The DOF's records.
    dof : str
        DOF name.
    dt : float
        Sample interval of the records [s].
    mass : float
        ``M_ii`` [kg] (NaN: normalised fit).
    choice : StructureChoice
        The fit without offsets.
    select : callable
        :func:`pipeline.fit.structure.select_structure` (passed in: that module calls this one).
    steady : Sequence[SteadyPoint]
        Steady points of the DOF.
    """
    if dof not in CURRENT_DOFS or not records or not over_ground(trial, records[0].channel):
        return ""
    if not math.isfinite(choice.heldout_rmse.get("quadratic", math.nan)):
        return ""
    # Cheap gate before the held-out scoring: offsets that do not lower the in-sample error of the
    # linear fit by CURRENT_SHRINK will not lower its held-out error by that much either.
    recs, dt_fit, _ = decimate_records(records, dt, dof)
    lin = choice.fits["linear"]
    with_offsets = fit_dof(recs, dof, dt_fit, mass, "linear", steady, drift=True)
    if not (lin.rmse > 0 and 1.0 - with_offsets.rmse / lin.rmse >= CURRENT_SHRINK):
        return ""
    drifted = select(records, dof, dt, mass, "auto", steady, drift=True)
    return current_note(choice, drifted)
