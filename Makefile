# Two commands for a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP_RUN  := $(VENV)/.installed-run
STAMP_TEST := $(VENV)/.installed-test
# The interpreter $(VENV) was made with (path and version), recorded in STAMP_PYTHON: a
# .venv made by another PYTHON (`make demo PYTHON=python3.10`, then plain `make demo`) is
# made again with this one.
PYTHON_ID    := $(shell $(PYTHON) -c 'import sys; print(sys.executable, sys.version.split()[0])' 2>/dev/null)
STAMP_PYTHON := $(VENV)/.python

.PHONY: demo test test-quick tools lint bench container-test deploy-lint clean screenshots

ifneq ($(file < $(STAMP_PYTHON)),$(PYTHON_ID))
.PHONY: $(STAMP_PYTHON)
endif
$(STAMP_PYTHON):
	@if [ -d $(VENV) ]; then echo "$(VENV) was made by another Python ($(or $(file < $(STAMP_PYTHON)),unknown)); making it again with $(PYTHON_ID)"; fi
	rm -rf $(VENV)
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	echo '$(PYTHON_ID)' > $@

$(STAMP_RUN): pyproject.toml $(STAMP_PYTHON)
	$(BIN)/pip install -q -e .
	touch $@

$(STAMP_TEST): pyproject.toml $(STAMP_PYTHON)
	$(BIN)/pip install -q -e '.[test]'
	touch $@ $(STAMP_RUN)

demo: $(STAMP_RUN)
	$(BIN)/canopen-gateway run -c config/demo.yaml

# The screenshots of docs/web.md (headless Chromium against the demo config).
screenshots: $(STAMP_TEST) tools
	$(BIN)/python -m tests.browser.screenshot config/demo.yaml docs/images

# Real clients for the tests and the docs: Debian's mbpoll (Modbus), chromium + chromium-driver
# (the web console in a browser, driven by selenium) and netcat-openbsd (`nc -N`, the CiA 309-3
# ASCII examples); best effort, the tests say when one is missing.
tools:
	@command -v mbpoll >/dev/null 2>&1 || { command -v apt-get >/dev/null 2>&1 && \
	  (apt-get update -qq && apt-get install -y -qq mbpoll) >/dev/null 2>&1; } || \
	  echo "note: mbpoll not installed; its tests will be skipped"
	@{ command -v chromium >/dev/null 2>&1 && command -v chromedriver >/dev/null 2>&1; } || \
	  { command -v apt-get >/dev/null 2>&1 && \
	  (apt-get update -qq && apt-get install -y -qq chromium chromium-driver) >/dev/null 2>&1; } || \
	  echo "note: chromium / chromium-driver not installed; the browser tests will be skipped"
	@{ command -v nc >/dev/null 2>&1 && nc -h 2>&1 | grep -q -- '-N'; } || \
	  { command -v apt-get >/dev/null 2>&1 && \
	  (apt-get update -qq && apt-get install -y -qq netcat-openbsd) >/dev/null 2>&1; } || \
	  echo "note: netcat-openbsd (nc -N, the ASCII gateway examples) not installed"

test: $(STAMP_TEST) tools
	$(BIN)/ruff check canopen_gateway tests deploy $(wildcard bench)
	$(BIN)/lint-imports --no-cache
	$(BIN)/mypy
	$(BIN)/python -m pytest -q

# Day to day: the lint and the unit tests (under 2 minutes); `make test` stays the whole suite.
test-quick: lint
	$(BIN)/python -m pytest -q tests/unit

lint: $(STAMP_TEST)
	$(BIN)/ruff check canopen_gateway tests deploy $(wildcard bench)
	$(BIN)/lint-imports --no-cache
	$(BIN)/mypy

bench: $(STAMP_TEST)
	$(BIN)/pip install -q -e '.[test,bench]'
	$(BIN)/python -m bench

container-test: $(STAMP_TEST)
	bash deploy/container-test.sh

deploy-lint:
	bash deploy/lint.sh

clean:
	rm -rf $(VENV) build dist *.egg-info
