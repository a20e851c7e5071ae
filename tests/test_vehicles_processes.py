"""Runtime and vehicles in separate processes over udp_multicast, in a private network
namespace (loopback only: nothing leaves the machine). Needs root and util-linux unshare."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent


def can_make_namespace() -> str | None:
    if os.geteuid() != 0:
        return "needs root to create a network namespace"
    if not shutil.which("unshare") or not shutil.which("ip"):
        return "needs unshare (util-linux) and ip (iproute2)"
    probe = subprocess.run(["unshare", "-n", "true"], capture_output=True, check=False)
    return None if probe.returncode == 0 else f"unshare -n refused: {probe.stderr.decode().strip()}"


REASON = can_make_namespace()


@pytest.mark.skipif(REASON is not None, reason=REASON or "")
def test_runtime_and_vehicles_in_separate_processes():
    inside = (
        "ip link set lo up && ip route add 224.0.0.0/4 dev lo && "
        f"exec {sys.executable} {HERE / 'udp_fleet_program.py'}"
    )
    result = subprocess.run(
        ["unshare", "-n", "sh", "-c", inside],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["arrived"] is True
    assert report["vehicles"]["vehicles"]["1"]["driven"] == [0, 6, 7, 8, 9, 24]
    assert report["vehicles"]["vehicles"]["2"]["driven"] == [1, 15, 2]
    assert report["driver"]["malformed"] == 0 and report["driver"]["frames_in"] > 0
