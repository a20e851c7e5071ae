"""The runtime's point between scans: ``between_scans`` is clear exactly while a scan runs,
and a driver's ``after_scan`` runs after each scan, outside its measured time."""

import pytest
from conftest import Probe

from plc_runtime import ConfigError, Runtime, VirtualClock


class RecordingDriver:
    name = "recorder"

    def __init__(self, rt: Runtime, log: list) -> None:
        self.rt, self.log = rt, log

    def open(self, image) -> None: ...

    def read_inputs(self, image, now_ns: int) -> None:
        self.log.append(("read", self.rt.between_scans.is_set()))

    def write_outputs(self, image, now_ns: int) -> None:
        self.log.append(("write", self.rt.between_scans.is_set()))

    def after_scan(self) -> None:
        self.log.append(("after", self.rt.between_scans.is_set(), self.rt.stats.scan.cycles))

    def close(self) -> None: ...

    def stats(self) -> dict[str, object]:
        return {}


def test_between_scans_is_clear_in_a_scan_and_after_scan_follows_its_statistics():
    rt = Runtime(cycle_time=0.01, clock=VirtualClock())
    log: list = []
    rt.add_task("main", [Probe(lambda ctx: log.append(("block", rt.between_scans.is_set())))])
    rt.add_driver(RecordingDriver(rt, log))
    assert rt.between_scans.is_set()
    rt.start()
    rt.run(cycles=3)
    assert rt.between_scans.is_set()
    scans = [log[i : i + 4] for i in range(0, len(log), 4)]
    assert len(scans) == 3
    for k, scan in enumerate(scans, start=1):
        assert scan[:3] == [("read", False), ("block", False), ("write", False)]
        assert scan[3] == ("after", True, k)  # recorded already: its time is not the scan's
    rt.stop()


def test_a_failing_after_scan_faults_the_runtime_naming_the_driver():
    rt = Runtime(cycle_time=0.01, clock=VirtualClock())
    driver = RecordingDriver(rt, [])

    def fail() -> None:
        raise ValueError("boom")

    driver.after_scan = fail
    rt.add_task("main", [Probe(lambda ctx: None)])
    rt.add_driver(driver)
    rt.start()
    rt.run(cycles=2)
    assert rt.state == "FAULT"
    assert "driver recorder: after_scan raised ValueError" in rt.fault_reason
    assert rt.between_scans.is_set()


class LeadClock(VirtualClock):
    """A virtual clock that notes, at every wait, where it waits to and the event's state."""

    def __init__(self) -> None:
        super().__init__()
        self.waits: list[tuple[int, bool]] = []
        self.rt: Runtime | None = None

    def wait_until(self, t_ns: int) -> None:
        self.waits.append((t_ns, self.rt.between_scans.is_set()))
        super().wait_until(t_ns)


def test_a_quiet_lead_clears_between_scans_before_the_scan_is_due():
    clock = LeadClock()
    rt = Runtime(cycle_time=0.01, clock=clock)
    clock.rt = rt
    seen: list[tuple[int, bool]] = []
    rt.add_task("main", [Probe(lambda ctx: seen.append(rt.between_scans.is_set()))])
    rt.ask_quiet_lead(0.002)
    rt.ask_quiet_lead(0.001)  # a smaller ask keeps the larger lead
    assert rt.quiet_lead == 0.002
    rt.start()
    clock.waits.clear()
    first = rt.ticks
    rt.run(cycles=2)
    # per tick: to 2 ms before the release with the event set, then to the release with
    # it clear; the blocks run with it clear, and it is set again after the scan
    releases = [rt._t0 + k * 10_000_000 for k in (first, first + 1)]
    assert clock.waits == [w for r in releases for w in ((r - 2_000_000, True), (r, False))]
    assert seen[-2:] == [False, False] and rt.between_scans.is_set()


def test_a_quiet_lead_is_checked():
    rt = Runtime(cycle_time=0.01, clock=VirtualClock())
    for bad in (-0.001, 0.006, float("nan"), "1"):
        with pytest.raises(ConfigError, match="quiet lead"):
            rt.ask_quiet_lead(bad)
    assert rt.quiet_lead == 0.0
