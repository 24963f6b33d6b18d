"""report stage: :class:`~pipeline.records.Fits` -> coefficient tables, figures and an HTML report.

:func:`write_report` writes, into one folder (created if missing, every file written atomically):

``coefficients.json``
    The contract other stages and scripts read back with :func:`load_coefficients`
    (structure in :mod:`pipeline.report.coefficients_json`).
``coefficients.tex``
    Booktabs tables ``tab:coefficients`` and ``tab:damping`` (AAUSHIP seed style).
``coefficients.md``
    The same tables as GitHub pipe tables.
``fit_<index>_<kind>_<dof>.png``, ``resid_<index>_<kind>_<dof>.png``
    Per segment fit: data, fit and residual; residual autocorrelation and input cross-correlation.
    At most ``MAX_FIT_FIGURES`` fits are drawn (failed fits, then the worst and best of each
    segment kind in turn: :func:`pipeline.report.figures.figure_selection`); every fit is in the
    quality table.
``segments.png``
    Trial overview with the segments shaded (only when a trial is given).
``report.html``
    One self-contained page (the PNGs embedded): summary, contents, warnings and notes, then the
    sections in flow order and a footer with version, date, command and input hashes.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

from ..atomic import atomic_write_text
from ..errors import ReportError
from ..records import Fits, Provenance, Segment, Segments, Trial
from . import figures as report_figures
from .coefficients_json import damping_from_dict, fits_to_dict, load_coefficients, write_coefficients_json
from .figures import (OVERVIEW_NAME, figure_problem, figure_selection, fit_figure_name,
                      plot_residual_analysis, plot_segment_fit, plot_trial_overview, resid_figure_name, save_figure)
from .html import check_extra_sections, embed_images, render_html
from .quality import segment_quality
from .rows import check_fits, segment_list
from .summary import diagnosis_headline, findings, summary_rows
from .tables import latex_tables, markdown_tables

__all__ = ["ReportPaths", "write_report", "fits_to_dict", "load_coefficients", "damping_from_dict",
           "latex_tables", "markdown_tables", "plot_segment_fit", "plot_trial_overview"]

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
        Per drawn segment fit, in ``Fits.segment_fits`` order: its fit PNG and its residual-analysis
        PNG (see ``MAX_FIT_FIGURES``).
    overview_figure : pathlib.Path or None
        Trial overview PNG; None when no trial was given.
    warnings, notes : tuple[str, ...]
        What the report lists as warnings (act on them) and notes.
    """

    out_dir: Path
    coefficients_json: Path
    coefficients_tex: Path
    coefficients_md: Path
    html: Path
    fit_figures: tuple[Path, ...] = ()
    overview_figure: Path | None = None
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()

    def moved_to(self, folder: Path) -> "ReportPaths":
        """The same files after the folder was renamed to ``folder`` (a staging folder swapped in).

        Parameters
        ----------
        folder : Path
            The new folder.
        """
        def mv(p: Path | None) -> Path | None:
            return None if p is None else folder / p.relative_to(self.out_dir)

        return ReportPaths(folder, mv(self.coefficients_json), mv(self.coefficients_tex), mv(self.coefficients_md),
                           mv(self.html), tuple(mv(p) for p in self.fit_figures), mv(self.overview_figure),
                           self.warnings, self.notes)

    @property
    def files(self) -> tuple[Path, ...]:
        """Every file written."""
        extra = (self.overview_figure,) if self.overview_figure is not None else ()
        return (self.coefficients_json, self.coefficients_tex, self.coefficients_md, self.html,
                *self.fit_figures, *extra)


def write_report(fits: Fits, out_dir: str | os.PathLike, trial: Trial | None = None,
                 segments: Segments | Sequence[Segment] | None = None,
                 extra_sections: Sequence[tuple[str, str]] = (), *, diagnosis=None,
                 provenance: Provenance | None = None,
                 added_mass: Mapping[str, float] | None = None) -> ReportPaths:
    """Write the coefficient contract, tables, figures and the self-contained HTML report.

    Parameters
    ----------
    fits : Fits
        Fit results; not modified.
    out_dir : str or os.PathLike
        Report folder; created if missing. Files of the same name are replaced atomically; other
        files in it are left alone (:func:`pipeline.flow.write_outputs` replaces a whole folder).
    trial : Trial, optional
        The trial the fits came from; adds ``segments.png``, a data-provenance section and the
        input cross-correlation of the residual analysis.
    segments : Segments or sequence of Segment, optional
        Segments for the overview and the segment table; by default the segments of
        ``fits.segment_fits``.
    extra_sections : sequence of (str, str)
        ``(title, html_fragment)`` pairs of the later stages (autopilot, diagnosis), in flow order.
    diagnosis : pipeline.diagnose.records.GapReport, optional
        For the summary's headline.
    provenance : Provenance, optional
        Version, date, command and input hashes for the footer.
    added_mass : Mapping[str, float], optional
        The vessel config's ``[added_mass]``; derivatives of DOFs without one are marked
        "added mass taken as zero". None: not known.

    Returns
    -------
    ReportPaths
        The files written.

    Raises
    ------
    ReportError
        When ``fits`` or ``extra_sections`` are malformed.
    OutputError
        When a file cannot be written.
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

    qualities = [segment_quality(sf, trial) for sf in fits.segment_fits]
    problems = []
    fit_paths, fig_names = [], []
    drawn = set(figure_selection(fits.segment_fits, [q.fit_percent for q in qualities],
                                 report_figures.MAX_FIT_FIGURES))
    for i, (sf, q) in enumerate(zip(fits.segment_fits, qualities)):
        name = fit_figure_name(i, sf)
        problem = figure_problem(sf)
        if problem:
            problems.append(f"figure {name}: {problem}")
        if i not in drawn:
            fig_names.append((None, None))
            continue
        fit_paths.append(save_figure(plot_segment_fit(sf, index=i), out / name))
        rname = None
        if q.resid is not None:
            rname = resid_figure_name(i, sf)
            fit_paths.append(save_figure(plot_residual_analysis(q.resid, index=i), out / rname))
        fig_names.append((name, rname))
    overview = None
    if trial is not None:
        overview = save_figure(plot_trial_overview(trial, segs), out / OVERVIEW_NAME)
    found = findings(fits, qualities, problems, added_mass)

    json_path = write_coefficients_json(fits, out / JSON_NAME)
    tex_path = atomic_write_text(out / TEX_NAME, latex_tables(fits, added_mass))
    md_path = atomic_write_text(out / MD_NAME, markdown_tables(fits, added_mass))
    page = render_html(fits, segments=segs, warnings=found.warnings, notes=found.notes, trial=trial,
                       extra_sections=extra, summary=summary_rows(fits, qualities),
                       headline=diagnosis_headline(diagnosis), qualities=qualities, fit_figures=fig_names,
                       overview=OVERVIEW_NAME if overview else None, added_mass=added_mass,
                       provenance=provenance)
    # Last, so every figure it embeds is already there.
    html_path = atomic_write_text(out / HTML_NAME, embed_images(page, out))
    return ReportPaths(out_dir=out, coefficients_json=json_path, coefficients_tex=tex_path,
                       coefficients_md=md_path, html=html_path, fit_figures=tuple(fit_paths),
                       overview_figure=overview, warnings=found.warnings, notes=found.notes)
