PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
HOST ?= 127.0.0.1
PORT ?= 8000
DATA_DIR ?= ./var
CHROMIUM ?= /usr/bin/chromium
# test processes (pytest-xdist; a file's tests stay in one process, which its module fixtures assume)
TEST_WORKERS ?= 2

.PHONY: run test lint venv bench clean browser

$(BIN)/illumon: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e ".[service,dev]"
	touch $(BIN)/illumon

venv: $(BIN)/illumon

run: venv
	mkdir -p -m 700 $(DATA_DIR)
	$(BIN)/illumon serve --host $(HOST) --port $(PORT) --data-dir $(DATA_DIR)

lint: venv
	$(BIN)/ruff check core service tests benchmarks tools

# Debian's chromium for the status-page browser test (tests/browser); that test skips with the reason when it is absent.
browser:
	@if [ -x "$(CHROMIUM)" ]; then echo "browser: $(CHROMIUM) present"; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	  echo "browser: installing Debian's chromium (apt-get) for the status-page test"; \
	  export DEBIAN_FRONTEND=noninteractive; log=$$(mktemp); \
	  { apt-get install -y -q --no-install-recommends chromium >$$log 2>&1 || \
	    { apt-get update -q >>$$log 2>&1 && apt-get install -y -q --no-install-recommends chromium >>$$log 2>&1; }; } \
	  || { tail -n 5 $$log; echo "browser: apt-get could not install chromium; the browser test will skip"; }; rm -f $$log; \
	else echo "browser: no $(CHROMIUM), and not root with apt-get: the browser test will skip"; fi

test: venv browser lint
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile -m "not serial"
	$(BIN)/python -m pytest -q -m serial

bench: venv
	$(BIN)/python benchmarks/retrieval.py

clean:
	rm -rf $(VENV) build *.egg-info
