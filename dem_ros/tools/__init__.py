"""User-facing tools: the ``dem-ros`` CLI, report, benchmarks, launcher, replay."""
