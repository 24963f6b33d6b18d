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

import numpy as np

from ..atomic import atomic_write_text
from ..parallel import ordered_map
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
           "latex_tables", "markdown_tables", "plot_segment_fit", "plot_trial_overview", "FigureJob", "FigureInputs",
           "figure_plan", "draw_figure"]

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


@dataclass(frozen=True)
class FigureJob:
    """One report figure: the fit or residual-analysis figure of a segment fit, or the trial overview.

    Attributes
    ----------
    kind : str
        ``fit``, ``resid`` or ``overview``.
    index : int
        Position of the fit in ``Fits.segment_fits`` (-1 for the overview).
    name : str
        File name in the report folder.
    """

    kind: str
    index: int
    name: str


@dataclass(frozen=True)
class FigureInputs:
    """What the report's figures are drawn from (every :class:`FigureJob` reads it).

    Attributes
    ----------
    fits : Fits
        Fit results.
    qualities : sequence of SegmentQuality
        Per segment fit (:func:`pipeline.report.quality.segment_quality`), residual tests included.
    trial : Trial or None
        For the overview.
    segments : tuple of Segment
        Shaded in the overview.
    out : pathlib.Path
        Report folder.
    """

    fits: Fits
    qualities: Sequence
    trial: Trial | None
    segments: tuple[Segment, ...]
    out: Path


def figure_plan(fits: Fits, qualities: Sequence, trial: Trial | None) -> tuple[FigureJob, ...]:
    """The figures a report draws, in the order they are listed: per drawn fit (at most
    ``MAX_FIT_FIGURES``, :func:`pipeline.report.figures.figure_selection`) its fit figure and, when it has
    a residual test, its residual-analysis figure; then the overview when a trial is given.

    Parameters
    ----------
    fits : Fits
        Fit results.
    qualities : sequence of SegmentQuality
        Per segment fit, in the same order.
    trial : Trial or None
        The trial (the overview is drawn only with one).
    """
    drawn = set(figure_selection(fits.segment_fits, [q.fit_percent for q in qualities],
                                 report_figures.MAX_FIT_FIGURES))
    jobs: list[FigureJob] = []
    for i, (sf, q) in enumerate(zip(fits.segment_fits, qualities)):
        if i not in drawn:
            continue
        jobs.append(FigureJob("fit", i, fit_figure_name(i, sf)))
        if q.resid is not None:
            jobs.append(FigureJob("resid", i, resid_figure_name(i, sf)))
    if trial is not None:
        jobs.append(FigureJob("overview", -1, OVERVIEW_NAME))
    return tuple(jobs)


def draw_figure(inputs: FigureInputs, job: FigureJob) -> Path:
    """Draw one report figure and write it into ``inputs.out`` (atomically).

    Parameters
    ----------
    inputs : FigureInputs
        What it is drawn from.
    job : FigureJob
        Which figure.

    Returns
    -------
    pathlib.Path
        The file written.
    """
    if job.kind == "fit":
        fig = plot_segment_fit(inputs.fits.segment_fits[job.index], index=job.index)
    elif job.kind == "resid":
        fig = plot_residual_analysis(inputs.qualities[job.index].resid, index=job.index)
    elif job.kind == "overview":
        fig = plot_trial_overview(inputs.trial, inputs.segments)
    else:
        raise ReportError(f"figure {job.name}: expected kind fit, resid or overview, found {job.kind!r}")
    return save_figure(fig, inputs.out / job.name)


def write_report(fits: Fits, out_dir: str | os.PathLike, trial: Trial | None = None,
                 segments: Segments | Sequence[Segment] | None = None,
                 extra_sections: Sequence[tuple[str, str]] = (), *, diagnosis=None,
                 provenance: Provenance | None = None,
                 added_mass: Mapping[str, float] | None = None, jobs: int | None = None,
                 qualities: Sequence | None = None, figures_written: bool = False) -> ReportPaths:
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
    jobs : int, optional
        Worker processes that draw the figures (:func:`pipeline.parallel.worker_count`; 1: this
        process). The figures do not depend on it.
    qualities : sequence of SegmentQuality, optional
        Per segment fit, when the caller has them already (:func:`pipeline.report.quality.segment_quality`
        with the same ``trial``); computed otherwise.
    figures_written : bool
        The figures of :func:`figure_plan` are already in ``out_dir`` (drawn by the caller beside
        other outputs, as :func:`pipeline.flow.write_outputs` does): they are listed, not drawn again.

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

    if qualities is None:
        qualities = [segment_quality(sf, trial) for sf in fits.segment_fits]
    elif len(qualities) != len(fits.segment_fits):
        raise ReportError(f"qualities: expected one per segment fit ({len(fits.segment_fits)}), found {len(qualities)}")
    problems = []
    for i, sf in enumerate(fits.segment_fits):
        problem = figure_problem(sf)
        # A failed fit that kept no samples has nothing to draw; its failure is already a warning.
        if problem and not (not sf.success and np.size(sf.t) == 0):
            problems.append(f"figure {fit_figure_name(i, sf)}: {problem}")
    plan = figure_plan(fits, qualities, trial)
    if figures_written:
        written = [out / job.name for job in plan]
    else:
        # Each figure on its own (worker processes when the cores allow), in plan order.
        written = ordered_map(draw_figure, plan, context=FigureInputs(fits, qualities, trial, segs, out), jobs=jobs)
    by_fit: dict[int, dict[str, str]] = {}
    for job in plan:
        by_fit.setdefault(job.index, {})[job.kind] = job.name
    fig_names = [(by_fit[i]["fit"], by_fit[i].get("resid")) if "fit" in by_fit.get(i, {}) else (None, None)
                 for i in range(len(fits.segment_fits))]
    fit_paths = [p for job, p in zip(plan, written) if job.kind != "overview"]
    overview = next((p for job, p in zip(plan, written) if job.kind == "overview"), None)
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
