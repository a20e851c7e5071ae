"""The JSON of the HTTP API (pydantic models; they are also its OpenAPI schema).

A new order is checked strictly, like an order file: integers must be JSON integers (not
``"21"``, ``21.0`` or ``true``), times finite numbers, no unknown keys; what needs the
plant (stations, vehicles, ids in use) is checked by the order book. An order without a
deadline has ``end_s`` null in both directions (JSON has no infinity).
"""

from __future__ import annotations

import math

from pydantic import BaseModel, ConfigDict, Field

from blocks.dispatch.orders import MAX_ID_CHARS, TransportOrder

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
    history: list[HistoryEntry]
    sections: dict[str, list[float]] = Field(description="section -> [start] or [start, end]")

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
            sections={name: list(times) for name, times in view.sections.items()},
        )


class OrderPage(BaseModel):
    """Orders ``offset`` .. ``offset + len(orders) - 1`` of ``total``, in the order added."""

    total: int
    offset: int
    orders: list[OrderOut]

    @classmethod
    def of(cls, page: Page) -> OrderPage:
        return cls(
            total=page.total, offset=page.offset, orders=[OrderOut.of(v) for v in page.orders]
        )


class ErrorOut(BaseModel):
    """Every error: one line, and the field it is about (null when it is about none)."""

    error: str
    field: str | None = None
