"""The fleet control program: the thesis' system end to end (``plc-runtime run CONFIG``).

One runtime, one task ``fleet`` at the configured cycle time:

    driver copy-in (every vehicle's status into its input record, from CAN or Modbus TCP)
      -> blockade schedule (level 3: segments closing and reopening)
      -> FleetCommands (an operator's blockade command and vehicle holds, fleet/tags.py)
      -> per vehicle: RecipeSequencer -> VehicleControl (verify, replan, release)
      -> TimeWindowTraffic (traffic = "time_windows": planning rounds, the pass order)
      -> ReservationMatrix -> DeadlockResolver -> FleetRecorder -> EventLog
      -> FleetStatus (the tags' words: every vehicle's status, counters, lifetime totals)
    -> driver copy-out (released routes as route commands)

With ``cosimulate`` the vehicles are simulated in the same process, in a task ``plant``
after the program in every tick, on the same virtual CAN bus (the runtime still talks to
them only through frames); an independent ConflictMonitor watches their true positions.
Without it, the vehicles are elsewhere: simulated in their own process on a shared bus,
or real vehicles; the program talks to them the same way.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable, Iterable

import can

from blocks.dispatch.executor import OrderRunner
from blocks.jobs.goals import GoalQueue
from blocks.jobs.recipe import RUNS_KEPT, RecipeRun, RecipeSequencer, StationChooser
from blocks.routing.constraints import RoutingConstraints
from blocks.routing.heuristic import HeuristicTable
from blocks.traffic.deadlock import DeadlockResolver
from blocks.traffic.records import (
    BATTERY_UNKNOWN,
    RECORD,
    STATES,
    RecordArea,
    VehicleRecordsView,
)
from blocks.traffic.reservation import OUT_OF_SERVICE, ReservationMatrix
from blocks.traffic.sipp import TurnTimes
from blocks.traffic.tw_traffic import TimeWindowTraffic
from blocks.traffic.vehicle_control import VehicleControl
from io_drivers.can_bus import bus_channels, bus_of, bus_options, by_bus
from io_drivers.can_driver import CanDriver, frames_per_tick
from io_drivers.modbus_vehicles import ModbusVehicleLink
from plc_runtime import CycleContext, FunctionBlock, Output, Runtime
from plc_runtime.clock import VirtualClock, WallClock
from plc_runtime.recent import RecentList
from topology.model import Plant
from topology.usage import SegmentUsage
from vehicles.agv import AGV
from vehicles.cosim import CoSimulation
from vehicles.fleet import Fleet
from vehicles.monitor import ConflictMonitor

from .config import VEHICLES_PER_BUS, Blockade, FleetConfig, check_config, modbus_endpoint
from .events import EventLog
from .order_system import OrderSystem, targets
from .tags import FleetCommands, FleetStatus, fleet_tags, marker_bytes, shown_phase

# the newest nodes each vehicle reported that the recorder keeps: the drawing shows the last
# 48 segments of each, and a few thousand are hours of driving to look back on in Python
DRIVEN_NODES_KEPT = 2000
AREA_BYTES = 1024  # one bus's records: 8 bytes x 127 ids, rounded up


class BlockadeSchedule(FunctionBlock):
    """Closes and reopens segments at the configured times (thesis level 3). Each entry
    closes its segment under its own name, so its end reopens only what it closed: a
    segment an operator or another entry still keeps closed stays closed."""

    def __init__(self, blockades: Iterable[Blockade], constraints: RoutingConstraints) -> None:
        super().__init__()
        entries = [(("schedule", k), b) for k, b in enumerate(blockades)]
        self.pending = sorted(entries, key=lambda e: e[1].at_s)
        self.open_until: list[tuple[tuple[str, int], Blockade]] = []
        self.constraints = constraints

    def cycle(self, ctx: CycleContext) -> None:
        now = ctx.time
        while self.pending and self.pending[0][1].at_s <= now:
            name, b = self.pending.pop(0)
            self.constraints.block(b.a, b.b, both_ways=True, by=name)
            if b.until_s is not None:
                self.open_until.append((name, b))
        for name, b in [e for e in self.open_until if e[1].until_s <= now]:
            self.open_until.remove((name, b))
            self.constraints.unblock(b.a, b.b, both_ways=True, by=name)


class FleetCycle(FunctionBlock):
    """Per vehicle, in id order: its sequencer, then its control (one instance each).

    Nothing is released before every vehicle has reported where it stands (or has been
    silent for ``grace_s``: it is then stale and reported as such): a vehicle whose start
    node is not known yet could otherwise be driven into."""

    ready = Output(False, doc="every vehicle's position is known")

    def __init__(
        self,
        pairs: list[tuple[RecipeSequencer | OrderRunner, VehicleControl]],
        grace_s: float,
        held: set[int] | None = None,
        battery: Callable[[int], int | None] | None = None,
    ) -> None:
        super().__init__()
        self.pairs = pairs
        self.battery = battery
        self.grace_ns = round(grace_s * 1e9)
        self.held = held if held is not None else set()  # vehicles an operator holds

    def cycle(self, ctx: CycleContext) -> None:
        if not self.ready:
            self.ready = ctx.time_ns > self.grace_ns or all(
                c.current is not None for _s, c in self.pairs
            )
        for seq, control in self.pairs:
            if isinstance(seq, OrderRunner):
                battery = self.battery(control.vehicle)
                seq(
                    ctx,
                    arrived=control.arrived,
                    current=control.current,
                    frontier=control.frontier,
                    battery=battery,
                    in_service=control.state not in OUT_OF_SERVICE,
                )
                seq.meter(ctx, battery=battery, on_charger=seq.phase == "charging")
            else:
                seq(ctx, arrived=control.arrived, current=control.current)
            control(
                ctx,
                target=seq.target,
                fixed_route=seq.fixed_route,
                hold=seq.hold or not self.ready or control.vehicle in self.held,
            )


class FleetRecorder(FunctionBlock):
    """The driven routes, for the drawing: the newest ``DRIVEN_NODES_KEPT`` reported nodes
    per vehicle (``driven``, in order) and how often each segment was driven over the whole
    run (``usage``, for the heat map), so neither grows with the run time."""

    def __init__(self, controls: dict[int, VehicleControl], plant: Plant) -> None:
        super().__init__()
        self.controls = controls
        self.driven: dict[int, RecentList[int]] = {
            v: RecentList(DRIVEN_NODES_KEPT) for v in controls
        }
        self._usage = SegmentUsage(plant)
        self.usage = self._usage.counts
        self.plant = plant

    def cycle(self, ctx: CycleContext) -> None:
        for v, control in self.controls.items():
            node = control.current
            path = self.driven[v]
            if node is not None and (not path or path[-1] != node):
                # the plant's own int for the node (a control's position is always a plant
                # node): every entry shares one object per node instead of holding the int
                # decoded from a status frame (28 bytes each)
                node = self.plant.node(node).id
                if path:
                    self._usage.step(path[-1], node)
                path.append(node)


class FleetProgram:
    def __init__(
        self,
        cfg: FleetConfig,
        clock: VirtualClock | WallClock | None = None,
        cosimulate: bool = True,
        bus: tuple[str, str] | None = None,
        retain_file: str | None = None,
    ) -> None:
        check_config(cfg)  # one built or changed in code is checked as a file is
        self.cfg = cfg
        plant = cfg.plant
        vehicles = sorted(cfg.starts)
        self.vehicles = vehicles
        n_buses = bus_of(vehicles[-1])[0] + 1
        interface, channel = bus or (cfg.bus_interface, cfg.bus_channel)
        if interface == "virtual":  # taken once the program is built (below)
            channel = _VIRTUAL_CHANNELS.free(channel, n_buses)
        self.bus_channel = channel  # the channel(s) the vehicle link uses
        self.rt = Runtime(
            cycle_time=cfg.cycle_time,
            clock=clock,
            watchdog=cfg.watchdog,
            gc_threshold=cfg.gc_threshold,
            gc_full_between_scans=cfg.gc_full_between_scans,
            retain_file=retain_file,
            image_sizes={
                "I": AREA_BYTES * (n_buses + 1),
                "Q": AREA_BYTES * (n_buses + 1),
                "M": marker_bytes(vehicles),  # the tags' words (fleet/tags.py)
            },
            tags=fleet_tags(vehicles),
        )
        areas, placement = [], {v: bus_of(v) for v in vehicles}
        on_bus = by_bus(dict.fromkeys(vehicles))
        for k in range(n_buses):
            local = sorted(on_bus.get(k, ()))
            base = AREA_BYTES * (k + 1)
            areas.append(RecordArea(base, base, max(local) if local else 1))
            if local:
                self.rt.add_driver(self._vehicle_link(interface, channel, k, n_buses, local, base))
        assert all(RECORD * (a.max_vehicle + 1) <= AREA_BYTES for a in areas)
        self.records = VehicleRecordsView(areas, placement)
        rows = {s for stations in cfg.clusters.values() for s in stations}
        if cfg.order_vehicles:
            rows |= set(targets(plant))
        self.table = HeuristicTable(plant, sorted(rows))
        self.blockades = RoutingConstraints(plant)
        self.reservation = ReservationMatrix(
            plant,
            vehicles,
            occupied_penalty=cfg.occupied_penalty,
            contraflow_penalty=cfg.contraflow_penalty,
            highway_factor=cfg.highway_factor,
            starts={v: cfg.starts[v] for v in vehicles if v in cfg.starts},
        )
        self.chooser = StationChooser(plant, cfg.clusters, cfg.strategy, self.table, cfg.seed)
        self.completed: RecentList[RecipeRun] = RecentList(RUNS_KEPT)
        self.controls: dict[int, VehicleControl] = {}
        self.sequencers: dict[int, RecipeSequencer] = {}
        # the vehicles a script sends to goals of its own: program.goals[v].send(node, ...)
        self.goals: dict[int, GoalQueue] = {}
        self.orders: OrderSystem | None = None
        if cfg.order_vehicles:
            self.orders = OrderSystem(
                cfg, self.table, self.blockades, self._available, self._occupied
            )
        self.traffic: TimeWindowTraffic | None = None
        if cfg.traffic == "time_windows":
            tw = cfg.time_windows
            self.traffic = TimeWindowTraffic(
                plant,
                self.table,
                self.reservation,
                self.blockades,
                self._priority,
                speed=cfg.agv.max_speed,
                turns=TurnTimes(cfg.agv.turn_90, cfg.agv.turn_180),
                gap_s=tw.gap_s,
                horizon_s=tw.horizon_s,
                window_s=max(tw.window_s, tw.horizon_s),
                replan_s=tw.replan_s,
                budget=tw.plan_budget,
                wait_free_s=tw.wait_free_s,
                wait_occupied_s=tw.wait_occupied_s,
                path_heat=tw.path_heat,
                highway_factor=cfg.highway_factor,
                plan_order=tw.plan_order,
                planner=tw.planner,
            )
        # each vehicle's job block: its recipe sequencer or its order runner
        self.jobs: dict[int, RecipeSequencer | OrderRunner | GoalQueue] = {}
        for v in vehicles:
            self.controls[v] = VehicleControl(
                v,
                plant,
                self.table,
                self.reservation,
                self.records,
                self.blockades,
                lookahead=cfg.lookahead,
                wait_replan_s=cfg.wait_replan_s,
                priority=self._priority,
                traffic=self.traffic,
            )
            self.controls[v].budget = cfg.astar_budget
            if v in cfg.goal_vehicles:
                self.goals[v] = self.jobs[v] = GoalQueue(v, plant)
                continue
            if v in cfg.order_vehicles:
                self.jobs[v] = self.orders.runners[v]
                continue
            self.sequencers[v] = self.jobs[v] = RecipeSequencer(
                v,
                plant,
                [cfg.recipes[name] for name in cfg.vehicle_recipes[v]],
                self.chooser,
                self._taken_by_other(v),
                processing_s=cfg.processing_s,
                rounds=cfg.rounds,
                completed=self.completed,
            )
        self.schedule = BlockadeSchedule(cfg.blockades, self.blockades)
        if self.traffic is not None:
            self.traffic.controls = self.controls
        self.resolver = DeadlockResolver(
            plant,
            self.controls,
            self.reservation,
            self.blockades,
            self._priority,
            self.table,
            pushes=self.traffic is None,
        )
        self.recorder = FleetRecorder(self.controls, plant)
        self.events = EventLog(
            self.controls,
            self.jobs,
            self.resolver,
            self.blockades,
            traffic=self.traffic,
            silent_after_s=cfg.stale_after_s,
        )
        self.commands = FleetCommands(plant, self.blockades, vehicles, self._acknowledge)
        self.status = FleetStatus(self, self.commands)
        self._startup = _Startup(self.table, self.records)
        self.rt.add_task(
            "fleet",
            [
                self._startup,
                self.schedule,
                self.commands,
                *(self.orders.blocks() if self.orders else ()),
                FleetCycle(
                    [(self.jobs[v], self.controls[v]) for v in vehicles],
                    cfg.stale_after_s,
                    self.commands.held,
                    self._battery,
                ),
                *((self.traffic,) if self.traffic is not None else ()),
                self.reservation,
                self.resolver,
                self.recorder,
                self.events,
                self.status,
            ],
            interval=cfg.cycle_time,
            priority=0,
        )
        self.fleet: Fleet | None = None
        self.fleets: list[Fleet] = []  # one per bus (126 vehicles each)
        self.monitor: ConflictMonitor | None = None
        self._sim_buses: list[can.BusABC] = []
        if cosimulate:
            try:
                self._add_simulation(interface, channel, n_buses)
            except BaseException:  # no bus of a program that was never made stays open
                self.close()
                raise
        if interface == "virtual":
            _VIRTUAL_CHANNELS.take(channel, n_buses, self)
        if self.orders is not None:
            self.orders.refusal = self._order_refusal

    def _order_refusal(self) -> str | None:
        """Why a request from Python would never be answered: the program started once and
        is not running any more (stopped, faulted; closed says so itself)."""
        if self.rt.state == "RUN" or self._startup.why_not is None:
            return None  # running, or not started yet: the first scans answer
        return f"the fleet program is in {self.rt.state} and starts once: no scan will answer"

    def _vehicle_link(
        self, interface: str, channel: str, k: int, n_buses: int, local: list[int], base: int
    ) -> CanDriver | ModbusVehicleLink:
        """Bus ``k``'s link: CAN frames, or a Modbus TCP client per vehicle (``modbus``:
        vehicle ``v`` serves on the base port + ``v``)."""
        suffix = str(k) if n_buses > 1 else ""
        if interface == "modbus":
            host, base_port = modbus_endpoint(channel)
            offset = k * VEHICLES_PER_BUS
            return ModbusVehicleLink(
                {lv: (host, base_port + lv + offset) for lv in local},
                stale_after=self.cfg.stale_after_s,
                input_base=base,
                output_base=base,
                name=f"modbus-vehicles{suffix}",
            )
        return CanDriver(
            local,
            interface=interface,
            channel=_channel(channel, k),
            input_base=base,
            output_base=base,
            stale_after=self.cfg.stale_after_s,
            max_frames=frames_per_tick(self.cfg.cycle_time, len(local), self.cfg.status_period_s),
            name=f"can{suffix}",
            **bus_options(interface, k),
        )

    def _add_simulation(self, interface: str, channel: str, n_buses: int) -> None:
        if interface != "virtual":
            return  # vehicles on a real bus are someone else's (their own process)
        cfg = self.cfg
        fleets, offsets = [], []
        starts, faults, charges = by_bus(cfg.starts), by_bus(cfg.faults), by_bus(cfg.battery.start)
        for k in range(n_buses):
            if k not in starts:
                continue
            bus = can.Bus(
                interface="virtual", channel=_channel(channel, k), receive_own_messages=False
            )
            self._sim_buses.append(bus)
            fleets.append(
                Fleet(
                    cfg.plant,
                    starts[k],
                    bus,
                    params=cfg.agv,
                    status_period=cfg.status_period_s,
                    faults=faults.get(k, {}),
                    seed=cfg.seed + k,
                    charges=charges.get(k, {}),
                )
            )
            offsets.append(k * VEHICLES_PER_BUS)
        self.fleets = fleets
        self.fleet = fleets[0]
        self.monitor = ConflictMonitor(fleets, offsets)
        self.rt.add_task(
            "plant",
            [
                CoSimulation(f, self.monitor if i == len(fleets) - 1 else None)
                for i, f in enumerate(fleets)
            ],
            interval=cfg.cycle_time,
            priority=1,
            # the vehicles' physics must not lose time when a scan is late on the wall clock
            overrun="catch_up",
        )

    def _available(self, vehicle: int) -> bool:
        """May the dispatcher give this vehicle an order? Not while it is offline, stale,
        faulty, suspect or held by an operator."""
        state = self.controls[vehicle].state
        return state not in OUT_OF_SERVICE and vehicle not in self.commands.held

    def _battery(self, vehicle: int) -> int | None:
        """The vehicle's charge in %, None until its first info frame."""
        battery = int(self.records.inputs(vehicle)["battery"])
        return None if battery == BATTERY_UNKNOWN else battery

    def _occupied(self, node: int, vehicle: int) -> int | None:
        """The vehicle other than ``vehicle`` that holds ``node`` or is in its area, if any."""
        return self.reservation.blocker(vehicle, self.cfg.plant.index[node])

    def _taken_by_other(self, vehicle: int):
        def taken(station: int) -> bool:
            idx = self.cfg.plant.index[station]
            holder = self.reservation.holder_of(idx)
            if holder is not None and holder != vehicle:
                return True
            return any(s.target == station for v, s in self.jobs.items() if v != vehicle)

        return taken

    def _acknowledge(self, ctx: CycleContext, vehicle: int) -> str | None:
        """An operator's acknowledge of a vehicle (the ``agvN.ack`` tag), logged: after
        looking at it, the operator confirms that a suspect vehicle stands where it reports
        (it returns to service), or, of a vehicle in service, that a load its order left on
        board (the order was withdrawn or failed after its Get began) was taken off (it
        takes orders again). One acknowledge confirms one thing: a vehicle that is both
        takes a second (a new value) for its load. Returns why not, or None."""
        control, job = self.controls[vehicle], self.jobs[vehicle]
        if not control.suspect and isinstance(job, OrderRunner) and job.load_left:
            order = job.load
            job.unloaded()
            self.events.add(ctx.time, "recovered", vehicle, f"load of order {order} taken off")
            return None
        reason = control.suspect_reason
        why = control.acknowledge(ctx)
        if why is None:
            text = f"acknowledged at node {control.current} (was: {reason})"
            self.events.add(ctx.time, "recovered", vehicle, text)
        else:
            if why == "not suspect" and isinstance(job, OrderRunner):
                why = "not suspect, and no load left on board"
            self.events.add_unless_repeated(
                ctx.time, "vehicle", vehicle, f"acknowledge refused: {why}"
            )
        return why

    def _priority(self, vehicle: int) -> tuple[int, int]:
        return (self.jobs[vehicle].priority_ns, vehicle)

    def simulated_vehicles(self) -> dict[int, AGV]:
        """Every vehicle simulated in this process, by its fleet-wide id: where each really
        is (``node``, ``target``, ``progress`` along the segment), which the controller's
        view (``controls``) trails by its reports. A vehicle above 126 runs on a further
        bus, whose fleet knows it by its id there (126 less per bus). Empty when the
        vehicles run elsewhere (their own process, a real bus)."""
        offsets = self.monitor.offsets if self.monitor is not None else []
        return {
            offset + v: agv
            for fleet, offset in zip(self.fleets, offsets, strict=True)
            for v, agv in fleet.vehicles.items()
        }

    def close(self) -> None:
        """Stop the runtime (outputs to their safe state), then close the simulated buses,
        give the channel back and end the waiting order requests, whatever failed first."""
        try:
            self.rt.stop()
        finally:
            for bus in self._sim_buses:
                bus.shutdown()
            self._sim_buses = []
            _VIRTUAL_CHANNELS.release(self)
            self._startup.why_not = "this fleet program was closed: build a new FleetProgram"
            if self.orders is not None:
                self.orders.close()

    # ----- what the program reports ----------------------------------------------------------
    def vehicle_rows(self) -> list[dict[str, object]]:
        rows = []
        for v in self.vehicles:
            c, s = self.controls[v], self.jobs[v]
            rec = self.records.inputs(v) if self.records.bound else None
            recipe = self.cfg.recipes.get(s.recipe_name)
            rows.append(
                {
                    "vehicle": v,
                    "state": c.state,
                    "reported": STATES[int(rec["state"])]
                    if rec is not None and int(rec["state"]) < len(STATES)
                    else "-",
                    "node": c.current,
                    "target": s.target,
                    "order": _orders_of(s),
                    "recipe": s.recipe_name,
                    "step": f"{s.step + 1}/{len(recipe.functions)}" if recipe else "-",
                    "phase": shown_phase(s),
                    "battery": self._battery(v) if rec is not None else None,
                    "rounds": s.rounds_done,
                    "waits": c.waits,
                    "replans": c.replans,
                }
            )
        return rows


