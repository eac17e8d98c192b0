"""The numerical core: plant, reference model, controllers, estimator, scenarios, metrics.

Imports numpy, scipy and numba only; never a middleware (a test enforces it).
Where numba caches the compiled kernels is the applications' choice:
:mod:`dem_ros.core.numba_cache`.
"""
