# Two commands on a fresh machine with Python 3.11: `make demo` and `make test`.
# Each creates its own virtual environment in .venv on first use.

PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
export NUMBA_CACHE_DIR := $(CURDIR)/.numba_cache
OUT ?= demo_out

.PHONY: demo test bench install clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(VENV)/.installed-test: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $@ $(VENV)/.installed

install: $(VENV)/.installed

## demo: install, then run the main job on the built-in synthetic city
demo: $(VENV)/.installed
	$(BIN)/skyrecon render stereo --seed 7 --out $(OUT)/stereo
	$(BIN)/skyrecon render sequence --seed 7 --frames 30 --out $(OUT)/flight
	@echo "Open $(OUT)/stereo/preview.png and $(OUT)/flight/preview.png"

## test: install with test extras, then run the whole test suite
test: $(VENV)/.installed-test
	$(BIN)/python -m pytest -n 2 -q

bench: $(VENV)/.installed-test
	$(BIN)/python benchmarks/render_speed.py

clean:
	rm -rf $(VENV) .numba_cache $(OUT) .pytest_cache
