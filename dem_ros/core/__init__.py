"""The numerical core: plant, reference model, controllers, estimator, scenarios, metrics.

Imports numpy, scipy and numba only; never a middleware (a test enforces it).
"""
