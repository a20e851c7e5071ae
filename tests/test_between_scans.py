"""The runtime's point between scans: ``between_scans`` is clear exactly while a scan runs,
and a driver's ``after_scan`` runs after each scan, outside its measured time."""

from conftest import Probe

from plc_runtime import Runtime, VirtualClock


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
