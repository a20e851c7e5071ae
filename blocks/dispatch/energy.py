"""EnergyMeter: what a vehicle's battery readings say of the energy its work takes, and the
chargers a fleet needs to keep working.

A fleet's batteries start charged, so a run of an hour or two says little of what charging
costs: the plant runs short only once the batteries have run down, and then for as long as
it runs. Whether it does follows from two rates: how fast a vehicle's charge falls while it
is off the chargers (driving, waiting and standing at stations together, its duty) and how
fast a charger fills it. A vehicle then spends ``drain / (drain + charge)`` of its time on a
charger, and a fleet of N needs that many times N chargers, sustained. Both rates are
measured from the state of charge the vehicles report, as the charging policy learns its
consumption per order: the controller needs no model of the drives.

Readings are whole per cents, so the meter sums the signed changes between successive
readings: over a stretch off the chargers they add up to its first reading less its last,
whatever the rounding or a gauge's noise. Time on a charger with a full battery is not
charging, and does not count.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from plc_runtime import CycleContext, FunctionBlock, Input, Output, Static


class EnergyMeter(FunctionBlock):
    battery = Input(None, doc="state of charge in %, from the vehicle's info frames; None: none")
    on_charger = Input(False, doc="TRUE while the vehicle stands charging on a charger")

    drained = Output(0.0, doc="% of the capacity lost off the chargers")
    drained_s = Output(0.0, doc="time off the chargers with readings, s")
    charged = Output(0.0, doc="% of the capacity gained on the chargers")
    charged_s = Output(0.0, doc="time charging a battery that was not full, s")

    last = Static(None)  # (reading %, time s, on a charger) of the reading before

    def cycle(self, ctx: CycleContext) -> None:
        if self.battery is None:  # no reading (yet, or any more): no stretch to measure
            self.last = None
            return
        if self.last is not None:
            before, since, charging = self.last
            change, took = self.battery - before, ctx.time - since
            if charging:
                if before < 100:
                    self.charged += change
                    self.charged_s += took
            else:  # a reading that rose (rounding, a gauge's noise) is taken back later
                self.drained -= change
                self.drained_s += took
        self.last = (self.battery, ctx.time, bool(self.on_charger))


@dataclass(frozen=True)
class EnergyBalance:
    """A fleet's rates, in % of the capacity per hour, and the chargers its work needs."""

    drain_per_h: float | None  # off the chargers, per vehicle
    charge_per_h: float | None  # on a charger
    chargers_needed: float | None  # sustained, for the whole fleet

    @classmethod
    def of(cls, meters: Iterable[EnergyMeter]) -> EnergyBalance:
        meters = list(meters)
        drained_s = sum(m.drained_s for m in meters)
        charged_s = sum(m.charged_s for m in meters)
        drain = 3600.0 * sum(m.drained for m in meters) / drained_s if drained_s > 0 else None
        charge = 3600.0 * sum(m.charged for m in meters) / charged_s if charged_s > 0 else None
        needed = None
        if drain is not None and charge is not None and drain + charge > 0:
            needed = len(meters) * drain / (drain + charge)
        return cls(drain, charge, needed)
