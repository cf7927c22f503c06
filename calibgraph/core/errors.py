"""Errors that calibgraph raises on purpose.

Every error carries one actionable sentence: what is wrong, where (file, camera, capture),
and what to do about it. The CLI prints the message and exits non-zero; it never shows a
traceback for these.
"""


class CalibgraphError(Exception):
    """Base class of every error calibgraph raises on purpose."""


class InputError(CalibgraphError, ValueError):
    """The input (dataset, pose, detection, spec) is malformed or inconsistent."""


class ObservabilityError(CalibgraphError):
    """The data cannot determine a parameter (too few views, degenerate motion).

    ``camera``: the camera concerned, when the cause is one camera's views (else None)."""

    def __init__(self, message: str = "", camera: str | None = None):
        super().__init__(message)
        self.camera = camera


class DetectionError(CalibgraphError):
    """An image could not be read or the target could not be found in it."""


class SolverError(CalibgraphError):
    """The optimiser could not produce a trustworthy estimate."""
