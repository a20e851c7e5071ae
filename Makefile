# Every target works from a clean clone: the virtual environment is created and the
# pinned dependencies installed on first use (and again whenever pyproject.toml changes).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test bench lint clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/plc-runtime run --duration 600 --out out

test: $(STAMP)
	$(BIN)/python -m pytest

bench: $(STAMP)
	$(BIN)/python bench/step_rate.py
	$(BIN)/python bench/scan_jitter.py
	$(BIN)/python bench/heuristic_table.py
	$(BIN)/python bench/astar_step.py
	$(BIN)/python bench/io_throughput.py
	$(BIN)/python bench/fleet_scale.py
	$(BIN)/python bench/warehouse_throughput.py

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis
