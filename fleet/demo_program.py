"""The demo program: a small two-task PLC program that exercises the standard library.

Task ``main`` (every base tick): a lamp ``%QX0.0`` flashes at 1 Hz unless the stop button
``%IX0.1`` is pressed; every flash is counted in a retentive marker word. Task ``slow``
(every 100 ms, phase 50 ms, lower priority) smooths the analog input ``%IW2`` into
``%MW10`` and keeps the uptime in whole seconds in ``%MD4``. It shows the runtime's
semantics without a fleet: ``plc-runtime run --program demo``.
"""

from __future__ import annotations

from blocks.standard import CTU, R_TRIG, TON
from plc_runtime import CycleContext, FunctionBlock, Runtime, Static, TagTable
from plc_runtime.clock import VirtualClock, WallClock


class Flasher(FunctionBlock):
    """Flash the lamp at 1 Hz while not stopped, count rising edges of the lamp."""

    def __init__(self) -> None:
        super().__init__()
        self.half_period = TON()
        self.lamp_edge = R_TRIG()
        self.flashes = CTU(retain=True)

    def cycle(self, ctx: CycleContext) -> None:
        img = ctx.image
        running = not img.read("stop_button")
        lamp = img.read("lamp")
        if self.half_period(ctx, IN=running, PT=0.5):
            lamp = not lamp
            self.half_period(ctx, IN=False)  # restart the timer in this same scan,
            self.half_period(ctx, IN=True)  # so the period is exactly 2 x PT
        if not running:
            lamp = False
        img.write("lamp", lamp)
        self.flashes(ctx, CU=self.lamp_edge(ctx, CLK=lamp), R=img.read("reset_count"), PV=32767)
        img.write("flash_count", self.flashes.CV)


class Supervisor(FunctionBlock):
    """Low-rate housekeeping: first-order filter of an analog input, uptime counter."""

    filtered = Static(0.0)

    def cycle(self, ctx: CycleContext) -> None:
        raw = ctx.image.read("analog_in")
        self.filtered += 0.2 * (raw - self.filtered)
        ctx.image.write("analog_filtered", round(self.filtered))
        ctx.image.write("uptime_s", int(ctx.time))


def tags() -> TagTable:
    table = TagTable()
    table.add("stop_button", "%IX0.1", "BOOL", comment="stops the flasher while TRUE")
    table.add("reset_count", "%IX0.2", "BOOL", comment="resets the flash counter")
    table.add("analog_in", "%IW2", "INT", comment="raw analog input")
    table.add("lamp", "%QX0.0", "BOOL", comment="the flashing lamp")
    table.add("flash_count", "%MW0", "INT", retain=True, comment="flashes counted")
    table.add("uptime_s", "%MD4", "DINT", comment="seconds since start")
    table.add("analog_filtered", "%MW10", "INT", comment="filtered analog input")
    return table


def build(
    clock: VirtualClock | WallClock | None = None,
    cycle_time: float = 0.010,
    watchdog: float = 0.150,
    retain_file: str | None = None,
) -> Runtime:
    rt = Runtime(
        cycle_time=cycle_time, clock=clock, watchdog=watchdog, tags=tags(), retain_file=retain_file
    )
    slow = max(cycle_time, round(0.100 / cycle_time) * cycle_time)
    rt.add_task("main", [Flasher()], interval=cycle_time, priority=0)
    rt.add_task(
        "slow",
        [Supervisor()],
        interval=slow,
        priority=1,
        phase=(round(slow / cycle_time) // 2) * cycle_time,
    )
    return rt
