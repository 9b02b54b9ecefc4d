"""The toolkit's exceptions.

Every error raised on bad input is a subclass of :class:`RadiolocError`, itself a
``ValueError``, and its message names the field, row or node at fault so that a user can
fix the input without reading a traceback.
"""

from __future__ import annotations


class RadiolocError(ValueError):
    """Base class of every error the toolkit raises on bad input or configuration."""


class InputError(RadiolocError):
    """A measurement, anchor or data file, or an array argument, is malformed.

    Examples: a missing column, text in a number column, a NaN or negative range, an
    unknown node or anchor id, duplicate anchor ids, an empty table, a wrong shape.
    """


class GeometryError(RadiolocError):
    """The geometry cannot determine a position: too few anchors, coincident nodes,
    collinear anchors, a singular information matrix.

    Batched estimators pass ``index``, the batch index of the first failing problem,
    ``detail``, the reason without it, so that a caller can name its own row or node, and
    ``anchors``, the indices of the anchors the reason is about (where it names some).
    """

    def __init__(self, message: str, *, index: tuple[int, ...] | None = None,
                 detail: str | None = None, anchors: tuple[int, ...] | None = None) -> None:
        super().__init__(message)
        self.index = index
        self.detail = detail if detail is not None else message
        self.anchors = anchors


class ConfigError(RadiolocError):
    """An experiment or estimator parameter is out of its valid range."""


class OutputError(RadiolocError):
    """An output file or folder cannot be written: ``--out`` names a folder where a file
    is expected (or the reverse), a path below a file, a read-only place or a full device.

    The message names the path and the reason (the operating system's, in words).
    """


class DataUnavailable(RadiolocError):
    """A real data set that an experiment needs is not on this machine.

    Experiments that need one raise it before running; the command line reports the
    experiment as skipped, with this message, rather than failing.
    """
