"""Goal vehicles: a script sends vehicles to nodes of its choosing, and the fleet program
drives them there with its routing, reservations and traffic, on a plant of realistic size,
in both traffic modes, with the independent monitor watching."""

from __future__ import annotations

import numpy as np
import pytest

from blocks.jobs.goals import GoalQueue
from fleet.config import FleetConfig
from fleet.program import FleetProgram
from fleet.report import summary
from fleet.tags import PHASE_CODES
from plc_runtime.errors import ConfigError
from topology import kiva


def goal_fleet(vehicles: int, traffic: str, seed: int = 0) -> FleetProgram:
    plant = kiva()
    starts = np.random.default_rng(seed).choice(plant.ids, size=vehicles, replace=False)
    cfg = FleetConfig(
        source="goals-test",
        plant=plant,
        starts={v + 1: int(s) for v, s in enumerate(starts)},
        recipes={},
        vehicle_recipes={},
        clusters={},
        goal_vehicles=list(range(1, vehicles + 1)),
        cycle_time=0.05,
        watchdog=5.0,  # behaviour, not wall time
        traffic=traffic,
    )
    return FleetProgram(cfg)


@pytest.mark.parametrize("traffic", ["reactive", "time_windows"])
def test_vehicles_reach_the_goals_a_script_sends_in_order(traffic, made):
    """20 vehicles on kiva (1,278 nodes), three goals each, sent while they run: every
    goal is reached, in the order sent, and the monitor counts no conflict."""
    p = goal_fleet(20, traffic)
    made.append(p)
    rng = np.random.default_rng(1)
    sent = {
        v: [int(n) for n in rng.choice(p.cfg.plant.ids, size=3, replace=False)] for v in p.goals
    }
    p.rt.start()
    p.rt.run(duration=1)
    for v, goals in sent.items():
        assert (
            p.goals[v].phase == "idle" and p.rt.image.read(f"agv{v}.phase") == PHASE_CODES["idle"]
        )
        p.goals[v].send(*goals)
    assert p.rt.run_until(
        lambda: all(g.rounds_done == 3 for g in p.goals.values()),
        max_cycles=round(400 / p.cfg.cycle_time),
    ), {v: g.rounds_done for v, g in p.goals.items()}
    for v, goals in sent.items():
        assert [node for node, _t in p.goals[v].reached] == goals
        assert p.goals[v].target is None and not p.goals[v].pending
    assert p.monitor.head_on == 0 and p.monitor.node == 0
    p.rt.step()
    assert p.rt.image.read("agv1.rounds") == 3
    assert summary(p, 0.0)["goals_reached"] == 60


def test_a_goal_vehicle_shows_where_it_is_sent(made):
    p = goal_fleet(3, "reactive")
    made.append(p)
    p.rt.start()
    p.rt.run(duration=1)
    far = int(p.cfg.plant.ids[-1])
    p.goals[2].send(far)
    p.rt.run(duration=1)
    assert p.rt.image.read("agv2.target") == far
    assert p.rt.image.read("agv2.phase") == PHASE_CODES["to_goal"]


def test_a_goal_that_is_no_node_is_refused_and_nothing_is_queued():
    queue = GoalQueue(4, kiva())
    with pytest.raises(ValueError, match="vehicle 4: goal 99999 is not a node of the plant kiva"):
        queue.send(0, 99999)
    with pytest.raises(ValueError, match="vehicle 4: goal '7' is not a node id"):
        queue.send("7")
    assert not queue.pending
    queue.send(np.int64(0), 1)  # numpy integers, as plant.ids gives them
    assert list(queue.pending) == [0, 1] and all(type(n) is int for n in queue.pending)


def test_goal_vehicles_are_checked_with_the_configuration(made):
    p = goal_fleet(2, "reactive")
    cfg = p.cfg
    cfg.goal_vehicles = [1, 2, 3]
    with pytest.raises(ConfigError, match="goal_vehicles: vehicle 3 has no start"):
        FleetProgram(cfg)
    cfg.goal_vehicles = [1]
    with pytest.raises(ConfigError, match="vehicle 2 has no recipes, takes no orders"):
        FleetProgram(cfg)
