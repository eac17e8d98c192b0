"""User-facing tools: the ``dem-ros`` CLI, report, benchmarks, launcher, replay."""

from ..core.numba_cache import configure as _configure_numba_cache

_configure_numba_cache()  # the CLI process, and through its environment the node processes it launches
