# Set-up is automatic: every target below creates .venv and installs the project first.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp

.PHONY: demo test test-slow test-all bench reproduce clean clean-cache

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	# torch is pinned to the small CPU build (pyproject.toml says why)
	$(BIN)/python -m pip install --quiet torch==2.13.0
	$(BIN)/python -m pip install --quiet -e '.[dev,render,agents,margins]'
	touch $(STAMP)

## main job: the passive bogie's linear critical speed, then the shipped v1 controller against it (protocol v2)
demo: $(STAMP)
	$(BIN)/bogie critical-speed
	$(BIN)/bogie evaluate --policy passive --policy pretrained --parts critical

## quick test suite (slow tests skipped), in two processes (pytest-xdist; the slow tests, which
## start Ray clusters, run in one)
test: $(STAMP)
	$(BIN)/python -m pytest -q -n 2

## only the tests marked slow
test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow

## everything
test-all: $(STAMP)
	$(BIN)/python -m pytest -q -m "slow or not slow"

## every Section 4-5 figure and the report (docs/reproduction.md)
reproduce: $(STAMP)
	$(BIN)/bogie reproduce --out docs/reproduction

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_dynamics.py

## drop compiled numba kernels (import bogie_env does this itself when their source changed)
clean-cache:
	find bogie_env -name '*.nbi' -delete -o -name '*.nbc' -delete

clean: clean-cache
	rm -rf $(VENV) build *.egg-info .pytest_cache
