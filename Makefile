# The quick-start commands: `make demo` (the main job), `make test` (`make test-fast`: the unit tier), `make report`,
# `make bench`.
# Each creates .venv and installs the package with its test extras when missing, then compiles the
# numba kernels once; every step prints a line at least every 5 s (a first run takes minutes).
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
PYTHON ?= python3

.PHONY: demo test test-fast bench report clean-venv

# pip -qq: errors only (setuptools' editable-install notice is nothing a user can act on); the background
# loop is the progress line that venv and pip do not give (it ends with the recipe's shell, Ctrl-C included)
$(STAMP): setup.py
	@echo "make: first run: creating $(VENV) and installing dem_ros with its test dependencies (numpy, scipy, numba, cyclonedds, ...)"
	@t0=$$(date +%s); me=$$$$; \
	( while sleep 5 && kill -0 $$me 2>/dev/null; do echo "make: setting up $(VENV) (pip installs from the package index; minutes) ... ($$(( $$(date +%s) - t0 )) s)"; done ) & beat=$$!; \
	{ echo "make: $(PYTHON) -m venv $(VENV)" && $(PYTHON) -m venv $(VENV) && \
	  echo "make: $(PY) -m pip install -qq -e '.[test]'" && \
	  $(PY) -m pip install -qq --upgrade pip && $(PY) -m pip install -qq -e '.[test]'; }; rc=$$?; \
	kill $$beat; \
	if [ $$rc -eq 0 ]; then echo "make: $(VENV) ready in $$(( $$(date +%s) - t0 )) s"; fi; exit $$rc
	@# compile the numba kernels once, here, with progress (demo, test and the nodes then load the cache),
	@# with the offline closed loop of the default laws (the demo compares its run with it). os._exit: the
	@# interpreter's teardown after a compile (numba's LLVM state) took 10-16 s at load 10-27 with nothing
	@# to show for it; the kernels are on disk by then
	$(PY) -c "import os, sys; from dem_ros.tools.common import warm_kernels; warm_kernels('make', offline=[(None, None)]); sys.stdout.flush(); sys.stderr.flush(); os._exit(0)"
	touch $(STAMP)

# the figures' command also after a degraded run (exit 1: its bag is there, the summary says what is missing)
demo: $(STAMP)
	@echo "$(VENV)/bin/dem-ros launch --scenario S1 --duration 30"; \
	$(VENV)/bin/dem-ros launch --scenario S1 --duration 30; rc=$$?; \
	bag=$$(ls -td bags/*_S1_adaptive 2>/dev/null | head -n 1); \
	if [ $$rc -le 1 ] && [ -n "$$bag" ]; then echo "make: figures of this run: $(VENV)/bin/dem-ros replay $$bag --plot figs/"; fi; \
	exit $$rc

test: $(STAMP)
	$(PY) -m pytest -q tests

# the unit tier (tests/conftest.py marks the tiers): no process, no DDS; a change is checked in a few minutes
test-fast: $(STAMP)
	$(PY) -m pytest -q -m "unit and not slow" tests

bench: $(STAMP)
	$(VENV)/bin/dem-ros bench sim

report: $(STAMP)
	$(VENV)/bin/dem-ros report --out docs/report

clean-venv:
	rm -rf $(VENV)
