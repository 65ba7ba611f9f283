# Two commands do everything:
#   make        create .venv, install pinned dependencies, reproduce every result
#   make test   create .venv if missing, install test tools, run the test suite
PYTHON ?= python3
VENV   := .venv
PY     := $(CURDIR)/$(VENV)/bin/python
RUNTIME_STAMP := $(VENV)/.runtime-installed
DEV_STAMP     := $(VENV)/.dev-installed

.PHONY: all problem1 test lint bench clean

all: problem1

$(VENV)/bin/python:
	$(PYTHON) -m venv $(VENV)

$(RUNTIME_STAMP): requirements.txt | $(VENV)/bin/python
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements.txt
	touch $@

$(DEV_STAMP): requirements-dev.txt $(RUNTIME_STAMP)
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements-dev.txt
	touch $@

## Problem 1: value iteration, Q-iteration, figures, stochasticity study (seconds).
problem1: $(RUNTIME_STAMP)
	cd problem1 && $(PY) train.py && $(PY) stochasticity_study.py

test: $(DEV_STAMP)
	$(PY) -m pytest

lint: $(DEV_STAMP)
	$(PY) -m ruff check problem1 problem2 tests bench report
	$(PY) -m ruff format --check problem1 problem2 tests bench report

bench: $(RUNTIME_STAMP)
	$(PY) bench/p1_scaling.py

clean:
	rm -rf $(VENV)
