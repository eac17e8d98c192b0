"""Where numba keeps its compiled kernels: one directory per version of the kernels' sources.

numba's on-disk cache does not notice when a kernel calls a function from
another file that has changed, so the cache lives in a directory keyed by a
hash of the sources of the core and the board (dem_ros/board): any edit (or upgrade) starts a
fresh cache.

The library does not touch the process environment on import. The
applications do, once, before any kernel is compiled: the ``dem-ros`` CLI
(``dem_ros.tools``) and every node process (``dem_ros.nodes``) call
:func:`configure`; the CLI sets it in its environment, so the node processes it
launches inherit the same directory and load the kernels compiled once, instead
of each compiling them. ``NUMBA_CACHE_DIR`` set by the user wins.
"""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path

__all__ = ["cache_dir", "configure"]


def cache_dir() -> str:
    """``$XDG_CACHE_HOME/dem_ros/numba-<hash of dem_ros/{core,board}/**.py>`` (default ``~/.cache``)."""
    pkg = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for root in (pkg / "core", pkg / "board"):  # every source of a compiled kernel
        for f in sorted(root.rglob("*.py")):
            h.update(f.relative_to(pkg).as_posix().encode())
            h.update(f.read_bytes())
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "dem_ros"
    return str(base / f"numba-{h.hexdigest()[:16]}")


def configure() -> str:
    """Point numba (and child processes) at :func:`cache_dir` unless ``NUMBA_CACHE_DIR`` is set;
    returns the directory."""
    if "NUMBA_CACHE_DIR" not in os.environ:
        os.environ["NUMBA_CACHE_DIR"] = cache_dir()
    numba = sys.modules.get("numba")
    if numba is not None:  # already imported: its config was read at import
        numba.config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]
    return os.environ["NUMBA_CACHE_DIR"]
