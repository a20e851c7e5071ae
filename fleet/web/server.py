"""WebServer: the HTTP API and the operator's page, served by uvicorn in its own thread and
event loop, beside the scan.

It is an IoDriver of the runtime, which gives it exactly the life it needs: ``open`` (the
startup phase) binds the socket, asks the runtime for a quiet lead before each scan and
starts the server thread; ``write_outputs`` (the end of every scan, in the scan thread, a
quiet point: no block runs until the next scan) answers the requests waiting in the desks
(:class:`FleetDesk`, :class:`OrderDesk`) and copies the live feed's snapshot when one is
due; ``after_scan`` (once the scan's time is recorded) wakes the server's loop to send the
answers; ``close`` (every stop: the end of the run, Ctrl-C, a fault, a failed start) stops
the thread and closes the socket. So a run never leaves the server behind.

The socket is bound here, before the thread starts, so an address in use is a clear error
at start and port 0 gives a free port (``port`` after ``open``). Binding anything but a
loopback address warns: the token protects writes, but the API is plain HTTP and anyone who
reaches it can read the order book (docs/security.md). uvicorn is told to leave logging,
signals and proxies alone: no access log on the operator's terminal, Ctrl-C stays the run's,
and ``X-Forwarded-For`` from a client is not believed.

Each connection is uvicorn's HTTP/1.1 connection with two limits uvicorn lacks
(:class:`_Connection`): at most ``max_connections`` at once, and the headers of each
request within ``header_timeout`` seconds.
"""

from __future__ import annotations

import asyncio
import logging
import os
import socket
import threading
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any, cast

import uvicorn
from uvicorn.protocols.http.h11_impl import H11Protocol

from io_drivers.modbus_server import is_loopback
from plc_runtime import ConfigError, ProcessImage
from plc_runtime.quiet import QuietSelector

from ..program import FleetProgram
from . import log_lines
from .api import ANSWER_TIMEOUT, PREFIX, build_app
from .desk import OrderDesk
from .feed import MAX_STREAMS, RATE_HZ, LiveFeed
from .fleet_desk import FleetDesk
from .gate import ScanGate
from .guard import (
    BODY_TIMEOUT,
    MAX_BODY,
    MAX_IN_FLIGHT,
    MAX_RATE,
    Guard,
    Receive,
    Scope,
    Send,
    reply,
)
from .views import FleetCopy

START_TIMEOUT = 10.0  # seconds for the server thread to start serving
STOP_TIMEOUT = 10.0  # seconds for it to end (it answers what is in flight first, up to 2 s)
GRACEFUL_S = 2.0
GATE_S = 0.5  # a request waits this long at most for a scan to end before it goes in
# The server's loop starts no work within this share of the cycle before a scan is due: a
# burst of work started just before a scan would run into it (Runtime.quiet_lead).
QUIET_LEAD = 0.1
# connections open at once beyond the streams and requests in flight: a browser keeps a
# few idle keep-alive connections per tab, and bodies still arriving hold no request place
SPARE_CONNECTIONS = 32
HEADER_TIMEOUT = 5.0  # seconds for a request's headers, from the connection or last answer
KEEP_ALIVE_S = 5  # an idle connection is closed after this many seconds

log = logging.getLogger(__name__)


class _Server(uvicorn.Server):
    """uvicorn's server, telling when it serves (or failed to start)."""

    def __init__(self, config: uvicorn.Config) -> None:
        super().__init__(config)
        self.serving = threading.Event()
        self.on_start: Callable[[asyncio.AbstractEventLoop], None] | None = None

    async def startup(self, sockets: list[socket.socket] | None = None) -> None:
        await super().startup(sockets)
        if self.on_start is not None:
            self.on_start(asyncio.get_running_loop())
        self.serving.set()


@dataclass
class _Limits:
    """What every connection of one server shares."""

    max_connections: int
    header_timeout: float
    where: str  # "web 127.0.0.1:8080", for the log
    warned: float = -float("inf")  # loop time of the last warning about the cap


async def _too_many(limit: int, scope: Scope, receive: Receive, send: Send) -> None:
    """The application of a connection beyond the cap: its request is refused."""
    why = f"too many connections (the limit is {limit}): retry"
    await reply(send, 503, why, [(b"connection", b"close")])


