"""The charging policy: its thresholds, the seed's rule, and idle vehicles topping up.

Unit tests of ChargePolicy, then the fleet program on the sample distribution centre (five
chargers): idle vehicles below ``top_up_below`` (``full`` by default) charge while a charger
is to spare, leave one free for a vehicle that must charge, and take an order off the
charger at once."""

from __future__ import annotations

from pathlib import Path

import pytest

from blocks.dispatch.charging import ChargePolicy
from blocks.dispatch.executor import Claims, OrderRunner
from blocks.dispatch.orders import OrderBook, OrderState
from fleet.config import first_vehicles, load_config
from fleet.order_report import order_summary
from fleet.program import FleetProgram
from fleet.tags import PHASE_CODES, PHASE_NAMES
from fleet.web.views import FleetCopy, render_vehicles
from plc_runtime.errors import ConfigError

DISTRIBUTION_CENTRE = (
    Path(__file__).resolve().parent.parent / "examples" / "distribution-centre.toml"
)
CHARGERS = 5  # the distribution centre's
# vehicles at 50 % that top up on all chargers but one (kept free for a vehicle that must
# charge), then two parked at 90 % that will be made to charge
TOPPING_UP = CHARGERS - 1
START_CHARGES = [50.0] * TOPPING_UP + [90.0, 90.0]


def test_thresholds_must_be_ordered():
    with pytest.raises(ValueError, match="critical <= good <= sufficient <= full"):
        ChargePolicy(critical=40.0, good=35.0)


def test_the_seeds_rule_with_the_learned_use_per_order():
    policy = ChargePolicy()  # 15 / 35 / 60 / 95, 2 % per order until one is measured
    assert policy.may_take(37.0) and not policy.may_take(36.9)
    policy.order_used(5.0)
    policy.order_used(-1.0)  # charged on the way: counts as 0
    assert policy.use_per_order == 2.5
    assert policy.may_take(37.5) and not policy.may_take(37.4)
    assert policy.must_charge(37.4) and not policy.must_charge(37.5)
    # a vehicle charging because it had to comes off the charger only once sufficient
    assert not policy.may_take(59.0, charging=True) and policy.may_take(60.0, charging=True)
    assert not policy.may_take(14.0)  # below critical nothing, whatever the use


def test_idle_vehicles_top_up_ten_points_below_full_unless_told_otherwise():
    policy = ChargePolicy()
    assert policy.tops_up(84.9) and not policy.tops_up(85.0)
    assert policy.charged(95.0) and not policy.charged(94.9)
    below = ChargePolicy(top_up_below=60.0)
    assert below.tops_up(59.9) and not below.tops_up(60.0)
    assert ChargePolicy(top_up_below=95.0).tops_up(94.9)
    assert ChargePolicy(full=90.0).top_up_below == 80.0
    assert ChargePolicy(sufficient=88.0, full=90.0).top_up_below == 88.0  # never below it
    assert not ChargePolicy(top_up=False).tops_up(10.0)
    assert not ChargePolicy(enabled=False).tops_up(10.0)


@pytest.mark.parametrize("value", [-1.0, 95.5])
def test_topping_up_past_full_is_refused(value):
    """Past ``full`` a vehicle would leave the charger full and come back to it at once."""
    with pytest.raises(ValueError, match=r"top_up_below must be in 0..full \(95\)"):
        ChargePolicy(top_up_below=value)


def test_top_up_below_in_the_file_and_its_errors(tmp_path):
    plant = DISTRIBUTION_CENTRE.parent / "plants" / "distribution-centre.toml"
    text = (
        DISTRIBUTION_CENTRE.read_text(encoding="utf-8")
        .replace('"plants/distribution-centre.toml"', f'"{plant}"')
        .replace("[battery]\n", "[battery]\ntop_up_below = 70\n")
    )
    path = tmp_path / "dc.toml"
    path.write_text(text, encoding="utf-8")
    assert load_config(path).battery.policy().top_up_below == 70.0
    path.write_text(text.replace("top_up_below = 70", "top_up_below = 99"), encoding="utf-8")
    with pytest.raises(ConfigError, match=r"battery: top_up_below must be in 0..full"):
        load_config(path)