def _orders_of(job: RecipeSequencer | OrderRunner) -> str | None:
    """ "active/next" order ids of a vehicle that takes orders; None for a recipe vehicle."""
    if not isinstance(job, OrderRunner):
        return None
    active = job.active.id if job.active is not None else "-"
    return f"{active}/{job.next.id}" if job.next is not None else active


class _Startup(FunctionBlock):
    """OB100 for the fleet: build the heuristic table and bind the record views.

    A fleet program starts once. Its state is the run's, not only the blocks' variables
    that a warm restart resets: the nodes each vehicle holds, the routes released, the
    orders on board. At a stop the outputs went to their safe state (every vehicle stopped)
    and the vehicles kept moving until they did, so none of that matches the plant any
    more, and a restart would drive on stale holds. A second start is refused; a new
    FleetProgram takes over from where the vehicles report they stand."""

    def __init__(self, table: HeuristicTable, records: VehicleRecordsView) -> None:
        super().__init__()
        self.table, self.records = table, records
        self.why_not: str | None = None  # why a start is refused

    def startup(self, ctx: CycleContext) -> None:
        if self.why_not is not None:
            raise RuntimeError(self.why_not)
        self.why_not = (
            "a fleet program starts once: after stop() or a fault, build a new "
            "FleetProgram (README, The Python API)"
        )
        self.table.startup(ctx)
        self.records.bind(ctx)

    def cycle(self, ctx: CycleContext) -> None:
        self.table.cycle(ctx)


