"""The examples/ folder: every fleet configuration runs, every plant file validates, the
default job there is the embedded one, and the MovingAI-format map is what its script makes.

A configuration runs on the virtual clock (fleet_scenarios.run: zero head-on, node and
single-vehicle area conflicts from the independent monitor after every cycle, the A*
budget, no forced takeover) for ``SIMULATED_S`` and must complete at least one recipe in
that time, or, with transport orders, run ``ORDERS_S`` and finish at least one order (a
distribution centre's transports take minutes, not seconds).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from fleet_scenarios import Trace, run

from blocks.jobs.recipe import EXIT, return_lanes
from fleet.config import DEFAULT_CONFIG, load_config
from fleet.program import FleetProgram
from topology import load

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
PLANTS = EXAMPLES / "plants"
CONFIGS = sorted(EXAMPLES.glob("*.toml"))
PLANT_FILES = sorted(
    p for p in PLANTS.iterdir() if p.suffix in (".toml", ".json", ".map", ".nodes")
)
SIMULATED_S = 90.0  # every example completes its first recipe well within this
ORDERS_S = 240.0  # and finishes its first transport order within this


def test_there_are_examples():
    names = {p.name for p in CONFIGS}
    assert {"default.toml", "warehouse.toml"} <= names and len(names) >= 3
    assert PLANT_FILES


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.name)
def test_example_config_runs_without_conflicts(path):
    cfg = load_config(path)
    cfg.watchdog = 5.0  # behaviour is tested here, not wall time: a busy machine must not fault
    program = FleetProgram(cfg)
    try:
        wanted = ORDERS_S if cfg.order_vehicles else SIMULATED_S
        seconds = min(cfg.duration_s, wanted)
        trace = run(program, seconds)
        assert program.rt.state == "RUN"
        assert program.monitor.head_on == 0 and program.monitor.node == 0
        assert program.monitor.area == 0, program.monitor.events
        assert program.resolver.unresolved == 0
        if seconds == wanted and cfg.order_vehicles:
            finished = program.orders.book.counts()["FINISHED"]
            assert finished, f"{path.name}: no order finished in {seconds} s"
        if seconds == wanted and cfg.vehicle_recipes:
            assert program.completed, f"{path.name}: no recipe completed in {seconds} s"
            if return_lanes(cfg.plant) and all(
                r.functions[-1] == EXIT for r in cfg.recipes.values()
            ):
                _came_back_for_the_next_recipe(program, trace)
    finally:
        program.close()


def _came_back_for_the_next_recipe(program: FleetProgram, trace: Trace) -> None:
    """Recipes that end at the exit end there, and a vehicle has driven the return lane back
    to the entry and started its next recipe."""
    lanes = return_lanes(program.cfg.plant)
    assert all(r.sections[-1].station in lanes for r in program.completed)
    again = [v for v, s in program.sequencers.items() if s.run.round >= 2]
    assert again, "no vehicle started a second recipe"
    for v in again:
        driven = trace.segments(v)
        assert any(lane[:2] in driven for lane in lanes.values()), (v, driven)


@pytest.mark.parametrize("path", PLANT_FILES, ids=lambda p: p.name)
def test_example_plant_validates_without_warnings(path):
    plant = load(path)
    assert plant.n > 0
    assert not plant.warnings, plant.warnings


def test_default_example_is_the_embedded_default():
    """fleet/default.toml is what ``plc-runtime run`` runs without a file (it must live in the
    package: an installed copy has no examples/ folder); examples/default.toml shows it."""
    assert (EXAMPLES / "default.toml").read_bytes() == DEFAULT_CONFIG.read_bytes()


def test_random_map_is_what_its_script_makes(tmp_path):
    out = tmp_path / "random-32-32.map"
    subprocess.run(
        [sys.executable, str(PLANTS / "make_random_map.py"), "--out", str(out)],
        check=True,
        timeout=60,
    )
    assert out.read_bytes() == (PLANTS / "random-32-32.map").read_bytes()
    plant = load(out)
    assert plant.n == 32 * 32 - (PLANTS / "random-32-32.map").read_text().count("@")
