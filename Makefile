# The two set-up commands of the README. Both create the environment first (idempotent).
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
# DVC stages call `python`: make it the environment's.
export PATH := $(abspath $(BIN)):$(PATH)

.PHONY: env pipeline test

$(BIN)/activate:
	$(PYTHON) -m venv $(VENV)

# torch is installed first and pinned: a bare `torch` would pull a multi-GB CUDA build.
$(VENV)/.installed: $(BIN)/activate pyproject.toml
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -e '.[dev]'
	touch $@

env: $(VENV)/.installed

pipeline: env
	$(BIN)/dvc repro

test: env
	$(BIN)/python -m pytest -n 2
