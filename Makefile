# Two entry points: `make demo` and `make test`. Both create .venv if missing and install the package
# (with the `ray`, `gtsam`, `clients`, `sbx` and `team` extras, so the sweep, iSAM2,
# client-library, JAX-backend and team-env tests run).
# `make test-rllib` runs the RLlib test in its own venv, .venv-rllib: ray[rllib] pins gymnasium
# 1.2.2, and .venv keeps the newest gymnasium.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# Single-threaded BLAS: faster for the filters' small matrices (see agents/lab/cli/main.py).
export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1
export MKL_NUM_THREADS ?= 1

DOCS_STAMP := $(VENV)/.docs-installed
RLLIB_VENV  := .venv-rllib
RLLIB_STAMP := $(RLLIB_VENV)/.installed

.PHONY: demo test test-rllib lint bench install docs wheel-smoke clean clean-kernels

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): $(BIN)/python pyproject.toml constraints.txt
	$(BIN)/pip install --quiet -c constraints.txt torch==2.13.0
	$(BIN)/pip install --quiet -c constraints.txt -e ".[dev,ray,gtsam,clients,sbx,team]"
	touch $(STAMP)

install: $(STAMP)

$(DOCS_STAMP): $(STAMP)
	$(BIN)/pip install --quiet -c constraints.txt -e ".[dev,ray,docs]"
	touch $(DOCS_STAMP)

# The documentation site (MkDocs + Material + mkdocstrings) into site/; warnings are errors.
docs: $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

demo: $(STAMP)
	$(BIN)/quadslam run

test: $(STAMP)
	MPLBACKEND=Agg $(BIN)/python -m pytest -q --durations=15

$(RLLIB_STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(RLLIB_VENV)
	$(RLLIB_VENV)/bin/python -m pip install --quiet --upgrade pip
	$(RLLIB_VENV)/bin/pip install --quiet -c constraints.txt torch==2.13.0
	$(RLLIB_VENV)/bin/pip install --quiet -c constraints.txt -e ".[test,rllib]"
	touch $(RLLIB_STAMP)

# RLlib's PPO on the env ids (tests/rl/test_rllib.py), in .venv-rllib.
test-rllib: $(RLLIB_STAMP)
	MPLBACKEND=Agg $(RLLIB_VENV)/bin/python -m pytest -q tests/rl/test_rllib.py

lint: $(STAMP)
	$(BIN)/ruff check . && $(BIN)/ruff format --check .
	$(BIN)/mypy
	$(BIN)/lint-imports

# The fresh-install check of CI: build the wheel, install it into a new venv outside the
# checkout, use it from an unrelated folder.
wheel-smoke: $(STAMP)
	.ci/wheel_smoke.sh $(PYTHON)

bench: $(STAMP)
	$(BIN)/quadslam bench

clean: clean-kernels
	rm -rf $(VENV) $(RLLIB_VENV) build dist site *.egg-info .pytest_cache .mypy_cache

# numba's kernel caches: a caller's cache does not notice an edited callee in another module
# (quadslam_env/models/jit.py), so delete them after editing a kernel.
clean-kernels:
	find quadslam_env estimators agents -name '*.nbi' -delete -o -name '*.nbc' -delete
