# Every target works from a clean clone: the virtual environment is created and the
# pinned dependencies installed on first use (and again whenever pyproject.toml changes).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test bench bench-quick lint clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/plc-runtime run --duration 600 --out out

test: $(STAMP)
	$(BIN)/python -m pytest

# The durations stated are measured for the cheap scripts and taken from the recorded runs
# for the fleet ones (docs/benchmarks.md, "Running them"); each script prints its own wall
# time at the end.
bench: $(STAMP)
	@echo "make bench: about 262 minutes in all on 2 otherwise idle vCPUs, much longer on a busy machine"
	@echo "  (minutes: step_rate 0.5, scan_jitter 2, heuristic_table 3, astar_step 1, io_throughput 1,"
	@echo "  fleet_scale 10, warehouse_throughput 80 (both plants) + 26 (both traffic modes, delays), allocation 75, order_backlog 1.5, long_run 32 (two processes), time_windows 0.1, windowed_search 0.1, lorr 25, web_load 5). make bench-quick runs them all reduced in about 6 minutes."
	$(BIN)/python bench/step_rate.py
	$(BIN)/python bench/scan_jitter.py
	$(BIN)/python bench/heuristic_table.py
	$(BIN)/python bench/astar_step.py
	$(BIN)/python bench/io_throughput.py
	$(BIN)/python bench/fleet_scale.py
	$(BIN)/python bench/warehouse_throughput.py
	$(BIN)/python bench/warehouse_throughput.py --plant kiva --sizes 60 140 --timesteps 300 --traffic reactive time_windows
	$(BIN)/python bench/warehouse_throughput.py --plant kiva --sizes 60 --timesteps 300 --traffic reactive time_windows --delay-rate 0 0.001 0.01
	$(BIN)/python bench/allocation.py
	$(BIN)/python bench/order_backlog.py
	$(BIN)/python bench/long_run.py --jobs 2
	$(BIN)/python bench/time_windows.py
	$(BIN)/python bench/windowed_search.py
	$(BIN)/python bench/lorr.py
	$(BIN)/python bench/lorr.py --kiva 60 100 140
	$(BIN)/python bench/lorr.py --kiva 60 100 140 --follow next_step
	$(BIN)/python bench/web_load.py

# Every benchmark in a reduced form (smaller plants, fewer cycles, timesteps and fleet sizes),
# with the same tables and ratios: a check that they all still run, not numbers to record.
bench-quick: $(STAMP)
	$(BIN)/python bench/step_rate.py --quick
	$(BIN)/python bench/scan_jitter.py --quick
	$(BIN)/python bench/heuristic_table.py --quick
	$(BIN)/python bench/astar_step.py --quick
	$(BIN)/python bench/io_throughput.py --quick
	$(BIN)/python bench/fleet_scale.py --quick
	$(BIN)/python bench/warehouse_throughput.py --quick
	$(BIN)/python bench/allocation.py --quick
	$(BIN)/python bench/order_backlog.py --quick
	$(BIN)/python bench/long_run.py --quick
	$(BIN)/python bench/time_windows.py --quick
	$(BIN)/python bench/windowed_search.py --quick
	$(BIN)/python bench/lorr.py --quick
	$(BIN)/python bench/web_load.py --quick

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis
