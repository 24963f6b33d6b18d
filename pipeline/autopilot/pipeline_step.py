"""The autopilot stage inside ``vesselid run``: identified Nomoto model -> autopilot files + report section.

When the fit identified K and T the stage designs the PD gains and the Kalman filter, runs the
closed-loop check and writes ``autopilot.toml`` (and its companions) into the report folder. When
K or T is missing the report says why instead of leaving the section out.
"""

from __future__ import annotations

import html
from pathlib import Path
from typing import Iterable

from ..errors import AutopilotError
from .section import autopilot_html_section
from .stage import build_autopilot, nomoto_from_fits, write_autopilot_outputs

TITLE = "Heading autopilot and Kalman filter"
#: omega_c T of the ship-autopilot seed's design (0.1 rad/s for T = 72.4 s). Keeping the product
#: fixed gives a small, fast model ship the same loop shape instead of a crossover 30x too low.
SEED_CROSSOVER_T = 0.1 * 72.4


def autopilot_for_report(fits, vessel, out_dir: str | Path, manifest=None) -> Iterable[tuple[str, str]]:
    """Build and write the autopilot for ``fits``; return the report section(s).

    Parameters
    ----------
    fits : pipeline.records.Fits
        Fit-stage output (needs ``K_nomoto`` and ``T_nomoto``).
    vessel : pipeline.vessel.Vessel
        Vessel config ([rudder] limits; [nomoto] as the simulated truth when given).
    out_dir : str or Path
        Report folder; ``autopilot.toml`` and its companions are written there.
    manifest : pipeline.manifest.Manifest, optional
        Trial manifest; its ``[autopilot]`` table may set ``crossover`` [rad/s] and
        ``phase_margin_deg`` [deg].

    Returns
    -------
    list of (str, str)
        ``(title, html_fragment)`` for :func:`pipeline.report.write_report`.

    Notes
    -----
    Without a crossover in the manifest, ``omega_c = SEED_CROSSOVER_T / T``.
    """
    opts = dict((manifest.options.get("autopilot", {}) if manifest is not None else {}) or {})
    unknown = sorted(set(opts) - {"crossover", "phase_margin_deg"})
    if unknown:
        raise AutopilotError(f"manifest [autopilot]: unknown key(s) {unknown}; allowed: crossover, phase_margin_deg")
    try:
        coefficients = nomoto_from_fits(fits)
    except AutopilotError as exc:
        return [(TITLE, f"<p>No autopilot was designed: {html.escape(str(exc))}</p>")]
    kwargs = {"crossover": float(opts.get("crossover", SEED_CROSSOVER_T / coefficients.T))}
    if "phase_margin_deg" in opts:
        import math

        kwargs["phase_margin"] = math.radians(float(opts["phase_margin_deg"]))
    result = build_autopilot(coefficients, vessel=vessel, **kwargs)
    write_autopilot_outputs(result, out_dir)
    return [autopilot_html_section(result)]
