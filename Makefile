# Two commands on a fresh machine with Python 3.11: `make demo` and `make test`.
# Each creates its own virtual environment in .venv on first use.

PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
export NUMBA_CACHE_DIR := $(CURDIR)/.numba_cache
OUT ?= demo_out
SOURCES := $(shell find src/skyrecon -name '*.py')
# Stamp of `skyrecon warmup` (kernels compiled into the cache); in the cache, so `make clean` drops it.
WARM := $(NUMBA_CACHE_DIR)/.skyrecon-warm

.PHONY: demo test lint bench install clean

# pip unpacks wheels under $(PIP_TMP), beside the venv, not in /tmp (which may be a small tmpfs), and
# keeps no cache: the install needs only the venv's own space (about 1.7 GB with the test extras).
PIP_TMP := $(VENV)/.pip-tmp
PIP := mkdir -p $(PIP_TMP) && TMPDIR=$(CURDIR)/$(PIP_TMP) $(BIN)/python -m pip install --quiet --no-cache-dir

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(PIP) --upgrade pip

$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(PIP) -e .
	rm -rf $(PIP_TMP)
	touch $@

$(VENV)/.installed-test: pyproject.toml | $(BIN)/python
	$(PIP) -e ".[test]"
	rm -rf $(PIP_TMP)
	touch $@ $(VENV)/.installed

install: $(VENV)/.installed

# Compile every kernel once after installing, and again when a source changes (Numba's cache is
# keyed on the source files), so that the first real command does not pay for compilation. A failed
# warmup does not stop the demo or the tests (they compile what is missing, and say what failed).
$(WARM): $(VENV)/.installed $(SOURCES)
	@if $(BIN)/skyrecon warmup; then mkdir -p $(@D) && touch $@; \
	else echo "skyrecon warmup failed: commands will compile their kernels on first use"; fi

## demo: install (and warm up), then fly one simulated delivery through a generated city (report.html at the end)
demo: $(VENV)/.installed $(WARM)
	$(BIN)/skyrecon demo --seed 1 --out $(OUT)

## test: install with test extras (and warm up), then run the whole test suite
test: $(VENV)/.installed-test $(WARM)
	$(BIN)/python -m pytest -n 2 -q

## lint: the gate CI runs before the tests: ruff (lint), ruff format --check, mypy
lint: $(VENV)/.installed-test
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/ruff format --check src tests benchmarks
	$(BIN)/mypy

$(VENV)/.installed-bench: pyproject.toml | $(BIN)/python
	$(PIP) -e ".[test,benchmarks]"
	rm -rf $(PIP_TMP)
	touch $@ $(VENV)/.installed $(VENV)/.installed-test

## bench: install the peers (OpenCV, poselib, pycolmap, OctoMap, OMPL), then run every side-by-side benchmark
bench: $(VENV)/.installed-bench
	$(BIN)/python benchmarks/render_speed.py
	$(BIN)/python benchmarks/stereo/run.py
	$(BIN)/python benchmarks/two_view/run.py
	$(BIN)/python benchmarks/sfm/run.py
	$(BIN)/python benchmarks/mvs/run.py
	$(BIN)/python benchmarks/mapping/run.py
	$(BIN)/python benchmarks/mapping/stereo_map.py
	$(BIN)/python benchmarks/planning/run.py

clean:
	rm -rf $(VENV) .numba_cache $(OUT) .pytest_cache
