"""The export package's error."""

from ..errors import VesselidError


class ExportError(VesselidError):
    """An identified model cannot be exported: names what was expected and what was found."""
