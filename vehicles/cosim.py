"""In-process co-simulation: the fleet stepped by the runtime's virtual clock.

The block only advances the simulated physics by the task interval; everything the
controller and the vehicles tell each other still goes over the (virtual) CAN bus. Put it
in its own task with the lowest priority, so it runs after the program in every tick.
"""

from __future__ import annotations

from plc_runtime import CycleContext, FunctionBlock

from .fleet import Fleet


class CoSimulation(FunctionBlock):
    def __init__(self, fleet: Fleet) -> None:
        super().__init__()
        self.fleet = fleet

    def cycle(self, ctx: CycleContext) -> None:
        self.fleet.step(ctx.dt)
