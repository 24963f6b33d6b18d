"""Many trials: a DuckDB catalogue, batch runs on Dask, comparisons and trends across trials.

``batch`` processes every trial manifest under a folder in parallel (:func:`run_batch`) and
stores each trial in the catalogue (:class:`Catalog`); :func:`compare_trials` and
:func:`coefficient_trend` read it back; :func:`write_catalog_pages` writes one HTML page per vessel.
"""

from ..lazy import lazy_exports

#: Public name -> submodule defining it. Submodules load on first use (PEP 562), so that
#: ``vesselid --help`` and the ``catalog`` parser do not import Dask, DuckDB and scipy.stats.
_EXPORTS = {
    "BatchSummary": ".batch", "find_trials": ".batch", "run_batch": ".batch",
    "CatalogError": ".errors", "write_catalog_pages": ".html", "SCHEMA_VERSION": ".schema", "migrate": ".schema",
    "Trend": ".stats", "coefficient_trend": ".stats", "compare_trials": ".stats", "holm": ".stats",
    "plot_trend": ".stats", "DEFAULT_CATALOG": ".schema", "Catalog": ".store", "TrialIdentity": ".trial_job",
    "TrialRecord": ".trial_job", "identify_trial": ".trial_job", "process_trial": ".trial_job",
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
