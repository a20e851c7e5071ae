"""A running controller with its HTTP API, for the order API and CLI tests.

The workshop-orders fleet (examples/workshop-orders.toml: 3 vehicles, a small plant) with a
``WebServer`` on a free loopback port. Scanning, it runs in a background thread on the
virtual clock paced at ``speed`` simulated seconds per wall second (the scan is the same as
unpaced; pacing only keeps the CPU use modest), with the watchdog widened so a busy machine
cannot fault it. Not scanning, it is started and never stepped: the controller as a client
sees it when the scan has stopped.

Leaving the ``with`` block stops the run and checks what every run must leave behind: no
server thread, and nothing listening on the port.
"""

from __future__ import annotations

import http.client
import json
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from fleet.config import load_config
from fleet.program import FleetProgram
from fleet.web.server import WebServer
from plc_runtime.clock import PacedClock, VirtualClock

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "examples" / "workshop-orders.toml"
TOKEN = "test-token-0123456789abcdef"
WATCHDOG_S = 30.0
START_TIMEOUT_S = 60.0  # the heuristic table is built in the startup phase


@dataclass
class Reply:
    status: int
    body: Any  # the decoded JSON
    headers: dict[str, str] = field(default_factory=dict)


class Controller:
    def __init__(
        self, *, speed: float = 50.0, scanning: bool = True, config: Path = CONFIG, **web: Any
    ) -> None:
        self.speed, self.scanning, self.web_options = speed, scanning, web
        self.config = config
        self._thread: threading.Thread | None = None
        self._failed: BaseException | None = None

    def __enter__(self) -> Controller:
        self._before = set(threading.enumerate())  # another controller's server may be up
        cfg = load_config(self.config)
        cfg.watchdog = WATCHDOG_S
        clock = PacedClock(self.speed) if self.scanning else VirtualClock()
        self.program = FleetProgram(cfg, clock=clock)
        self.web = WebServer(self.program, "127.0.0.1", 0, token=TOKEN, **self.web_options)
        self.program.rt.add_driver(self.web)
        if not self.scanning:
            self.program.rt.start()
        else:
            started = threading.Event()
            self._thread = threading.Thread(
                target=self._run, args=(started,), name="test-controller"
            )
            self._thread.start()
            if not started.wait(START_TIMEOUT_S) or self._failed is not None:
                self.__exit__(None, None, None)
                raise RuntimeError(f"the controller did not start: {self._failed}")
        self.port = self.web.port
        self.url = self.web.url
        return self

    def _run(self, started: threading.Event) -> None:
        try:
            self.program.rt.start()
        except BaseException as exc:
            self._failed = exc
            return
        finally:
            started.set()
        self.program.rt.run()  # until request_stop()

    def __exit__(self, *exc: object) -> None:
        self.program.rt.request_stop()
        if self._thread is not None:
            self._thread.join(START_TIMEOUT_S)
            assert not self._thread.is_alive(), "the controller's run did not end"
        self.program.close()
        assert_server_gone(getattr(self, "port", None), self._before)

    def call(
        self,
        method: str,
        path: str,
        body: object = None,
        *,
        token: str | None = None,
        headers: dict[str, str] | None = None,
        raw: bytes | None = None,
    ) -> Reply:
        """``method path`` on the API; ``body`` as JSON, or ``raw`` bytes as they are."""
        return call(self.port, method, path, body, token=token, headers=headers, raw=raw)

    def sim_time(self) -> float:
        return self.program.rt.clock.now_ns() / 1e9


def call(
    port: int,
    method: str,
    path: str,
    body: object = None,
    *,
    token: str | None = None,
    headers: dict[str, str] | None = None,
    raw: bytes | None = None,
) -> Reply:
    sent = dict(headers or {})
    data = raw
    if body is not None:
        data = json.dumps(body).encode()
        sent.setdefault("Content-Type", "application/json")
    if token is not None:
        sent["Authorization"] = f"Bearer {token}"
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    try:
        conn.request(method, path, data, sent)
        reply = conn.getresponse()
        text = reply.read()
        return Reply(reply.status, json.loads(text), {k.lower(): v for k, v in reply.getheaders()})
    finally:
        conn.close()


def assert_server_gone(port: int | None, before: set[threading.Thread] = frozenset()) -> None:
    """No HTTP server thread is left (but those in ``before``), and nothing listens on
    ``port`` any more."""
    left = [t.name for t in set(threading.enumerate()) - before if t.name.startswith("fleet-web")]
    assert not left, f"server threads left behind: {left}"
    if port is not None:
        assert_port_closed(port)


def assert_port_closed(port: int) -> None:
    with socket.socket() as s:
        assert s.connect_ex(("127.0.0.1", port)) != 0, f"port {port} still accepts connections"


WAIT_WALL_S = 60.0  # a wait for the running scan: far beyond what the simulated time needs


def eventually(check: Callable[[], Any], what: str, wall_s: float = WAIT_WALL_S) -> Any:
    """Poll ``check()`` until it returns something truthy; fail naming ``what``. A wall-clock
    deadline, never a duration asserted: the server answers on its own thread."""
    deadline = time.monotonic() + wall_s
    while time.monotonic() < deadline:
        result = check()
        if result:
            return result
        time.sleep(0.05)
    pytest.fail(f"{what}: not seen within {wall_s:g} s of wall time")
