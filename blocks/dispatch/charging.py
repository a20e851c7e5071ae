"""ChargePolicy: when a vehicle stops taking orders, goes charging, and comes back.

Thresholds as openTCS names them (state of charge in %):

* ``critical`` (default 15): below it a vehicle takes nothing, not even an order while it is
  charging;
* ``good`` (default 35, the seed's threshold): a vehicle takes a new order only if it is
  expected to end that order at or above it;
* ``sufficient`` (default 60): a charging vehicle may be taken off the charger for an order
  (the charge is interruptible) once it has this much;
* ``full`` (default 95): a charging vehicle with no order leaves the charger.

The seed's policy: estimate the consumption of the next order (learned as the mean drop per
finished order; ``default_use`` until one is known); if it would end below ``good`` the
vehicle deregisters, finishes its active order and drives to a free charger, and it
re-registers when the charge is sufficient. Consumption is learned from what the vehicles
report, so the controller needs no model of their drives.

Idle vehicles top up (openTCS's "recharge idle vehicles"): with ``top_up`` on, a vehicle that
has no order and is below ``top_up_below`` charges instead of parking, while one charger
stays free for a vehicle that must charge. Such a vehicle is charging by choice, not by
need, so it stays available: it takes an order by the plain ``good`` rule, off the charger
at once. A fleet that charges in its idle minutes seldom has to stop working
to charge. Topping up from well above ``sufficient`` matters once the batteries the fleet
started with have run down: the chargers' idle hours before that are energy the fleet needs
later, and vehicles that charged at different times no longer all need a charger at once.
By default ``top_up_below`` is ``TOP_UP_GAP`` points below ``full`` (not below
``sufficient``): a vehicle that left the charger full does not come back to it for the few
points it loses driving to a parking place and standing there.
"""

from __future__ import annotations

from dataclasses import dataclass, field

# points of charge below ``full`` where idle vehicles top up by default: a vehicle leaves the
# charger at ``full``, and standing with its servos off it loses some 2.4 % an hour (4.5 A of
# 185,000 As), so it comes back after hours, not minutes
TOP_UP_GAP = 10.0


@dataclass
class ChargePolicy:
    critical: float = 15.0
    good: float = 35.0
    sufficient: float = 60.0
    full: float = 95.0
    default_use: float = 2.0  # % per order until the first order was measured
    window: int = 50  # orders the mean consumption is taken over
    enabled: bool = True
    top_up: bool = True
    top_up_below: float | None = None  # idle, it charges by choice below it; None: the default
    _uses: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        levels = (self.critical, self.good, self.sufficient, self.full)
        if not all(0.0 <= x <= 100.0 for x in levels) or list(levels) != sorted(levels):
            raise ValueError(
                "battery thresholds must satisfy 0 <= critical <= good <= sufficient <= full "
                f"<= 100, got {levels}"
            )
        if self.top_up_below is None:
            self.top_up_below = max(self.sufficient, self.full - TOP_UP_GAP)
        if not 0.0 <= self.top_up_below <= self.full:
            # above full a vehicle would leave the charger full and come back at once
            raise ValueError(
                f"top_up_below must be in 0..full ({self.full:g}), got {self.top_up_below:g}"
            )

    @property
    def use_per_order(self) -> float:
        """The expected consumption of one order, in % of the capacity."""
        return sum(self._uses) / len(self._uses) if self._uses else self.default_use

    def order_used(self, percent: float) -> None:
        """A finished order used ``percent`` of the capacity (a negative value, charged on
        the way, counts as 0)."""
        self._uses.append(max(0.0, float(percent)))
        del self._uses[: -self.window]

    def may_take(self, battery: float, charging: bool = False) -> bool:
        """May a vehicle at ``battery`` % take a new order? One charging because it had to
        (``charging``) only once its charge is sufficient (the charge is interrupted)."""
        if not self.enabled:
            return True
        if battery < self.critical or (charging and battery < self.sufficient):
            return False
        return battery - self.use_per_order >= self.good

    def must_charge(self, battery: float) -> bool:
        """Without an order: must the vehicle go charging? Not once it is full: a vehicle
        whose orders are expected to use more than ``full - good`` stays idle at full
        charge rather than shuttling to the charger for ever (the thresholds are too tight
        for its orders, which the summary's charging figures show)."""
        return self.enabled and battery < self.full and not self.may_take(battery)

    def tops_up(self, battery: float) -> bool:
        """Without an order: may the vehicle charge by choice (a charger free to spare)?"""
        return self.enabled and self.top_up and battery < self.top_up_below

    def charged(self, battery: float) -> bool:
        """Charging without an order: may it leave the charger?"""
        return not self.enabled or battery >= self.full
