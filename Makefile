# The two commands of the README: `make studio` and `make test`. Both set up everything they need.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export MIMICKIT_TEST_DATA ?= $(abspath ../shared/data)

.PHONY: setup studio test browser lint format

setup: $(STAMP)

# torch first, from the pinned CPU wheel: a looser pin resolved later would pull a CUDA build.
$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q torch==2.13.0
	$(BIN)/pip install -q -e ".[dev]"
	touch $(STAMP)

# The studio on the embedded default: the project's humanoid and demo clip, MuJoCo on the CPU.
studio: setup
	$(BIN)/mimickit-studio serve

# Chromium from Debian for the browser tests (Playwright's own download is not used).
browser:
	@command -v chromium >/dev/null || { apt-get update -q && apt-get install -y -q chromium; }

test: setup browser
	$(BIN)/python -m pytest -q

lint: setup
	$(BIN)/ruff check mimickit studio tests benchmarks

format: setup
	$(BIN)/ruff format mimickit studio tests benchmarks
