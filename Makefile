# Two entry points: `make demo` and `make test`. Both create .venv if missing and install the package.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# Single-threaded BLAS: faster for the filters' small matrices (see agents/cli.py).
export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1
export MKL_NUM_THREADS ?= 1

DOCS_STAMP := $(VENV)/.docs-installed

.PHONY: demo test lint bench install docs wheel-smoke clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): $(BIN)/python pyproject.toml constraints.txt
	$(BIN)/pip install --quiet -c constraints.txt torch==2.13.0
	$(BIN)/pip install --quiet -c constraints.txt -e ".[dev]"
	touch $(STAMP)

install: $(STAMP)

$(DOCS_STAMP): $(STAMP)
	$(BIN)/pip install --quiet -c constraints.txt -e ".[dev,docs]"
	touch $(DOCS_STAMP)

# The documentation site (MkDocs + Material + mkdocstrings) into site/; warnings are errors.
docs: $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

demo: $(STAMP)
	$(BIN)/quadslam run

test: $(STAMP)
	MPLBACKEND=Agg $(BIN)/python -m pytest -q

lint: $(STAMP)
	$(BIN)/ruff check . && $(BIN)/ruff format --check .
	$(BIN)/mypy

# The fresh-install check of CI: build the wheel, install it into a new venv outside the
# checkout, use it from an unrelated folder.
wheel-smoke: $(STAMP)
	.ci/wheel_smoke.sh $(PYTHON)

bench: $(STAMP)
	$(BIN)/quadslam bench

clean:
	rm -rf $(VENV) build dist site *.egg-info .pytest_cache .mypy_cache
