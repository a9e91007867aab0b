# The two commands of the README: `make run` (the main job) and `make test`. Both create and
# use the virtual environment .venv/ and are safe to re-run.
PYTHON ?= python3
VENV := .venv
STAMP := $(VENV)/.installed
# Tests and CI read the standard datasets from ../shared/datasets when that folder exists and
# POPBENCH_DATA is not set; otherwise popbench uses its per-user cache (and downloads).
SHARED_DATA := $(abspath ../shared/datasets)
ifeq ($(origin POPBENCH_DATA), undefined)
ifneq ($(wildcard $(SHARED_DATA)),)
export POPBENCH_DATA := $(SHARED_DATA)
endif
endif

.PHONY: install run test lint bench

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install --quiet --upgrade pip
	$(VENV)/bin/pip install --quiet -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

run: $(STAMP)
	$(VENV)/bin/popbench run table1

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

test: lint
	$(VENV)/bin/python -m pytest -q -rs

# Every benchmark with its default arguments, one after the other (long: full convergence tables).
bench: $(STAMP)
	for script in benchmarks/bench_*.py; do $(VENV)/bin/python $$script || exit 1; done