@pytest.fixture
def program():
    made: list[FleetProgram] = []

    def build(
        vehicles: int,
        charge: float | list[float],
        tmp_path: Path,
        top_up: bool = True,
        top_up_below: float | None = None,
        park: bool = True,
        order_s: float = 300.0,
    ) -> FleetProgram:
        cfg = load_config(DISTRIBUTION_CENTRE)
        first_vehicles(cfg, vehicles)
        cfg.watchdog = 5.0
        orders = tmp_path / "orders.csv"
        orders.write_text(f"id,get,put,start_s\nlate,31,41,{order_s:g}\n", encoding="utf-8")
        cfg.orders.file, cfg.orders.generator, cfg.orders.lead_s = orders, None, 0.0
        cfg.dispatch.park = park
        charges = charge if isinstance(charge, list) else [charge] * vehicles
        cfg.battery.start = dict(zip(sorted(cfg.starts), charges, strict=True))
        cfg.battery.top_up = top_up
        cfg.battery.top_up_below = top_up_below
        p = FleetProgram(cfg)
        made.append(p)
        p.rt.start()
        return p

    yield build
    for p in made:
        p.close()


def run(p: FleetProgram, seconds: float) -> None:
    for _ in range(round(seconds / p.cfg.cycle_time)):
        p.rt.step()
        assert p.rt.state == "RUN", p.rt.fault_reason


def released(p: FleetProgram):
    """The order of the file once the book has it (at its start time, 300 s)."""
    return next(iter(p.orders.book), None)


def all_but_one_topping_up(p: FleetProgram, seconds: float = 120.0) -> tuple[list[int], list[int]]:
    """Run a program of vehicles charged ``START_CHARGES`` until the first ``TOPPING_UP``
    top up on chargers; return them and the other two."""
    runners = p.orders.runners
    by_choice, others = sorted(runners)[:TOPPING_UP], sorted(runners)[TOPPING_UP:]
    run(p, seconds)
    assert all(runners[v].phase == "charging" and runners[v].topping_up for v in by_choice)
    return by_choice, others


def drain(p: FleetProgram, vehicles: list[int], percent: float = 20.0) -> None:
    """The simulated batteries of ``vehicles`` drop to ``percent``: they must charge."""
    for v in vehicles:
        battery = p.fleet.vehicles[v].battery
        battery.charge_as = percent / 100.0 * battery.params.capacity_as


def test_idle_vehicles_top_up_and_leave_one_charger_free(program, tmp_path):
    assert len(load_config(DISTRIBUTION_CENTRE).plant.with_role("charger")) == CHARGERS
    p = program(CHARGERS, 50.0, tmp_path)
    run(p, 250.0)
    runners = p.orders.runners
    charging = sorted(v for v, r in runners.items() if r.phase == "charging")
    assert len(charging) == TOPPING_UP  # one charger stays free for a vehicle that must charge
    assert all(runners[v].topping_up for v in charging)
    (other,) = set(runners) - set(charging)
    assert runners[other].phase == "parked"
    held = {place for place, v in p.orders.claims.holder.items() if v in charging}
    assert held == {runners[v].current for v in charging}
    assert set(p.cfg.plant.with_role("charger")) - held  # (a charger is free)


def test_a_vehicle_that_must_charge_gets_a_charger_from_one_topping_up(program, tmp_path):
    """Five chargers: four vehicles at 50 % top up, leaving one charger free; two more,
    parked at 90 %, then drop to 20 % and must charge. The first takes the free charger,
    the second finds every charger taken: one vehicle topping up, and only one, gives its
    charger up and backs out of the charger's spur while the other waits to drive in."""
    p = program(len(START_CHARGES), START_CHARGES, tmp_path)
    runners = p.orders.runners
    by_choice, must = all_but_one_topping_up(p)
    drain(p, must)
    run(p, 170.0)  # (the file's order comes at 300 s)
    for v in must:
        assert runners[v].phase == "charging" and not runners[v].topping_up, v
    still = [v for v in by_choice if runners[v].phase == "charging" and runners[v].topping_up]
    assert len(still) == TOPPING_UP - 1
    (gave_up,) = set(by_choice) - set(still)
    assert runners[gave_up].phase == "parked" and runners[gave_up].charges == 1
    assert runners[gave_up].battery < 60  # it left before it was charged: it was asked to
    claims = p.orders.claims
    assert {claims.holder[c] for c in p.cfg.plant.with_role("charger")} == {*must, *still}
    assert claims.offered == {runners[v].current: v for v in still}
    assert p.monitor.head_on == p.monitor.node == p.monitor.area == 0
    charging = order_summary(p.orders)["charging"]
    assert (charging["visits"], charging["top_ups"], charging["given_up"]) == (6, 4, 1)
    assert runners[gave_up].chargers_given_up == 1


