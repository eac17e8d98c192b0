"""The suite's own set-up (tests/conftest.py): the numba warm-up is keyed as numba keys its kernels."""

from __future__ import annotations

import hashlib
import importlib.util
import os
from pathlib import Path


def _conftest():
    """tests/conftest.py as a module of its own (the one pytest loaded is not importable by name)."""
    spec = importlib.util.spec_from_file_location("_suite_conftest", Path(__file__).with_name("conftest.py"))
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_warm_up_marker_is_per_checkout_as_numba_keeps_the_kernels(tmp_path, monkeypatch):
    """Review defect: the marker ``warmed-by-tests`` sat in NUMBA_CACHE_DIR, keyed by the core's source
    contents only, but numba keeps kernels per source *path*: after one checkout's suite ran, another
    checkout of the same version skipped the warm-up and its graph tests' node processes all compiled at
    once. The marker now carries the key warm_kernels and numba use (the core directory's absolute path)."""
    import numba

    import dem_ros.core
    import dem_ros.tools.common as common

    conf = _conftest()
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(numba.config, "CACHE_DIR", numba.config.CACHE_DIR)  # configure() sets it: restored after
    warmed: list[str] = []
    monkeypatch.setattr(common, "warm_kernels", lambda prefix, stream=None: warmed.append(dem_ros.core.__file__))
    here = dem_ros.core.__file__
    conf._fill_numba_cache()  # this checkout, a cache it has not filled: warmed
    conf._fill_numba_cache()  # filled: each process only loads
    assert len(warmed) == 1
    # another checkout of the same version: the same cache directory (same sources), other kernels
    monkeypatch.setattr(dem_ros.core, "__file__", str(tmp_path / "other" / "dem_ros" / "core" / "__init__.py"))
    conf._fill_numba_cache()
    assert len(warmed) == 2, "another checkout's warm-up was taken for this one's"
    conf._fill_numba_cache()
    assert len(warmed) == 2
    monkeypatch.setattr(dem_ros.core, "__file__", here)
    conf._fill_numba_cache()
    assert len(warmed) == 2  # the first checkout's marker is still there
    # the key is warm_kernels' (dem_ros/tools/common.py: numba's directory of this checkout's core kernels)
    core = os.path.abspath(os.path.join(os.path.dirname(common.__file__), os.pardir, "core"))
    assert conf.warm_marker(str(tmp_path)).name == f"warmed-by-tests-core_{hashlib.sha1(core.encode()).hexdigest()}"
