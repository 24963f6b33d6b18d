"""Many trials: a DuckDB catalogue, batch runs on Dask, comparisons and trends across trials.

``batch`` processes every trial manifest under a folder in parallel (:func:`run_batch`) and
stores each trial in the catalogue (:class:`Catalog`); :func:`compare_trials` and
:func:`coefficient_trend` read it back; :func:`write_catalog_pages` writes one HTML page per vessel.
"""

from .errors import CatalogError
from .schema import SCHEMA_VERSION, migrate
from .store import DEFAULT_CATALOG, Catalog
from .trial_job import TrialIdentity, TrialRecord, identify_trial, process_trial

__all__ = ["CatalogError", "SCHEMA_VERSION", "migrate", "DEFAULT_CATALOG", "Catalog", "TrialIdentity",
           "TrialRecord", "identify_trial", "process_trial"]
