"""Texts from users reach the operator's screen literally: an order id ``[/oops]`` or
``[red]x``, a station name, a reason or a file name is not rich markup (it used to stop a
live run with a MarkupError, or show ``[red]x`` as a red "x")."""

from __future__ import annotations

import pytest
from rich.console import Console

from blocks.dispatch.orders import TransportOrder
from fleet.config import load_config
from fleet.dashboard import dashboard, final_tables
from fleet.program import FleetProgram
from fleet.report import summary

CONFIG = "examples/workshop-orders.toml"
MARKUP = ("[/oops]", "[red]x")


def rendered(renderable: object, width: int) -> str:
    console = Console(width=width, record=True, force_terminal=False, color_system=None)
    console.print(renderable)
    return console.export_text()


@pytest.fixture
def program():
    """The workshop fleet with the two orders taken by vehicles 1 and 2."""
    p = FleetProgram(load_config(CONFIG))
    try:
        p.rt.start()
        p.orders.submit(TransportOrder(MARKUP[0], 21, 25, priority=9, vehicle=1))
        p.orders.submit(TransportOrder(MARKUP[1], 23, 27, priority=9, vehicle=2))
        for _ in range(100):
            p.rt.step()
            if {r["order"] for r in p.vehicle_rows()} >= set(MARKUP):
                break
        assert {r["order"] for r in p.vehicle_rows()} >= set(MARKUP)
        p.events.add(p.rt.clock_time, "replan", 3, "[bold]segment[/bold] [/oops]")
        yield p
    finally:
        p.close()


@pytest.mark.parametrize("width", [80, 200])
def test_the_dashboard_shows_order_ids_and_events_literally(program, width):
    text = rendered(dashboard(program, None, width=width), width)
    for oid in MARKUP:
        assert f" {oid} " in text
    assert "[bold]segment[/bold] [/oops]" in text


def test_the_final_tables_show_names_reasons_and_files_literally(program):
    result = summary(program, wall_s=1.0)
    result["station_utilisation"]["[/s]"] = {
        "assigned": 1,
        "visits": 1,
        "busy_s": 5.0,
        "utilisation": 0.5,
    }
    result["fault_reason"] = "block [red]x raised [/oops]"
    result["files"] = {"summary": "[/out]/summary.json"}
    result["charging"].update(visits=7, top_ups=5, given_up=2)
    text = rendered(final_tables(result), 200)
    for literal in ("[/s]", "FAULT: block [red]x raised [/oops]", "[/out]/summary.json"):
        assert literal in text
    assert "7 visits (5 topping up, 2 given up)" in text


@pytest.mark.parametrize(
    "needed, chargers, says",
    [
        (4.43, 4, "4 in the plant, 4.43 needed sustained: too few, the fleet falls behind"),
        (4.43, 5, "5 in the plant, 4.43 needed sustained"),
        (None, 1, "1 in the plant; needed: unknown until a vehicle has charged"),
    ],
)
def test_the_final_tables_say_whether_the_plant_has_chargers_enough(
    program, needed, chargers, says
):
    """Batteries start charged, so a short run shows no shortage of chargers yet: the
    table compares the plant's chargers with the run's energy balance."""
    result = summary(program, wall_s=1.0)
    result["charging"].update(chargers_needed=needed, chargers=chargers)
    text = " ".join(rendered(final_tables(result), 400).split())
    assert says in text
    assert ("too few" in text) == (needed is not None and needed > chargers)


@pytest.mark.parametrize("width", [80, 60])
def test_the_final_tables_never_cut_a_number_short(program, width):
    """A long run's numbers in an 80-column terminal (COLUMNS=80) or narrower: every one
    is shown whole, on lines no wider than the terminal, the columns split over more
    tables where one cannot take them all."""
    result = summary(program, wall_s=1.0)
    for stats in [*result["tasks"].values(), result["scan"]]:
        stats["cycles"], stats["overruns"], stats["omitted"] = 60000, 12345, 54321
        stats["exec_us"] |= {"mean": 96.0, "p99": 255.4, "max": 18044123.3}
        stats["lateness_us"] |= {"p99": 7000.5, "max": 1234567.5}
    text = rendered(final_tables(result), width)
    assert "…" not in text and max(len(line) for line in text.splitlines()) <= width
    for number in ("60000", "96.0", "255.4", "18044123.3", "7000.5", "1234567.5", "12345", "54321"):
        rows = [line for line in text.splitlines() if f" {number} " in line]
        assert len(rows) == len(result["tasks"]) + 1, number  # each task's and the scan's
