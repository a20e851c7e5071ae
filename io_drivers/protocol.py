"""The AGV message set: one DBC file (``agv.dbc``), encoded and decoded with cantools.

Frame ids are standard 11-bit ids, ``base + id`` (see docs/protocol.md):

    0x080 + v  StopGo        controller -> vehicle v (v = 127: every vehicle)
    0x100 + v  VehicleStatus vehicle v -> everyone (periodic and on every tag read)
    0x200 + v  RouteCommand  controller -> vehicle v: the next 1..3 verified nodes
    0x700 + n  Heartbeat     node n alive (n = 0: the controller)

Vehicle ids 1..126, node ids 0..65534 (65535 means "none"). The vehicle id is also a
signal of every frame; a frame whose signal disagrees with its frame id is malformed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cantools

DBC_PATH = Path(__file__).with_name("agv.dbc")
STOP_GO, STATUS, ROUTE, HEARTBEAT = 0x080, 0x100, 0x200, 0x700
ID_SPAN = 0x80  # 128 ids per message kind
MAX_VEHICLE_ID = 126
ALL_VEHICLES = 127
CONTROLLER = 0
NO_NODE = 0xFFFF
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


class MalformedFrame(ValueError):
    """A frame with a known id but a wrong length or out-of-range contents."""


class UnknownFrame(ValueError):
    """A frame id outside the message set."""


@dataclass(frozen=True, slots=True)
class Status:
    vehicle: int
    current_node: int
    next_node: int  # NO_NODE when the vehicle has no verified next node
    state: str
    battery: int  # percent
    speed: float  # m/s
    alive: int  # 0..15, increments with every status frame
    fault: bool = False
    clear: bool = False  # left the current node's crossing zone (driving on beyond it)


@dataclass(frozen=True, slots=True)
class RouteCommand:
    vehicle: int
    sequence: int  # 0..15
    nodes: tuple[int, ...]  # 1..3 node ids


@dataclass(frozen=True, slots=True)
class StopGo:
    vehicle: int  # ALL_VEHICLES for everyone
    go: bool


@dataclass(frozen=True, slots=True)
class Heartbeat:
    node: int
    alive: int


Message = Status | RouteCommand | StopGo | Heartbeat


class Codec:
    """Encode and decode the message set; ``decode`` validates everything it returns."""

    def __init__(self, dbc: Path = DBC_PATH) -> None:
        db = cantools.database.load_file(str(dbc))
        self._msg = {m.frame_id: m for m in db.messages}

    def encode(self, message: Message) -> tuple[int, bytes]:
        if isinstance(message, Status):
            return STATUS + message.vehicle, self._msg[STATUS].encode(
                {
                    "vehicle_id": message.vehicle,
                    "fault_code": int(message.fault),
                    "clear": int(message.clear),
                    "current_node": message.current_node,
                    "next_node": message.next_node,
                    "state": STATE_CODE[message.state],
                    "alive": message.alive % 16,
                    "battery": message.battery,
                    "speed": round(min(max(message.speed, 0.0), 2.55), 2),
                },
                strict=True,
            )
        if isinstance(message, RouteCommand):
            nodes = (*message.nodes, NO_NODE, NO_NODE, NO_NODE)[:3]
            return ROUTE + message.vehicle, self._msg[ROUTE].encode(
                {
                    "vehicle_id": message.vehicle,
                    "sequence": message.sequence % 16,
                    "count": len(message.nodes),
                    "node1": nodes[0],
                    "node2": nodes[1],
                    "node3": nodes[2],
                },
                strict=True,
            )
        if isinstance(message, StopGo):
            return STOP_GO + message.vehicle, self._msg[STOP_GO].encode(
                {"vehicle_id": message.vehicle, "go": int(message.go)}, strict=True
            )
        return HEARTBEAT + message.node, self._msg[HEARTBEAT].encode(
            {"node_id": message.node, "alive": message.alive % 256}, strict=True
        )

    def decode(self, frame_id: int, data: bytes) -> Message:
        base, sender = frame_id & ~(ID_SPAN - 1), frame_id & (ID_SPAN - 1)
        msg = self._msg.get(base)
        if msg is None:
            raise UnknownFrame(f"unknown frame id 0x{frame_id:03X}")
        if len(data) != msg.length:
            raise MalformedFrame(
                f"0x{frame_id:03X}: {len(data)} data bytes, {msg.name} has {msg.length}"
            )
        s = msg.decode(bytes(data), decode_choices=False, scaling=True)
        own_id = s["node_id"] if base == HEARTBEAT else s["vehicle_id"]
        if own_id != sender:
            raise MalformedFrame(
                f"0x{frame_id:03X}: id signal {own_id} does not match the frame id"
            )
        if base == STATUS:
            if (
                s["state"] >= len(STATES)
                or s["battery"] > 100
                or sender == 0
                or sender > MAX_VEHICLE_ID
            ):
                raise MalformedFrame(f"0x{frame_id:03X}: out-of-range status {dict(s)}")
            return Status(
                sender,
                int(s["current_node"]),
                int(s["next_node"]),
                STATES[s["state"]],
                int(s["battery"]),
                float(s["speed"]),
                int(s["alive"]),
                bool(s["fault_code"]),
                bool(s["clear"]),
            )
        if base == ROUTE:
            count = int(s["count"])
            nodes = tuple(int(s[f"node{k}"]) for k in range(1, count + 1))
            if count == 0 or NO_NODE in nodes:
                raise MalformedFrame(
                    f"0x{frame_id:03X}: route command with {count} node(s) {nodes}"
                )
            return RouteCommand(sender, int(s["sequence"]), nodes)
        if base == STOP_GO:
            return StopGo(sender, bool(s["go"]))
        return Heartbeat(sender, int(s["alive"]))
