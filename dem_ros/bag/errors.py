"""The error class of :mod:`dem_ros.bag`."""

from __future__ import annotations

__all__ = ["BagError"]


class BagError(Exception):
    """A bag could not be written, read or understood.

    The message says which path and, where it applies, which byte offset,
    topic or record is at fault; it is meant to be printed as is, without a
    traceback.
    """
