"""The catalogue's HTML pages: an index of vessels and, per vessel, its trials and trend plots.

Each page is self-contained (figures embedded as PNG data URIs) except for the links to the
trials' own report folders, which are relative so the pages and reports can move together.
"""

from __future__ import annotations

import base64
import io
import math
import os
from pathlib import Path

import pandas as pd

from ..atomic import atomic_path
from ..text_format import esc, plus_minus
from .stats import coefficient_trend, plot_trend
from .store import Catalog

#: Most trend plots on one vessel page (coefficients identified in the most trials first).
MAX_TRENDS = 8
#: Coefficient columns in the trial table.
MAX_TABLE_COEFFICIENTS = 6

_STYLE = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
          "table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ccc;padding:3px 6px;text-align:right}"
          "th{background:#eee}td.l{text-align:left}.failed{background:#fdd}.sig{color:#b00;font-weight:bold}")


def _png(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def _page(title: str, body: str) -> str:
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{esc(title)}</title>"
            f"<style>{_STYLE}</style></head><body><h1>{esc(title)}</h1>{body}</body></html>\n")


def _write(path: Path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def _vessel_page(cat: Catalog, vessel: str, trials: pd.DataFrame, out_dir: Path) -> str:
    ids = trials["trial_id"].tolist()
    coefs = cat.query("SELECT trial_id, name, value, stderr, unit, success FROM coefficients WHERE success AND "
                      f"trial_id IN ({', '.join('?' * len(ids))})", ids) if ids else pd.DataFrame()
    counts = coefs.groupby("name").size().sort_values(ascending=False, kind="stable") if not coefs.empty else pd.Series()
    shown = list(counts.index[:MAX_TABLE_COEFFICIENTS])
    head = ["trial", "date (UTC, from the logs)", "place (lat, lon)", "status", "vesselid", "mode", "diagnosis"]
    head += [f"{c} [{coefs[coefs['name'] == c]['unit'].iloc[0]}]" for c in shown]
    diag = cat.query("SELECT trial_id, status, effect FROM diagnoses")
    diag = {r.trial_id: (r.effect or r.status) for r in diag.itertuples()}
    rows = []
    for t in trials.itertuples():
        link = esc(t.name)
        if isinstance(t.report_dir, str) and (Path(t.report_dir) / "report.html").exists():
            rel = os.path.relpath(Path(t.report_dir) / "report.html", out_dir)
            link = f"<a href='{esc(rel)}'>{esc(t.name)}</a>"
        date = "" if pd.isna(t.started_utc) else pd.Timestamp(t.started_utc).strftime("%Y-%m-%d %H:%M")
        place = "" if pd.isna(t.lat) else f"{t.lat:.4f}, {t.lon:.4f}"
        cells = [link, date, place, esc(t.status if t.status == "ok" else f"failed: {t.error}"),
                 esc(t.package_version), esc(str(t.mode or "")), esc(str(diag.get(t.trial_id, "")))]
        for c in shown:
            m = coefs[(coefs["trial_id"] == t.trial_id) & (coefs["name"] == c)]
            cells.append(plus_minus(m["value"].iloc[0], m["stderr"].iloc[0], sign=" ± ", missing="") if len(m) else "")
        cls = " class='failed'" if t.status != "ok" else ""
        rows.append(f"<tr{cls}>" + "".join(f"<td class='l'>{c}</td>" if i < 7 else f"<td>{c}</td>"
                                            for i, c in enumerate(cells)) + "</tr>")
    table = ("<table><tr>" + "".join(f"<th>{esc(h)}</th>" for h in head) + "</tr>" + "".join(rows) + "</table>")
    plots = []
    for c in [n for n in counts.index if counts[n] >= 3][:MAX_TRENDS]:
        for tr in coefficient_trend(cat, c, vessel):
            text = (f"drift {tr.slope:.4g} ± {tr.slope_se:.2g} {tr.unit} per {tr.x_unit} ({100 * tr.rel_slope:+.3g} ± "
                    f"{100 * tr.rel_slope_se:.2g} % per {tr.x_unit}), p = {tr.p_value:.3g}; x = {tr.x_label}; {tr.note}"
                    if math.isfinite(tr.slope) else tr.note)
            cls = " class='sig'" if tr.significant else ""
            plots.append(f"<h3>{esc(c)}</h3><p{cls}>{'significant drift: ' if tr.significant else ''}"
                         f"{esc(text)}</p><img src='data:image/png;base64,{_png(plot_trend(tr))}'>")
    return _page(f"vesselid catalogue: {vessel}",
                 f"<p>{len(trials)} trial(s); values ± standard error. Trend plots: coefficients identified in 3 or "
                 f"more trials, weighted straight-line drift, 95% band of the slope dotted.</p>{table}"
                 f"<h2>Trends</h2>{''.join(plots) or '<p>No coefficient is identified in 3 or more trials.</p>'}")


def write_catalog_pages(cat: Catalog, out_dir: str | Path) -> list[Path]:
    """Write ``index.html`` and one ``<vessel>.html`` per vessel into ``out_dir``.

    Parameters
    ----------
    cat : Catalog
        Open catalogue.
    out_dir : str or Path
        Folder for the pages (created).

    Returns
    -------
    list[Path]
        The pages written, index first.
    """
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    trials = cat.trials()
    trials["vessel_name"] = trials["vessel_name"].fillna("(unknown vessel)")
    written = []
    items = []
    for vessel, g in trials.groupby("vessel_name", sort=True):
        safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in vessel)
        page = out_dir / f"vessel-{safe}.html"
        _write(page, _vessel_page(cat, vessel, g, out_dir))
        written.append(page)
        n_ok = int((g["status"] == "ok").sum())
        items.append(f"<li><a href='{esc(page.name)}'>{esc(vessel)}</a>: {len(g)} trial(s), "
                     f"{n_ok} processed, {len(g) - n_ok} failed</li>")
    index = out_dir / "index.html"
    _write(index, _page("vesselid catalogue", f"<p>Catalogue {esc(str(cat.path))}.</p><ul>{''.join(items)}</ul>"))
    return [index] + written
