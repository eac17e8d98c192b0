"""Fixtures of the bag tests live in bagutil (a unique module name: test dirs share no conftest)."""
from bagutil import *  # noqa: F403  (fixtures)
