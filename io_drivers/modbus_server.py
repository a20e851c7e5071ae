"""ModbusServer: the process image for HMIs and SCADA over Modbus TCP (pymodbus 3.16).

OpenPLC-compatible map (what HMIs built for OpenPLC expect):

    coils             0..8191  FC1 read, FC5/FC15 write   %QX0.0..%QX1023.7 (as last copied out)
    discrete inputs   0..8191  FC2 read only              %IX0.0..%IX1023.7 (as the program saw them)
    input registers   0..1023  FC4 read only              %IW0..%IW1023
    holding registers 0..1023  FC3 read, FC6/FC16 write   %QW0..%QW1023
    holding registers 1024..                              %MW0.. (the whole marker area)

The marker area is served whole, as far as Modbus addresses reach (%MW0..%MW64511,
holding registers 1024..65535): an image sized for a large program (a fleet of hundreds
of vehicles) is read the same way as a small one.

The server runs pymodbus' asyncio server in its own thread. Reads are answered from the
process image under its lock (never a half-copied image); writes are queued into the
runtime's quiet point with ``write_many``, so a multi-register write lands in one cycle and
never mid-scan. Addresses beyond the map get exception 2, function codes other than the
eight above exception 1, a failing callback exception 4; the read-only areas have no write
function at all. Binds 127.0.0.1 unless told otherwise. Any unit id is answered.

Requests are framed here, not by pymodbus (``_Connection``): requests pipelined on one
connection are answered one by one, in order. A header that is not Modbus/TCP's (protocol
id other than 0, a length outside 2..254) closes the connection at once; a request with a
function code of 128..255, which mark exception responses, gets exception 1. A client that
sends faster than it reads its answers is held back by TCP flow control: the server stops
reading while its answers back up or more than MAX_BACKLOG bytes of its requests wait.

Modbus/TCP has no authentication (docs/security.md), so the server is closed by default:

- Writes go through an allow-list. The input and output images (coils and holding
  registers 0..1023, i.e. %QX and %QW; %IX and %IW have no write function) can never be
  written: the field and the program own them, and the vehicles' route commands and
  stop/go bits are %QW. Naming one of them in an allow-list is a configuration error. In
  the marker area a client may write the tags the program declares ``writable`` (or the
  ``writable`` list given instead) plus what ``writable_extra`` opens: tags, %M addresses,
  %MW ranges. A range over a read-only tag is an error: opening what the program publishes
  takes naming the tag. A request touching anything else is refused whole with exception
  2 (illegal data address) and nothing of it is applied.
- At most ``max_connections`` clients (16) at once, the next one is closed at once; a
  connection that sends no request for ``idle_timeout`` seconds (60) is closed.
- A frame that is not Modbus/TCP's closes its connection at once.
- Every refused request or connection is one log line (a warning), never a traceback; one
  a second per client at most (every loopback address together), the next line saying how
  many were left out, so a client pipelining refused requests cannot flood the log.
- Listening on anything but a loopback address warns (a RuntimeWarning, on stderr).

pymodbus 3.16.1 has neither a connection limit nor an idle timeout: both live in the
connection handler this module gives pymodbus' server (``_Connection``). The handler also
keeps per-request state (the function code received, an invalid coil value, why a request
was refused) with its connection, because requests of different clients interleave on the
loop. pymodbus' own register memory is only a scratch buffer: its documented SimDevice
``action`` hook fills it from the image before a reply is built and receives every write.
(Checked against pymodbus 3.16.1, whose simulator API is marked experimental and whose
request handler is internal; re-check on upgrade.)
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import re
import socket
import threading
import time
import warnings
from collections.abc import Callable, Iterable, Sequence
from contextvars import ContextVar
from dataclasses import dataclass

import numpy as np
from pymodbus.constants import ExcCodes
from pymodbus.pdu import ExceptionResponse, ModbusPDU
from pymodbus.server import ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler
from pymodbus.simulator import DataType, SimData, SimDevice

from plc_runtime import (
    Address,
    ConfigError,
    PlcError,
    ProcessImage,
    Runtime,
    WritesBacklogged,
    parse_address,
)
from plc_runtime.quiet import QuietSelector
from plc_runtime.throttle import LineThrottle, client_of, left_out

log = logging.getLogger(__name__)

ReadFn = Callable[[str, int, int], Sequence[int] | Sequence[bool]]
WriteFn = Callable[[str, int, list], "ExcCodes | None"]
Part = tuple[str, int, int]  # (area "coil" | "hr" | "mw", first address in it, count)
AllowFn = Callable[[list[Part]], "str | None"]  # None: allowed; else why it is refused

N_COILS = 8192
N_DISCRETE = 8192
N_INPUT_REGS = 1024
MW_BASE = 1024  # holding registers 0..1023 are %QW, from here on %MW
MAX_MW_WORDS = 0x10000 - MW_BASE  # %MW0..%MW64511: the holding registers Modbus can address
SUPPORTED_FCS = frozenset({1, 2, 3, 4, 5, 6, 15, 16})
REGISTER_BYTES = 2 * N_INPUT_REGS  # bytes of %I and %Q served as registers (1024 words each)
BIT_BYTES = N_COILS // 8  # bytes of %I and %Q also served bit by bit (8192 bits each)
MAX_CONNECTIONS = 16
IDLE_TIMEOUT = 60.0  # seconds without a request before a connection is closed
MBAP_HEADER = 7  # transaction id (2), protocol id (2), length (2), unit id (1)
MBAP_LENGTHS = range(2, 255)  # the length field: unit id + a PDU of 1..253 bytes
MAX_BACKLOG = 16 * 1024  # bytes of requests waiting on one connection before reading stops
QUIET_LEAD = 0.1  # of a cycle: no request is started this long before a scan
QUIET_WAIT_S = 0.5  # a request waits this long at most for a scan to end (then it goes on)
_DEFAULT_REASONS = {
    ExcCodes.ILLEGAL_FUNCTION: "function code not served",
    ExcCodes.ILLEGAL_ADDRESS: "address outside the served map",
    ExcCodes.ILLEGAL_VALUE: "count or value out of range",
    ExcCodes.DEVICE_FAILURE: "server failure",
    ExcCodes.DEVICE_BUSY: "the runtime takes no more writes now (not scanning)",
}


@dataclass(frozen=True)
class MapEntry:
    """Where an image location is served: a Modbus table, its first element and how many."""

    table: str  # "coil" | "discrete input" | "input register" | "holding register"
    first: int
    count: int
    bits: tuple[int, int] | None = None  # part of one register (a bit or a byte): lowest, highest

    def __str__(self) -> str:
        """Short: ``HR 1088``, ``HR 1024..1025``, ``HR 1034 bit 8``, ``coil 33``, ``DI 8``, ``IR 3``."""
        short = {"holding register": "HR", "input register": "IR", "discrete input": "DI"}
        last = self.first + self.count - 1
        text = f"{short.get(self.table, self.table)} {self.first}"
        text += f"..{last}" if last > self.first else ""
        if self.bits is not None:
            lo, hi = self.bits
            text += f" bit {lo}" if lo == hi else f" bits {lo}-{hi}"
        return text


def map_entry(address: Address) -> MapEntry | None:
    """Where ``address`` is served in the map above, None if it is not served (a marker
    beyond the image's M area is not served either, but that is the image's to refuse).

    Bits of %I and %Q are discrete inputs and coils; every other size is served as
    registers (a %MD is two holding registers, low word first; a bit or a byte of %M is
    part of one)."""
    a = address
    if a.is_bit and a.area != "M":
        if a.byte_offset >= BIT_BYTES:
            return None
        table = "discrete input" if a.area == "I" else "coil"
        return MapEntry(table, a.byte_offset * 8 + a.bit, 1)
    if a.byte_offset + a.nbytes > (2 * MAX_MW_WORDS if a.area == "M" else REGISTER_BYTES):
        return None
    table = "input register" if a.area == "I" else "holding register"
    bits = None
    if a.nbytes == 1:
        lo = (a.byte_offset % 2) * 8
        bits = (lo + a.bit, lo + a.bit) if a.is_bit else (lo, lo + 7)
    first = (MW_BASE if a.area == "M" else 0) + a.byte_offset // 2
    return MapEntry(table, first, max(1, a.nbytes // 2), bits)


def _bits_to_regs(bits: Sequence[bool]) -> list[int]:
    """Pack bits into 16-bit words, bit 0 of the word = first bit (pymodbus layout)."""
    regs = []
    for i in range(0, len(bits), 16):
        word = 0
        for j, bit in enumerate(bits[i : i + 16]):
            if bit:
                word |= 1 << j
        regs.append(word)
    return regs


def _make_unsupported_pdu(fc: int) -> type[ModbusPDU]:
    """A request class that answers ILLEGAL FUNCTION (01) for function code fc."""

    async def datastore_update(self, context, device_id):  # noqa: ARG001
        return ExceptionResponse(self.function_code, ExcCodes.ILLEGAL_FUNCTION)

    # decode() is inherited (no-op): the TCP framer delimits frames with the MBAP length.
    return type(
        f"Unsupported{fc}",
        (ModbusPDU,),
        {"function_code": fc, "datastore_update": datastore_update},
    )


# Every function code 1..127 except the 8 supported ones. Overrides pymodbus' built-in
# FC7/8/11/12/17/20/21/22/23/24/43 handlers and the unknown-FC path: FC22 (mask write) and
# FC23 (read/write) would be two more ways to write, so they are not served at all.
_UNSUPPORTED_PDUS = [_make_unsupported_pdu(fc) for fc in range(1, 128) if fc not in SUPPORTED_FCS]


def mbap_error(head: bytes | bytearray) -> str | None:
    """What is wrong with the start of an MBAP frame (as far as it has arrived), or None.

    Only protocol id 0 is Modbus/TCP, and the length counts the unit id and a PDU of 1..253
    bytes (a 260-byte ADU at most). A length outside that cannot be skipped safely: the
    next frame would start at a guessed offset, so the connection is closed instead."""
    if len(head) >= 4 and (pid := int.from_bytes(head[2:4], "big")) != 0:
        return f"protocol id {pid}, not Modbus/TCP's 0"
    if len(head) >= 6 and (length := int.from_bytes(head[4:6], "big")) not in MBAP_LENGTHS:
        return (
            f"MBAP length {length} outside {MBAP_LENGTHS.start}..{MBAP_LENGTHS.stop - 1} "
            "(unit id + a PDU of 1..253 bytes)"
        )
    return None


def request_length(frame: bytes) -> int | None:
    """The length a frame of its function's request must have (MBAP header included), for
    the functions served; None for others (they are refused by function code)."""
    fc = frame[7]
    if fc in (1, 2, 3, 4, 5, 6):
        return MBAP_HEADER + 5  # function code, address, count or value
    if fc in (15, 16):
        # function code, address, count, byte count, then the bytes it counts
        return MBAP_HEADER + 6 + frame[12] if len(frame) > 12 else MBAP_HEADER + 6
    return None


def check_limits(name: str, max_connections: int, idle_timeout: float | None) -> None:
    """The connection cap and the idle timeout must make sense (ConfigError naming them)."""
    if isinstance(max_connections, bool) or not isinstance(max_connections, int):
        raise ConfigError(
            f"{name}: max_connections must be a whole number, not {max_connections!r}"
        )
    if max_connections < 1:
        raise ConfigError(f"{name}: max_connections must be 1 or more, not {max_connections}")
    if idle_timeout is not None and not (
        isinstance(idle_timeout, (int, float)) and idle_timeout > 0
    ):
        raise ConfigError(f"{name}: idle_timeout must be positive or None, not {idle_timeout!r}")


def is_loopback(host: str) -> bool:
    """Whether listening on ``host`` keeps the server on this machine: every address it
    resolves to is a loopback address. The wildcard ("", 0.0.0.0, ::) is not."""
    if not host:
        return False
    try:
        infos = socket.getaddrinfo(host, None, proto=socket.IPPROTO_TCP)
    except OSError:
        return False  # binding will fail and say why
    return all(ipaddress.ip_address(str(info[4][0]).split("%")[0]).is_loopback for info in infos)


# The connection whose request is being handled: set in its request task, read by the
# SimDevice action (which pymodbus calls without saying for which connection).
_CONNECTION: ContextVar[_Connection | None] = ContextVar("modbus_connection", default=None)


# While the server starts: what pymodbus logs of a failure (why the bind failed, which its
# exception leaves out), to be said in the one error line instead of a stray log line.
_STARTING: ContextVar[list[str] | None] = ContextVar("modbus_starting", default=None)


class _QuietWhileServing(logging.Filter):
    """pymodbus logs some refusals itself (an undecodable frame, a failing request), some
    with frame dumps or a traceback. While one of our connections handles a request, the
    connection's own line replaces them; while the server starts, its error does.
    pymodbus' debug output and the logging of its clients (the vehicle link) are left
    alone."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno < logging.WARNING:
            return True
        starting = _STARTING.get()
        if starting is not None:
            starting.append(record.getMessage())
            return False
        return _CONNECTION.get() is None


