"""The catalogue's error class."""

from ..errors import VesselidError


class CatalogError(VesselidError):
    """A catalogue cannot be opened, migrated or queried, or a batch cannot start."""
