# pvo — set-up, build, test and demo. Every target is idempotent: a re-run with nothing changed
# re-uses the venv and the colcon build.
SHELL := /bin/bash
.SHELLFLAGS := -eo pipefail -c
PYTHON ?= python3.11
VENV := .venv
VENV_STAMP := $(VENV)/.pvo-installed
BUILD_STAMP := install/.pvo-built
ENV := source scripts/env.sh
PVO_DATA_DIR ?= $(abspath ../shared/data)
export PVO_DATA_DIR
# Everything colcon builds from: any change to it triggers a rebuild.
SOURCES := $(shell find src -type f -not -path '*/__pycache__/*' -not -name '*.pyc' 2>/dev/null) colcon.meta
PYTEST_ARGS ?=

.PHONY: all venv build test lint demo bench clean distclean help
all: build

help:
	@echo "make build   create .venv (pinned deps) and build the colcon workspace"
	@echo "make test    build, then run the whole test suite (what CI runs)"
	@echo "make demo    build, then run the main job on the embedded sample bag"
	@echo "make lint    ruff over the sources"
	@echo "make bench   conversion, bag-play, stereo VO, simulator, fusion and demo benchmarks"
	@echo "make clean   remove build products (keeps .venv); make distclean also removes .venv"

venv: $(VENV_STAMP)
$(VENV_STAMP): requirements.txt constraints.txt
	@if [ ! -x $(VENV)/bin/python ]; then echo "[pvo] creating $(VENV) with $(PYTHON)"; $(PYTHON) -m venv $(VENV); fi
	@echo "[pvo] installing pinned dependencies"
	$(VENV)/bin/python -m pip install --disable-pip-version-check -q -r requirements.txt -c constraints.txt 2>&1 \
	  | { grep -v "is ignored: it is neither a file nor a directory" || true; }
	@touch $@

build: $(BUILD_STAMP)
$(BUILD_STAMP): $(VENV_STAMP) $(SOURCES)
	@echo "[pvo] colcon build"
	$(ENV) && colcon --log-base log build --event-handlers console_cohesion- summary+ \
	  --cmake-args -DPython3_EXECUTABLE=$(abspath $(VENV))/bin/python 2>&1 \
	  | { grep -v "doesn't contain any 'local_setup" || true; }
	@touch $@

test: build lint
	$(ENV) && python -m pytest $(PYTEST_ARGS)

lint: $(VENV_STAMP)
	$(VENV)/bin/ruff check src test benchmarks conftest.py && $(VENV)/bin/ruff format --check src test benchmarks conftest.py

demo: build
	$(ENV) && bash scripts/demo.sh

bench: build
	$(ENV) && python benchmarks/bench_bags.py
	$(ENV) && pvo bench vo $(PVO_DATA_DIR)/kitti/sequences/06 --poses $(PVO_DATA_DIR)/kitti/poses/06.txt --compare
	$(ENV) && pvo bench sim --preset urban && pvo bench sim --preset planetary
	$(ENV) && pvo bench realism -o runs/bench-realism
	$(ENV) && pvo bench fusion --data $(PVO_DATA_DIR) --sequence 00
	$(ENV) && pvo experiment sun-sim --data $(PVO_DATA_DIR) --through-nodes 05 --frames 1000 --rate 5 -o runs/bench-fusion-nodes
	$(ENV) && pvo demo -o runs/bench-demo   # the main job's wall time (target: under 2 minutes for both samples)

clean:
	rm -rf build install log runs .pytest_cache
distclean: clean
	rm -rf $(VENV)
