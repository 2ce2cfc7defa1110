# Two commands for a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP_RUN  := $(VENV)/.installed-run
STAMP_TEST := $(VENV)/.installed-test

.PHONY: demo test lint bench container-test clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip

$(STAMP_RUN): pyproject.toml | $(BIN)/python
	$(BIN)/pip install -q -e .
	touch $@

$(STAMP_TEST): pyproject.toml | $(BIN)/python
	$(BIN)/pip install -q -e '.[test]'
	touch $@ $(STAMP_RUN)

demo: $(STAMP_RUN)
	$(BIN)/canopen-gateway run -c config/demo.yaml

test: $(STAMP_TEST)
	$(BIN)/ruff check gateway tests bench
	$(BIN)/python -m pytest -q

lint: $(STAMP_TEST)
	$(BIN)/ruff check gateway tests bench
	$(BIN)/ruff format --check gateway tests bench

bench: $(STAMP_TEST)
	$(BIN)/python -m bench

container-test: $(STAMP_TEST)
	bash deploy/container-test.sh

clean:
	rm -rf $(VENV) build *.egg-info