def test_the_operator_tells_a_vehicle_topping_up_from_one_that_must_charge(program, tmp_path):
    """The same six vehicles as above. The HMI's phase word, the report's rows and the web
    API show a vehicle driving to a charger or charging by choice as ``to_top_up`` /
    ``topping_up``, and one whose battery needs the charge as ``to_charger`` /
    ``charging``."""
    p = program(len(START_CHARGES), START_CHARGES, tmp_path)
    runners = p.orders.runners
    by_choice, must = sorted(runners)[:TOPPING_UP], sorted(runners)[TOPPING_UP:]

    def shown(r: OrderRunner) -> str:
        if r.phase in ("to_charger", "charging") and r.topping_up:
            return {"to_charger": "to_top_up", "charging": "topping_up"}[r.phase]
        return r.phase

    seen: dict[int, set[str]] = {v: set() for v in runners}
    before = {v: shown(r) for v, r in runners.items()}
    for second in range(290):
        if second == 120:
            drain(p, must)
        run(p, 1.0)
        for v, r in runners.items():
            word = p.rt.image.read(f"agv{v}.phase")
            # the phase of this scan, or of the one before if it changed after the word's copy
            assert word in (PHASE_CODES[shown(r)], PHASE_CODES[before[v]]), (v, second)
            seen[v].add(PHASE_NAMES[word])
            before[v] = shown(r)
    for v in by_choice:
        assert {"to_top_up", "topping_up"} <= seen[v], v
    for v in must:
        assert {"to_charger", "charging"} <= seen[v] and "topping_up" not in seen[v], v
    rows = {row["vehicle"]: row["phase"] for row in p.vehicle_rows()}
    api = {row["id"]: row["phase"] for row in render_vehicles(FleetCopy(p)())}
    assert rows == api == {v: shown(r) for v, r in runners.items()}
    # one gave its charger up
    assert sorted(rows.values()).count("topping_up") == TOPPING_UP - 1
    assert [rows[v] for v in must] == ["charging", "charging"]


def test_a_charger_held_by_a_vehicle_out_of_service_is_not_asked_for(program, tmp_path):
    """As above, but the vehicles topping up nearest to the second vehicle that must
    charge, all but the farthest, fail on their chargers and are given up: it asks the
    farthest, not one of theirs (they may never move)."""
    p = program(len(START_CHARGES), START_CHARGES, tmp_path)
    runners = p.orders.runners
    by_choice, must = all_but_one_topping_up(p, 100.0)
    asking = runners[must[1]]
    nearest = sorted(by_choice, key=lambda v: asking.distance(asking.current, runners[v].current))
    for v in nearest[:-1]:
        p.fleet.vehicles[v].fault = True
    run(p, 65.0)  # (out of service for 60 s, a vehicle gives up)
    assert p.orders.claims.out_of_service == set(nearest[:-1])
    drain(p, must)
    run(p, 130.0)  # (the file's order comes at 300 s)
    assert runners[must[0]].phase == runners[must[1]].phase == "charging"
    assert runners[nearest[-1]].phase == "parked"
    assert p.monitor.head_on == p.monitor.node == p.monitor.area == 0


def test_a_vehicle_topping_up_takes_an_order_off_the_charger(program, tmp_path):
    p = program(1, 50.0, tmp_path)
    runner = p.orders.runners[1]
    run(p, 295.0)
    assert runner.phase == "charging" and runner.battery < 60  # below sufficient
    assert p.rt.run_until(lambda: released(p) is not None, max_cycles=round(10 / 0.05))
    order = released(p)
    assert p.rt.run_until(lambda: order.assigned == 1, max_cycles=round(10 / 0.05))
    assert p.rt.run_until(lambda: order.state is OrderState.FINISHED, max_cycles=round(600 / 0.05))
    assert runner.charges == 1


def test_an_idle_vehicle_above_sufficient_tops_up_to_full_unless_told_otherwise(program, tmp_path):
    """The chargers' idle hours are energy the fleet needs once its batteries have run
    down: an idle vehicle at 80 % charges too, and leaves the charger full; one at 90 %
    parks (it would lose that much parking after a charge)."""
    p = program(1, 80.0, tmp_path)
    runner = p.orders.runners[1]
    run(p, 250.0)
    assert runner.phase == "charging" and runner.topping_up
    p.close()  # (one runtime at a time: the watchdog's interrupt is the process's)
    full = program(1, 90.0, tmp_path)
    run(full, 250.0)
    assert full.orders.runners[1].phase == "parked"
    full.close()
    low = program(1, 80.0, tmp_path, top_up_below=60.0)
    run(low, 250.0)
    assert low.orders.runners[1].phase == "parked"


def test_without_top_up_idle_vehicles_park(program, tmp_path):
    p = program(2, 50.0, tmp_path, top_up=False)
    run(p, 250.0)
    assert [r.phase for r in p.orders.runners.values()] == ["parked", "parked"]


