"""Test helpers for fleet tests: a small dispatching program over the CanDriver image map."""

from io_drivers.can_driver import GO_BIT, ONLINE
from plc_runtime import FunctionBlock


def record(v, base=1024):
    return base + 8 * v


class Dispatcher(FunctionBlock):
    """Test program: releases each vehicle's route three nodes at a time, following the
    position it reports (a new window whenever it reaches a node), and sets its go bit."""

    def __init__(self, routes):
        super().__init__()
        self.routes = routes  # vehicle -> every node from its start to its goal
        self.sequence = {}
        self.released = {}

    def cycle(self, ctx):
        img = ctx.image
        for v, route in self.routes.items():
            base = record(v)
            if not img.read(f"%IB{base + 7}") & ONLINE:
                continue
            current = img.read(f"%IW{base // 2}")
            if current not in route:
                continue
            window = tuple(route[route.index(current) + 1 :][:3])
            if window and window != self.released.get(v):
                self.released[v] = window
                self.sequence[v] = self.sequence.get(v, 0) % 255 + 1
                for k, node in enumerate(window):
                    img.write(f"%QW{base // 2 + k}", node)
                img.write(f"%QB{base + 7}", self.sequence[v])
            img.write(f"%QB{base + 6}", GO_BIT | len(self.released.get(v, ())))