logging.getLogger("pymodbus.logging").addFilter(_QuietWhileServing())


class _Connection(ServerRequestHandler):
    """One client connection: counted against the cap, closed when idle, refusals logged.

    It also frames the byte stream itself: pymodbus decodes one frame per receive and drops
    a receive over 516 bytes, so of requests pipelined in one TCP segment (legal in
    Modbus/TCP: each has its own transaction id) it would answer one or none. Here the bytes
    are buffered, cut into MBAP frames and handed to pymodbus one at a time, the next once
    the previous one is answered: answers go out in request order, and the per-request
    state below always belongs to the frame being handled."""

    def __init__(self, owner: ModbusTcpServer, guard: _ModbusThread) -> None:
        super().__init__(owner, self._trace, None, None)
        self.guard = guard
        self.peer = "?"
        self.client = "?"  # who its log lines count against (plc_runtime.throttle)
        self.rx_fc = 0  # function code of the request being handled
        self.bad_coil_value = False  # that request is an FC5 with a value other than on/off
        self.reason: str | None = None  # why the request being handled is refused
        self._last_request = 0.0
        self._idle: asyncio.TimerHandle | None = None
        self._rx = bytearray()  # received, not yet handed to pymodbus
        self._in_flight = False  # a request is with pymodbus, its answer not yet sent
        self._writing_paused = False  # the client does not read its answers fast enough
        self._eof = False  # the client has half-closed: answer what it sent, then close

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        peer = transport.get_extra_info("peername")
        if peer:
            host = str(peer[0])
            self.peer = f"[{host}]:{peer[1]}" if ":" in host else f"{host}:{peer[1]}"
            self.client = client_of(host)
        if not self.guard.admit(self):
            self.close()  # unregisters it from pymodbus' listener (it has no transport yet)
            transport.close()
            return
        super().connection_made(transport)
        self._last_request = self.loop.time()
        timeout = self.guard.idle_timeout
        if timeout is not None:
            self._idle = self.loop.call_later(timeout, self._check_idle, timeout)

    def connection_lost(self, exc: Exception | None) -> None:
        self.guard.release(self)
        if self._idle is not None:
            self._idle.cancel()
            self._idle = None
        self._rx.clear()
        super().connection_lost(exc)

    def _check_idle(self, timeout: float) -> None:
        quiet = self.loop.time() - self._last_request
        if quiet < timeout:
            self._idle = self.loop.call_later(timeout - quiet, self._check_idle, timeout)
            return
        self._idle = None
        self.guard.idle_closed(self)
        self.close()

    # ----- framing -------------------------------------------------------------------
    def _taking_requests(self) -> bool:
        """Whether the connection still takes requests (admitted, not closed)."""
        return self.transport is not None and not self.is_closing

    def data_received(self, data: bytes) -> None:
        """asyncio: bytes from the client, buffered here rather than in pymodbus (see the
        class docstring)."""
        if not self._taking_requests():
            return
        self._rx += data
        self._pump()

    def _pump(self) -> None:
        """Hand the complete frames waiting to pymodbus, one at a time, then decide whether
        to read on."""
        while self._taking_requests() and not (self._in_flight or self._writing_paused):
            frame = self._next_frame()
            if frame is None:
                break
            self._serve(frame)
        if self._eof and not (self._in_flight or self._writing_paused):
            self.close()  # all it sent is answered (a partial frame never completes)
            return
        self._throttle()

    def eof_received(self) -> bool:
        """asyncio: the client will send nothing more (a half-close, as a client that sends
        its requests and then shuts its side down does). What it sent is still answered,
        and the connection closes after the last answer: True keeps it open for them."""
        self._eof = True
        self._pump()
        return True

    def _next_frame(self) -> bytes | None:
        """The first frame, taken out of the buffer; None while it is incomplete. A header
        that is not Modbus/TCP's closes the connection (``mbap_error``)."""
        if (why := mbap_error(self._rx[:MBAP_HEADER])) is not None:
            self._drop(why)
            return None
        if len(self._rx) < MBAP_HEADER:
            return None
        size = 6 + int.from_bytes(self._rx[4:6], "big")  # the length counts from the unit id
        if len(self._rx) < size:
            return None
        frame = bytes(self._rx[:size])
        del self._rx[:size]
        return frame

    def _drop(self, why: str) -> None:
        """Close the connection at once for a framing error, with one log line."""
        self.guard.dropped(self, why)
        self._rx.clear()
        self.close()

    def _throttle(self) -> None:
        """Read from the client only while it is not too far ahead.

        Reading stops while its answers back up (it does not read them) or while more than
        MAX_BACKLOG bytes of its requests wait, and resumes once both have cleared (the
        backlog at half): TCP then holds the rest on the client's side, so a client that
        sends faster than it reads costs a bounded amount of memory and loses nothing."""
        if not self._taking_requests():
            return
        transport: asyncio.Transport = self.transport  # type: ignore[assignment]
        if self._writing_paused or len(self._rx) > MAX_BACKLOG:
            if transport.is_reading():
                transport.pause_reading()
        elif len(self._rx) <= MAX_BACKLOG // 2 and not transport.is_reading():
            transport.resume_reading()

    def pause_writing(self) -> None:
        """asyncio: the transport's send buffer is full; take no request until it drains."""
        self._writing_paused = True
        self._throttle()

    def resume_writing(self) -> None:
        """asyncio: the send buffer has drained; go on with the requests waiting."""
        self._writing_paused = False
        self._pump()

    # ----- one request ---------------------------------------------------------------
    def _serve(self, frame: bytes) -> None:
        """One complete frame: answered by pymodbus, or here if it cannot be a request."""
        self.rx_fc = frame[7]
        # FC5 allows only 0xFF00 (on) and 0x0000 (off); pymodbus takes any other value as
        # "on": remember it so the action can refuse the write with exception 3.
        self.bad_coil_value = (
            frame[7] == 5 and len(frame) >= 12 and frame[10:12] not in (b"\xff\x00", b"\x00\x00")
        )
        if frame[7] & 0x80:
            self._not_a_request(frame)
            return
        if (expected := request_length(frame)) is not None and len(frame) != expected:
            self._wrong_length(frame, expected)
            return
        self._in_flight = True
        self.callback_data(frame)
        # no request scheduled: pymodbus could not decode it and has answered already
        self._in_flight = self.last_pdu is not None

    def _not_a_request(self, frame: bytes) -> None:
        """Answer a request with function code 128..255 with exception 01.

        The Modbus application protocol reserves these codes for exception responses, so
        such a frame is no request of any function: ILLEGAL FUNCTION is the answer the spec
        gives for a function code the server does not serve, and it keeps the client's
        transaction from waiting for a timeout. The exception response's function code is
        the request's with bit 7 set, i.e. the request's own code here (pymodbus would
        answer 04, as if it had failed serving it)."""
        self.reason = "function codes 128..255 are reserved for exception responses, not requests"
        tid, unit = int.from_bytes(frame[0:2], "big"), frame[6]
        answer = ExceptionResponse(frame[7], ExcCodes.ILLEGAL_FUNCTION, unit, tid)
        self.server_send(answer, None)

    def _wrong_length(self, frame: bytes, expected: int) -> None:
        """Answer a request of a served function whose frame is longer or shorter than that
        function's request with exception 03, changing nothing. pymodbus reads the fields
        it expects and ignores bytes after them, so a write with trailing bytes (a
        corrupted or crafted frame) would otherwise be carried out."""
        self.reason = f"a function {frame[7]} request is {expected} bytes, this one {len(frame)}"
        tid, unit = int.from_bytes(frame[0:2], "big"), frame[6]
        self.server_send(ExceptionResponse(frame[7], ExcCodes.ILLEGAL_VALUE, unit, tid), None)

    def callback_data(self, data: bytes, addr: tuple | None = None) -> int:
        """One complete frame (from ``_serve``) to pymodbus."""
        token = _CONNECTION.set(self)  # also inherited by the request task it schedules
        try:
            return super().callback_data(data, addr)
        finally:
            _CONNECTION.reset(token)

    async def handle_request(self) -> None:
        _CONNECTION.set(self)  # this request's task only
        try:
            await super().handle_request()
        finally:
            self._in_flight = False  # answered: the next frame may go
            self._pump()

    def _trace(self, sending: bool, data: bytes) -> bytes:
        """pymodbus' packet hook: fix, time and log what is sent.

        pymodbus 3.16 answers a request it cannot decode (count out of range, e.g. FC1
        count=0/2001, FC3 count=126) with function code 0x80 + code 01 instead of
        (fc | 0x80) + code 03. Frames are handled one at a time, so the request answered is
        always the last one received (``rx_fc``)."""
        if not sending:
            return data
        if len(data) == 9 and data[7] == 0x80 and 0 < self.rx_fc < 0x80:
            fc = self.rx_fc
            code = ExcCodes.ILLEGAL_VALUE if fc in SUPPORTED_FCS else ExcCodes.ILLEGAL_FUNCTION
            data = data[:7] + bytes((fc | 0x80, code))
        self._last_request = self.loop.time()  # a request was answered: not idle
        if len(data) >= 9 and data[7] & 0x80:
            self.guard.refused(self, self.rx_fc, data[8])
        return data


