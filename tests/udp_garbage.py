"""Run inside a private network namespace by test_vehicles_processes.py: a datagram on the
udp_multicast bus's group and port that is no frame at all (a stray sender, a faulty
node), read by the controller's driver and by the simulated vehicles. Prints what each
made of it, as one JSON line."""

import json
import socket
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from fleet_helpers import Dispatcher  # noqa: E402

from io_drivers.can_bus import UDP_MULTICAST_PORT, open_can_bus  # noqa: E402
from io_drivers.can_driver import CanDriver  # noqa: E402
from plc_runtime import Runtime, VirtualClock  # noqa: E402
from topology import model_plant  # noqa: E402
from vehicles.fleet import Fleet  # noqa: E402

GROUP = "239.74.163.2"

driver = CanDriver([1], interface="udp_multicast", channel=GROUP)
rt = Runtime(cycle_time=0.010, clock=VirtualClock(), watchdog=60.0)
rt.add_driver(driver)
rt.add_task("program", [Dispatcher({})])
rt.start()
fleet = Fleet(model_plant(), {1: 0}, bus=open_can_bus("udp_multicast", GROUP))
sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
sender.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
sender.sendto(b"\xc1 no packed frame", (GROUP, UDP_MULTICAST_PORT))
sender.close()
for _ in range(20):  # the datagram, then the vehicle's own frames, on both ends
    fleet.step(0.010)
    rt.step()
print(json.dumps({"state": rt.state, "driver": driver.counters, "vehicles": fleet.counters}))
rt.stop()
fleet.bus.shutdown()
