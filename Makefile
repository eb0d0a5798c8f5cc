PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
HOST ?= 127.0.0.1
PORT ?= 8000
DATA_DIR ?= ./var

.PHONY: run test lint venv bench clean

$(BIN)/illumon: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e ".[service,dev]"
	touch $(BIN)/illumon

venv: $(BIN)/illumon

run: venv
	mkdir -p $(DATA_DIR)
	$(BIN)/illumon serve --host $(HOST) --port $(PORT) --data-dir $(DATA_DIR)

lint: venv
	$(BIN)/ruff check core service tests benchmarks

test: venv
	$(BIN)/ruff check core service tests benchmarks
	$(BIN)/python -m pytest -q

bench: venv
	$(BIN)/python benchmarks/retrieval.py

clean:
	rm -rf $(VENV) build *.egg-info