class _TcpServer(ModbusTcpServer):
    """pymodbus' TCP server, with ``_Connection`` as the handler of each client."""

    def __init__(self, guard: _ModbusThread, *args, **kwargs) -> None:
        self._guard = guard
        super().__init__(*args, **kwargs)

    def callback_new_connection(self) -> _Connection:
        return _Connection(self, self._guard)


class _ModbusThread:
    """The pymodbus TCP server in a thread with its own event loop; start()/stop() from sync code.

    ``allow`` vets every write request before anything of it is written (None: every write
    in the map goes to ``write``). ``max_connections`` clients at once; ``idle_timeout``
    seconds without a request close a connection (None: never)."""

    def __init__(
        self,
        read: ReadFn,
        write: WriteFn,
        host: str = "127.0.0.1",
        port: int = 502,
        allow: AllowFn | None = None,
        *,
        name: str = "modbus",
        max_connections: int = MAX_CONNECTIONS,
        idle_timeout: float | None = IDLE_TIMEOUT,
        between_scans: threading.Event | None = None,
        marker_words: int = 1024,
    ):
        check_limits(name, max_connections, idle_timeout)
        # holding registers served: %QW0..%QW1023, then %MW0 .. %MW<marker_words - 1>
        self.holding = MW_BASE + min(marker_words, MAX_MW_WORDS)
        self._between_scans = between_scans  # serve only while it is set (None: always)
        self._selector: QuietSelector | None = None  # the loop's, when it waits for scans
        self._read = read
        self._write = write
        self._allow = allow
        self.name = name
        self.host = host
        self.requested_port = port
        self.port: int | None = None  # actual bound port after start()
        self.max_connections = max_connections
        self.idle_timeout = idle_timeout
        self.counters = {"connections_refused": 0, "idle_closed": 0, "exceptions": 0}
        self._open: set[_Connection] = set()  # touched in the server thread only
        self._lines = LineThrottle()  # the warnings, per client; touched in the server thread
        self.clock: Callable[[], float] = time.monotonic  # seconds, for the throttle
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop_evt: asyncio.Event | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None

    # ---------------------------------------------------------------- connections
    @property
    def connections(self) -> int:
        """Clients connected now."""
        return len(self._open)

    def _where(self) -> str:
        return f"{self.name} {self.host}:{self.port}"

    def admit(self, conn: _Connection) -> bool:
        """Count a new connection in, unless the cap is reached (then log it)."""
        if len(self._open) >= self.max_connections:
            self.counters["connections_refused"] += 1
            self._warn(
                conn,
                "%s: refused connection from %s: %d connections open (the limit)",
                self._where(),
                conn.peer,
                len(self._open),
            )
            return False
        self._open.add(conn)
        return True

    def release(self, conn: _Connection) -> None:
        self._open.discard(conn)

    def idle_closed(self, conn: _Connection) -> None:
        self.counters["idle_closed"] += 1
        log.info(
            "%s: closed connection from %s: no request for %g s",
            self._where(),
            conn.peer,
            self.idle_timeout,
        )

    def dropped(self, conn: _Connection, why: str) -> None:
        self._warn(conn, "%s: closed connection from %s: %s", self._where(), conn.peer, why)

    def refused(self, conn: _Connection, fc: int, code: int) -> None:
        """One line per request answered with an exception: who, what, why."""
        self.counters["exceptions"] += 1
        reason = conn.reason or _DEFAULT_REASONS.get(code, "refused")
        conn.reason = None
        self._warn(
            conn,
            "%s: refused FC%d from %s: exception %02d, %s",
            self._where(),
            fc,
            conn.peer,
            code,
            reason,
        )

    def _warn(self, conn: _Connection, form: str, *args: object) -> None:
        """A warning about what ``conn``'s client did, one a second per client at most: a
        client pipelining refused requests would otherwise write thousands of lines a
        second. The next line written says how many were left out."""
        count = self._lines.admit(conn.client, self.clock())
        if count is not None:
            log.warning(form + "%s", *args, left_out(count, "from this client"))

    @staticmethod
    def _refuse(code: ExcCodes, reason: str) -> ExcCodes:
        """Answer the current request with ``code``; its log line says ``reason``."""
        conn = _CONNECTION.get()
        if conn is not None:
            conn.reason = reason
        return code

    # ---------------------------------------------------------------- callbacks
    def _read_bits(self, area: str, address: int, count: int) -> list[bool]:
        vals = [bool(v) for v in self._read(area, address, count)]
        if len(vals) != count:
            raise ValueError(f"read({area!r}, {address}, {count}) returned {len(vals)} values")
        return vals

    @staticmethod
    def _holding_parts(address: int, count: int) -> list[Part]:
        """Holding registers ``address`` .. ``address + count - 1``: %QW below MW_BASE, %MW from it."""
        end = address + count
        parts = []
        if address < MW_BASE:
            parts.append(("hr", address, min(end, MW_BASE) - address))
        if end > MW_BASE:
            lo = max(address, MW_BASE)
            parts.append(("mw", lo - MW_BASE, end - lo))
        return parts

    def _read_regs(self, address: int, count: int, fc: int) -> list[int]:
        """Read holding (fc 3) or input (fc 4) registers, splitting hr/mw for holding."""
        parts = [("ir", address, count)] if fc == 4 else self._holding_parts(address, count)
        out: list[int] = []
        for area, addr, cnt in parts:
            vals = [int(v) for v in self._read(area, addr, cnt)]
            if len(vals) != cnt or any(not 0 <= v <= 0xFFFF for v in vals):
                raise ValueError(f"read({area!r}, {addr}, {cnt}) returned bad data")
            out.extend(vals)
        return out

    def _write_regs(self, address: int, values: list[int]) -> ExcCodes | None:
        done = 0
        for area, first, count in self._holding_parts(address, len(values)):
            if rc := self._write(area, first, values[done : done + count]):
                return rc
            done += count
        return None

    async def _action(
        self,
        fc: int,
        start_address: int,
        address: int,
        count: int,
        registers: list[int],
        set_values,
    ) -> ExcCodes | None:
        """SimDevice action: called by pymodbus after its range check, before it
        builds the response / stores the write into `registers` (its scratch buffer).

        For coil/discrete blocks pymodbus passes: address = requested bit address,
        count = number of 16-bit words spanned, start_address/registers in words.
        """
        try:
            if set_values is not None:  # FC5/FC15/FC6/FC16 write
                conn = _CONNECTION.get()
                if fc == 5 and conn is not None and conn.bad_coil_value:
                    return self._refuse(
                        ExcCodes.ILLEGAL_VALUE, "a coil value must be 0xFF00 (on) or 0x0000 (off)"
                    )
                vals = list(set_values)
                coils = fc in (5, 15)
                parts = (
                    [("coil", address, len(vals))]
                    if coils
                    else self._holding_parts(address, len(vals))
                )
                if self._allow is not None and (why := self._allow(parts)) is not None:
                    return self._refuse(ExcCodes.ILLEGAL_ADDRESS, why)  # nothing of it applied
                if coils:
                    return self._write("coil", address, [bool(v) for v in vals])
                return self._write_regs(address, [int(v) for v in vals])
            if fc in (5, 6):
                # Read-back that pymodbus does to build the FC5/FC6 echo response:
                # the scratch buffer already holds the value just written; don't
                # overwrite it with the (not yet applied) PLC value.
                return None
            if fc in (1, 2):
                area = "coil" if fc == 1 else "di"
                word0 = address // 16
                bits = self._read_bits(area, word0 * 16, count * 16)
                i = word0 - start_address
                registers[i : i + count] = _bits_to_regs(bits)
            else:  # FC3 / FC4
                i = address - start_address
                registers[i : i + count] = self._read_regs(address, count, fc)
            return None
        except Exception as exc:  # pylint: disable=broad-except
            # one line in the refusal log, no traceback: what failed and with what
            return self._refuse(
                ExcCodes.DEVICE_FAILURE,
                f"server failure at address {address}: {type(exc).__name__}: {exc}",
            )

    # ---------------------------------------------------------------- device
    def _build_device(self) -> SimDevice:
        return SimDevice(
            id=0,  # 0 = catch-all: answers every device/unit id (0..255)
            simdata=(
                # BITS: pass a list, NOT count=8192 (pymodbus 3.16 then builds a
                # count*count list while validating: ~0.5 GB RAM and ~1.5 s).
                [SimData(0, values=[False] * N_COILS, datatype=DataType.BITS)],
                [SimData(0, values=[False] * N_DISCRETE, datatype=DataType.BITS)],
                [SimData(0, count=self.holding, values=0, datatype=DataType.REGISTERS)],
                [SimData(0, count=N_INPUT_REGS, values=0, datatype=DataType.REGISTERS)],
            ),
            action=self._action,
        )

    # ---------------------------------------------------------------- thread
    def start(self, timeout: float = 5.0) -> int:
        """Start the server thread; returns the bound port once listening.

        Warns before binding an address other people can reach."""
        if self._thread is not None:
            raise RuntimeError("already started")
        if not is_loopback(self.host):
            warnings.warn(
                f"{self.name}: Modbus TCP server on {self.host or '*'}:{self.requested_port}, "
                "not a loopback address: Modbus has no authentication, anyone who reaches "
                "it can read the image and write what is writable; keep that network "
                "isolated (docs/security.md)",
                RuntimeWarning,
                stacklevel=2,
            )
        self._ready.clear()
        self._error = None
        self._thread = threading.Thread(target=self._thread_main, name="modbus-tcp", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            self.stop()
            raise TimeoutError("modbus server did not start")
        if self._error is not None:
            self._thread.join()
            self._thread = None
            raise RuntimeError(f"modbus server failed to start: {self._error}") from self._error
        return self.port  # type: ignore[return-value]

    def stop(self, timeout: float = 5.0) -> None:
        """Shut the server down and join the thread. Idempotent."""
        thread, loop, evt = self._thread, self._loop, self._stop_evt
        if thread is None:
            return
        if self._selector is not None:
            self._selector.release()  # its shutdown does not wait for scans
        if loop is not None and evt is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(evt.set)
            except RuntimeError:  # loop already closed
                pass
        thread.join(timeout)
        if thread.is_alive():
            raise TimeoutError("modbus server thread did not stop")
        self._thread = self._loop = self._stop_evt = None
        self.port = None

    def _new_loop(self) -> asyncio.AbstractEventLoop:
        if self._between_scans is None:
            return asyncio.new_event_loop()
        self._selector = QuietSelector(self._between_scans, QUIET_WAIT_S)
        return asyncio.SelectorEventLoop(self._selector)

    def _thread_main(self) -> None:
        try:
            with asyncio.Runner(loop_factory=self._new_loop) as runner:
                runner.run(self._serve())
        except BaseException as exc:  # pylint: disable=broad-except
            self._error = exc
        finally:
            self._ready.set()  # unblock start() on any failure

    async def _serve(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop_evt = asyncio.Event()
        server = _TcpServer(  # must be created inside the running loop
            self,
            self._build_device(),
            address=(self.host, self.requested_port),
            custom_pdu=_UNSUPPORTED_PDUS,
        )
        # background=True: returns once listening; raises RuntimeError if bind fails
        starting: list[str] = []
        token = _STARTING.set(starting)
        try:
            await server.serve_forever(background=True)
        except RuntimeError as exc:
            # (pymodbus' logging may be off: another part of the process can set its level)
            why = starting[-1].removeprefix("Failed to start server ") if starting else None
            problem = why or _bind_problem(self.host, self.requested_port) or exc
            raise RuntimeError(str(problem)) from None

        finally:
            _STARTING.reset(token)
        listener = server.transport  # asyncio.Server
        self.port = listener.sockets[0].getsockname()[1]
        self._ready.set()
        try:
            await self._stop_evt.wait()
        finally:
            await server.shutdown()  # closes listener + all client connections
            await listener.wait_closed()
            for _ in range(3):  # let transports' close callbacks run
                await asyncio.sleep(0)
            self._open.clear()


def _bind_problem(host: str, port: int) -> str | None:
    """Why ``host:port`` cannot be listened on, as the OS says it (None: it can now)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    try:
        with socket.create_server((host, port), family=family):
            return None
    except OSError as exc:
        return f"cannot listen on {host}:{port}: {exc.strerror or exc}"


# %MW<first>..%MW<last>: a range of marker words for writable_extra
_RANGE_RE = re.compile(r"%MW([0-9]+)\.\.%MW([0-9]+)")  # fullmatch: ASCII digits, no newline
_AREA_NAMES = {"I": "the input image (%I)", "Q": "the output image (%Q)"}
_MW_BITS = MAX_MW_WORDS * 16  # bits of %M that Modbus can address (holding registers 1024..65535)


def _nbits(address: Address) -> int:
    return 1 if address.is_bit else address.nbytes * 8


def _check_area(where: str, address: Address) -> None:
    """%I and %Q can never be opened: a configuration error naming ``where``."""
    if address.area in _AREA_NAMES:
        raise ConfigError(
            f"{where}: {_AREA_NAMES[address.area]} is never writable over Modbus; only markers "
            f"can be opened (%MW0.., holding registers {MW_BASE}..)"
        )


def _address_span(where: str, address: Address, served_bits: int = _MW_BITS) -> tuple[int, int]:
    """The bits of %M an address covers (first, count), which must be served."""
    _check_area(where, address)
    first = address.byte_offset * 8 + max(address.bit, 0)
    return _marker_span(where, first, _nbits(address), served_bits)


def _marker_span(
    where: str, first: int, nbits: int, served_bits: int = _MW_BITS
) -> tuple[int, int]:
    """(first, nbits), or a ConfigError if they reach beyond the ``served_bits`` of %M."""
    if first + nbits > served_bits:
        words = served_bits // 16
        raise ConfigError(
            f"{where}: beyond the Modbus map (%MW0..%MW{words - 1}, "
            f"holding registers {MW_BASE}..{MW_BASE + words - 1})"
        )
    return first, nbits


class ModbusServer:
    """An IoDriver that serves the image over Modbus TCP while the runtime runs.

    What a client may write (only ever in the marker area, holding registers 1024 on):

    ``writable``: tag names or %M addresses; None (the default) means the tags the image's
    tag table declares writable (those beyond the map stay unreachable). An empty list
    makes the server read-only.
    ``writable_extra``: opened in addition (an HMI set-point): tag names, %M addresses and
    ranges ``%MW200..%MW209``. Naming a read-only tag opens it; a range or address over a
    read-only tag is an error naming the tag, so nothing the program publishes is opened
    by accident.

    A %I or %Q location in either list, or a writable tag there, is a configuration error
    naming it: the input and output images are never writable over Modbus. Addresses are
    checked here, tag names when the runtime starts.

    ``max_connections`` clients at once (16); ``idle_timeout`` seconds without a request
    close a connection (60; None: never)."""

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 502,
        name: str = "modbus",
        writable: Iterable[str] | None = None,
        writable_extra: Iterable[str] = (),
        *,
        max_connections: int = MAX_CONNECTIONS,
        idle_timeout: float | None = IDLE_TIMEOUT,
    ) -> None:
        self.name = name
        self.host, self.requested_port = host, port
        self.port: int | None = None
        self._server: _ModbusThread | None = None
        self.writable = None if writable is None else list(writable)
        self.writable_extra = list(writable_extra)
        for ref in [*(self.writable or ()), *self.writable_extra]:
            self._span(ref)  # addresses and ranges fail now, before anything runs
        check_limits(name, max_connections, idle_timeout)
        self.max_connections, self.idle_timeout = max_connections, idle_timeout
        self.counters = {"reads": 0, "writes": 0, "refused": 0, "failures": 0}
        self._link_counters: dict[str, int] = {}  # connections and refusals, from the thread
        self.served_port: int | None = None  # the port it listened on, also after close()
        self._allowed = np.zeros(0, dtype=bool)  # per bit of %M served: a client may write it
        self._writable_regs = np.zeros(0, dtype=bool)  # per %MW served: every bit of it
        self._owners: dict[int, str] = {}  # %MW index -> the read-only tag in it
        self._between_scans: threading.Event | None = None  # set by added_to()

    def added_to(self, runtime: Runtime) -> None:
        """Serve between scans: the server's thread shares the interpreter with the scan,
        and requests decoded and answered while a scan runs would lengthen it (clients
        polling without pause, bench/io_throughput.py). The loop waits after every wake-up
        until no scan runs (``plc_runtime.quiet``), and the runtime clears its event a
        tenth of a cycle before each scan, so a request does not start just before one."""
        self._between_scans = runtime.between_scans
        runtime.ask_quiet_lead(QUIET_LEAD * runtime.cycle_time)

    def open(self, image: ProcessImage) -> None:
        # %I and %Q are served at fixed sizes; %M as far as the image's marker area goes
        for area, needed in (("I", 2048), ("Q", 2048)):
            if image.sizes[area] < needed:
                raise ConfigError(
                    f"ModbusServer needs at least {needed} bytes of area {area}, image has {image.sizes[area]}"
                )
        self._image = image
        self._served_bits = min(8 * image.sizes["M"], _MW_BITS)
        self._words = {
            "ir": image.inputs.view("<u2"),
            "hr": image.published_outputs.view("<u2"),
            "mw": image.markers.view("<u2"),
        }
        self._bits = {"coil": image.published_outputs.bytes, "di": image.inputs.bytes}
        self._allow_list(image)
        server = _ModbusThread(
            self._read,
            self._write,
            self.host,
            self.requested_port,
            allow=self._allow,
            name=self.name,
            max_connections=self.max_connections,
            idle_timeout=self.idle_timeout,
            between_scans=self._between_scans,
            marker_words=self._served_bits // 16,
        )
        self._link_counters = server.counters
        try:
            self.port = self.served_port = server.start()
        except (RuntimeError, TimeoutError, OSError) as exc:
            raise ConfigError(
                f"Modbus server on {self.host}:{self.requested_port}: {exc}"
            ) from None
        self._server = server

    def close(self) -> None:
        if self._server is not None:
            self._server.stop()
            self._server = None
            self.port = None

    def read_inputs(self, image: ProcessImage, now_ns: int) -> None:
        pass  # requests are served by the server thread; writes arrive via the quiet point

    def write_outputs(self, image: ProcessImage, now_ns: int) -> None:
        pass

    @property
    def connections(self) -> int:
        """Clients connected now."""
        return self._server.connections if self._server is not None else 0

    def stats(self) -> dict[str, object]:
        return {
            **self.counters,
            **self._link_counters,
            "address": f"{self.host}:{self.served_port}",
        }

    # ----- the allow-list --------------------------------------------------------------
    def _span(self, ref: str, served_bits: int = _MW_BITS) -> tuple[int, int] | None:
        """The bits of %M (first, count) an address or a range names; None for a tag name.

        Raises ConfigError for what can never be opened: %I and %Q, and %M beyond the
        ``served_bits`` of the map (before the image is known: beyond what Modbus reaches)."""
        where = f"{self.name}: writable {ref!r}"
        if not isinstance(ref, str) or not ref.strip():
            raise ConfigError(f"{where}: expected a tag name, a %M address or %MWa..%MWb")
        text = ref.strip(" ")
        if not text.startswith("%"):
            return None
        if match := _RANGE_RE.fullmatch(text.upper()):
            lo, hi = int(match[1]), int(match[2])
            if hi < lo:
                raise ConfigError(f"{where}: the range ends before it starts")
            return _marker_span(where, lo * 16, (hi - lo + 1) * 16, served_bits)
        try:
            address = parse_address(text)
        except PlcError as exc:
            raise ConfigError(f"{where}: {exc}; a range is %MWa..%MWb") from None
        return _address_span(where, address, served_bits)

    def _allow_list(self, image: ProcessImage) -> None:
        """Resolve the allow-list against the image's tag table (when the runtime starts)."""
        served = self._served_bits
        allowed = np.zeros(served, dtype=bool)
        owned: dict[int, str] = {}  # bit of %M -> the read-only tag it belongs to (the first)
        for tag in image.tags:
            a = tag.address
            if not tag.writable and a.area == "M":
                first = a.byte_offset * 8 + max(a.bit, 0)
                for bit in range(first, min(first + _nbits(a), served)):
                    owned.setdefault(bit, tag.name)
        if self.writable is None:
            for tag in image.tags.writable():
                a = tag.address
                _check_area(f"{self.name}: writable tag {tag.name!r} ({a.text})", a)
                first = a.byte_offset * 8 + max(a.bit, 0)
                allowed[first : first + _nbits(a)] = True  # beyond the map: unreachable
        named = []
        for ref in [*(self.writable or ()), *self.writable_extra]:
            first, nbits = self._resolve(ref, image, owned)
            allowed[first : first + nbits] = True
            named.append((ref, first, nbits))
        self._allowed = allowed
        self._writable_regs = allowed.reshape(-1, 16).all(axis=1)
        for ref, first, nbits in named:
            registers = range(first // 16, (first + nbits - 1) // 16 + 1)
            if not any(self._writable_regs[r] for r in registers):
                n = registers[0]
                raise ConfigError(
                    f"{self.name}: writable {ref!r}: only part of holding register "
                    f"{MW_BASE + n} (%MW{n}); clients write whole registers, so it could never "
                    f"be written: open %MW{n} (or the tags that make it up) instead"
                )
        self._owners = {}
        for bit, name in owned.items():
            self._owners.setdefault(bit // 16, name)

    def _resolve(self, ref: str, image: ProcessImage, owned: dict[int, str]) -> tuple[int, int]:
        """The bits ``ref`` opens. A tag named opens, whatever its flag; an address or a
        range must not cover a read-only tag."""
        where = f"{self.name}: writable {ref!r}"
        span = self._span(ref, self._served_bits)
        if span is None:
            try:
                address = image.tags.get(ref.strip()).address
            except PlcError as exc:
                raise ConfigError(f"{where}: {exc}") from None
            return _address_span(f"{where} ({address.text})", address, self._served_bits)
        first, nbits = span
        for bit in range(first, first + nbits):
            if bit in owned:
                raise ConfigError(
                    f"{where}: covers the read-only tag {owned[bit]!r}, which the program "
                    "writes; name the tag to open it"
                )
        return span

    # ----- called in the server thread -----------------------------------------------
    def _allow(self, parts: list[Part]) -> str | None:
        """None if every bit a write request touches may be written, else why not (counted)."""
        for area, first, count in parts:
            why = self._closed(area, first, count)
            if why is not None:
                self.counters["refused"] += 1
                return why
        return None

    def _closed(self, area: str, first: int, count: int) -> str | None:
        """Why a part of a write request may not be written; None if it may."""
        last = first + count - 1
        if area == "coil":
            return (
                f"coils {first}..{last} are %QX{first >> 3}.{first & 7}..%QX{last >> 3}.{last & 7}"
                ", the output image: never writable over Modbus"
            )
        if area == "hr":
            return (
                f"holding registers {first}..{last} are %QW{first}..%QW{last}"
                ", the output image: never writable over Modbus"
            )
        closed = np.flatnonzero(~self._writable_regs[first : first + count])
        if not len(closed):
            return None
        n = first + int(closed[0])
        why = f"holding register {MW_BASE + n} (%MW{n}) "
        if n in self._owners:
            return why + f"is the read-only tag {self._owners[n]!r}"
        if self._allowed[16 * n : 16 * n + 16].any():
            return why + "is only partly writable (a writable bit or byte tag in it)"
        return why + "is not on the write allow-list"

    def _read(self, area: str, address: int, count: int) -> list:
        self.counters["reads"] += 1
        with self._image._lock:  # the same lock that guards copy-in and copy-out
            if area in self._bits:
                raw = self._bits[area]
                return [
                    bool((int(raw[(a >> 3)]) >> (a & 7)) & 1)
                    for a in range(address, address + count)
                ]
            return self._words[area][address : address + count].tolist()

    def _write(self, area: str, address: int, values: list) -> ExcCodes | None:
        """Queue an allowed write of marker words for the quiet point."""
        if area != "mw":  # _allow refused it already; a last line of defence for the outputs
            return ExcCodes.ILLEGAL_ADDRESS
        self.counters["writes"] += 1
        refs = {f"%MW{a}": int(v) for a, v in enumerate(values, start=address)}
        try:
            self._image.write_many(refs)  # applied together at the next quiet point
        except WritesBacklogged:
            self.counters["failures"] += 1
            return ExcCodes.DEVICE_BUSY  # the runtime takes no writes now: try again later
        except PlcError:
            self.counters["failures"] += 1
            return ExcCodes.ILLEGAL_VALUE
        return None
