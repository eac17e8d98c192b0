# The two quick-start commands: `make demo` (main job) and `make test`.
# Both create .venv and install the package with its test extras when missing.
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
PYTHON ?= python3

.PHONY: demo test bench report clean-venv

$(STAMP): setup.py
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	@# compile the numba kernels once, here, with progress (demo, test and the nodes then load the cache)
	$(PY) -c "from dem_ros.tools.common import warm_kernels; warm_kernels('make')"
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/dem-ros launch --scenario S1 --duration 30

test: $(STAMP)
	$(PY) -m pytest -q tests

bench: $(STAMP)
	$(VENV)/bin/dem-ros bench sim

report: $(STAMP)
	$(VENV)/bin/dem-ros report --out docs/report

clean-venv:
	rm -rf $(VENV)
