"""The scan's side of the fleet endpoints: vehicles, plant, blockades, tags, statistics and
events, answered at the quiet point like the orders (:mod:`fleet.web.desk` says why).

Changes are applied where the program's own blocks apply them, at the same quiet point:

* a blockade closes or reopens the segment both ways in the routing constraints, as the
  operator's blockade command of the Modbus map does (``FleetCommands``); vehicles replan
  around it and the event log records it;
* a tag is written or forced in the process image (CODESYS semantics, plc_runtime/image.py),
  only where the tag is declared writable: the rule of the Modbus server, so nothing a
  client writes over HTTP reaches what it could not write over Modbus, and every writable
  tag is a command the program checks (a hold, an acknowledge, the blockade command).

A refusal is a :class:`Refusal` (HTTP status, one line, the field) and changes nothing.
"""

from __future__ import annotations

from concurrent.futures import Future
from typing import Any

from plc_runtime.errors import PlcError

from ..program import FleetProgram
from . import views
from .desk import SCAN_BUDGET, Desk

MAX_WATCH = 200  # tags in one watch request


class Refusal(Exception):
    """The desk's no: HTTP status, one line, the field it is about."""

    def __init__(self, status: int, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.status, self.message, self.field = status, message, field


class FleetDesk(Desk):
    """Requests about the fleet; each ``ask_*`` returns a Future ending with a JSON-ready
    value or a copy to render (vehicles, statistics: :mod:`fleet.web.views`), or raising
    :class:`Refusal` or ``ControllerStopped``."""

    def __init__(
        self,
        program: FleetProgram,
        budget: int = SCAN_BUDGET,
        fleet_copy: views.FleetCopy | None = None,
    ) -> None:
        super().__init__(budget)
        self._program = program
        self._fleet_copy = fleet_copy or views.FleetCopy(program)
        self.plant = program.cfg.plant  # fixed while the program runs: any thread reads it
        self._segments = views.ClosedSegments(program)

    # ----- the HTTP side (any thread) -----------------------------------------------------
    def ask_plant(self) -> Future:
        """The closed segments: the rest of the plant model is fixed (``views.plant``)."""
        return self._ask(lambda done: self._answer(done, self._segments))

    def ask_vehicles(self) -> Future:
        n = len(self._program.vehicles)
        return self._ask(lambda done: self._answer(done, self._fleet_copy, n))

    def ask_vehicle(self, vehicle: int) -> Future:
        return self._ask(lambda done: self._answer(done, lambda: self._vehicle(vehicle)))

    def ask_blockades(self) -> Future:
        return self._ask(lambda done: self._answer(done, self._segments))

    def ask_blockade(self, a: int, b: int, closed: bool) -> Future:
        return self._ask(lambda done: self._answer(done, lambda: self._set_blockade(a, b, closed)))

    def ask_stats(self) -> Future:
        return self._ask(lambda done: self._answer(done, lambda: views.copy_stats(self._program)))

    def ask_events(self, after: int, limit: int) -> Future:
        return self._ask(
            lambda done: self._answer(done, lambda: views.events(self._program, after, limit))
        )

    def ask_tags(self, names: list[str]) -> Future:
        return self._ask(lambda done: self._answer(done, lambda: self._read(names), len(names)))

    def ask_tag(self, name: str) -> Future:
        return self._ask(lambda done: self._answer(done, lambda: self._read([name], "name")[0]))

    def ask_write(self, name: str, value: object) -> Future:
        return self._ask(
            lambda done: self._answer(done, lambda: self._change(name, "write", value))
        )

    def ask_force(self, name: str, value: object) -> Future:
        return self._ask(
            lambda done: self._answer(done, lambda: self._change(name, "force", value))
        )

    def ask_unforce(self, name: str) -> Future:
        return self._ask(lambda done: self._answer(done, lambda: self._change(name, "unforce")))

    def tag_catalogue(self) -> list[dict[str, Any]]:
        """Every tag, without values. The tag table is fixed once the program is built, so
        this reads no live state and needs no quiet point."""
        return [
            {
                "name": t.name,
                "address": t.address.text,
                "type": t.type.name,
                "writable": t.writable,
                "comment": t.comment,
            }
            for t in self._program.rt.image.tags
        ]

    # ----- the scan side (at the quiet point) ---------------------------------------------
    @staticmethod
    def _answer(done: Future, work: Any, cost: int = 1) -> int:
        try:
            done.set_result(work())
        except Refusal as exc:
            done.set_exception(exc)
        return cost

    def _vehicle(self, vehicle: int) -> tuple[Any, list[views.VehicleCopy]]:
        if vehicle not in self._program.controls:
            raise Refusal(404, f"there is no vehicle {vehicle}", "vehicle")
        return self._fleet_copy.of([vehicle])

    def _set_blockade(self, a: int, b: int, closed: bool) -> dict[str, Any]:
        plant = self.plant
        for field, node in (("a", a), ("b", b)):
            if node not in plant.index:
                raise Refusal(404, f"there is no node {node} in plant {plant.name!r}", field)
        if (a, b) not in plant.arc_index and (b, a) not in plant.arc_index:
            raise Refusal(404, f"there is no segment between nodes {a} and {b}", "b")
        if closed:
            self._program.blockades.block(a, b, both_ways=True)
        else:
            self._program.blockades.unblock(a, b, both_ways=True)
        return {"a": min(a, b), "b": max(a, b), "closed": closed}

    def _tag(self, name: str, field: str = "name") -> Any:
        try:
            return self._program.rt.image.tags.get(name)
        except PlcError:
            raise Refusal(404, f"there is no tag {name!r}", field) from None

    def _read(self, names: list[str], field: str | None = None) -> list[dict[str, Any]]:
        """The tags' values; an unknown name is refused naming ``field`` (else its place in
        ``names``)."""
        image = self._program.rt.image
        forces = image.forces
        out = []
        for i, name in enumerate(names):
            tag = self._tag(name, field or f"names[{i}]")
            out.append(
                {
                    "name": tag.name,
                    "address": tag.address.text,
                    "type": tag.type.name,
                    "value": _json_value(image.read(tag.name)),
                    "writable": tag.writable,
                    "forced": tag.name in forces,
                    "forced_value": _json_value(forces.get(tag.name)),
                    "comment": tag.comment,
                }
            )
        return out

    def _change(self, name: str, action: str, value: object = None) -> dict[str, Any]:
        """Write, force or unforce a writable tag, applied at once: no block runs between
        two scans, where the runtime applies queued writes too; the next scan sees it."""
        tag = self._tag(name)
        if not tag.writable:
            raise Refusal(
                403,
                f"tag {name!r} ({tag.address.text}) is read-only: the program computes it; "
                "only tags declared writable can be written or forced (plc-runtime tags)",
                "name",
            )
        image = self._program.rt.image
        try:
            if action == "write":
                image.write(tag.name, value)
            elif action == "force":
                image.force(tag.name, value)
            else:
                image.unforce(tag.name)
        except (PlcError, TypeError, ValueError) as exc:
            raise Refusal(422, f"value for {name!r}: {exc}", "value") from None
        image.apply_quiet_point()
        return self._read([tag.name])[0]


def _json_value(value: object) -> object:
    """A tag's value as JSON has it (numpy scalars to Python numbers)."""
    item = getattr(value, "item", None)
    return item() if callable(item) else value
