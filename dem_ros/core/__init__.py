"""The numerical core: plant, reference model, controllers, estimator, scenarios, metrics.

Imports numpy, scipy and numba only; never a middleware (a test enforces it).

numba's on-disk cache does not notice when a kernel calls a function from
another file that has changed, so the cache lives in a directory keyed by a
hash of this package's sources: any edit (or upgrade) starts a fresh cache.
``NUMBA_CACHE_DIR`` set by the user wins.
"""

import hashlib as _hashlib
import os as _os
from pathlib import Path as _Path


def _cache_dir() -> str:
    root = _Path(__file__).resolve().parent
    h = _hashlib.sha256()
    for f in sorted(root.rglob("*.py")):
        h.update(f.relative_to(root).as_posix().encode())
        h.update(f.read_bytes())
    base = _Path(_os.environ.get("XDG_CACHE_HOME", _Path.home() / ".cache")) / "dem_ros"
    return str(base / f"numba-{h.hexdigest()[:16]}")


if "NUMBA_CACHE_DIR" not in _os.environ:
    _os.environ["NUMBA_CACHE_DIR"] = _cache_dir()
    try:  # numba already imported by the user: set its config too
        import numba as _numba

        _numba.config.CACHE_DIR = _os.environ["NUMBA_CACHE_DIR"]
    except Exception:  # pragma: no cover
        pass
