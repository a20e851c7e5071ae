"""The JSON of the HTTP API (pydantic models; they are also its OpenAPI schema).

A new order is checked strictly, like an order file: integers must be JSON integers (not
``"21"``, ``21.0`` or ``true``), times finite numbers, no unknown keys; what needs the
plant (stations, vehicles, ids in use) is checked by the order book. An order without a
deadline has ``end_s`` null in both directions (JSON has no infinity).
"""

from __future__ import annotations

import math
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator

from blocks.dispatch.orders import HISTORY_KEPT, MAX_ID_CHARS, TransportOrder

from .desk import OrderView, Page


class OrderIn(BaseModel):
    """A transport order to add (docs/orders.md, "The order")."""

    model_config = ConfigDict(extra="forbid", strict=True)

    id: str = Field(min_length=1, max_length=MAX_ID_CHARS, description="unique in the run")
    get: int = Field(ge=0, description="Get station: node id where the load is picked up")
    put: int = Field(ge=0, description="Put station: node id where it is delivered")
    start_s: float = Field(0.0, ge=0, allow_inf_nan=False, description="earliest pickup, s")
    end_s: float | None = Field(
        None, ge=0, allow_inf_nan=False, description="latest delivery, s; null: no deadline"
    )
    priority: int = Field(0, description="larger is more urgent")
    vehicle: int | None = Field(None, description="the only vehicle that may take it")

    def order(self) -> TransportOrder:
        return TransportOrder(
            self.id,
            self.get,
            self.put,
            self.start_s,
            math.inf if self.end_s is None else self.end_s,
            self.priority,
            self.vehicle,
        )


class HistoryEntry(BaseModel):
    time_s: float
    state: str


class OrderOut(BaseModel):
    """An order as the scan saw it when the request was answered."""

    id: str
    get: int
    put: int
    start_s: float
    end_s: float | None
    priority: int
    vehicle: int | None
    state: str = Field(description="RAW, DISPATCHABLE, BEING_PROCESSED or a final state")
    assigned: int | None = Field(description="the vehicle that has it")
    reason: str = Field(description="why its last transition happened")
    history: list[HistoryEntry] = Field(
        description="its transitions (an order taken back again and again keeps its first "
        f"two and its newest ones, {HISTORY_KEPT} at most)"
    )
    history_dropped: int = Field(
        0,
        description="transitions dropped from its history, oldest first after the first two: "
        "pairs of being given out and taken back",
    )
    sections: dict[str, list[float]] = Field(description="section -> [start] or [start, end]")
    position: int = Field(
        description="the orders added to the book before it in the run: never changes, the "
        "order of the book's pages"
    )

    @classmethod
    def of(cls, view: OrderView) -> OrderOut:
        return cls(
            id=view.id,
            get=view.get,
            put=view.put,
            start_s=view.start_s,
            end_s=view.end_s,
            priority=view.priority,
            vehicle=view.vehicle,
            state=view.state.value,
            assigned=view.assigned,
            reason=view.reason,
            history=[HistoryEntry(time_s=t, state=s.value) for t, s in view.history],
            history_dropped=view.history_dropped,
            sections={name: list(times) for name, times in view.sections.items()},
            position=view.position,
        )


class OrderPage(BaseModel):
    """Up to ``limit`` orders of the book from position ``offset`` on, in the order added
    (an order's position: the orders added before it in the run; final orders leave the
    book a while after they end, and are skipped). ``total``: the orders in the book now;
    ``next_offset``: where the next page starts; ``added``: the orders added in the run so
    far (the newest ``n`` are from ``added - n`` on)."""

    total: int
    offset: int
    orders: list[OrderOut]
    next_offset: int
    added: int

    @classmethod
    def of(cls, page: Page) -> OrderPage:
        return cls(
            total=page.total,
            offset=page.offset,
            orders=[OrderOut.of(v) for v in page.orders],
            next_offset=page.next_offset,
            added=page.added,
        )


class ErrorOut(BaseModel):
    """Every error: one line, and the field it is about (null when it is about none)."""

    error: str
    field: str | None = None


class NodeOut(BaseModel):
    id: int
    name: str
    x: float = Field(description="metres")
    y: float = Field(description="metres")
    role: str = Field(description="transit, station, entry, exit, charger, parking or queue")
    functions: list[int] = Field(description="functions a station provides")
    queue_for: int | None = Field(description="role queue: the station it is a waiting place of")
    area: str | None = Field(description="the single-vehicle area it belongs to")