class _VirtualChannels:
    """The in-process virtual bus channels the programs of this process use. Two programs
    on one channel would each read the other's vehicles (a side-by-side comparison in one
    script, a notebook, a test suite): a program whose channel another program still
    holds gets its own, the name with ``~2``, ``~3``, ... added (``FleetProgram.bus_channel``
    says which). A program holds its channels until it is closed or garbage."""

    def __init__(self) -> None:
        self._holders: weakref.WeakValueDictionary[str, FleetProgram] = (
            weakref.WeakValueDictionary()
        )

    def free(self, channel: str, n_buses: int) -> str:
        """``channel``, or the first of its numbered variants no live program holds."""
        candidate, k = channel, 1
        while any(_channel(candidate, b) in self._holders for b in range(n_buses)):
            k += 1
            candidate = ",".join(f"{name}~{k}" for name in bus_channels(channel))
        return candidate

    def take(self, channel: str, n_buses: int, program: FleetProgram) -> None:
        for b in range(n_buses):
            self._holders[_channel(channel, b)] = program

    def release(self, program: FleetProgram) -> None:
        for name in [n for n, p in self._holders.items() if p is program]:
            del self._holders[name]


_VIRTUAL_CHANNELS = _VirtualChannels()


def _channel(channel: str, k: int) -> str:
    """Bus ``k``'s channel: the k-th of the link's comma-separated channels. The in-process
    virtual bus may name fewer (one, by default): it numbers the others after the first."""
    channels = bus_channels(channel)
    return channels[k] if k < len(channels) else f"{channels[0]}{k}"
