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

# the figures' command also after a failed or degraded run (exit 1 / 3: its bag is there, the summary says what)
demo: $(STAMP)
	@echo "$(VENV)/bin/dem-ros launch --scenario S1 --duration 30"; \
	$(VENV)/bin/dem-ros launch --scenario S1 --duration 30; rc=$$?; \
	bag=$$(ls -td bags/*_S1_adaptive 2>/dev/null | head -n 1); \
	if { [ $$rc -le 1 ] || [ $$rc -eq 3 ]; } && [ -n "$$bag" ]; then echo "make: figures of this run: $(VENV)/bin/dem-ros replay $$bag --plot figs/"; fi; \
	exit $$rc

# the `ros` extra (ROS 2 Jazzy's rclpy on Fast DDS from the package index) so the rclpy tests run: the wheels
# are cp311 manylinux x86_64. The stamp keeps what happened (installed, or why not) until setup.py changes;
# where the wheels cannot be had the rclpy tests skip, and every `make test` says so in one line
ROS_STAMP := $(VENV)/.ros-stamp
$(ROS_STAMP): $(STAMP) setup.py
	@if $(PY) -c "import sys, platform; sys.exit(0 if sys.version_info[:2] == (3, 11) and sys.platform == 'linux' and platform.machine() == 'x86_64' else 1)"; then \
	  echo "make: $(PY) -m pip install -qq -e '.[ros]' (rclpy for the rclpy transport's tests)"; \
	  if $(PY) -m pip install -qq -e '.[ros]' 2>$(VENV)/.ros-pip.log; then echo installed > $@; \
	  else echo "unavailable: pip install -e '.[ros]' failed (see $(VENV)/.ros-pip.log)" > $@; fi; \
	else \
	  echo "unavailable: the ROS 2 Jazzy wheels are cp311 linux x86_64, this is $$($(PY) -c "import sys, platform; print(f'cp{sys.version_info[0]}{sys.version_info[1]} {sys.platform} {platform.machine()}')")" > $@; \
	fi

# the Cortex-M cross-build of the firmware (make -C firmware test-arm: arm-none-eabi-gcc, qemu-system-arm), from
# Debian's packages where apt-get can install them (root; about 100 MB to download, a minute); elsewhere the ARM
# test skips and every `make test` says why. The stamp keeps what happened until this Makefile changes
ARM_PKGS  := gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm
ARM_STAMP := $(VENV)/.arm-stamp
$(ARM_STAMP): $(STAMP) Makefile
	@if command -v arm-none-eabi-gcc >/dev/null && command -v qemu-system-arm >/dev/null; then echo installed > $@; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  echo "make: apt-get install $(ARM_PKGS) (the firmware's Cortex-M test; about a minute)"; \
	  if { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $(ARM_PKGS); } \
	     >$(VENV)/.arm-apt.log 2>&1; then echo installed > $@; \
	  else echo "unavailable: apt-get install $(ARM_PKGS) failed (see $(VENV)/.arm-apt.log)" > $@; fi; \
	else echo "unavailable: needs root and apt-get to install $(ARM_PKGS)" > $@; fi

test: $(STAMP) $(ROS_STAMP) $(ARM_STAMP)
	@grep -q '^installed' $(ROS_STAMP) || echo "make: no rclpy, the rclpy tests skip: $$(cat $(ROS_STAMP))"
	@grep -q '^installed' $(ARM_STAMP) || echo "make: no Cortex-M toolchain, the firmware's ARM test skips: $$(cat $(ARM_STAMP))"
	$(PY) -m pytest -q --durations=25 tests

# the unit tier (tests/conftest.py marks the tiers): no process, no DDS; a change is checked in a few minutes
test-fast: $(STAMP)
	$(PY) -m pytest -q -m "unit and not slow" tests

bench: $(STAMP)
	$(VENV)/bin/dem-ros bench sim

report: $(STAMP)
	$(VENV)/bin/dem-ros report --out docs/report

clean-venv:
	rm -rf $(VENV)
