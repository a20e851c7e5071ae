"""The fleet's tags: a name and an address for everything a user wants to watch or force.

Everything lives in the marker area, one 16-bit word per field (no packed bytes: a bit
never shares a register with another field), so an HMI reads a vehicle with one request
(docs/hmi-map.md has the tables for HMI builders):

    %MW0  .. %MW63     the fleet: counters of this run, lifetime totals (retentive), commands
    %MW64 + 24*(v-1)   vehicle v: 24 words (its status, and its hold command)

The image's M area is sized for the highest id, and the Modbus server serves it whole
(%MWn is holding register 1024 + n), so an HMI reaches every vehicle of the largest fleet
a configuration allows.

Two blocks keep the words. ``FleetCommands`` at the start of the fleet task reads the
writable ones (the blockade command, the vehicles' holds) and applies them through the
paths the program itself uses (the routing constraints, the ``hold`` input of the vehicle
control), so nothing a client writes moves a vehicle past the reservations.
``FleetStatus`` at the end of the task mirrors what the scan decided. The program never
writes a writable word, and a client can write no other.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from blocks.dispatch.executor import PHASES
from blocks.dispatch.orders import OrderState
from blocks.routing.constraints import RoutingConstraints
from blocks.traffic.records import COUNT_MASK, FAULT, NO_NODE, ONLINE, RECORD, STALE, STATES
from plc_runtime import CycleContext, FunctionBlock, Static, TagTable
from topology import Plant

if TYPE_CHECKING:
    from .program import FleetProgram

VEHICLE_BASE = 64  # %MW64: vehicle 1's first word
STRIDE = 24  # words per vehicle
HOLDING_BASE = 1024  # the holding register of %MW0
MAX_UINT, MAX_UDINT = 0xFFFF, 0xFFFFFFFF

# the vehicle control's states as numbers (255: a state this table does not know)
STATE_CODES = {
    s: i
    for i, s in enumerate(
        (
            "offline",
            "idle",
            "planning",
            "driving",
            "waiting",
            "arrived",
            "no_route",
            "stale",
            "fault",
            "suspect",
        )
    )
}
UNKNOWN_STATE = 255
# a recipe vehicle's sequencer phases, then an order vehicle's, then a goal vehicle's own
# (its idle is the order vehicle's; docs/hmi-map.md), then the two an order vehicle shows
# while it charges by choice (after the others, so that no code of theirs moves)
TOPPING_UP = {"to_charger": "to_top_up", "charging": "topping_up"}
PHASE_CODES = {
    p: i
    for i, p in enumerate(
        (
            "start",
            "to_station",
            "processing",
            "returning",
            "done",
            *PHASES,
            "to_goal",
            *TOPPING_UP.values(),
        )
    )
}

UNKNOWN_PHASE = 255
PHASE_NAMES = {i: p for p, i in PHASE_CODES.items()}


class _Job(Protocol):
    phase: str


def shown_phase(job: _Job) -> str:
    """The phase an operator sees of a vehicle's job (recipe, orders or goals). An order
    vehicle charging by choice (idle, topping up, still available for orders and giving
    its charger up to one that must charge) shows ``to_top_up`` / ``topping_up``, apart
    from one whose battery needs the charge."""
    phase = job.phase
    return TOPPING_UP.get(phase, phase) if getattr(job, "topping_up", False) else phase


# a vehicle's acknowledge: the results the program answers with
ACK_DONE, ACK_REFUSED = 1, 2

# the blockade command: the codes a client writes, the results the program answers with
CLOSE, REOPEN = 1, 2
DONE, UNKNOWN_COMMAND, UNKNOWN_NODE, NO_SEGMENT = 1, 2, 3, 4
RESULTS = {
    DONE: "done",
    UNKNOWN_COMMAND: "unknown command code",
    UNKNOWN_NODE: "unknown node",
    NO_SEGMENT: "no such segment",
}


@dataclass(frozen=True)
class Field:
    """One word of the map (a UDINT counter: two, low word first)."""

    name: str
    type: str  # UINT (one word), UDINT (two words) or BOOL (bit 0 of its word)
    comment: str
    writable: bool = False
    retain: bool = False
    word: int = 0  # fleet fields: the %MW index; vehicle fields: their position


def _codes(codes: dict[str, int]) -> str:
    return ", ".join(f"{i} {name}" for name, i in codes.items())


# The fleet's words. Counters first (UDINT, in this order: FleetStatus writes them as one
# slice), then the gauges (UINT, likewise), the lifetime totals, the blockade command.
COUNTERS = (
    Field("fleet.recipes_completed", "UDINT", "recipes completed in this run", word=0),
    Field("fleet.stations_visited", "UDINT", "stations reached in this run", word=2),
    Field("fleet.replans", "UDINT", "routes recomputed because the next segment was taken", word=4),
    Field("fleet.waits", "UDINT", "times a vehicle stopped for a node held by another", word=6),
    Field("fleet.deadlocks_detected", "UDINT", "waits-for cycles found", word=8),
    Field("fleet.deadlocks_resolved", "UDINT", "waits-for cycles broken", word=10),
    Field("fleet.deadlocks_unresolved", "UDINT", "waits-for cycles nobody could leave", word=12),
    Field("fleet.pushes", "UDINT", "standing vehicles moved aside for a more urgent one", word=14),
)
GAUGES = (
    Field("fleet.vehicles", "UINT", "vehicles configured", word=16),
    Field("fleet.online", "UINT", "vehicles whose status arrives", word=17),
    Field("fleet.stale", "UINT", "vehicles silent for longer than stale_after", word=18),
    Field("fleet.faulted", "UINT", "vehicles reporting a fault", word=19),
    Field("fleet.held", "UINT", "vehicles an operator holds", word=20),
    Field("fleet.blocked_segments", "UINT", "segments closed now (schedule or operator)", word=21),
    Field("fleet.heartbeat", "UINT", "scans of the fleet task, modulo 65536", word=22),
)
TOTALS = (
    Field("fleet.total.recipes", "UDINT", "recipes completed, all runs", retain=True, word=32),
    Field(
        "fleet.total.station_visits", "UDINT", "stations reached, all runs", retain=True, word=34
    ),
    Field("fleet.total.busy_s", "UDINT", "station processing s, all runs", retain=True, word=36),
    Field("fleet.total.run_s", "UDINT", "seconds in RUN, all runs", retain=True, word=38),
    Field("fleet.total.starts", "UDINT", "starts, this one included", retain=True, word=40),
)
COMMAND = (
    Field("fleet.cmd.seq", "UINT", "blockade command: a new value 1..65535 runs it", True, word=48),
    Field(
        "fleet.cmd.code", "UINT", f"{CLOSE} close the segment, {REOPEN} reopen it", True, word=49
    ),
    Field("fleet.cmd.a", "UINT", "node at one end of the segment", True, word=50),
    Field("fleet.cmd.b", "UINT", "node at the other end", True, word=51),
    Field("fleet.cmd.ack", "UINT", "seq of the last command run (0: none yet)", word=52),
    Field(
        "fleet.cmd.result",
        "UINT",
        f"result of the command run: {_codes({v: k for k, v in RESULTS.items()})}",
        word=53,
    ),
)
# The transport orders in the book by state (all 0 for a fleet of recipe vehicles), in this
# order: FleetStatus writes them as one slice whenever an order changed state.
ORDERS = (
    Field(
        "fleet.orders.waiting",
        "UDINT",
        "transport orders waiting for a vehicle (DISPATCHABLE)",
        word=54,
    ),
    Field(
        "fleet.orders.active",
        "UDINT",
        "transport orders a vehicle has taken, as its active or next order (BEING_PROCESSED)",
        word=56,
    ),
    Field("fleet.orders.finished", "UDINT", "transport orders FINISHED in this run", word=58),
    Field(
        "fleet.orders.failed",
        "UDINT",
        "transport orders FAILED or UNROUTABLE in this run",
        word=60,
    ),
    Field("fleet.orders.withdrawn", "UDINT", "transport orders WITHDRAWN in this run", word=62),
)
FLEET_FIELDS = COUNTERS + GAUGES + TOTALS + COMMAND + ORDERS
F = {f.name: f.word for f in FLEET_FIELDS}

# A vehicle's words, at their position from its first word. FleetStatus writes the words
# before ``hold`` as one row in this order; the client's words come last: ``hold`` and
# ``ack``, then ``ack_result``, which FleetCommands answers.
VEHICLE_FIELDS = tuple(
    Field(name, type_, comment, writable, word=i)
    for i, (name, type_, comment, writable) in enumerate(
        (
            (
                "node",
                "UINT",
                "node last reported (65535: none yet, or one not in the plant: see suspect)",
                False,
            ),
            ("state", "UINT", f"control state: {_codes(STATE_CODES)}", False),
            ("battery", "UINT", "battery charge in %", False),
            ("speed", "UINT", "speed in cm/s", False),
            ("next", "UINT", "next node reported (65535: standing, or not in the plant)", False),
            ("target", "UINT", "node it is sent to (65535: none)", False),
            ("recipe", "UINT", "its recipe: position in the [[recipes]] list, from 1", False),
            ("step", "UINT", "step of the recipe, from 1 (0: none)", False),
            (
                "phase",
                "UINT",
                f"sequencer phase: {_codes(PHASE_CODES)} (255: a phase this table does not know)",
                False,
            ),
            ("waits", "UINT", "times it stopped for a node held by another", False),
            ("replans", "UINT", "routes recomputed because the next segment was taken", False),
            ("rounds", "UINT", "recipes it completed in this run", False),
            (
                "waiting_for",
                "UINT",
                "the vehicle it waits for (0: none, also while it waits for a time-window "
                "planning round; its state is then 2 planning)",
                False,
            ),
            (
                "reported",
                "UINT",
                f"state it reports: {_codes({s: i for i, s in enumerate(STATES)})}",
                False,
            ),
            ("online", "BOOL", "its status arrives", False),
            ("stale", "BOOL", "silent for longer than stale_after: nothing released", False),
            ("fault", "BOOL", "it reports a fault", False),
            ("go", "BOOL", "go bit of its route command", False),
            ("released", "UINT", "nodes in its route command (0..3)", False),
            ("held", "BOOL", "the operator hold is in effect", False),
            (
                "suspect",
                "BOOL",
                "an implausible report: stopped, holds kept (docs/security.md)",
                False,
            ),
            ("hold", "UINT", "operator: nonzero holds it (no new route), 0 releases", True),
            (
                "ack",
                "UINT",
                "operator: a new nonzero value acknowledges the vehicle: a suspect one stands "
                "where it reports; else, a load its order left on board was taken off",
                True,
            ),
            (
                "ack_result",
                "UINT",
                f"result of the last ack: {ACK_DONE} done, {ACK_REFUSED} refused (nothing to "
                "acknowledge, or its node is held by another: see the event log)",
                False,
            ),
        )
    )
)
V = {f.name: f.word for f in VEHICLE_FIELDS}
MIRRORED = V["hold"]  # FleetStatus writes words 0 .. MIRRORED - 1 of every vehicle

# how FleetStatus reads an input record (blocks/traffic/records.py, IN_RECORD) and packs words
_IN_RECORD = struct.Struct("<HHBBBB")  # current, next, state, battery %, speed cm/s, flags
_ROW = struct.Struct(f"<{MIRRORED}H")
_COUNTERS = struct.Struct(f"<{len(COUNTERS)}I")
_GAUGES = struct.Struct(f"<{len(GAUGES)}H")
_ORDERS = struct.Struct(f"<{len(ORDERS)}I")


def vehicle_word(vehicle: int, field: str = "node") -> int:
    """The %MW index of a vehicle's field."""
    return VEHICLE_BASE + STRIDE * (vehicle - 1) + V[field]


