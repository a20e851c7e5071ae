"""The AGV message set: one DBC file (``agv.dbc``), compiled once into fast codecs.

Frame ids are standard 11-bit ids, ``base + id`` (see docs/protocol.md):

    0x080 + v  StopGo        controller -> vehicle v (v = 127: every vehicle)
    0x100 + v  VehicleStatus vehicle v -> everyone (periodic and on every event)
    0x200 + v  RouteCommand  controller -> vehicle v: the next 1..3 verified nodes (0: cancel)
    0x600 + v  VehicleInfo   vehicle v -> everyone: battery (every second and on change)
    0x700 + n  Heartbeat     node n alive (n = 0: the controller)

Every message is end-to-end protected (io_drivers/e2e.py): byte 0 is a CRC-8 SAE J1850 over
the frame id and the rest of the payload, and a 4-bit counter follows. The sender's id is
the frame id's low 7 bits; the CRC covers it. Vehicle ids 1..126, node ids 0..65534 (65535
means "none").

The DBC stays the one definition both sides use: at startup cantools loads it, and each
message's layout (start bit, length, scale, offset of every signal) is compiled into one
Python function of integer shifts and masks, so a frame costs a few microseconds to decode
instead of a generic signal-by-signal decode (tests/test_e2e_protection.py checks the
compiled codec against cantools on random frames).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cantools

from .e2e import INIT, XOR_OUT, crc8_update, data_id

DBC_PATH = Path(__file__).with_name("agv.dbc")
STOP_GO, STATUS, ROUTE, INFO, HEARTBEAT = 0x080, 0x100, 0x200, 0x600, 0x700
ID_SPAN = 0x80  # 128 ids per message kind
MAX_VEHICLE_ID = 126
ALL_VEHICLES = 127
CONTROLLER = 0
NO_NODE = 0xFFFF
BATTERY_UNKNOWN = 0xFF  # the record's battery byte until the vehicle's first info frame
MAX_NODE_ID = 0xFFFE
STATES = (
    "IDLE",
    "DRIVING",
    "STOPPING_AT_NODE",
    "WAITING_FOR_ROUTE",
    "PROCESSING",
    "CHARGING",
    "FAULT",
)
STATE_CODE = {name: code for code, name in enumerate(STATES)}
PROTECTION = ("crc", "counter")  # the first two signals of every message, in this order


class MalformedFrame(ValueError):
    """A frame with a known id but a wrong length or out-of-range contents."""


class CorruptFrame(ValueError):
    """A frame whose CRC does not match its frame id and payload."""


class UnknownFrame(ValueError):
    """A frame id outside the message set."""


# Messages are plain slotted dataclasses (not frozen: a frozen dataclass costs several times
# as much to create, and the controller creates one per received frame).
@dataclass(slots=True)
class Status:
    vehicle: int
    current_node: int
    next_node: int  # NO_NODE when the vehicle has no verified next node
    state: str
    speed: float  # m/s
    counter: int  # 0..15, increments with every status frame
    fault: bool = False
    clear: bool = False  # left the current node's crossing zone (driving on beyond it)
    route_ack: int = 0  # the counter of the last route command received intact


@dataclass(slots=True)
class Info:
    vehicle: int
    battery: int  # percent
    counter: int


@dataclass(slots=True)
class RouteCommand:
    vehicle: int
    sequence: int  # 0..15, the frame's counter
    nodes: tuple[int, ...]  # 1..3 node ids; none cancels the route


@dataclass(slots=True)
class StopGo:
    vehicle: int  # ALL_VEHICLES for everyone
    go: bool
    counter: int = 0


@dataclass(slots=True)
class Heartbeat:
    node: int
    counter: int


Message = Status | Info | RouteCommand | StopGo | Heartbeat


@dataclass(frozen=True)
class Layout:
    """One DBC message compiled: ``unpack(data)`` gives every signal's physical value in DBC
    order, ``pack(*values)`` the payload bytes (CRC and all, as given)."""

    name: str
    base: int
    length: int
    signals: tuple[str, ...]
    maxima: tuple[float, ...]  # each signal's physical maximum
    unpack: Callable[[bytes], tuple]
    pack: Callable[..., bytes]

    def index(self, name: str) -> int:
        return self.signals.index(name)


def compile_layout(message: cantools.database.Message, source: str = DBC_PATH.name) -> Layout:
    """Generate the unpack and pack functions of one message from its DBC layout.

    Only what the message set uses is supported (little-endian unsigned integer signals
    with a linear scale, the CRC in byte 0 and a 4-bit counter next); anything else in the
    DBC is refused here, at startup, naming the message and signal."""
    name = message.name
    unpack_terms, pack_terms, checks, args = [], [], [], []
    for k, s in enumerate(message.signals):
        where = f"{source}: {name}.{s.name}"
        if s.byte_order != "little_endian" or s.is_signed or s.is_float:
            raise ValueError(f"{where}: only unsigned little-endian integer signals")
        if s.start + s.length > 8 * message.length:
            raise ValueError(f"{where}: beyond the message's {message.length} bytes")
        mask, scale, offset = (1 << s.length) - 1, s.scale, s.offset
        raw = f"(v >> {s.start} & {mask})"
        arg = f"a{k}"
        args.append(arg)
        if scale == 1 and offset == 0:
            unpack_terms.append(raw)
            encoded = arg
        else:
            unpack_terms.append(f"{raw} * {scale!r} + {offset!r}")
            encoded = f"round(({arg} - {offset!r}) / {scale!r})"
        pack_terms.append(f"r{k} << {s.start}")
        checks.append((f"r{k} = {encoded}", f"r{k} & ~{mask}"))
    protection = [(s.name, s.start, s.length) for s in message.signals[:2]]
    if protection != [(PROTECTION[0], 0, 8), (PROTECTION[1], 8, 4)]:
        raise ValueError(f"{source}: {name}: must begin with crc (bits 0-7) and counter (8-11)")
    error = repr(f"{name}: a value out of its signal range: ")
    code = "\n".join(
        [
            "def unpack(data):",
            "    v = int.from_bytes(data, 'little')",
            f"    return ({', '.join(unpack_terms)},)",
            f"def pack({', '.join(args)}):",
            *(f"    {assign}" for assign, _ in checks),
            f"    if {' | '.join(bad for _, bad in checks)}:",
            f"        raise ValueError({error} + repr(({', '.join(args)},)))",
            f"    return ({' | '.join(pack_terms)}).to_bytes({message.length}, 'little')",
        ]
    )
    namespace: dict[str, object] = {}
    exec(compile(code, f"<{name} layout from {source}>", "exec"), namespace)
    return Layout(
        name,
        message.frame_id,
        message.length,
        tuple(s.name for s in message.signals),
        tuple(s.maximum for s in message.signals),
        namespace["unpack"],
        namespace["pack"],
    )


def load_layouts(dbc: Path = DBC_PATH) -> dict[int, Layout]:
    """Every message of the DBC, compiled, by base frame id."""
    db = cantools.database.load_file(str(dbc))
    return {m.frame_id: compile_layout(m, dbc.name) for m in db.messages}


class Codec:
    """Encode and decode the message set; ``decode`` checks the CRC and validates everything
    it returns. The counter is checked by the receiver (io_drivers/e2e.py, CounterCheck),
    which keeps the per-sender state."""

    def __init__(self, dbc: Path = DBC_PATH) -> None:
        self.layouts = load_layouts(dbc)
        self._seeds: dict[int, int] = {}  # frame id -> CRC register after its data id
        self._decoders = {
            STATUS: self._status_decoder(self.layouts[STATUS]),
            INFO: self._info_decoder(self.layouts[INFO]),
            ROUTE: self._route_decoder(self.layouts[ROUTE]),
            STOP_GO: self._stop_go_decoder(self.layouts[STOP_GO]),
            HEARTBEAT: self._heartbeat_decoder(self.layouts[HEARTBEAT]),
        }
        self._pack = {base: layout.pack for base, layout in self.layouts.items()}
        status = self.layouts[STATUS]
        self._max_speed = status.maxima[status.index("speed")]

    # ----- the CRC ----------------------------------------------------------------------------
    def crc(self, frame_id: int, data: bytes) -> int:
        """The CRC a frame with this id and payload must carry in byte 0."""
        seed = self._seeds.get(frame_id)
        if seed is None:
            seed = self._seeds[frame_id] = crc8_update(INIT, data_id(frame_id))
        return crc8_update(seed, data[1:]) ^ XOR_OUT

    def _protect(self, frame_id: int, payload: bytes) -> tuple[int, bytes]:
        return frame_id, bytes((self.crc(frame_id, payload),)) + payload[1:]

    # ----- encoding ---------------------------------------------------------------------------
    def encode(self, message: Message) -> tuple[int, bytes]:
        """(frame id, payload) with the CRC filled in; the counter is the message's."""
        if isinstance(message, Status):
            return self._protect(
                STATUS + message.vehicle,
                self._pack[STATUS](
                    0,
                    message.counter % 16,
                    STATE_CODE[message.state],
                    message.current_node,
                    message.next_node,
                    int(message.fault),
                    int(message.clear),
                    message.route_ack % 16,
                    min(max(message.speed, 0.0), self._max_speed),
                ),
            )
        if isinstance(message, Info):
            return self._protect(
                INFO + message.vehicle,
                self._pack[INFO](0, message.counter % 16, message.battery),
            )
        if isinstance(message, RouteCommand):
            nodes = (*message.nodes, NO_NODE, NO_NODE, NO_NODE)[:3]
            return self._protect(
                ROUTE + message.vehicle,
                self._pack[ROUTE](0, message.sequence % 16, len(message.nodes), *nodes),
            )
        if isinstance(message, StopGo):
            return self._protect(
                STOP_GO + message.vehicle,
                self._pack[STOP_GO](0, message.counter % 16, int(message.go)),
            )
        return self._protect(
            HEARTBEAT + message.node, self._pack[HEARTBEAT](0, message.counter % 16)
        )

    # ----- decoding ---------------------------------------------------------------------------
    def decode(self, frame_id: int, data: bytes) -> Message:
        base, sender = frame_id & ~(ID_SPAN - 1), frame_id & (ID_SPAN - 1)
        decoder = self._decoders.get(base)
        if decoder is None:
            raise UnknownFrame(f"unknown frame id 0x{frame_id:03X}")
        length, decode = decoder
        if len(data) != length:
            raise MalformedFrame(f"0x{frame_id:03X}: {len(data)} data bytes, expected {length}")
        if self.crc(frame_id, data) != data[0]:
            raise CorruptFrame(f"0x{frame_id:03X}: CRC mismatch")
        return decode(frame_id, sender, data)

    @staticmethod
    def _status_decoder(layout: Layout) -> tuple[int, Callable]:
        unpack = layout.unpack
        counter, state, current, nxt, fault, clear, ack, speed = map(
            layout.index,
            (
                "counter",
                "state",
                "current_node",
                "next_node",
                "fault",
                "clear",
                "route_ack",
                "speed",
            ),
        )
        n_states = len(STATES)

        def decode(frame_id: int, sender: int, data: bytes) -> Status:
            t = unpack(data)
            if t[state] >= n_states or not 1 <= sender <= MAX_VEHICLE_ID:
                raise MalformedFrame(f"0x{frame_id:03X}: state {t[state]}, vehicle {sender}")
            return Status(
                sender,
                t[current],
                t[nxt],
                STATES[t[state]],
                t[speed],
                t[counter],
                t[fault] == 1,
                t[clear] == 1,
                t[ack],
            )

        return layout.length, decode

    @staticmethod
    def _info_decoder(layout: Layout) -> tuple[int, Callable]:
        unpack = layout.unpack
        counter, battery = layout.index("counter"), layout.index("battery")

        def decode(frame_id: int, sender: int, data: bytes) -> Info:
            t = unpack(data)
            if t[battery] > 100 or not 1 <= sender <= MAX_VEHICLE_ID:
                raise MalformedFrame(f"0x{frame_id:03X}: battery {t[battery]}, vehicle {sender}")
            return Info(sender, t[battery], t[counter])

        return layout.length, decode

    @staticmethod
    def _route_decoder(layout: Layout) -> tuple[int, Callable]:
        unpack = layout.unpack
        counter, count = layout.index("counter"), layout.index("count")
        first = layout.index("node1")

        def decode(frame_id: int, sender: int, data: bytes) -> RouteCommand:
            t = unpack(data)
            nodes = t[first : first + t[count]]  # none: cancel the route
            if NO_NODE in nodes or not 1 <= sender <= MAX_VEHICLE_ID:
                raise MalformedFrame(f"0x{frame_id:03X}: route command with nodes {nodes}")
            return RouteCommand(sender, t[counter], nodes)

        return layout.length, decode

    @staticmethod
    def _stop_go_decoder(layout: Layout) -> tuple[int, Callable]:
        unpack = layout.unpack
        counter, go = layout.index("counter"), layout.index("go")

        def decode(frame_id: int, sender: int, data: bytes) -> StopGo:
            t = unpack(data)
            if sender == CONTROLLER:
                raise MalformedFrame(f"0x{frame_id:03X}: stop/go for vehicle 0")
            return StopGo(sender, t[go] == 1, t[counter])

        return layout.length, decode

    @staticmethod
    def _heartbeat_decoder(layout: Layout) -> tuple[int, Callable]:
        unpack = layout.unpack
        counter = layout.index("counter")

        def decode(frame_id: int, sender: int, data: bytes) -> Heartbeat:
            return Heartbeat(sender, unpack(data)[counter])

        return layout.length, decode
