"""Runtime and vehicles in separate processes over udp_multicast, in a private network
namespace (loopback only: nothing leaves the machine). Needs root and util-linux unshare."""

import json
import sys
from pathlib import Path

import pytest
from netns import run_isolated, unavailable

HERE = Path(__file__).resolve().parent


REASON = unavailable()


@pytest.mark.skipif(REASON is not None, reason=REASON or "")
def test_runtime_and_vehicles_in_separate_processes():
    result = run_isolated(f"{sys.executable} {HERE / 'udp_fleet_program.py'}")
    assert result.returncode == 0, result.stderr[-2000:]
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["arrived"] is True
    assert report["vehicles"]["vehicles"]["1"]["driven"] == [0, 6, 7, 8, 9, 24]
    assert report["vehicles"]["vehicles"]["2"]["driven"] == [1, 15, 2]
    assert report["driver"]["malformed"] == 0 and report["driver"]["frames_in"] > 0


@pytest.mark.skipif(REASON is not None, reason=REASON or "")
def test_a_datagram_that_is_no_frame_is_counted_and_the_reading_goes_on():
    """python-can's udp_multicast raises on a datagram it cannot unpack; neither end lets
    that out of its step (it faulted the controller and ended the vehicles' process)."""
    result = run_isolated(f"{sys.executable} {HERE / 'udp_garbage.py'}")
    assert result.returncode == 0, result.stderr[-2000:]
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["state"] == "RUN"
    assert report["driver"]["receive_errors"] == 1
    assert report["driver"]["frames_in"] > 0  # the vehicle's own frames after it
    assert report["vehicles"]["ignored"] == 1 and report["vehicles"]["sent"] > 0
