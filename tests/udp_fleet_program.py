"""Run inside a private network namespace by test_vehicles_processes.py: the vehicles in one
process, the runtime in this one, talking over udp_multicast on loopback only."""

import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from fleet_helpers import Dispatcher, record  # noqa: E402

from io_drivers.can_driver import CanDriver  # noqa: E402
from plc_runtime import Runtime, WallClock  # noqa: E402

GROUP = "udp_multicast:239.74.163.2"
script = Path(sys.executable).parent / "plc-runtime"
vehicles = subprocess.Popen(
    [
        str(script),
        "vehicles",
        "--plant",
        "model-plant",
        "--count",
        "2",
        "--bus",
        GROUP,
        "--duration",
        "60",
        "--json",
    ],
    stdout=subprocess.PIPE,
    stderr=subprocess.PIPE,
    text=True,
)
try:
    vehicles.stderr.readline()  # the vehicles process is up
    driver = CanDriver([1, 2], interface="udp_multicast", channel=GROUP.split(":", 1)[1])
    rt = Runtime(
        cycle_time=0.010, clock=WallClock(), watchdog=5.0
    )  # a busy machine must not fault it
    rt.add_driver(driver)
    program = Dispatcher({1: [0, 6, 7, 8, 9, 24], 2: [1, 15, 2]})
    rt.add_task("program", [program])
    rt.start()
    arrived = rt.run_until(
        lambda: (
            rt.image.read(f"%IW{record(1) // 2}") == 24
            and rt.image.read(f"%IW{record(2) // 2}") == 2
        ),
        max_cycles=3000,
    )
    stats = driver.stats()
    rt.stop()
    vehicles.terminate()  # SIGTERM: the vehicles process stops cleanly and reports
    out, _err = vehicles.communicate(timeout=30)
finally:
    if vehicles.poll() is None:
        vehicles.terminate()
        vehicles.wait(timeout=10)
print(json.dumps({"arrived": arrived, "driver": stats, "vehicles": json.loads(out)}))
