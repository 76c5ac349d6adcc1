# The two commands of the README: `make studio` and `make test`. Both set up everything they need.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export MIMICKIT_TEST_DATA ?= $(abspath ../shared/data)

NEWTON_VENV := .venv-newton
NEWTON_BIN := $(NEWTON_VENV)/bin
NEWTON_STAMP := $(NEWTON_VENV)/.installed

.PHONY: setup studio test test-unit test-install browser lint format setup-newton test-newton

setup: $(STAMP)

# torch first, from the pinned CPU wheel: a looser pin resolved later would pull a CUDA build.
$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q torch==2.13.0
	$(BIN)/pip install -q -e ".[dev,onnx,smp]"
	touch $(STAMP)

# The studio on the embedded default: the project's humanoid and demo clip, MuJoCo on the CPU.
studio: setup
	$(BIN)/mimickit-studio serve

# Chromium from Debian for the browser tests (Playwright's own download is not used).
browser:
	@command -v chromium >/dev/null || { apt-get update -q && apt-get install -y -q chromium; }

# Ray for the Ray executor's tests (tests/studio/test_ray_executor.py start a local Ray head).
RAY_STAMP := $(VENV)/.installed-ray

$(RAY_STAMP): $(STAMP)
	$(BIN)/pip install -q -e ".[dev,ray]"
	touch $(RAY_STAMP)

# Two workers, one test module each at a time (--dist loadfile: a module's fixtures stay in one process),
# modules in the order tests/studio/conftest.py sorts them (--no-loadscope-reorder: those on the shared
# Chromium after the rest, in each worker). Serial, the suite took 1,608 s here; two workers 1,151 s.
test: setup $(RAY_STAMP) browser
	$(BIN)/python -m pytest -q -n 2 --dist loadfile --no-loadscope-reorder --durations=25

# The fast subset (under a minute): no subprocess, server, browser, or test that trains to an improvement or
# takes seconds (markers in pyproject.toml; the guard in tests/conftest.py fails an unmarked test that starts
# a process).
test-unit: setup
	$(BIN)/python -m pytest -q -m "not integration and not browser and not slow"

# A normal (non-editable) install from a wheel, in a fresh venv, run from another folder (also in `make test`).
test-install: setup
	$(BIN)/python -m pytest -q tests/test_install.py

lint: setup
	$(BIN)/ruff check mimickit studio tests benchmarks

format: setup
	$(BIN)/ruff format mimickit studio tests benchmarks

# The Newton engine in its own venv: newton[sim] pins mujoco 3.17, the main venv keeps mujoco 4.
# Same order as setup: the CPU torch wheel first. Runs the Newton engine and sim2sim tests on warp's
# CPU device (the first run JIT-compiles the kernels into ~/.cache/warp), the viewers' `mujoco_view` and a
# Newton run rolled out, replayed, rendered and benched, and the MuJoCo engine and env tests once more, on
# mujoco 3.17.
setup-newton: $(NEWTON_STAMP)

$(NEWTON_STAMP): pyproject.toml
	$(PY) -m venv $(NEWTON_VENV)
	$(NEWTON_BIN)/pip install -q --upgrade pip
	$(NEWTON_BIN)/pip install -q torch==2.13.0
	$(NEWTON_BIN)/pip install -q -e ".[dev,newton,smp]"
	touch $(NEWTON_STAMP)

test-newton: setup-newton
	$(NEWTON_BIN)/python -m pytest -q tests/engines/test_newton_engine.py tests/engines/test_mujoco_engine.py \
		tests/engines/test_ball_joints.py tests/engines/test_mujoco_view.py tests/studio/test_newton_rollout.py tests/envs