def marker_bytes(vehicles: Iterable[int]) -> int:
    """Bytes of the M area the map needs: at least the runtime's default of 8192."""
    words = VEHICLE_BASE + STRIDE * max(vehicles, default=0)
    return max(8192, -(-2 * words // 8) * 8)


def _address(word: int, type_: str) -> str:
    if type_ == "BOOL":
        return f"%MX{2 * word}.0"
    if type_ == "UDINT":
        return f"%MD{word // 2}"
    return f"%MW{word}"


def fleet_tags(vehicles: Iterable[int]) -> TagTable:
    """The tag table of a fleet with these vehicle ids."""
    table = TagTable()
    for f in FLEET_FIELDS:
        address = _address(f.word, f.type)
        table.add(f.name, address, f.type, retain=f.retain, writable=f.writable, comment=f.comment)
    for v in sorted(vehicles):
        for f in VEHICLE_FIELDS:
            address = _address(vehicle_word(v, f.name), f.type)
            table.add(f"agv{v}.{f.name}", address, f.type, writable=f.writable, comment=f.comment)
    return table


class _Words:
    """The map's words (bound in startup: the image's buffers never move): the fleet's as
    numpy views and as bytes, the vehicles' rows as numpy words and as bytes."""

    def __init__(self, ctx: CycleContext, vehicles: list[int]) -> None:
        raw = ctx.image.record_view("M", 0, 2 * vehicle_word(max(vehicles) + 1))
        self.fleet = memoryview(raw[: 2 * VEHICLE_BASE])
        self.fleet16 = raw[: 2 * VEHICLE_BASE].view("<u2")
        self.fleet32 = raw[: 2 * VEHICLE_BASE].view("<u4")
        self.rows = memoryview(raw[2 * VEHICLE_BASE :])
        self.vehicles = raw[2 * VEHICLE_BASE :].view("<u2").reshape(-1, STRIDE)  # row v - 1


class FleetCommands(FunctionBlock):
    """Start of the fleet task: the blockade command and the vehicles' holds.

    The blockade command is a handshake: a client writes ``a``, ``b`` and ``code`` together
    with a new ``seq`` (one request); the program runs it once and answers with ``ack`` =
    seq and a ``result``. A repeated write of the same seq does nothing, so a request a
    client retries is never applied twice."""

    done_seq = Static(0, doc="the seq of the last command run")

    def __init__(
        self,
        plant: Plant,
        blockades: RoutingConstraints,
        vehicles: list[int],
        acknowledge: Callable[[CycleContext, int], str | None] | None = None,
    ) -> None:
        super().__init__()
        self.plant = plant
        self.blockades = blockades
        self.vehicles = list(vehicles)
        # acknowledge(ctx, vehicle) -> why not, or None: an operator's ack of a suspect vehicle
        self.acknowledge = acknowledge
        self.acked: dict[int, int] = {}  # vehicle -> the ack value last run
        self.held: set[int] = set()  # vehicles an operator holds; FleetCycle reads the same set
        self._words: _Words | None = None
        self._holds = np.zeros(0, dtype="<u2")
        self._known = frozenset(self.vehicles)

    def startup(self, ctx: CycleContext) -> None:
        self._words = _Words(ctx, self.vehicles)
        self._holds = self._words.vehicles[:, V["hold"]]
        self._acks = self._words.vehicles[:, V["ack"]]
        self.held.clear()
        self.acked.clear()

    def cycle(self, ctx: CycleContext) -> None:
        if self.held or self._holds.any():  # changed in place: the set is FleetCycle's too
            self.held.clear()
            self.held.update(
                v for v in (np.flatnonzero(self._holds) + 1).tolist() if v in self._known
            )
        if self.acknowledge is not None and (self.acked or self._acks.any()):
            self._acknowledge(ctx)
        fleet = self._words.fleet16
        seq = int(fleet[F["fleet.cmd.seq"]])
        if seq and seq != self.done_seq:
            self.done_seq = seq
            code, a, b = (int(fleet[F[f"fleet.cmd.{k}"]]) for k in ("code", "a", "b"))
            # the result before the ack: a client that reads its seq in ack reads its result
            fleet[F["fleet.cmd.result"]] = self._run(code, a, b)
            fleet[F["fleet.cmd.ack"]] = seq

    def _acknowledge(self, ctx: CycleContext) -> None:
        """A new nonzero ``ack`` value runs once (a retried write of the same value does not
        acknowledge again, and a value left standing cannot acknowledge a later suspicion)."""
        for row in np.flatnonzero(self._acks).tolist():
            v, value = row + 1, int(self._acks[row])
            if v not in self._known or self.acked.get(v) == value:
                continue
            self.acked[v] = value
            why = self.acknowledge(ctx, v)
            self._words.vehicles[row, V["ack_result"]] = ACK_DONE if why is None else ACK_REFUSED

    def _run(self, code: int, a: int, b: int) -> int:
        if code not in (CLOSE, REOPEN):
            return UNKNOWN_COMMAND
        if a not in self.plant.index or b not in self.plant.index:
            return UNKNOWN_NODE
        if (a, b) not in self.plant.arc_index and (b, a) not in self.plant.arc_index:
            return NO_SEGMENT
        if code == CLOSE:
            self.blockades.block(a, b, both_ways=True)
        else:
            self.blockades.unblock(a, b, both_ways=True)
        return DONE


class FleetStatus(FunctionBlock):
    """End of the fleet task: every vehicle's status and the fleet's counters into the
    words of the map, and the lifetime totals counted on.

    Per vehicle it unpacks the input record, reads the blocks' outputs, and writes the row
    of words where it differs from the image (``struct``: a few microseconds a vehicle;
    numpy costs more per call than that, which a small fleet would pay in full). A total is
    counted on from its word (the value restored from the retain file, or one an operator
    set), adding what happened; the seconds of RUN and of processing are added as whole
    seconds, once a second of run time, the rest carried on."""

    seen_recipes = Static(0)
    seen_visits = Static(0)
    seen_busy_s = Static(0.0)
    busy_s = Static(0.0, doc="processing seconds not yet added to the whole-second total")
    run_ns = Static(0, doc="time in RUN not yet added to the whole-second total")
    counted_ns = Static(0, doc="time in RUN counted so far: up to the end of the last scan")

    def __init__(self, program: FleetProgram, commands: FleetCommands) -> None:
        super().__init__()
        self.program = program
        self.commands = commands
        self.recipe_numbers = {name: i + 1 for i, name in enumerate(program.cfg.recipes)}
        self._words: _Words | None = None
        self._slots: list[tuple] = []
        self._epoch = -1
        self._blocked = 0
        self._orders_revision = -1  # the order book's revision the order words show

    @property
    def blocked_segments(self) -> int:
        """Segments closed after the last scan (counted when the constraints changed)."""
        return self._blocked

    def startup(self, ctx: CycleContext) -> None:
        """Bind the buffers: per vehicle, where its input record, the control byte of its
        route command and its row of words are; then the first rows (no node 0 before a
        vehicle reported one)."""
        p = self.program
        self._words = _Words(ctx, p.vehicles)
        self._slots = []
        for k, area in enumerate(p.records.areas):
            size = RECORD * (area.max_vehicle + 1)
            inputs = memoryview(ctx.image.record_view("I", area.input_base, size))
            outputs = memoryview(ctx.image.record_view("Q", area.output_base, size))
            for v, (a, local) in sorted(p.records.vehicles.items()):
                if a == k:
                    c, s = p.controls[v], p.jobs[v]
                    row = 2 * (vehicle_word(v) - VEHICLE_BASE)
                    self._slots.append(
                        (c, s, inputs, RECORD * local, outputs, RECORD * local + 6, row)
                    )
        sums = self._mirror_vehicles()
        self.seen_recipes, self.seen_visits = p.completed.total, sums[-1]
        self.seen_busy_s = sum(p.chooser.busy_s.values())
        self._epoch = self._orders_revision = -1
        self._add_total("fleet.total.starts", 1)
        self._mirror_fleet(0, sums)

    def rows(self) -> np.ndarray:
        """Every vehicle's words as the last scan left them, row ``v - 1`` for vehicle
        ``v`` (a view of the image: copy it to keep it)."""
        return self._words.vehicles

    def cycle(self, ctx: CycleContext) -> None:
        sums = self._mirror_vehicles()
        self._mirror_fleet(ctx.cycle + 1, sums)
        self._count_totals(ctx, sums[-1])

    def _mirror_vehicles(self) -> tuple[int, ...]:
        """Every vehicle's row; the sums the fleet's words need: vehicles online, stale,
        faulted, held, their waits, replans and stations visited."""
        held, numbers, rows = self.commands.held, self.recipe_numbers, self._words.rows
        unpack, unpack_row, pack = _IN_RECORD.unpack_from, _ROW.unpack_from, _ROW.pack_into
        online = stale = faulted = n_held = waits = replans = visits = 0
        for c, s, inputs, i, outputs, o, row in self._slots:
            current, next_, reported, battery, speed, flags = unpack(inputs, i)
            known = flags & (ONLINE | STALE)
            command = outputs[o]
            is_held = c.vehicle in held
            values = (  # in the order of VEHICLE_FIELDS
                current if known and current in c.index else NO_NODE,
                STATE_CODES.get(c.state, UNKNOWN_STATE),
                battery,
                speed,
                next_ if known and next_ in c.index else NO_NODE,
                NO_NODE if s.target is None else s.target,
                numbers.get(s.recipe_name, 0),
                s.step + 1 if s.recipe_name else 0,
                PHASE_CODES.get(shown_phase(s), UNKNOWN_PHASE),
                min(c.waits, MAX_UINT),
                min(c.replans, MAX_UINT),
                min(s.rounds_done, MAX_UINT),
                c.waiting_for or 0,
                reported,
                flags & ONLINE,
                (flags & STALE) >> 1,
                (flags & FAULT) >> 2,
                command >> 7,
                command & COUNT_MASK,
                is_held,
                c.suspect,
            )
            if unpack_row(rows, row) != values:  # most scans change no word of a vehicle
                pack(rows, row, *values)
            online += flags & ONLINE
            stale += (flags & STALE) >> 1
            faulted += (flags & FAULT) >> 2
            n_held += is_held
            waits += c.waits
            replans += c.replans
            visits += s.stations_visited
        return online, stale, faulted, n_held, waits, replans, visits

    def _mirror_fleet(self, heartbeat: int, sums: tuple[int, ...]) -> None:
        online, stale, faulted, n_held, waits, replans, visits = sums
        p, fleet = self.program, self._words.fleet
        r = p.resolver
        counters = (p.completed.total, visits, replans, waits)
        counters += (r.detected, r.resolved, r.unresolved, r.pushes)
        first = 2 * COUNTERS[0].word
        if _COUNTERS.unpack_from(fleet, first) != counters:  # they change now and then
            _COUNTERS.pack_into(fleet, first, *[min(n, MAX_UDINT) for n in counters])
        if self._epoch != p.blockades.epoch:
            self._epoch = p.blockades.epoch
            closed = {(min(a, b), max(a, b)) for a, b in p.blockades.blocked_segments()}
            self._blocked = min(len(closed), MAX_UINT)
        _GAUGES.pack_into(
            fleet,
            2 * GAUGES[0].word,
            min(len(self._slots), MAX_UINT),
            min(online, MAX_UINT),
            min(stale, MAX_UINT),
            min(faulted, MAX_UINT),
            min(n_held, MAX_UINT),
            self._blocked,
            heartbeat % 0x10000,
        )
        book = p.orders.book if p.orders is not None else None
        if book is not None and book.revision != self._orders_revision:
            self._orders_revision = book.revision
            n = book.counts()
            counts = (
                n[OrderState.DISPATCHABLE] + n[OrderState.RAW],
                n[OrderState.BEING_PROCESSED],
                n[OrderState.FINISHED],
                n[OrderState.FAILED] + n[OrderState.UNROUTABLE],
                n[OrderState.WITHDRAWN],
            )
            _ORDERS.pack_into(fleet, 2 * ORDERS[0].word, *[min(k, MAX_UDINT) for k in counts])

    def _add_total(self, tag: str, n: int) -> None:
        if n:
            words, i = self._words.fleet32, F[tag] // 2
            words[i] = min(int(words[i]) + n, MAX_UDINT)

    def _count_totals(self, ctx: CycleContext, visits: int) -> None:
        recipes = self.program.completed.total
        if recipes != self.seen_recipes or visits != self.seen_visits:
            self._add_total("fleet.total.recipes", recipes - self.seen_recipes)
            self._add_total("fleet.total.station_visits", visits - self.seen_visits)
            self.seen_recipes, self.seen_visits = recipes, visits
        end = ctx.time_ns + ctx.interval_ns  # omitted scans' time included
        self.run_ns += end - self.counted_ns
        self.counted_ns = end
        if self.run_ns >= 1_000_000_000:  # once a second: the sum over every station
            whole = self.run_ns // 1_000_000_000
            self._add_total("fleet.total.run_s", whole)
            self.run_ns -= whole * 1_000_000_000
            busy_s = sum(self.program.chooser.busy_s.values())
            self.busy_s += busy_s - self.seen_busy_s
            self.seen_busy_s = busy_s
            whole = int(self.busy_s)
            self._add_total("fleet.total.busy_s", whole)
            self.busy_s -= whole
