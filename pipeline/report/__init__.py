"""report stage: :class:`~pipeline.records.Fits` -> coefficient tables, figures and an HTML report.

:func:`write_report` writes, into one folder (created if missing, every file written atomically):

``coefficients.json``
    The contract other stages and scripts read back with :func:`load_coefficients`
    (structure in :mod:`pipeline.report.coefficients_json`).
``coefficients.tex``
    Booktabs tables ``tab:coefficients`` and ``tab:damping`` (AAUSHIP seed style).
``coefficients.md``
    The same tables as GitHub pipe tables.
``fit_<index>_<kind>_<dof>.png``
    One figure per segment fit: data, fit and residual.
``segments.png``
    Trial overview with the segments shaded (only when a trial is given).
``report.html``
    One page with all of the above, warnings, the segment table and sections from other stages.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from ..errors import ReportError
from ..records import CHANNEL_UNITS, Fits, Segment, Segments, Trial
from ._common import check_fits, finite, format_number, report_warnings, segment_list
from .atomic import atomic_write_bytes, atomic_write_text
from .coefficients_json import damping_from_dict, fits_to_dict, load_coefficients, write_coefficients_json
from .figures import (OVERVIEW_NAME, figure_problem, fit_figure_name, plot_segment_fit, plot_trial_overview,
                      save_figure)
from .html import check_extra_sections, render_html
from .tables import latex_tables, markdown_tables

__all__ = ["ReportPaths", "write_report", "fits_to_dict", "load_coefficients", "damping_from_dict",
           "latex_tables", "markdown_tables", "plot_segment_fit", "plot_trial_overview",
           "atomic_write_bytes", "atomic_write_text"]

JSON_NAME = "coefficients.json"
TEX_NAME = "coefficients.tex"
MD_NAME = "coefficients.md"
HTML_NAME = "report.html"


@dataclass(frozen=True)
class ReportPaths:
    """Files :func:`write_report` wrote.

    Attributes
    ----------
    out_dir : pathlib.Path
        The report folder.
    coefficients_json, coefficients_tex, coefficients_md, html : pathlib.Path
        Contract, LaTeX tables, Markdown tables, report page.
    fit_figures : tuple[pathlib.Path, ...]
        One PNG per segment fit, in ``Fits.segment_fits`` order.
    overview_figure : pathlib.Path or None
        Trial overview PNG; None when no trial was given.
    """

    out_dir: Path
    coefficients_json: Path
    coefficients_tex: Path
    coefficients_md: Path
    html: Path
    fit_figures: tuple[Path, ...] = ()
    overview_figure: Path | None = None

    @property
    def files(self) -> tuple[Path, ...]:
        """Every file written."""
        extra = (self.overview_figure,) if self.overview_figure is not None else ()
        return (self.coefficients_json, self.coefficients_tex, self.coefficients_md, self.html,
                *self.fit_figures, *extra)


def _fit_caption(index: int, sf) -> str:
    seg = sf.segment
    unit = CHANNEL_UNITS.get(sf.channel, "")
    rmse = f"RMSE {format_number(sf.rmse, 3)} {unit}".rstrip() if finite(sf.rmse) else "no RMSE"
    text = (f"fit {index}: {sf.model} fitted to {sf.channel} over the {seg.kind} segment in "
            f"{seg.dof} (t = {seg.t_start:.1f}-{seg.t_end:.1f} s, {seg.origin}). Top: data (points) "
            f"and fit (line); bottom: residual. {rmse}; angles are shown in degrees.")
    if not sf.success:
        text += f" The fit failed: {sf.message or 'no reason given'}."
    return text


def write_report(fits: Fits, out_dir: str | os.PathLike, trial: Trial | None = None,
                 segments: Segments | Sequence[Segment] | None = None,
                 extra_sections: Sequence[tuple[str, str]] = ()) -> ReportPaths:
    """Write the coefficient contract, tables, figures and HTML report for ``fits``.

    Parameters
    ----------
    fits : Fits
        Fit results; not modified.
    out_dir : str or os.PathLike
        Report folder; created if missing. Files of the same name are replaced atomically; other
        files in it are left alone.
    trial : Trial, optional
        The trial the fits came from; adds ``segments.png`` and a data-provenance section.
    segments : Segments or sequence of Segment, optional
        Segments for the overview and the segment table; by default the segments of
        ``fits.segment_fits``.
    extra_sections : sequence of (str, str)
        ``(title, html_fragment)`` pairs appended to ``report.html`` (autopilot, diagnosis).

    Returns
    -------
    ReportPaths
        The files written.

    Raises
    ------
    ReportError
        When ``fits`` or ``extra_sections`` are malformed or a file cannot be written.
    """
    check_fits(fits)
    extra = check_extra_sections(extra_sections)
    if trial is not None and not isinstance(trial, Trial):
        raise ReportError(f"trial: expected a pipeline.records.Trial or None, found {type(trial).__name__}")
    segs = segment_list(fits, segments)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ReportError(f"out_dir {out}: expected a folder, found a file")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ReportError(f"cannot create report folder {out}: {exc}") from exc

    warnings = list(report_warnings(fits))
    figures: list[tuple[str, str]] = []
    fit_paths = []
    for i, sf in enumerate(fits.segment_fits):
        name = fit_figure_name(i, sf)
        problem = figure_problem(sf)
        if problem:
            warnings.append(f"figure {name}: {problem}")
        fit_paths.append(save_figure(plot_segment_fit(sf, index=i), out / name))
        figures.append((name, _fit_caption(i, sf)))
    overview = None
    if trial is not None:
        overview = save_figure(plot_trial_overview(trial, segs), out / OVERVIEW_NAME)
        figures.insert(0, (OVERVIEW_NAME, f"trial {trial.name}: main channels with the {len(segs)} "
                                          f"segments shaded and numbered as in the segment table; "
                                          f"angles in degrees."))

    json_path = write_coefficients_json(fits, out / JSON_NAME)
    tex_path = atomic_write_text(out / TEX_NAME, latex_tables(fits))
    md_path = atomic_write_text(out / MD_NAME, markdown_tables(fits))
    # Last, so the page never links a figure that is not there yet.
    html_path = atomic_write_text(out / HTML_NAME, render_html(
        fits, figures=figures, segments=segs, warnings=warnings, trial=trial, extra_sections=extra))
    return ReportPaths(out_dir=out, coefficients_json=json_path, coefficients_tex=tex_path,
                       coefficients_md=md_path, html=html_path, fit_figures=tuple(fit_paths),
                       overview_figure=overview)
