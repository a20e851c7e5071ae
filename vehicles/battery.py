"""Battery model of seed-000 (OpenShuttle study): current A = b0 + b1*v + b2*a (a clipped at
0), 185,000 As capacity, 30 A on a charger; servos switch off after a few idle seconds and
the draw falls to the idle current. The coefficients are configurable; the defaults give
the reported ~3.5 h discharge from 100 % to 35 % at typical duty."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class BatteryParams:
    capacity_as: float = 185_000.0
    b0: float = 7.0  # A, servos on, standing
    b1: float = 5.0  # A per m/s
    b2: float = 10.0  # A per m/s^2 (acceleration only)
    idle_current: float = 4.5  # A, servos off
    servo_off_after: float = 5.0  # s without motion
    charge_current: float = 30.0  # A on a charger


class Battery:
    def __init__(self, params: BatteryParams | None = None, charge: float = 1.0) -> None:
        self.params = params or BatteryParams()
        self.charge_as = self.params.capacity_as * charge
        self.idle_for = 0.0
        self.failed = False

    @property
    def percent(self) -> float:
        return 0.0 if self.failed else 100.0 * self.charge_as / self.params.capacity_as

    def step(self, dt: float, speed: float, accel: float, charging: bool) -> None:
        p = self.params
        self.idle_for = 0.0 if speed > 0 else self.idle_for + dt
        if charging:
            self.charge_as = min(p.capacity_as, self.charge_as + p.charge_current * dt)
            return
        current = (
            p.idle_current
            if self.idle_for >= p.servo_off_after
            else p.b0 + p.b1 * speed + p.b2 * max(accel, 0.0)
        )
        self.charge_as = max(0.0, self.charge_as - current * dt)