def test_a_vehicle_that_must_charge_waits_for_the_sufficient_charge(program, tmp_path):
    """Below good + the use of an order it charges by need: no order until 60 %."""
    p = program(1, 36.0, tmp_path)
    runner = p.orders.runners[1]
    run(p, 400.0)
    assert runner.phase == "charging" and not runner.topping_up
    assert runner.battery < 60
    order = released(p)
    assert order.state is OrderState.DISPATCHABLE and order.assigned is None


def test_a_vehicle_queued_for_a_charger_cut_off_asks_another(program, tmp_path):
    """A vehicle that must charge queues for a charger a vehicle tops up on; then a
    blockade closes the way into that charger's spur (the vehicle there can still back
    out). It cannot get there: it asks a charger it can reach, whose vehicle tops up,
    and the charger cut off does not stay reserved for it."""
    p = program(len(START_CHARGES), START_CHARGES, tmp_path)
    runners, claims, plant = p.orders.runners, p.orders.claims, p.cfg.plant
    _by_choice, must = all_but_one_topping_up(p)
    drain(p, must)
    asked = None
    for _ in range(round(120.0 / p.cfg.cycle_time)):
        p.rt.step()
        asked = next(
            ((c, q[0]) for c, q in claims.waiting.items() if c in plant.with_role("charger") and q),
            None,
        )
        if asked is not None:
            break
    assert asked is not None
    charger, waiter = asked
    (lane,) = {int(plant.ids[j]) for j, _a, _w in plant.neighbors[plant.idx(charger)]}
    p.blockades.block(lane, charger, both_ways=False)  # in: closed; out: open
    run(p, 120.0)
    assert not runners[waiter]._reachable(charger)
    assert runners[waiter].phase == "charging", (
        runners[waiter].phase,
        claims.waiting,
        {v: (r.phase, r.topping_up, r.current) for v, r in runners.items()},
    )


def test_without_parking_a_vehicle_topping_up_keeps_its_charger(program, tmp_path):
    """With ``park = false`` an idle vehicle stays where it is: one topping up that gave
    its charger up to a vehicle that must charge would stand on it for ever, charging
    neither itself nor the other."""
    p = program(len(START_CHARGES), START_CHARGES, tmp_path, park=False, order_s=3000.0)
    runners = p.orders.runners
    _by_choice, must = all_but_one_topping_up(p)
    drain(p, must)
    run(p, 300.0)
    charging = {v for v, r in runners.items() if r.phase == "charging"}
    on_chargers = {r.current for r in runners.values()} & set(p.cfg.plant.with_role("charger"))
    # every vehicle that stands on a charger charges on it
    assert len(charging) == len(on_chargers), {
        v: (r.phase, r.topping_up, r.current, r.battery) for v, r in runners.items()
    }
    assert runners[must[0]].phase == "charging"


def test_a_vehicle_that_gave_its_charger_up_does_not_take_it_again(program, tmp_path):
    """Chargers 81, 82 and 85 are cut off; two vehicles top up on 83 and 84. A third must
    charge and asks one of them for its charger: that one gives it up and does not take
    it straight back (the two chargers cut off count as free to it). (Or, with the
    chargers cut off not counted as spare, only one tops up.)"""
    p = program(3, [50.0, 50.0, 90.0], tmp_path)
    for charger, lane in ((81, 482), (82, 481), (85, 475)):
        p.blockades.block(lane, charger)
    runners = p.orders.runners
    run(p, 120.0)
    assert runners[1].phase == "charging" and runners[1].topping_up
    drain(p, [3])
    run(p, 120.0)
    assert runners[3].phase == "charging", {
        v: (r.phase, r.topping_up, r.current, r.charges) for v, r in runners.items()
    }
    assert all(runners[v].charges <= 2 for v in (1, 2))


def test_a_vehicle_back_on_the_charger_it_was_leaving_offers_it_only_by_choice():
    """Leaving its charger, a vehicle offers it to one that must charge; back on it because
    it must charge itself (its order was taken back before it moved), it does not, and
    topping up there, it does again."""
    plant = load_config(DISTRIBUTION_CENTRE).plant
    claims = Claims()
    book = OrderBook({s: "station" for s in plant.with_role("station")})
    runner = OrderRunner(1, plant, book, claims, ChargePolicy(), distance=lambda _a, _b: 0.0)
    charger = plant.with_role("charger")[0]
    assert claims.claim(charger, 1)
    runner.vacating = charger  # it stands on it, given up
    runner._offer_charger()
    assert claims.offered == {charger: 1}
    runner.place = charger  # it must charge, and took the same charger again
    runner._offer_charger()
    assert claims.offered == {}
    runner.topping_up = True
    runner._offer_charger()
    assert claims.offered == {charger: 1}
