"""OrderRunner: one vehicle works off its transport orders, section by section (seed 000).

An order runs through the seed's sections, each time-stamped in the order:

* ``Go_To_Cluster``: from taking the order until the vehicle enters the cluster zone of the
  Get station (the nodes of the station's units, plant key ``zone``); until then the
  dispatcher may still give the order to another vehicle (the two-stage allocation);
* ``Go_To_Get``: inside the zone, until it reaches the station or starts waiting for it;
* ``Get_Queue``: waiting for the station (at a queue position, off the lanes), or for the
  order's start time (the load is not ready before it), until it stands at the station;
* ``Get``: the dwell at the station (loading);
* ``Go_To_Put``, ``Put_Queue``, ``Put``: the same for the Put station (unloading).

A transfer station takes one vehicle at a time, first come first served: a vehicle drives
onto it only while it holds the station's claim (:class:`Claims`). It asks for the claim
only once it is near the station (``near_m`` metres of route from it, not of straight
line: on one-way lanes a station beside the vehicle can be a lap away), so the order of
service is the order of arrival: a vehicle still far away never keeps one already there
waiting. Until it holds the claim it heads for the entry of the station's single-vehicle
area (the node just outside it, :func:`area_entries`), never into the area: what is
released to a vehicle cannot be taken back, and one that drove into a dead-end spur
without the claim would stand face to face with the holder. Refused, it waits at a free
queue position of the station, else at the free parking position nearest to it, and only
when there is none, where it stands, but not on hold: the deadlock resolver may push it
out of the holder's way. Pushed onto the very station it waits for, it takes the claim
over (:meth:`Claims.take_over`) and is served there: the holder cannot get past it. A station's claim covers its single-vehicle area (plant key
``area``) and ends only when the vehicle has left that area, so a vehicle leaving a
station spur never meets the next one in it. Routing and traffic (VehicleControl and the
reservations) decide how it drives; this block only sets the target and the hold. Without
an order a vehicle charges when its ChargePolicy says it must, tops up when it is below
``top_up_below`` and a charger is to spare (still available for orders, and giving the
charger up as soon as a vehicle that must charge finds every charger taken), and otherwise
parks at a free parking position, out of the others' way.

A load stays on board when its order ends without its Put (withdrawn, or failed: a
blockade cut the Put station off, the vehicle was out of service too long). The vehicle
then takes no order, next or new, until an operator confirms the load was taken off
(:meth:`unloaded`, the vehicle's acknowledge): given one, it would drive to a Get station
with a load already on its deck. Meanwhile it parks, and charges when it must.
"""

from __future__ import annotations

from collections.abc import Callable

from plc_runtime import CycleContext, FunctionBlock, Input, Output, Static
from topology import Plant

from .charging import ChargePolicy
from .energy import EnergyMeter
from .orders import OrderBook, OrderState, TransportOrder

PHASES = (
    "idle",
    "to_get",
    "get_queue",
    "get",
    "to_put",
    "put_queue",
    "put",
    "to_charger",
    "charging",
    "to_parking",
    "parked",
)


def area_entries(plant: Plant) -> dict[int, int]:
    """Station -> the entry of its single-vehicle area: the node outside the area from which
    one drives in (for a station on a spur, the lane junction). Stations whose area has no
    single entry, and stations without an area, have none."""
    out: dict[int, int] = {}
    for nodes in plant.areas.values():
        area = set(nodes)
        outside = {
            int(plant.ids[j])
            for n in area
            for j, _arc, _w in plant.neighbors[plant.idx(n)]
            if int(plant.ids[j]) not in area
        }
        if len(outside) != 1:
            continue
        (entry,) = outside
        for n in area:
            if plant.node(n).role == "station":
                out[n] = entry
    return out


