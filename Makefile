# The two set-up commands of the README. Both create the environment first (idempotent).
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
# DVC stages call `python`: make it the environment's.
export PATH := $(abspath $(BIN)):$(PATH)

.PHONY: env system-deps pipeline test

$(BIN)/activate:
	$(PYTHON) -m venv $(VENV)

# torch is installed first and pinned: a bare `torch` would pull a multi-GB CUDA build.
# constraints.txt pins every other package to the versions the committed results were made with.
$(VENV)/.installed: $(BIN)/activate pyproject.toml constraints.txt
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -c constraints.txt -e '.[dev]'
	touch $@

env: $(VENV)/.installed

# Programs from Debian that the end-to-end tests drive: Chromium (tests/test_mlflow_ui.py) and
# PostgreSQL (tests/test_mlflow_postgres.py). Installs only what is missing, with sudo unless root.
SUDO := $(if $(filter 0,$(shell id -u)),,sudo)
system-deps:
	@missing=""; \
	[ -x /usr/bin/chromium ] || missing="chromium"; \
	command -v initdb >/dev/null || ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1 || missing="$$missing postgresql"; \
	if [ -n "$$missing" ]; then \
		echo "make system-deps: installing from Debian:$$missing"; \
		$(SUDO) apt-get update -qq && \
		$(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $$missing >/dev/null; \
	fi

pipeline: env
	$(BIN)/dvc repro

test: env system-deps
	$(BIN)/python -m pytest -n 2
