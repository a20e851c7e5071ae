"""Records that keep their newest entries (``plc_runtime.recent.RecentList``): copies,
entries added other than at the end, and the reports read from them once they were
trimmed."""

from __future__ import annotations

import copy
import json
import pickle
from pathlib import Path

import pytest

import vehicles.monitor
from fleet.cli import main
from fleet.config import DEFAULT_CONFIG
from plc_runtime.recent import RecentList
from vehicles.monitor import ConflictMonitor


def trimmed() -> RecentList[int]:
    kept = RecentList(3, range(10))
    assert kept == [7, 8, 9] and kept.total == 10
    return kept


@pytest.mark.parametrize(
    "clone",
    [copy.copy, copy.deepcopy, lambda r: pickle.loads(pickle.dumps(r))],
    ids=["copy", "deepcopy", "pickle"],
)
def test_a_copy_of_a_recent_list_keeps_its_entries_count_and_capacity(clone):
    kept = trimmed()
    other = clone(kept)
    assert isinstance(other, RecentList)
    assert other == [7, 8, 9] and other.total == 10 and other.capacity == 3
    other.append(10)
    assert kept.total == 10 and other.total == 11  # a copy, not the same record


@pytest.mark.parametrize(
    "grow",
    [
        lambda r: r.insert(0, 99),
        lambda r: r.__setitem__(slice(len(r), len(r)), range(20)),
        lambda r: r.__imul__(10),
    ],
    ids=["insert", "slice", "imul"],
)
def test_entries_are_added_at_the_end_only_counted_and_trimmed(grow):
    """An entry added another way would be neither counted nor ever trimmed."""
    kept = trimmed()
    with pytest.raises(TypeError):
        grow(kept)
    assert kept == [7, 8, 9] and kept.total == 10


def test_changing_entries_in_place_is_still_allowed():
    kept = trimmed()
    kept[0] = 70
    kept[1:3] = [80, 90]
    assert kept == [70, 80, 90] and kept.total == 10


def test_the_vehicle_process_monitor_report_shows_the_newest_conflicts(tmp_path, monkeypatch):
    """``vehicles --monitor-out``: once the monitor trimmed its conflicts, the report's
    events are the newest ones, not whichever happened to be the oldest kept."""
    from ports import free_base_port

    monkeypatch.setattr(vehicles.monitor, "EVENTS_KEPT", 100)

    class Busy(ConflictMonitor):
        """250 node conflicts at the first step: 149 of them kept (trimmed to 100 at the
        201st), the oldest kept being the 102nd."""

        def check(self) -> None:
            while self.node < 250:
                self.node += 1
                conflict = vehicles.monitor.Conflict(float(self.node), "node", (1,), (1, 2))
                self.events.append(conflict)

    monkeypatch.setattr(vehicles.monitor, "ConflictMonitor", Busy)
    report = tmp_path / "m.json"
    port = str(free_base_port(4))
    args = ["vehicles", "--config", str(DEFAULT_CONFIG), "--modbus-base-port", port]
    assert main([*args, "--duration", "0.3", "--monitor-out", str(report)]) == 0
    out = json.loads(report.read_text())
    assert out["node_conflicts"] == 250
    times = [e["time_s"] for e in out["events"]]
    assert times == [float(k) for k in range(151, 251)]  # the newest 100, oldest first


def test_the_documented_examples_count_recipes_by_their_total():
    """``program.completed`` keeps the newest runs: its length is not the recipes done."""
    root = Path(__file__).resolve().parent.parent
    for page in [root / "README.md", *sorted((root / "docs").glob("*.md"))]:
        assert "len(program.completed)" not in page.read_text(encoding="utf-8"), page.name


class ManyConflicts(ConflictMonitor):
    """250 node conflicts at the first check: with 100 kept, 149 of them are held (trimmed
    to 100 at the 201st), the oldest held being the 102nd."""

    def check(self) -> None:
        while self.node < 250:
            self.node += 1
            conflict = vehicles.monitor.Conflict(float(self.node), "node", (1,), (1, 2))
            self.events.append(conflict)


def test_the_warehouse_bench_counts_the_conflicts_it_does_not_print(monkeypatch, capsys):
    import fleet.program

    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parent.parent / "bench"))
    import warehouse_throughput

    monkeypatch.setattr(vehicles.monitor, "EVENTS_KEPT", 100)
    monkeypatch.setattr(fleet.program, "ConflictMonitor", ManyConflicts)
    argv = ["warehouse_throughput.py", "--plant", "kiva", "--sizes", "3", "--timesteps", "15"]
    monkeypatch.setattr("sys.argv", [*argv, "--bound-timesteps", "15"])
    warehouse_throughput.main()
    out = capsys.readouterr().out
    assert "... 240 more conflicts with 3 vehicles" in out


def test_the_simulated_vehicles_json_says_how_many_nodes_driven_holds():
    """``vehicles --json``: ``driven`` holds the newest DRIVEN_KEPT nodes at least and twice
    that at most (``RecentList``), which is what the README tells a script to expect."""
    from topology import model_plant
    from vehicles.agv import AGV, DRIVEN_KEPT

    agv = AGV(1, model_plant(), 6)
    for k in range(int(1.5 * DRIVEN_KEPT)):  # as AGV.step records a node reached
        agv.driven.append(7 if k % 2 == 0 else 6)
    assert DRIVEN_KEPT < len(agv.driven) <= 2 * DRIVEN_KEPT
    readme = " ".join((Path(__file__).resolve().parent.parent / "README.md").read_text().split())
    assert f"the newest {DRIVEN_KEPT} at least ({2 * DRIVEN_KEPT} at most)" in readme