class EdgeOut(BaseModel):
    a: int = Field(description="source node")
    b: int = Field(description="target node")
    length: float = Field(description="metres")
    bidirectional: bool = Field(description="false: one-way from a to b")
    routable: bool
    highway: bool = Field(description="two-way, but a -> b is the preferred direction")


class PlantOut(BaseModel):
    """The plant model, with the segments closed now."""

    name: str
    nodes: list[NodeOut]
    edges: list[EdgeOut]
    stations: list[int]
    chargers: list[int]
    parking: list[int]
    queues: dict[str, list[int]] = Field(description="station -> its queue positions, in order")
    functions: dict[str, str] = Field(description="function id -> name")
    blockades: list[list[int]] = Field(description="closed segments as [a, b], a < b")


class VehicleOut(BaseModel):
    """A vehicle as the controller knows it (its reports, its routes, its job)."""

    id: int
    state: str = Field(
        description="offline, idle, planning, driving, waiting, arrived, no_route, stale, "
        "fault or suspect"
    )
    node: int | None = Field(description="the node it last reported")
    next: int | None = Field(description="the next node it reports (null: standing)")
    target: int | None = Field(description="the node it is sent to")
    phase: str = Field(
        description="what its job is at: a recipe vehicle's start, to_station, processing, "
        "returning, done; an order vehicle's idle, to_get, get_queue, get, to_put, "
        "put_queue, put, to_charger, charging (its battery needs the charge), to_parking, "
        "parked, to_top_up, topping_up (charging by choice: still available for orders); "
        "a goal vehicle's idle, to_goal (docs/hmi-map.md)"
    )
    released: list[int] = Field(description="nodes released to it and not reached, in order")
    planned: list[int] = Field(description="planned nodes after the released ones")
    battery: int | None = Field(description="charge in % (null: not reported yet)")
    speed_cm_s: int
    order: str | None = Field(description="its active transport order")
    next_order: str | None = Field(description="its next transport order")
    recipe: str | None = Field(description="its recipe (vehicles that run recipes)")
    waiting_for: int | None = Field(
        description="the vehicle holding the node it waits for (null while it waits for a "
        "time-window planning round; its state is then planning)"
    )
    online: bool
    stale: bool = Field(description="silent for longer than stale_after: nothing released")
    fault: bool
    suspect: bool = Field(description="an implausible report: stopped (docs/security.md)")
    suspect_reason: str
    load: str | None = Field(
        description="the order whose load is on board, from the start of its Get (null: "
        "none). When it is not its active order, that order ended without its Put "
        "(withdrawn, failed): the vehicle takes no order until the load is taken off and "
        "the vehicle acknowledged (agvN.ack)"
    )
    held: bool = Field(description="an operator holds it")
    waits: int
    replans: int


class BlockadeOut(BaseModel):
    a: int
    b: int
    closed: bool


class TagInfo(BaseModel):
    name: str
    address: str
    type: str
    writable: bool = Field(description="clients may write and force it")
    comment: str


class TagOut(TagInfo):
    value: bool | int | float
    forced: bool
    forced_value: bool | int | float | None


class TagValueIn(BaseModel):
    """A value to write or force: a JSON number, or true/false for a BOOL. Its range is the
    tag's type's, checked by the process image."""

    model_config = ConfigDict(extra="forbid", strict=True)

    value: Any = Field(
        description="a JSON number, or true/false",
        json_schema_extra={"anyOf": [{"type": "number"}, {"type": "boolean"}]},
    )

    @field_validator("value")
    @classmethod
    def _number(cls, value: Any) -> bool | int | float:
        if not isinstance(value, bool | int | float) or (
            isinstance(value, float) and not math.isfinite(value)
        ):
            raise ValueError(f"expected a finite JSON number or true/false, got {value!r}")
        return value


class EventOut(BaseModel):
    seq: int = Field(description="the event's number in the run, from 1")
    time_s: float
    kind: str
    vehicle: int | None
    text: str


class EventPage(BaseModel):
    first: int = Field(description="the oldest event the log still keeps")
    last: int = Field(description="the newest event's number (0: none yet)")
    events: list[EventOut]


class StatsOut(BaseModel):
    """The runtime's cycle statistics (times in microseconds) and the fleet's counters."""

    state: str
    cycles: int
    cycle_time_s: float
    sim_time_s: float
    overruns: int
    fault_reason: str | None
    watchdog_ms: float
    scan: dict[str, Any] = Field(description="whole scans: cycles, exec_us, lateness_us")
    tasks: dict[str, Any] = Field(description="per task, as scan")
    drivers: dict[str, Any]
    fleet: dict[str, Any]
