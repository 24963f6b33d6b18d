"""Write the autopilot stage's files: the config, the ArduPilot parameters, the closed-loop check, figures
and the report fragment (what the CLI and ``run`` call after :func:`pipeline.autopilot.design.build_autopilot`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Mapping

from ..atomic import atomic_write_bytes
from ..errors import AutopilotError
from ..records import AutopilotResult
from .config import write_ardupilot_params, write_autopilot_toml
from .figures import closed_loop_figure, wave_fit_figure
from .report_section import autopilot_html_section


def write_autopilot_outputs(result: AutopilotResult, out_dir: str | Path, toml_name: str = "autopilot.toml",
                            figures: bool = True) -> dict[str, Path]:
    """Write the stage's files into ``out_dir`` (:func:`write_autopilot_outputs_and_section` without the section).

    Parameters
    ----------
    result : AutopilotResult
    out_dir : str or Path
        Folder (created).
    toml_name : str
        File name of the config.
    figures : bool
        Write PNG figures.

    Returns
    -------
    dict
        File role -> path written.
    """
    return write_autopilot_outputs_and_section(result, out_dir, toml_name, figures)[0]


def write_autopilot_outputs_and_section(result: AutopilotResult, out_dir: str | Path,
                                        toml_name: str = "autopilot.toml", figures: bool = True
                                        ) -> tuple[dict[str, Path], tuple[str, str]]:
    """Write the stage's files into ``out_dir`` and return the report section they embed.

    The section is :func:`pipeline.autopilot.report_section.autopilot_html_section` with the figures
    just written (each closed-loop figure is drawn once, not again for the report page).

    Files: ``autopilot.toml``; ``ardupilot_steering.param``; with a closed-loop check
    ``closed_loop.json`` and, if ``figures``, ``closed_loop_<scenario>.png``; with a wave fit
    ``wave_fit.png``; and ``autopilot.html``, the report section as a standalone fragment.

    Parameters
    ----------
    result : AutopilotResult
    out_dir : str or Path
        Folder (created).
    toml_name : str
        File name of the config.
    figures : bool
        Write PNG figures.

    Returns
    -------
    written : dict
        File role -> path written.
    section : tuple of str
        ``(title, html_fragment)`` of the report page (``figures`` embedded when requested).
    """
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise AutopilotError(f"{out}: expected a writable output folder, found: {exc}") from None
    images: dict[str, bytes] = {}
    written = {"config": write_autopilot_toml(result.config, out / toml_name),
               "ardupilot": write_ardupilot_params(result.config, out / "ardupilot_steering.param")}
    if result.check is not None:
        doc = {"metrics": result.check.to_dict(),
               "observability": {k: {**v, "states": list(v["states"])} for k, v in result.observability.items()},
               "margins": [{**m, "phase_margin_deg": math.degrees(m["phase_margin"])} for m in result.margins]}
        p = out / "closed_loop.json"
        atomic_write_bytes(p, (json.dumps(_clean(doc), indent=2, allow_nan=False) + "\n").encode())
        written["closed_loop"] = p
        if figures:
            for s in result.check.scenarios:
                p = out / f"closed_loop_{s.name}.png"
                images[p.stem] = closed_loop_figure(result.check, s.name)
                atomic_write_bytes(p, images[p.stem])
                written[f"figure_{s.name}"] = p
    if result.wave_fit is not None and figures:
        p = out / "wave_fit.png"
        images[p.stem] = wave_fit_figure(result.wave_fit)
        atomic_write_bytes(p, images[p.stem])
        written["figure_waves"] = p
    title, frag = autopilot_html_section(result, figures=figures, images=images)
    p = out / "autopilot.html"
    atomic_write_bytes(p, f"<section>\n<h2>{title}</h2>\n{frag}\n</section>\n".encode())
    written["html"] = p
    return written, (title, frag)


def _clean(obj):
    """JSON has no NaN or infinity: they become null."""
    if isinstance(obj, Mapping):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, bool) or obj is None or isinstance(obj, (int, str)):
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    return _clean(float(obj))
