"""What the terminal shows: whether a progress bar is wanted (one rule for every stage).

Progress bars appear on an interactive terminal only; they stay quiet under CI (``CI`` set) and
when stderr is piped to a file. This module imports nothing from the package, so every stage
(the ingest readers included) can use it.
"""

from __future__ import annotations

import os
import sys


def show_progress() -> bool:
    """Progress bars on an interactive terminal only; quiet under CI and when piped."""
    return sys.stderr.isatty() and not os.environ.get("CI")


def want_progress(progress: bool | None, size: int | None = None, min_bytes: int = 0) -> bool:
    """Whether a reader shows a progress bar.

    Parameters
    ----------
    progress : bool or None
        The caller's choice; None means automatic (:func:`show_progress`).
    size : int, optional
        Size of the input [bytes]; with ``min_bytes``, an input this small reads too fast to need a bar.
    min_bytes : int
        Inputs of at most this many bytes show no bar in automatic mode [bytes].

    Returns
    -------
    bool
        True when a bar is to be shown.
    """
    if progress is not None:
        return bool(progress)
    if size is not None and size <= min_bytes:
        return False
    return show_progress()