class Claims:
    """Who may stand at a place that takes one vehicle: stations, queue positions,
    chargers, parking positions. A station's waiting vehicles are served in the order they
    asked, so a vehicle in its queue is never overtaken by one arriving later.

    ``occupied(place, vehicle)`` names the vehicle other than ``vehicle`` that stands on
    the place (or in its single-vehicle area) right now, as the reservations know it (None:
    nobody): a place is given only when it is physically empty too. A vehicle can be on a
    place it holds no claim of (it was pushed aside onto it, or it is a recipe vehicle), and
    one sent to a dead-end spur with someone in it would stand face to face with it."""

    def __init__(self, occupied: Callable[[int, int], int | None] | None = None) -> None:
        self.holder: dict[int, int] = {}
        self.waiting: dict[int, list[int]] = {}
        self.occupied = occupied or (lambda _place, _vehicle: None)
        # vehicles out of service long enough to have given their orders up
        self.out_of_service: set[int] = set()
        # charger -> the vehicle on it that would give it up: charging there by choice
        # (topping up while idle), or leaving it. A vehicle that must charge and finds every
        # charger taken queues for one of these.
        self.offered: dict[int, int] = {}

    def stuck(self, place: int) -> bool:
        """Whether ``place`` is claimed, or stood on, by a vehicle that has been out of
        service long enough to give its orders up: nobody can be served there until it
        comes back or is taken away."""
        if not self.out_of_service:
            return False
        oos = self.out_of_service
        return self.holder.get(place) in oos or self.occupied(place, 0) in oos

    def claim(self, place: int, vehicle: int) -> bool:
        """Take ``place`` if it is free and nobody asked before; else join its queue."""
        holder = self.holder.get(place)
        if holder == vehicle:
            return True
        queue = self.waiting.setdefault(place, [])
        if (
            holder is None
            and (not queue or queue[0] == vehicle)
            and not self.occupied(place, vehicle)
        ):
            if queue:
                queue.pop(0)
            self.holder[place] = vehicle
            return True
        if vehicle not in queue:
            queue.append(vehicle)
        return False

    def take_over(self, place: int, vehicle: int) -> None:
        """``vehicle`` stands on ``place`` without its claim (pushed onto it while it
        waited): it takes the claim, and the holder, who cannot get onto the place past it,
        is first in line again. Otherwise each would wait for the other for ever: the
        holder for the node, the vehicle on it for the claim."""
        holder = self.holder.get(place)
        if holder == vehicle:
            return
        queue = self.waiting.setdefault(place, [])
        if vehicle in queue:
            queue.remove(vehicle)
        if holder is not None:
            queue.insert(0, holder)
        self.holder[place] = vehicle

    def open_to(self, place: int, vehicle: int) -> bool:
        """Whether ``vehicle`` would get ``place`` if it claimed it now: nobody holds it,
        nobody asked for it before ``vehicle``, and no other vehicle is on it."""
        queue = self.waiting.get(place)
        return (
            place not in self.holder
            and (not queue or queue[0] == vehicle)
            and not self.occupied(place, vehicle)
        )

    def free(self, place: int, vehicle: int) -> bool:
        """Nobody holds or waits for ``place``, and no vehicle but ``vehicle`` is on it."""
        return (
            place not in self.holder
            and not self.waiting.get(place)
            and not self.occupied(place, vehicle)
        )

    def release(self, place: int, vehicle: int) -> None:
        if self.holder.get(place) == vehicle:
            del self.holder[place]

    def leave(self, place: int, vehicle: int) -> None:
        """``vehicle`` has left ``place`` for good: it neither holds it nor waits for it (a
        holder the place was taken over from waits first in line, and one that was only
        driving out would otherwise keep everybody behind it waiting)."""
        self.release(place, vehicle)
        queue = self.waiting.get(place)
        if queue and vehicle in queue:
            queue.remove(vehicle)

    def forget(self, vehicle: int, keep: frozenset[int] = frozenset()) -> None:
        """``vehicle`` holds and waits for nothing any more (but the places in ``keep``)."""
        for place in [p for p, v in self.holder.items() if v == vehicle and p not in keep]:
            del self.holder[place]
        for place, queue in self.waiting.items():
            if vehicle in queue and place not in keep:
                queue.remove(vehicle)


