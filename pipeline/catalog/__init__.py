"""Many trials: a DuckDB catalogue, batch runs on Dask, comparisons and trends across trials.

``batch`` processes every trial manifest under a folder in parallel (:func:`run_batch`) and
stores each trial in the catalogue (:class:`Catalog`); :func:`compare_trials` and
:func:`coefficient_trend` read it back; :func:`write_catalog_pages` writes one HTML page per vessel.
"""

from .batch import BatchSummary, find_trials, run_batch
from .errors import CatalogError
from .html import write_catalog_pages
from .schema import SCHEMA_VERSION, migrate
from .stats import Trend, coefficient_trend, compare_trials, holm, plot_trend
from .store import DEFAULT_CATALOG, Catalog
from .trial_job import TrialIdentity, TrialRecord, identify_trial, process_trial

__all__ = ["BatchSummary", "find_trials", "run_batch", "CatalogError", "write_catalog_pages", "SCHEMA_VERSION",
           "migrate", "Trend", "coefficient_trend", "compare_trials", "holm", "plot_trend", "DEFAULT_CATALOG",
           "Catalog", "TrialIdentity", "TrialRecord", "identify_trial", "process_trial"]
