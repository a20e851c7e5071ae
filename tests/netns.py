"""Running a command in a private network namespace with multicast on loopback: processes
talk over udp_multicast and nothing leaves the machine. Needs root and util-linux unshare."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys


def unavailable() -> str | None:
    """Why no namespace can be made here, or None."""
    if os.geteuid() != 0:
        return "needs root to create a network namespace"
    if not shutil.which("unshare") or not shutil.which("ip"):
        return "needs unshare (util-linux) and ip (iproute2)"
    probe = subprocess.run(["unshare", "-n", "true"], capture_output=True, check=False)
    return None if probe.returncode == 0 else f"unshare -n refused: {probe.stderr.decode().strip()}"


def run_isolated(command: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """``command`` (a shell line) inside a fresh namespace with lo up and a multicast route."""
    inside = f"ip link set lo up && ip route add 224.0.0.0/4 dev lo && exec {command}"
    return subprocess.run(
        ["unshare", "-n", "sh", "-c", inside],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


def realtime_run(arguments: str) -> dict:
    """``plc-runtime run --realtime --json ARGUMENTS`` in a fresh namespace (the vehicles a
    child process over udp_multicast): its summary, after the checks every such run must
    pass: it ended well on the wall clock, and the vehicles' own monitor, which reports
    into the summary, counted no conflict."""
    if "--watchdog" not in arguments:  # a busy machine must not fault a wall-clock run
        arguments = f"--watchdog 5000 {arguments}"
    result = run_isolated(f"{sys.executable} -m fleet run --realtime --json {arguments}")
    assert result.returncode == 0, result.stderr[-2000:]
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    assert summary["clock"] == "wall" and summary["state"] == "RUN"
    assert "vehicles' process" in summary["conflict_monitor"]
    assert summary["head_on_conflicts"] == 0 and summary["node_conflicts"] == 0
    return summary
