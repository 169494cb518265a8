# fringelab: `make run` starts everything on this machine, `make test` runs the whole test suite.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
# The d3plot tests need lasso-python, which pins plotly 5 and psutil 5: they run in a second environment, the
# project with its `lsdyna` extra, so that the main one keeps the plotly the dashboard is tested with.
LSDYNA_VENV  := .venv-lsdyna
LSDYNA_STAMP := $(LSDYNA_VENV)/.installed-stamp

.PHONY: run test lint install install-lsdyna clean

$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "fringelab needs Python 3.11 or newer (set PYTHON=python3.11)")'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[dev]"
	@touch $(STAMP)

$(LSDYNA_STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "fringelab needs Python 3.11 or newer (set PYTHON=python3.11)")'
	$(PYTHON) -m venv $(LSDYNA_VENV)
	$(LSDYNA_VENV)/bin/python -m pip install --quiet --upgrade pip
	$(LSDYNA_VENV)/bin/python -m pip install --quiet -e ".[dev,lsdyna]"
	@touch $(LSDYNA_STAMP)

install: $(STAMP)

install-lsdyna: $(LSDYNA_STAMP)

run: $(STAMP)
	$(BIN)/fringelab up

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy fringelab backend worker

test: lint $(LSDYNA_STAMP)
	$(LSDYNA_VENV)/bin/python -m pytest -m lsdyna
	$(BIN)/python -m pytest -m "not lsdyna"

clean:
	rm -rf $(VENV) $(LSDYNA_VENV) .pytest_cache .mypy_cache .ruff_cache
