"""Error classes: one per stage, all deriving from :class:`VesselidError`.

Every error message names what was expected and what was found, so the CLI can print it as
``error: <message>`` without a traceback.
"""

from __future__ import annotations


class VesselidError(Exception):
    """Base class of every error the pipeline raises on bad input or a failed stage."""


class ConfigError(VesselidError):
    """A vessel config or trial manifest is malformed (unknown key, wrong type, missing value)."""


class IngestError(VesselidError):
    """A log file cannot be read: empty, truncated, wrong format, missing channels."""


class AlignError(VesselidError):
    """Raw logs cannot be put on one clock (non-monotonic time, no overlap, no usable channel)."""


class SegmentError(VesselidError):
    """Segments cannot be detected or a manifest segment does not fit the trial."""


class FitError(VesselidError):
    """A fit cannot be made (segment too short, no excitation, non-convergence)."""


class OutputError(VesselidError):
    """An output file or folder cannot be written (names the path and why)."""


class ReportError(VesselidError):
    """A report cannot be written."""


class AutopilotError(VesselidError):
    """An autopilot configuration cannot be built from the given coefficients."""


class DiagnoseError(VesselidError):
    """A diagnosis cannot be made from the given trial and fits."""


class SimError(VesselidError):
    """A simulation or log-writing request is malformed."""
