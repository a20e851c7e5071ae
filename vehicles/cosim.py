"""In-process co-simulation: the fleet stepped by the runtime's virtual clock.

The block only advances the simulated physics by the task interval; everything the
controller and the vehicles tell each other still goes over the (virtual) CAN bus. Put it
in its own task with the lowest priority, so it runs after the program in every tick.
"""

from __future__ import annotations

from plc_runtime import CycleContext, FunctionBlock

from .fleet import Fleet
from .monitor import ConflictMonitor


class CoSimulation(FunctionBlock):
    def __init__(self, fleet: Fleet, monitor: ConflictMonitor | None = None) -> None:
        super().__init__()
        self.fleet = fleet
        self.monitor = monitor

    def cycle(self, ctx: CycleContext) -> None:
        self.fleet.step(ctx.dt)
        if self.monitor is not None:
            self.monitor.check()