class _Connection(H11Protocol):
    """uvicorn's HTTP/1.1 connection, with two limits of its own.

    * At most ``max_connections`` at once: the request of one beyond gets 503 (JSON, like
      every refusal) and its connection is closed; one warning a second at most. uvicorn's
      ``limit_concurrency`` does the same but answers in plain text and logs every refusal.
    * A request's headers must arrive within ``header_timeout`` seconds of the connection
      opening or of the previous answer, else the connection is closed. uvicorn's
      keep-alive timeout stops at the first byte of a request, and nothing bounds the rest:
      a client sending a header line now and then would hold its connection for ever.
    """

    def __init__(self, *args: Any, limits: _Limits, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._limits = limits
        self._timer: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        limits = self._limits
        if len(self.connections) > limits.max_connections:
            self.app = partial(_too_many, limits.max_connections)
            if self.loop.time() - limits.warned >= 1.0:
                limits.warned = self.loop.time()
                log.warning(
                    "%s: refused a connection from %s: %d open (the limit)",
                    limits.where,
                    f"{self.client[0]}:{self.client[1]}" if self.client else "?",
                    limits.max_connections,
                )
        self._expect_request()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        self._expect_request()

    def connection_lost(self, exc: Exception | None) -> None:
        if self._timer is not None:
            self._timer.cancel()
        super().connection_lost(exc)

    def _expect_request(self) -> None:
        """A request's headers are due within the timeout (a new request makes a new
        ``cycle``; the one now, if any, is answered already)."""
        if self._timer is not None:
            self._timer.cancel()
        if not self.transport.is_closing():
            self._timer = self.loop.call_later(
                self._limits.header_timeout, self._headers_due, self.cycle
            )

    def _headers_due(self, cycle: object) -> None:
        """Close the connection if no request has come since ``cycle`` (and none runs)."""
        self._timer = None
        if self.cycle is cycle and (cycle is None or self.cycle.response_complete):
            self.transport.close()


class WebServer:
    """The HTTP API of ``program`` on ``host:port`` (port 0: a free one); writes (POST,
    PUT, DELETE) need ``token``. ``announce(url)`` is called once it listens (the command
    line prints it). ``answer_timeout``, ``max_body``, ``max_in_flight``, ``max_rate``,
    ``body_timeout``, ``stream_hz`` and ``max_streams``: see api.py, guard.py and feed.py;
    ``max_connections`` (None: every stream and request in flight and
    :data:`SPARE_CONNECTIONS` more) and ``header_timeout``: :class:`_Connection`."""

    def __init__(
        self,
        program: FleetProgram,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        token: str,
        name: str = "web",
        answer_timeout: float = ANSWER_TIMEOUT,
        max_body: int = MAX_BODY,
        max_in_flight: int = MAX_IN_FLIGHT,
        max_rate: float = MAX_RATE,
        body_timeout: float = BODY_TIMEOUT,
        max_connections: int | None = None,
        header_timeout: float = HEADER_TIMEOUT,
        stream_hz: float = RATE_HZ,
        max_streams: int = MAX_STREAMS,
        announce: Callable[[str], None] | None = None,
    ) -> None:
        self.name = name
        self.host, self.requested_port = host, port
        self.port: int | None = None  # the bound port while open
        self._program = program
        self._orders = program.orders
        self.desk = OrderDesk(program.orders) if program.orders is not None else None
        self.fleet_desk = FleetDesk(program)
        self.feed = LiveFeed(program, stream_hz, max_streams)
        self.gate = ScanGate(min(answer_timeout, GATE_S))
        self._token = token
        self._answer_timeout = answer_timeout
        self._max_body = max_body
        self._max_in_flight = max_in_flight
        self._max_rate = max_rate
        self._body_timeout = body_timeout
        self._max_connections = (
            max_streams + max_in_flight + SPARE_CONNECTIONS
            if max_connections is None
            else max_connections
        )
        self._header_timeout = header_timeout
        self.guard: Guard | None = None
        self._announce = announce
        self._socket: socket.socket | None = None
        self._server: _Server | None = None
        self._thread: threading.Thread | None = None
        self._selector: QuietSelector | None = None  # its loop's, released at close
        self._error: BaseException | None = None
        self.answered = 0  # requests answered at quiet points

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}"

    # ----- IoDriver ---------------------------------------------------------------------------
    def open(self, image: ProcessImage) -> None:
        log_lines.install()
        loopback = is_loopback(self.host)
        if not loopback:
            warnings.warn(
                f"{self.name}: HTTP API on {self.host or '*'}:{self.requested_port}, not a "
                "loopback address: writes need the token, but it travels in clear text and "
                "anyone who reaches the port can read the order book (docs/security.md)",
                RuntimeWarning,
                stacklevel=2,
            )
        try:
            self._socket = _bind(self.host, self.requested_port)
        except OSError as exc:  # the runtime reports it as "driver web: cannot open: ..."
            why = os.strerror(exc.errno) if exc.errno and exc.errno > 0 else exc.strerror or exc
            raise ConfigError(f"HTTP API on {self.host}:{self.requested_port}: {why}") from None
        self.port = self._socket.getsockname()[1]
        rt = self._program.rt
        rt.ask_quiet_lead(QUIET_LEAD * rt.cycle_time)
        # fresh queues for every start
        self.desk = OrderDesk(self._orders) if self._orders is not None else None
        shared = FleetCopy(self._program)  # one copy of the vehicles per scan, for all
        self.fleet_desk = FleetDesk(self._program, fleet_copy=shared)
        self.feed = LiveFeed(
            self._program, 1.0 / self.feed.period_s, self.feed.max_streams, fleet_copy=shared
        )
        self.gate = ScanGate(min(self._answer_timeout, GATE_S))
        where = f"{self.name} {self.host}:{self.port}"
        app = self.guard = Guard(
            build_app(self.fleet_desk, self.desk, self.feed, self.gate, self._answer_timeout),
            token=self._token,
            where=where,
            loopback=loopback,
            max_body=self._max_body,
            max_in_flight=self._max_in_flight,
            max_rate=self._max_rate,
            body_timeout=self._body_timeout,
            unmetered=(f"{PREFIX}/stream",),
            gate=self.gate,
        )
        limits = _Limits(self._max_connections, self._header_timeout, where)
        config = uvicorn.Config(
            app,
            log_config=None,
            log_level="warning",
            access_log=False,
            lifespan="off",
            # uvicorn calls it as it would the class
            http=cast(type[asyncio.Protocol], partial(_Connection, limits=limits)),
            ws="none",
            loop="asyncio",
            proxy_headers=False,
            server_header=False,
            timeout_keep_alive=KEEP_ALIVE_S,
            timeout_graceful_shutdown=GRACEFUL_S,
        )
        self._server = _Server(config)
        self._server.on_start = self._attach
        self._error = None
        self._thread = threading.Thread(target=self._serve, name=f"fleet-{self.name}", daemon=True)
        self._thread.start()
        if not self._server.serving.wait(START_TIMEOUT) or self._error is not None:
            why = self._error or f"did not start within {START_TIMEOUT:g} s"
            self.close()
            raise ConfigError(f"HTTP API on {self.url}: {why}")
        if self._announce is not None:
            self._announce(self.url)

    def _attach(self, loop: asyncio.AbstractEventLoop) -> None:
        """The server's loop runs: the feed and the gate hand over to it from now on."""
        self.feed.attach(loop)
        self.gate.attach(loop)

    def _serve(self) -> None:
        """The server thread: uvicorn on an event loop whose selector waits, after every
        wake-up, until no scan runs (gate.py), until ``should_exit``."""
        server, sock = self._server, self._socket
        assert server is not None and sock is not None
        selector = self._selector = QuietSelector(self._program.rt.between_scans, GATE_S)
        try:
            with asyncio.Runner(loop_factory=lambda: asyncio.SelectorEventLoop(selector)) as runner:
                runner.run(server.serve([sock]))
        except BaseException as exc:  # a failed start: open() reports it
            self._error = exc
        finally:
            server.serving.set()

    def read_inputs(self, image: ProcessImage, now_ns: int) -> None:
        """Nothing: requests are answered at the end of the scan (``write_outputs``)."""

    def write_outputs(self, image: ProcessImage, now_ns: int) -> None:
        """The end of the scan, after the outputs are copied out: no block runs until the
        next scan, so this is a quiet point too, and the answers show the scan just ended.
        Answering here rather than at the scan's start matters on the wall clock: the
        server's thread renders and sends what it is given while the scan waits for its
        next release, instead of competing with the scan for the interpreter."""
        self.answered += self.fleet_desk.answer()
        if self.desk is not None:
            self.answered += self.desk.answer()
        snapshot = self.feed.due_snapshot()
        self.gate.scan_ended(None if snapshot is None else partial(self.feed.arrive, snapshot))

    def after_scan(self) -> None:
        """After the scan: the server's loop is woken if a request waits or a snapshot is
        due (woken inside the scan, it would take the interpreter from it)."""
        self.gate.after_scan()

    def close(self) -> None:
        """Fail what waits, stop the server thread, close the socket. Idempotent."""
        self.fleet_desk.close()
        if self.desk is not None:
            self.desk.close()
        self.feed.detach()
        self.gate.detach()
        server, thread, sock = self._server, self._thread, self._socket
        self._server = self._thread = self._socket = None
        if self._selector is not None:
            self._selector.release()  # its shutdown does not wait for scans
        if server is not None:
            server.should_exit = True
        if thread is not None:
            thread.join(STOP_TIMEOUT)
            if thread.is_alive():
                warnings.warn(
                    f"{self.name}: HTTP server thread did not stop within {STOP_TIMEOUT:g} s",
                    RuntimeWarning,
                    stacklevel=2,
                )
        if sock is not None:
            sock.close()
        self.port = None

    def stats(self) -> dict[str, object]:
        guard = self.guard
        return {
            "port": self.port,
            "answered": self.answered,
            "waiting": self.fleet_desk.waiting + (self.desk.waiting if self.desk else 0),
            "streams": self.feed.streams,
            "snapshots": self.feed.published,
            "refused": guard.refused if guard is not None else 0,
        }


def _bind(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host:port`` (IPv4 or IPv6, as the host resolves; an
    empty host is every IPv4 address), with Nagle's algorithm off: an answer goes out in
    two writes (headers, body), and on a kept-alive connection the body otherwise waited
    for the client's delayed acknowledgement, some 40 ms a request. asyncio turns it off
    only for sockets made with the protocol named, which ``create_server``'s are not;
    connections accepted on Linux take it from the listening socket."""
    if not host:
        sock = socket.create_server(("", port), backlog=64)
    else:
        family, _, _, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        sock = socket.create_server(address, family=family, backlog=64)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock
