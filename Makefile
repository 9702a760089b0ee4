# Two entry points for a new user (see README):
#   make demo   create .venv, install, run the end-to-end demo on the embedded default
#   make test   create .venv, install with the dev extra, lint, run the default test suite
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
DEMO_OUT ?= demo_out

.PHONY: demo test test-all lint bench venv clean

venv: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet -e ".[dev]"
	touch $@

demo: venv
	$(BIN)/srde-fusion demo --out $(DEMO_OUT)

test: venv
	$(BIN)/ruff check srde_fusion adapters tests examples benchmarks
	$(BIN)/python -m pytest -q

test-all: venv
	$(BIN)/python -m pytest -q -m "slow or not slow"

lint: venv
	$(BIN)/ruff check srde_fusion adapters tests examples benchmarks

bench: venv
	for b in benchmarks/*.py; do $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) $(DEMO_OUT) build *.egg-info
