# scene_recon: set-up, tests, demo. Every target that starts ROS nodes keeps DDS on loopback.
SHELL := /bin/bash
.DEFAULT_GOAL := help

PYTHON_BASE ?= $(shell command -v python3.11 || command -v python3)
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(VENV)/bin/pip
# DDS discovery stays on 127.0.0.1 (these machines allow loopback traffic only) on our own domain.
ROS_ENV := ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST ROS_DOMAIN_ID=$${ROS_DOMAIN_ID:-77}
REQ_STAMP := $(VENV)/.requirements.stamp
PKG_STAMP := $(VENV)/.package.stamp
DEMO_OUT ?= out/demo

.PHONY: help setup system-deps test lint demo bench bench-quick bench-full bench-robustness bench-robustness-quick bench-heldout clean

help:  ## list the targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | sed -E 's/:.*## /\t/' | column -t -s $$'\t'

setup: system-deps $(REQ_STAMP) interfaces $(PKG_STAMP)  ## install everything (idempotent; a second run takes seconds)
	@echo "setup: done ($(VENV) ready; nothing needs sourcing)"

system-deps:  ## Debian packages: compiler, cmake, Python headers/venv, libusb (Open3D)
	@bash tools/system_deps.sh "$(PYTHON_BASE)"

$(VENV)/bin/python:
	$(PYTHON_BASE) -m venv $(VENV)

$(REQ_STAMP): requirements.txt requirements.lock | $(VENV)/bin/python
	$(PIP) install -q --upgrade "pip==26.3"
	$(PIP) install -q -r requirements.txt -c requirements.lock
	touch $@

.PHONY: interfaces
interfaces: $(REQ_STAMP)
	@VENV=$(VENV) bash tools/build_interfaces.sh

$(PKG_STAMP): setup.py setup.cfg package.xml $(REQ_STAMP)
	$(PIP) install -q --no-deps --no-build-isolation -e .
	touch $@

test: setup  ## run the test suite (pytest; real DDS on loopback)
	$(ROS_ENV) $(PY) -m pytest -q

lint: setup  ## ruff, the layer contract (import-linter) and the type checker (mypy) over the core and the stages
	$(VENV)/bin/ruff check .
	$(VENV)/bin/lint-imports
	$(VENV)/bin/mypy

demo: setup  ## the main job on the embedded default scene
	$(ROS_ENV) $(VENV)/bin/scene-recon demo --out $(DEMO_OUT)

bench: setup  ## benchmarks (print figures, write JSON under benchmarks/results)
	$(ROS_ENV) $(PY) benchmarks/run_all.py

BENCH_OUT ?= out/benchmark
bench-quick: setup  ## end-to-end benchmark, quick suite (< 3 min): presets, time vs accuracy -> $(BENCH_OUT)/quick
	$(ROS_ENV) $(VENV)/bin/scene-recon benchmark --suite quick --out $(BENCH_OUT)/quick

bench-full: setup  ## end-to-end benchmark, full suite (< 30 min): sweeps, Pareto plots, skips, scaling -> $(BENCH_OUT)/full
	$(ROS_ENV) $(VENV)/bin/scene-recon benchmark --suite full --out $(BENCH_OUT)/full

bench-robustness: setup  ## the robustness protocol (~1 h on 2 cores): 8 scenes x 3 noise draws, full vs baseline vs the paper's birth rule vs the paper's 2 cm map -> $(BENCH_OUT)/robustness
	$(ROS_ENV) $(VENV)/bin/scene-recon benchmark --suite robustness --paper-birth --single-resolution --out $(BENCH_OUT)/robustness

bench-robustness-quick: setup  ## its CI subset (~5 min): 2 scenes (one outside the suite) x 3 draws, full vs baseline -> $(BENCH_OUT)/robustness-quick
	$(ROS_ENV) $(VENV)/bin/scene-recon benchmark --suite robustness-quick --out $(BENCH_OUT)/robustness-quick

HELDOUT_SCENES ?= gen-1234-14 gen-2468-18 gen-9090-12 gen-3131-22
bench-heldout: setup  ## the protocol on generated rooms it does not hold (~5 min): HELDOUT_SCENES x 2 draws, full vs baseline -> $(BENCH_OUT)/heldout
	$(ROS_ENV) $(VENV)/bin/scene-recon benchmark --suite robustness --scenes $(HELDOUT_SCENES) --draws 2 --out $(BENCH_OUT)/heldout

clean:  ## remove build products (keeps the venv)
	rm -rf .build build log out .pytest_cache
