"""vesselid: sea-trial logs -> hydrodynamic coefficients -> Kalman heading autopilot -> gap diagnosis.

Stages, one subpackage each, in flow order: ``ingest``, ``align``, ``segment``, ``fit``, ``report``,
``autopilot``, ``diagnose``; ``sim`` writes synthetic trials in every format ``ingest`` reads.
Records passed between stages are in :mod:`pipeline.records`; the shared model right-hand sides in
:mod:`pipeline.model`.
"""

__version__ = "0.1.0"
