# The quick-start commands: `make demo` (the main job), `make test`, `make report`, `make bench`.
# Each creates .venv and installs the package with its test extras when missing, then compiles the
# numba kernels once; every step prints a line at least every 5 s (a first run takes minutes).
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
PYTHON ?= python3

.PHONY: demo test bench report clean-venv

# pip -qq: errors only (setuptools' editable-install notice is nothing a user can act on); the
# background loop is the progress line pip does not give when its output is not a terminal
$(STAMP): setup.py
	@echo "make: first run: creating $(VENV) and installing dem_ros with its test dependencies (numpy, scipy, numba, cyclonedds, ...)"
	$(PYTHON) -m venv $(VENV)
	@t0=$$(date +%s); \
	( while sleep 5; do echo "make:   ... pip install -e '.[test]' ($$(( $$(date +%s) - t0 )) s)"; done ) & beat=$$!; \
	$(PY) -m pip install -qq --upgrade pip && $(PY) -m pip install -qq -e '.[test]'; rc=$$?; \
	kill $$beat; \
	if [ $$rc -eq 0 ]; then echo "make: installed in $$(( $$(date +%s) - t0 )) s"; fi; exit $$rc
	@# compile the numba kernels once, here, with progress (demo, test and the nodes then load the cache)
	$(PY) -c "from dem_ros.tools.common import warm_kernels; warm_kernels('make')"
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/dem-ros launch --scenario S1 --duration 30
	@echo "make: figures of this run: $(VENV)/bin/dem-ros replay $$(ls -td bags/*_S1_adaptive | head -n 1) --plot figs/"

test: $(STAMP)
	$(PY) -m pytest -q tests

bench: $(STAMP)
	$(VENV)/bin/dem-ros bench sim

report: $(STAMP)
	$(VENV)/bin/dem-ros report --out docs/report

clean-venv:
	rm -rf $(VENV)