class OrderRunner(FunctionBlock):
    arrived = Input(False, doc="the vehicle control reports: at the target, nothing left to drive")
    current = Input(None, doc="the node the vehicle last reported")
    frontier = Input(
        None, doc="the last node released to the vehicle, where it will stand (None: current)"
    )
    battery = Input(
        None, doc="state of charge in %, from the vehicle's info frames; None: none yet"
    )
    in_service = Input(True, doc="FALSE while the vehicle is offline, stale, faulty or suspect")

    target = Output(None, doc="the node the vehicle should drive to")
    fixed_route = Output(None, doc="never set: orders are planned, not driven on fixed lanes")
    hold = Output(False, doc="TRUE while loading, unloading or charging")
    phase = Output("idle", doc="|".join(PHASES))
    section = Output("", doc="the running section of the active order")
    priority_ns = Output(0, doc="when the current task was released: older goes first")
    orders_done = Output(0)
    stations_visited = Output(0)
    charges = Output(0, doc="visits to a charger")
    top_ups = Output(0, doc="of its visits to a charger, those it began by choice (topping up)")
    chargers_given_up = Output(
        0, doc="chargers it gave up (on one or on its way), topping up, for one that must charge"
    )
    charging_s = Output(0.0, doc="time spent on a charger, finished visits")
    min_battery = Output(100, doc="the lowest state of charge seen, %")
    load = Output(
        "",
        doc="the order whose load is on board ('' when none): from the start of its Get to "
        "the end of its Put, or, when the order ended without its Put, until an operator "
        "confirms the load was taken off",
    )

    active = Static(None)  # the order being driven (TransportOrder)
    next = Static(None)  # the order after it, changeable until taken up
    frozen = Static(False)  # the active order can no longer go to another vehicle
    dwell_until_ns = Static(0)
    place = Static(None)  # the charger or parking node it heads for or stands at
    leaving = Static(None)  # the station it was served at, claimed until it has left it
    vacating = Static(None)  # the queue, parking or charger place it stands on, given up
    charging_since = Static(None)  # when the current charger visit began (s)
    topping_up = Static(False)  # charging by choice while idle, not by need: still available
    battery_at_start = Static(None)
    out_since_ns = Static(None)  # out of service since then (None: in service)

    def __init__(
        self,
        vehicle: int,
        plant: Plant,
        book: OrderBook,
        claims: Claims,
        charging: ChargePolicy,
        distance: Callable[[int, int], float],
        get_s: float = 10.0,
        put_s: float = 10.0,
        park: bool = True,
        near_m: float = 20.0,
        on_section: Callable[[TransportOrder, str, float, float], None] | None = None,
        out_of_service_s: float = 60.0,
        reaches: Callable[[int, int], bool] | None = None,
    ) -> None:
        super().__init__()
        self.vehicle = vehicle
        self.plant = plant
        self.book = book
        self.claims = claims
        # the vehicle's energy over the run, from the same readings: what charging costs
        self.meter = EnergyMeter()
        self.charging = charging
        self.distance = distance
        self.dwell_s = {"Get": get_s, "Put": put_s}
        self.park = park
        self.near_m = near_m
        self.on_section = on_section  # a finished section: (order, name, start_s, end_s)
        # can a vehicle at one node (id) drive to another over the segments open now? The
        # distances above ignore blockades: a place it cannot reach is never chosen, and
        # one cut off after it was chosen is given up for another
        self.reaches = reaches or (lambda _a, _b: True)
        # out of service this long, the vehicle gives its orders up (it may never come back)
        self.out_of_service_ns = round(out_of_service_s * 1e9)
        self.queues = plant.queues
        self.zones = {
            s: frozenset().union(*(plant.zones.get(f, ()) for f in plant.node(s).functions)) | {s}
            for s in plant.with_role("station")
        }
        # a station's single-vehicle area (plant key ``area``): its claim covers all of it
        self.area_of = {node: frozenset(nodes) for nodes in plant.areas.values() for node in nodes}
        self.entries = area_entries(plant)
        self.chargers = plant.with_role("charger")
        self.parking = plant.with_role("parking")

    # what reports show of a recipe vehicle, for a vehicle that takes orders
    recipe_name = ""
    step = 0

    @property
    def rounds_done(self) -> int:
        return self.orders_done

    # ----- what the dispatcher sees and does ---------------------------------------------------
    @property
    def busy(self) -> bool:
        return self.active is not None

    @property
    def load_left(self) -> bool:
        """A load is on board whose order ended without its Put: no order for this vehicle
        until an operator confirms it was taken off."""
        return bool(self.load) and (self.active is None or self.active.id != self.load)

    def unloaded(self) -> str | None:
        """An operator confirms the load left on board was taken off: the vehicle takes
        orders again. Returns why not (None: done)."""
        if not self.load_left:
            return "no load left on board"
        self.load = ""
        return None

    def take(self, ctx: CycleContext, order: TransportOrder) -> None:
        """The dispatcher gives ``order`` to this vehicle: active if it has none, else next."""
        order.assigned = self.vehicle
        if order.state is not OrderState.BEING_PROCESSED:
            self.book.transition(order, OrderState.BEING_PROCESSED, ctx.time)
        if self.active is None:
            self._activate(ctx, order)
        else:
            self.next = order

    def give_back(self, ctx: CycleContext, why: str = "reassigned") -> list[TransportOrder]:
        """The orders the dispatcher may still move to another vehicle: the next order, and
        the active one while the vehicle has not entered its Get zone. They are dispatchable
        again; the vehicle keeps driving until it gets one."""
        back = []
        if self.next is not None:
            order, self.next = self.next, None
            order.assigned = None
            self.book.transition(order, OrderState.DISPATCHABLE, ctx.time, why)
            back.append(order)
        if self.active is not None and not self.frozen:
            back.append(self.active)
            self._drop_active(ctx, why)
        return back

    def _drop_active(self, ctx: CycleContext, why: str) -> None:
        """The active order, not picked up yet, goes back to the pool."""
        order = self.active
        self.active, self.frozen = None, False
        self._let_go()
        self.phase, self.section = "idle", ""
        order.assigned = None
        self.book.transition(order, OrderState.DISPATCHABLE, ctx.time, why)

    def withdrawn(self, ctx: CycleContext) -> None:
        """Drop orders that were withdrawn or failed meanwhile (the book's state says so);
        the section that was running ends now (it is not learned from: it was cut short)."""
        if self.next is not None and self.next.state.final:
            self.next = None
        if self.active is not None and self.active.state.final:
            if self.section and len(self.active.sections.get(self.section, ())) == 1:
                self.book.end_section(self.active, self.section, ctx.time)
            self.active, self.hold, self.section = None, False, ""
            self._let_go()
            self.phase = "idle"

    def _given_up(self, ctx: CycleContext) -> bool:
        """The vehicle is silent, stalled or suspect. A short outage (a spoofed frame, a
        link dropping out for a second) changes nothing; once it has lasted
        ``out_of_service_s`` the vehicle gives its orders up, since it may never come back:
        those not picked up go back to the pool, one with its load on board fails. It keeps
        the claims of where it stands (``_let_go``), frees the others, and until it is back
        in service nothing new is started for it, and its places count as stuck."""
        if self.out_since_ns is None:
            self.out_since_ns = ctx.time_ns
        if ctx.time_ns - self.out_since_ns < self.out_of_service_ns:
            return False
        if self.vehicle not in self.claims.out_of_service:
            self.claims.out_of_service.add(self.vehicle)
            self._give_up(ctx)
        return True

    def _give_up(self, ctx: CycleContext) -> None:
        why = f"vehicle {self.vehicle} out of service"
        if self.active is not None and self.phase in ("get", "to_put", "put_queue", "put"):
            self.book.transition(
                self.active, OrderState.FAILED, ctx.time, f"{why} with the load on board"
            )
            self.withdrawn(ctx)
        self.frozen = False
        self.give_back(ctx, why)
        self._let_go()
        self.hold, self.phase, self.target = False, "idle", self.current

    def _left_area(self) -> None:
        """Once the vehicle has left the station it was leaving and its single-vehicle
        area, the station's claim goes: the next vehicle may come."""
        if self.leaving is not None and self.current not in self._area(self.leaving):
            self.claims.leave(self.leaving, self.vehicle)
            self.leaving = None

    def _let_go(self) -> None:
        """Give up the claims of an order that ended early, but those of where the vehicle
        stands: the place it stands on, and a station whose area it is in, which it keeps
        until it has left the area, as after a visit (a vehicle sent into a station's spur
        past it would meet it face to face)."""
        self._left_area()  # (before another station may become the one it is leaving)
        for station, holder in self.claims.holder.items():
            if (
                holder == self.vehicle
                and station in self.zones
                and self.current in self._area(station)
            ):
                self.leaving = station
                break
        self._forget()
        self.place = None  # (a queue or parking place it stands on is given up as it leaves)

    # ----- the scan --------------------------------------------------------------------------
    def cycle(self, ctx: CycleContext) -> None:
        self._scan(ctx)
        self._offer_charger()

    def _offer_charger(self) -> None:
        """Tell the claims whether the vehicle would give its charger up: it is on it (or
        bound for it) by choice and could drive off to a parking place, or it is leaving
        it. A vehicle that must charge may then queue for that charger."""
        offered = self.claims.offered
        if (
            self.topping_up
            and self.place in self.chargers
            and self._holds(self.place)
            and self._can_leave()
        ):
            mine = self.place
        elif (
            self.vacating in self.chargers
            and self.vacating != self.place  # (not back on it to charge by need)
            and self._holds(self.vacating)
        ):
            mine = self.vacating
        else:
            mine = None
        for c in [c for c, v in offered.items() if v == self.vehicle and c != mine]:
            del offered[c]
        if mine is not None:
            offered[mine] = self.vehicle

    def _scan(self, ctx: CycleContext) -> None:
        if self.current is None:
            return
        if self.in_service:
            self.out_since_ns = None
            self.claims.out_of_service.discard(self.vehicle)
        else:
            self.withdrawn(ctx)  # first: giving orders up must not touch a final one
            if self._given_up(ctx):
                return  # nothing new for a vehicle that may never come back
        if self.battery is not None:  # (no reading yet is not an empty battery)
            self.min_battery = min(self.min_battery, self.battery)
        self._left_area()
        if self.vacating is not None and self.current != self.vacating:
            if self.target != self.vacating:  # (unless it took the same place again)
                self.claims.release(self.vacating, self.vehicle)
            self.vacating = None
        if self.charging_since is not None and self.phase != "charging":
            self.charging_s += ctx.time - self.charging_since
            self.charging_since = None
        self.withdrawn(ctx)
        order = self.active
        if (
            order is not None
            and self.phase in ("to_get", "get_queue")
            and (self.claims.stuck(order.get) or self.claims.stuck(order.put))
        ):  # not picked up yet: it waits in the pool, not in a queue for ever
            self._drop_active(ctx, "a station is held by a vehicle out of service")
        if self.active is None and self.next is not None:
            order, self.next = self.next, None
            if self.load_left:
                # its last order ended with the load on board: not one more on top of it
                order.assigned = None
                self.book.transition(order, OrderState.DISPATCHABLE, ctx.time, "load on board")
            elif self.battery is not None and not self.charging.may_take(self.battery):
                # the charge fell faster than the dispatcher expected when it gave the order:
                # the vehicle goes charging, and the order to whoever can drive it
                order.assigned = None
                self.book.transition(order, OrderState.DISPATCHABLE, ctx.time, "battery low")
            else:
                self._activate(ctx, order)
        if self.active is not None:
            self._drive_order(ctx)
        else:
            self._without_order(ctx)

    # ----- an order ----------------------------------------------------------------------------
    def _activate(self, ctx: CycleContext, order: TransportOrder) -> None:
        self.active, self.frozen = order, False
        self.topping_up = False
        self.battery_at_start = self.battery
        self._forget()  # leaves a charger or parking place
        self.place, self.hold = None, False
        self.priority_ns = ctx.time_ns
        self.phase, self.target = "to_get", order.get
        self._start(ctx, "Go_To_Cluster")
        self._drive_order(ctx)

    def _drive_order(self, ctx: CycleContext) -> None:
        order = self.active
        if self.phase in ("to_get", "get_queue"):
            self._approach(ctx, order.get, "Get", self.zones.get(order.get, {order.get}))
        elif self.phase in ("to_put", "put_queue"):
            self._approach(ctx, order.put, "Put", frozenset({order.put}))
        elif self.phase in ("get", "put") and ctx.time_ns >= self.dwell_until_ns:
            self._dwelt(ctx)

    def _approach(self, ctx: CycleContext, station: int, kind: str, zone) -> None:
        going = f"Go_To_{kind}"
        if kind == "Get" and self.section == "Go_To_Cluster" and self.current in zone:
            self.frozen = True  # in the Get zone: the order is this vehicle's for good
            self._next_section(ctx, going)
        if not self._near(station):
            # far off: it drives on, claiming nothing, up to the area's entry at most
            self.target, self.hold = self.entries.get(station, station), False
            return
        early = kind == "Get" and ctx.time < self.active.start_s  # (the load is not ready)
        if not early and self.arrived and self.current == station:
            self.claims.take_over(station, self.vehicle)  # pushed onto it: served there
        if not early and self.claims.claim(station, self.vehicle):
            self._forget(station)  # its queue place is free again
            self.target, self.hold = station, False
            if self.arrived and self.current == station:
                self._arrive(ctx, station, kind)
            return
        # the station is someone else's: wait at a queue position, or where it is
        queue = self._queue_place(station)
        aside = (
            self._aside()
            if queue is None
            and self.leaving is not None
            and self.current in self._area(self.leaving)
            else None
        )
        if aside is not None:
            # it waits, but not on the station it was served at: the next one may need it
            self.target, self.hold = aside, False
        elif queue is None:
            # no queue position free: it stops where its released route ends, and waits
            self.target, self.hold = self.current, False
        else:
            self.target = queue
        waiting = f"{kind}_Queue"
        if self.section != waiting and (queue is None or (self.arrived and self.current == queue)):
            if kind == "Get" and self.section == "Go_To_Cluster":
                self.frozen = True
                self._next_section(ctx, going)
            self._next_section(ctx, waiting)
            self.phase = "get_queue" if kind == "Get" else "put_queue"

    def _near(self, station: int) -> bool:
        """Whether the vehicle is close enough to ``station`` to queue for it: within
        ``near_m`` of route, or already holding or waiting for it."""
        if self.vehicle == self.claims.holder.get(station):
            return True
        if self.vehicle in self.claims.waiting.get(station, ()):
            return True
        return self.distance(self.current, station) <= self.near_m

    def _queue_place(self, station: int) -> int | None:
        """Where to wait for ``station``, off the lanes: the queue position it holds, or a
        free one of the station it now claims; when they are all taken, the free parking
        position nearest to the station (a vehicle stopped on a lane would block every
        vehicle behind it). None if there is none."""
        places = self.queues.get(station, ())
        for q in [*places, *self.parking]:
            if self._holds(q) and not self._reachable(q) and q != self.current:
                self.claims.leave(q, self.vehicle)  # cut off on its way there: another
                if self.place == q:
                    self.place = None
        for q in places:
            if self._holds(q):
                return q
        for q in places:
            if (
                q not in self.claims.holder
                and self._reachable(q)
                and self.claims.claim(q, self.vehicle)
            ):
                return q
        if self.place in self.parking and self._holds(self.place):
            return self.place
        free = [
            p
            for p in self.parking
            if self.claims.free(p, self.vehicle) and self._reachable(p) and self.reaches(p, station)
        ]
        if not free:
            return None
        self.place = min(free, key=lambda p: self.distance(p, station))
        self.claims.claim(self.place, self.vehicle)
        return self.place

    def _arrive(self, ctx: CycleContext, station: int, kind: str) -> None:
        if kind == "Get":
            self.frozen = True
            self.load = self.active.id  # (loading has begun: on board, as far as anyone knows)
        self._next_section(ctx, kind)
        self.stations_visited += 1
        self.phase, self.hold = kind.lower(), True
        self.dwell_until_ns = ctx.time_ns + round(self.dwell_s[kind] * 1e9)

    def _dwelt(self, ctx: CycleContext) -> None:
        order = self.active
        self.hold = False
        if self.phase == "get":
            self.leaving = order.get  # its claim ends when the vehicle has left the station
            self.phase, self.target = "to_put", order.put
            self._next_section(ctx, "Go_To_Put")
            return
        self.leaving = order.put
        self.load = ""
        self._end(ctx)
        self.book.transition(order, OrderState.FINISHED, ctx.time)
        if self.battery_at_start is not None and self.battery is not None:
            self.charging.order_used(self.battery_at_start - self.battery)
        self.orders_done += 1
        self.active, self.frozen, self.section = None, False, ""
        self.phase = "idle"

    def _forget(self, keep: int | None = None) -> None:
        """Give up every claim and queue place but ``keep``, the station it still stands
        at, and the place it stands on: a place is the vehicle's until it has physically
        left it (a queue or parking spur given to the next vehicle while this one still
        stands in it would put the two face to face)."""
        kept = {k for k in (keep, self.leaving) if k is not None}
        if self.current not in kept and self.claims.holder.get(self.current) == self.vehicle:
            self.vacating = self.current
            kept.add(self.current)
        self.claims.forget(self.vehicle, frozenset(kept))

    def _start(self, ctx: CycleContext, name: str) -> None:
        self.book.start_section(self.active, name, ctx.time)
        self.section = name

    def _end(self, ctx: CycleContext) -> None:
        if self.section:
            order = self.active
            self.book.end_section(order, self.section, ctx.time)
            if self.on_section is not None:
                start = order.sections[self.section][0]
                self.on_section(order, self.section, start, ctx.time)

    def _next_section(self, ctx: CycleContext, name: str) -> None:
        if self.section == name:
            return
        self._end(ctx)
        self._start(ctx, name)

    # ----- without an order ----------------------------------------------------------------------
    def _without_order(self, ctx: CycleContext) -> None:
        battery = self.battery
        if battery is None:  # nothing known of its charge yet: it parks until it is
            if self.phase == "idle":
                self.target = self.current
            if self.park and self.parking:
                self._go_parking(ctx)
            return
        if self.phase in ("to_charger", "charging"):
            if self.charging.charged(battery):
                self._forget()
                self.place, self.hold, self.phase = None, False, "idle"
                self.topping_up = False
            else:
                if self.topping_up and self.charging.must_charge(battery):
                    self.topping_up = False  # (its orders turned out to need more)
                asked = self.place in self.chargers and self.claims.waiting.get(self.place)
                if not (self.topping_up and asked and self._can_leave()):
                    self._charge(ctx)
                    return
                # one that must charge waits for this charger: charging by choice, it gives
                # the charger up (it stays available for orders, and parks)
                self._forget()
                self.place, self.hold, self.phase = None, False, "idle"
                self.topping_up = False
                self.chargers_given_up += 1
        if self.charging.must_charge(battery) and self.chargers:
            self.topping_up = False
            self._charge(ctx)
            return
        if self.charging.tops_up(battery) and self._spare_charger():
            self.topping_up = True
            self._charge(ctx)
            return
        if self.phase == "idle":
            self.target = self.current
        if self.park and self.parking:
            self._go_parking(ctx)
        if self.phase == "idle" and self.leaving is not None:
            aside = self._aside()  # nothing to do, nowhere to park, but on a station
            if aside is not None:
                self.target = aside

    def _reachable(self, place: int) -> bool:
        """Whether the vehicle can drive to ``place`` over the segments open now, from
        where the nodes released to it take it."""
        start = self.frontier if self.frontier is not None else self.current
        return start is None or self.reaches(start, place)

    def _holds(self, place: int) -> bool:
        """Whether the vehicle holds the claim of ``place``: the place it last chose may
        have been given up since (it waited there for a station, then drove on)."""
        return self.claims.holder.get(place) == self.vehicle

    def _area(self, station: int) -> frozenset[int]:
        return self.area_of.get(station, frozenset((station,)))

    def _aside(self) -> int | None:
        """The nearest node (in hops) outside the station's area, off the stations, to
        wait at: the station it was served at is then free for the next vehicle (two
        vehicles each waiting on the other's station would otherwise wait for ever)."""
        plant = self.plant
        area = self._area(self.leaving)
        seen, frontier = {self.current}, [self.current]
        for _hop in range(4):
            reached = []
            for node in frontier:
                for neighbour, _arc, _length in plant.neighbors[plant.idx(node)]:
                    n = int(plant.ids[neighbour])
                    if n in seen:
                        continue
                    seen.add(n)
                    reached.append(n)
                    role = plant.node(n).role
                    if (
                        n not in area
                        and role in ("transit", "parking")
                        and n not in self.claims.holder
                    ):
                        return n
            frontier = reached
        return None

    def _free_places(self, places: list[int]) -> list[int]:
        """Those of ``places`` nobody holds, waits for or stands on, that the vehicle can
        reach."""
        return [p for p in places if self.claims.free(p, self.vehicle) and self._reachable(p)]

    def _can_leave(self) -> bool:
        """Whether the vehicle, giving its charger up, would drive off it: to a parking
        place it holds, or a free one it can reach."""
        return self.park and (
            any(self._holds(p) for p in self.parking) or bool(self._free_places(self.parking))
        )

    def _spare_charger(self) -> bool:
        """Whether a charger is free for charging by choice: two free that it can reach,
        so that one stays free for a vehicle that must charge."""
        return len(self._free_places(self.chargers)) >= 2

    def _charge(self, ctx: CycleContext) -> None:
        if (
            self.place in self.chargers
            and self._holds(self.place)
            and not self._reachable(self.place)
        ):
            self._forget()  # cut off by a blockade on its way there: another one
            self.place = None
        if self.place not in self.chargers or not self._holds(self.place):
            # (one it holds already counts: it may stand on it, back from an outage)
            # (one it queued for counts once the vehicle charging there by choice has left)
            free = [
                c
                for c in self.chargers
                if (self._holds(c) or self.claims.open_to(c, self.vehicle))
                and self._reachable(c)
                and not (self.topping_up and self.claims.waiting.get(c))
            ]
            if not free:
                if not self.topping_up:
                    self._ask_for_charger()
                self._await_charger()
                return
            self.place = min(free, key=lambda c: self.distance(self.current, c))
            self._forget(self.place)  # (keeps its place in that charger's queue)
            self.claims.claim(self.place, self.vehicle)
            self.phase, self.target, self.hold = "to_charger", self.place, False
        if self.phase == "to_charger" and self.arrived and self.current == self.place:
            self.phase, self.hold = "charging", True
            self.charges += 1
            self.top_ups += self.topping_up
            self.charging_since = ctx.time

    def _ask_for_charger(self) -> None:
        """Every charger is taken, and this vehicle must charge: it queues for a charger
        whose vehicle would give it up (the nearest no one else waits for), and a vehicle
        there by choice gives it up. Topping up must never keep a vehicle that needs the
        charge from it."""
        claims = self.claims
        for c in self.chargers:
            if self.vehicle not in claims.waiting.get(c, ()):
                continue
            holder = claims.holder.get(c)
            if (
                (holder is None or claims.offered.get(c) == holder)
                and not claims.stuck(c)
                and self._reachable(c)
            ):
                return  # it asked already, and the charger is being given up for it
            # its vehicle has come to need the charge itself or is out of service, or a
            # blockade has cut it off
            claims.leave(c, self.vehicle)
        offered = [
            c
            for c, v in claims.offered.items()
            if claims.holder.get(c) == v
            and not claims.waiting.get(c)
            and not claims.stuck(c)
            and self._reachable(c)
        ]
        if offered:
            claims.claim(min(offered, key=lambda c: self.distance(self.current, c)), self.vehicle)

    def _await_charger(self) -> None:
        """Every charger is taken: the vehicle waits for one, holding none, on a parking
        place off the lanes if one is free, else where it is, but not on the station it
        was served at (the next vehicle for that station would wait the hour a charger
        takes to come free)."""
        self.phase = "to_charger"
        if self.place in self.parking and self._holds(self.place) and self._reachable(self.place):
            self.target = self.place
            return
        if self.place is not None and self._holds(self.place):
            self._forget()  # a parking place cut off by a blockade on its way there
        self.place, self.target = None, self.current
        spots = self._free_places(self.parking)
        if spots:
            self.place = min(spots, key=lambda p: self.distance(self.current, p))
            self.claims.claim(self.place, self.vehicle)
            self.target = self.place
        elif self.leaving is not None and self.current in self._area(self.leaving):
            aside = self._aside()
            if aside is not None:
                self.target = aside

    def _go_parking(self, ctx: CycleContext) -> None:
        if (
            self.place in self.parking
            and self._holds(self.place)
            and not self._reachable(self.place)
        ):
            self._forget()  # cut off by a blockade on its way there: another one, or none
            self.place, self.phase, self.target = None, "idle", self.current
        if self.place not in self.parking or not self._holds(self.place):
            if self.current in self.parking and self.claims.claim(self.current, self.vehicle):
                self.place = self.current
            else:
                free = self._free_places(self.parking)
                if not free:
                    return  # every parking position is taken or cut off: it stays idle
                self.place = min(free, key=lambda p: self.distance(self.current, p))
                self.claims.claim(self.place, self.vehicle)
        self.target = self.place
        self.phase = "parked" if self.current == self.place else "to_parking"
