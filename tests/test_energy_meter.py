"""EnergyMeter and EnergyBalance: the rates a fleet's battery readings give, and the chargers
its work needs sustained. The expected figures are worked out here from the readings fed in,
and, for a whole run, from the simulated battery's own currents."""

from __future__ import annotations

import pytest
from test_orders_program import config, run, start

from blocks.dispatch.energy import EnergyBalance, EnergyMeter
from plc_runtime import CycleContext


def feed(meter: EnergyMeter, readings: list[tuple[float, int | None, bool]]) -> EnergyMeter:
    """Readings (time s, battery %, on a charger), one scan each."""
    ctx = CycleContext(None, "fleet", 50_000_000)
    for t, battery, on_charger in readings:
        ctx.time_ns = round(t * 1e9)
        meter(ctx, battery=battery, on_charger=on_charger)
    return meter


def test_off_the_chargers_the_drop_from_the_first_reading_to_the_last_is_counted():
    # a gauge that reads up once on the way (rounding, noise) counts no extra drain
    meter = feed(
        EnergyMeter(), [(0, 80, False), (60, 79, False), (120, 80, False), (180, 77, False)]
    )
    assert meter.drained == 3 and meter.drained_s == 180
    assert meter.charged == 0 and meter.charged_s == 0


def test_charging_counts_until_the_battery_is_full_and_a_stretch_by_its_start():
    meter = feed(
        EnergyMeter(),
        [
            (0, 60, False),
            (100, 58, True),  # the stretch before this reading was off a charger
            (700, 88, True),
            (1300, 100, True),
            (1900, 100, True),  # full on the charger: not charging, not counted
            (2000, 99, False),  # a stretch counts as what the vehicle was at its start
            (2100, 98, False),
        ],
    )
    assert meter.drained == 2 + 1 and meter.drained_s == 100 + 100
    assert meter.charged == 42 and meter.charged_s == 1200


def test_a_vehicle_without_readings_starts_a_new_stretch():
    meter = feed(
        EnergyMeter(), [(0, 90, False), (10, None, False), (500, 50, False), (510, 49, False)]
    )
    assert meter.drained == 1 and meter.drained_s == 10  # the silent 490 s say nothing


def test_the_chargers_needed_are_the_fleets_share_of_time_on_a_charger():
    # 20 % an hour off the chargers, 60 % an hour on one: a quarter of the time charging
    a = feed(EnergyMeter(), [(0, 90, False), (1800, 80, False)])
    b = feed(EnergyMeter(), [(0, 50, False), (1800, 40, True), (3600, 70, True)])
    balance = EnergyBalance.of([a, b])
    assert balance.drain_per_h == pytest.approx(20.0)
    assert balance.charge_per_h == pytest.approx(60.0)
    assert balance.chargers_needed == pytest.approx(2 * 20 / (20 + 60))
    assert EnergyBalance.of([a]).chargers_needed is None  # nothing charged yet: not known
    assert EnergyBalance.of([]) == EnergyBalance(None, None, None)


def test_a_run_reports_the_simulated_batterys_rates_and_the_chargers_it_needs(tmp_path, made):
    """One vehicle, an order, a charge: the summary's rates against the battery model (30 A
    on a charger into 185,000 As is 58.4 % an hour)."""
    extra = "[battery]\ngood = 35\nsufficient = 36\nfull = 42\n"
    cfg = config("id,get,put\na,20,29\nb,22,27\n", tmp_path, vehicles=((1, 0),), extra=extra)
    cfg.battery.start = {1: 36.0}
    p = start(cfg, made)
    runner, agv = p.orders.runners[1], p.fleet.vehicles[1]
    run(p, 1200)
    assert runner.charges >= 1
    meter = runner.meter
    params = agv.battery.params
    assert meter.charged_s > 300
    # whole per cents: the charge counted is the model's over that time within the rounding
    # of a reading at each end
    model_per_h = 100 * 3600 * params.charge_current / params.capacity_as
    assert abs(meter.charged - model_per_h * meter.charged_s / 3600) <= 1.5, (
        meter.charged,
        meter.charged_s,
    )
    per_h = 3600.0 * meter.charged / meter.charged_s
    from fleet.report import summary

    charging = summary(p, 1.0)["charging"]
    assert charging["charge_pct_per_h"] == round(per_h, 2)
    assert charging["drain_pct_per_h"] == round(3600.0 * meter.drained / meter.drained_s, 2)
    drain, charge = charging["drain_pct_per_h"], charging["charge_pct_per_h"]
    assert charging["chargers_needed"] == pytest.approx(drain / (drain + charge), abs=0.01)
    assert charging["chargers"] == len(p.cfg.plant.with_role("charger"))
