"""The vehicle records of the process image, as the fleet blocks read and write them.

The layout is the one the vehicle links write (docs/protocol.md): per vehicle ``v`` an
8-byte input record at ``input_base + 8 * v`` (WORD current node, WORD next node, BYTE
state, BYTE battery %, BYTE speed cm/s, BYTE flags) and an 8-byte output record at
``output_base + 8 * v`` (WORD nodes 1..3, BYTE count | go bit, BYTE sequence). The blocks
see the image through numpy structured views, one row per vehicle, so a scan over a
thousand vehicles reads fields, not addresses. Fleets larger than one bus (126 vehicles)
span several record areas; each vehicle names its area.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from plc_runtime import CycleContext

IN_RECORD = np.dtype(
    [
        ("current", "<u2"),
        ("next", "<u2"),
        ("state", "u1"),
        ("battery", "u1"),
        ("speed", "u1"),
        ("flags", "u1"),
    ]
)
OUT_RECORD = np.dtype([("nodes", "<u2", (3,)), ("control", "u1"), ("sequence", "u1")])
RECORD = 8
NO_NODE = 0xFFFF
BATTERY_UNKNOWN = 0xFF  # battery byte: no info frame from the vehicle yet
ONLINE, STALE, FAULT, CLEAR = 0x01, 0x02, 0x04, 0x08
# bits 4-6: the link's count of the vehicle's message counter jumps (restart, second sender)
LINK_JUMPS, LINK_JUMP_SHIFT = 0x70, 4
GO_BIT, COUNT_MASK = 0x80, 0x03  # count 0 with a new sequence: cancel the vehicle's route
MAX_RELEASED = 3  # nodes per route command
STATES = (
    "IDLE",
    "DRIVING",
    "STOPPING_AT_NODE",
    "WAITING_FOR_ROUTE",
    "PROCESSING",
    "CHARGING",
    "FAULT",
)


@dataclass(frozen=True)
class RecordArea:
    """Where one bus's vehicle records live: byte offsets of vehicle 0's (unused) records."""

    input_base: int
    output_base: int
    max_vehicle: int  # the highest local vehicle id in this area


class VehicleRecordsView:
    """Per-scan numpy views of every vehicle's input and output record.

    ``vehicles`` maps the fleet's vehicle key to (area, local id on that bus)."""

    def __init__(self, areas: list[RecordArea], vehicles: Mapping[int, tuple[int, int]]) -> None:
        self.areas = areas
        self.vehicles = dict(vehicles)
        self._in: list[np.ndarray] = []
        self._out: list[np.ndarray] = []

    def bind(self, ctx: CycleContext) -> None:
        """(Re)create the views: once at startup (the image's buffers never move)."""
        self._in, self._out = [], []
        for a in self.areas:
            size = RECORD * (a.max_vehicle + 1)
            self._in.append(ctx.image.record_view("I", a.input_base, size).view(IN_RECORD))
            self._out.append(ctx.image.record_view("Q", a.output_base, size).view(OUT_RECORD))

    @property
    def bound(self) -> bool:
        return bool(self._in)

    def inputs(self, vehicle: int) -> np.void:
        area, local = self.vehicles[vehicle]
        return self._in[area][local]

    def write_command(self, vehicle: int, nodes: tuple[int, ...], go: bool, sequence: int) -> None:
        area, local = self.vehicles[vehicle]
        rec = self._out[area][local]
        padded = (list(nodes) + [NO_NODE] * MAX_RELEASED)[:MAX_RELEASED]
        rec["nodes"] = padded
        rec["control"] = min(len(nodes), MAX_RELEASED) | (GO_BIT if go else 0)
        rec["sequence"] = sequence
