# MEMS hardware emulator on ROS 2 Kilted (PyPI wheels).
#   make demo   set up if needed, run the default scenario, print its table, write runs/
#   make test   set up if needed, run the whole test suite
#   make bench  set up if needed, run the benchmarks (ratios measured in one run)
#   make acceptance  set up if needed, run the long seeded runs and campaigns (slow tests)
#   make lint   ruff check and ruff format --check (make test runs it first)
#   make bags   regenerate the reference recordings in bags/
# Setup: venv at .venv/ with the pinned wheels of requirements.lock, the
# interface package msg_defs/ (mems_msgs) built with rosidl into the venv, and
# this package installed (editable) with its executables in .venv/bin, and the venv made an
# ament prefix for it (ament index, share/mems_emulator, lib/mems_emulator) as colcon would.

SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python

# The graph never leaves this machine; each target has a domain of its own.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
export NUMBA_CACHE_DIR := $(CURDIR)/$(VENV)/numba-cache
export MPLBACKEND := Agg
# The same floats on every x86-64 machine with AVX2 and FMA: numpy's and OpenBLAS's
# kernel choice pinned (AVX2 kernels, no BLAS reduction split over threads). Importing the
# package applies the same pins (mems_sim/cpu_pins.py, for every executable); they are
# exported here for the scripts that import numpy first (test/architecture checks that the
# two agree). docs/testing.md states the rule.
export NPY_DISABLE_CPU_FEATURES := X86_V4 AVX512_ICL AVX512_SPR
export OPENBLAS_CORETYPE := Haswell
export OPENBLAS_NUM_THREADS := 1
DEMO_DOMAIN ?= 61
BENCH_DOMAIN ?= 62
TEST_DOMAIN ?= 63
ACCEPTANCE_DOMAIN ?= 64
BAGS_DOMAIN ?= 65

PIP_VERSION := 26.3
DEPS_STAMP := $(VENV)/.stamp-deps
MSGS_STAMP := $(VENV)/.stamp-msgs
PKG_STAMP := $(VENV)/.stamp-pkg
MSG_FILES := $(wildcard msg_defs/msg/*.msg)
KERNEL_STAMP := $(VENV)/.stamp-kernels
KERNEL_SOURCES := $(shell grep -rl --include=*.py numba.njit mems_sim mems_estimation)
# numba targets besides the host CPU that test/architecture/test_portable_results.py compiles for
PORTABLE_TARGETS := generic haswell

.PHONY: setup demo test lint acceptance bench bags clean

setup: $(KERNEL_STAMP)

$(DEPS_STAMP): requirements.lock tools/bootstrap_system.sh
	bash tools/bootstrap_system.sh
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --disable-pip-version-check -q pip==$(PIP_VERSION)
	$(PY) -m pip install --disable-pip-version-check -q -r requirements.lock
	touch $@

$(MSGS_STAMP): $(DEPS_STAMP) msg_defs/package.xml msg_defs/CMakeLists.txt $(MSG_FILES) tools/build_msgs.sh tools/fix_ros_wheel_cmake.py
	VENV=$(VENV) bash tools/build_msgs.sh
	touch $@

$(PKG_STAMP): $(MSGS_STAMP) setup.py pyproject.toml package.xml requirements.lock LICENSE CHANGELOG.rst resource/mems_emulator $(wildcard launch/* config/*)
	$(PY) -m pip install --disable-pip-version-check -q --no-build-isolation --no-deps -e .
	$(PY) tools/install_ament_prefix.py
	touch $@

# numba's cache for the host CPU and for the other targets the portable-results test plays
# (test/portable_probe.py runs every kernel family once per target; the cache keeps one
# entry per target), so that the test costs seconds
$(KERNEL_STAMP): $(PKG_STAMP) $(KERNEL_SOURCES) test/portable_probe.py
	for cpu in $(PORTABLE_TARGETS); do \
	  $(PY) test/portable_probe.py --target $$cpu --deliberate-fastmath > /dev/null || exit 1; \
	done
	$(PY) test/portable_probe.py --deliberate-fastmath > /dev/null
	touch $@

demo: setup
	ROS_DOMAIN_ID=$(DEMO_DOMAIN) $(VENV)/bin/run_scenario gyro_calibration --seed 1

lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

test: lint
	ROS_DOMAIN_ID=$(TEST_DOMAIN) $(PY) -m pytest test -m "not slow" -n 2 --dist loadfile

acceptance: setup
	ROS_DOMAIN_ID=$(ACCEPTANCE_DOMAIN) $(PY) -m pytest test -m slow -rA

bags: setup
	ROS_DOMAIN_ID=$(BAGS_DOMAIN) $(PY) tools/make_bags.py

bench: setup
	ROS_DOMAIN_ID=$(BENCH_DOMAIN) $(PY) bench/run_all.py

clean:
	rm -rf build install log runs .pytest_cache
