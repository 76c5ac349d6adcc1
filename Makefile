# The two commands of the README: `make demo` and `make test`. Both set up everything they need.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export MIMICKIT_TEST_DATA ?= $(abspath ../shared/data)

.PHONY: setup demo test lint format

setup: $(STAMP)

# torch first, from the pinned CPU wheel: a looser pin resolved later would pull a CUDA build.
$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q torch==2.13.0
	$(BIN)/pip install -q -e ".[dev]"
	touch $(STAMP)

# Until the studio lands, the embedded default is shown as the report of the project's demo clip.
demo: setup
	$(BIN)/mimickit motion info data/motions/humanoid_demo_squat.pkl --char data/assets/humanoid/humanoid.xml

test: setup
	$(BIN)/python -m pytest -q

lint: setup
	$(BIN)/ruff check mimickit tests benchmarks

format: setup
	$(BIN)/ruff format mimickit tests benchmarks
