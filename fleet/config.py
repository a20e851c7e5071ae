"""The fleet configuration file (TOML; docs/fleet-config.md): plant, vehicles, recipes,
function clusters, station strategy, cycle time, bus and routing settings.

Every error names the file and the key (``fleet.toml: vehicles[2].start: ...``), and every
value is checked against the plant before anything runs: unknown nodes, functions nobody
provides, two vehicles on one start node, unknown recipe names.
"""

from __future__ import annotations

import ipaddress
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from blocks.dispatch.strategies import strategy_names
from blocks.jobs.recipe import STRATEGIES, Recipe
from blocks.traffic.planners import planner_names
from blocks.traffic.tw_traffic import PLAN_ORDERS
from io_drivers.can_bus import bus_channels, bus_of, interface_problem
from io_drivers.protocol import MAX_NODE_ID, MAX_VEHICLE_ID
from plc_runtime.collector import DEFAULT_YOUNG_THRESHOLD
from plc_runtime.errors import ConfigError
from plc_runtime.files import FileProblem, read_limited
from plc_runtime.runtime import MAX_TIME
from topology import SAMPLES, Plant, TopologyError, load
from topology.formats.numbers import parse_int
from topology.validate import text_problem
from vehicles.agv import AgvParams
from vehicles.fleet import Faults

from .config_reader import TableReader
from .liveness import standing_steps, stranded_starts
from .orders_config import (
    BatteryConfig,
    DispatchConfig,
    OrdersConfig,
    parse_battery,
    parse_dispatch,
    parse_orders,
)

DEFAULT_CONFIG = Path(__file__).with_name("default.toml")
VEHICLES_PER_BUS = MAX_VEHICLE_ID  # vehicle ids on one CAN bus: 7 bits, 0 and 127 taken
MAX_BUSES = 8  # a configuration's vehicle ids go up to VEHICLES_PER_BUS * MAX_BUSES
MODBUS = "modbus"  # the bus "interface" that means one Modbus TCP server per vehicle
LOOPBACK = ("127.0.0.1", "localhost", "::1")  # where simulated Modbus vehicles can serve

# a configuration is a few kilobytes; this is far above any, and bounds what a wrong path costs
MAX_CONFIG_BYTES = 4 * 2**20


def parse_bus(spec: str) -> tuple[str, str]:
    """``INTERFACE:CHANNEL`` of ``--bus``: a python-can interface with its channel (several,
    comma-separated, for a fleet on several buses), or ``modbus`` with ``HOST:BASE_PORT``;
    ConfigError naming the option and what is wrong."""
    interface, sep, channel = spec.partition(":")
    if not sep or not interface or not channel:
        raise ConfigError(f"--bus {spec!r}: expected INTERFACE:CHANNEL, e.g. socketcan:vcan0")
    if interface == MODBUS:
        modbus_endpoint(channel)
    elif (problem := interface_problem(interface)) is not None:
        raise ConfigError(f"--bus {spec!r}: {problem}, or modbus")
    elif not all(bus_channels(channel)):
        raise ConfigError(f"--bus {spec!r}: an empty channel between commas")
    return interface, channel


def link_problem(interface: str, channel: str, highest: int) -> str | None:
    """Why the link cannot carry vehicle ids up to ``highest``, or None. The in-process
    virtual bus makes as many buses as the ids need; any other CAN link needs a channel per
    126 ids, and a Modbus link a port per vehicle."""
    if interface == MODBUS:
        _, base = modbus_endpoint(channel)
        if base + highest > 65535:
            return (
                f"vehicle {highest} would serve on port {base + highest}, past 65535: "
                "give a lower base port"
            )
        return None
    if interface == "virtual":
        return None
    needed, given = bus_of(highest)[0] + 1, len(bus_channels(channel))
    if given >= needed:
        return None
    return (
        f"vehicle {highest} needs {needed} buses ({VEHICLES_PER_BUS} vehicles a bus: ids "
        f"1..{VEHICLES_PER_BUS} on the first channel, {VEHICLES_PER_BUS + 1}.."
        f"{2 * VEHICLES_PER_BUS} on the second, ...), and {channel!r} names {given}: give "
        "them comma-separated, e.g. vcan0,vcan1"
    )


def modbus_endpoint(channel: str) -> tuple[str, int]:
    """``HOST:BASE_PORT`` of a Modbus vehicle link: vehicle ``v`` serves on BASE_PORT + v
    (whether the fleet's highest id still fits below 65536 is :func:`link_problem`'s)."""
    try:
        host, port = host_port(channel, "127.0.0.1:5100", "HOST:BASE_PORT")
    except ValueError as exc:
        raise ConfigError(f"modbus vehicle link: {exc}") from None
    if not 1 <= port <= 65534:
        raise ConfigError(
            f"modbus vehicle link {channel!r}: expected HOST:BASE_PORT with a base port in "
            "1..65534, e.g. 127.0.0.1:5100 (vehicle v serves on BASE_PORT + v)"
        )
    return host, port


@dataclass(frozen=True)
class Blockade:
    a: int
    b: int
    at_s: float
    until_s: float | None  # None: for the rest of the run


TRAFFIC_MODES = ("reactive", "time_windows")
# driving against a highway lane (docs/plant-format.md) costs this many times its length
HIGHWAY_FACTOR = 3.0


@dataclass
class TimeWindowsConfig:
    """The time-window traffic mode's planner ([time_windows], docs/fleet-config.md)."""

    gap_s: float = 0.5  # safety gap between two vehicles' windows on a node or segment
    horizon_s: float = 20.0  # how far ahead a plan is booked and released
    # how far ahead conflicts are resolved (>= horizon_s, which it then follows; a day: all)
    window_s: float = 30.0
    replan_s: float = 2.0  # a planning round at least this often
    plan_budget: int = 200  # search expansions, or vehicles read, per scan (about 5 ms)
    wait_free_s: float = 15.0  # T_w1: a wait for a vehicle still on its way, then replan
    wait_occupied_s: float = 30.0  # T_w2: a wait for a vehicle on the node, then replan
    path_heat: bool = False  # the seed's congestion-aware arc weights in the search
    plan_order: str = "release"  # who is planned first (PLAN_ORDERS)
    # who finds a vehicle's plan: "sipp", or a planner registered in this process
    planner: str = "sipp"


@dataclass
class FleetConfig:
    source: str
    plant: Plant
    starts: dict[int, int]  # vehicle id -> start node
    recipes: dict[str, Recipe]
    vehicle_recipes: dict[int, list[str]]
    clusters: dict[int, list[int]]
    strategy: str = "random"
    seed: int = 0
    processing_s: float = 3.0
    rounds: int = 0
    cycle_time: float = 0.010
    watchdog: float = 0.150
    # the collector's young-generation threshold while running; None: Python's own
    gc_threshold: int | None = DEFAULT_YOUNG_THRESHOLD
    # full collections between scans, not in them; False: Python's own
    gc_full_between_scans: bool = True
    duration_s: float = 600.0
    astar_budget: int = 4
    lookahead: int = 2
    wait_replan_s: float = 5.0
    occupied_penalty: float = 0.0
    contraflow_penalty: float = 3.0
    highway_factor: float = HIGHWAY_FACTOR  # cost factor against a highway lane's direction
    traffic: str = "reactive"  # or "time_windows" (TRAFFIC_MODES)
    time_windows: TimeWindowsConfig = field(default_factory=TimeWindowsConfig)
    time_windows_given: bool = False  # the configuration has a [time_windows] table
    bus_interface: str = "virtual"
    bus_channel: str = "agv"
    status_period_s: float = 0.1
    stale_after_s: float = 0.5
    blockades: list[Blockade] = field(default_factory=list)
    # fault injection into the simulated vehicles' links (a commissioning test): vehicle -> faults
    faults: dict[int, Faults] = field(default_factory=dict)
    # transport orders (docs/orders.md): where they come from, who takes them, how
    orders: OrdersConfig | None = None
    order_vehicles: list[int] = field(default_factory=list)  # the others run recipes
    # vehicles driven to the goals a script sends them (program.goals[v].send(node))
    goal_vehicles: list[int] = field(default_factory=list)
    # the vehicles --vehicles-count dropped (an order may still name one: the error says why)
    vehicles_left_out: set[int] = field(default_factory=set)
    dispatch: DispatchConfig = field(default_factory=DispatchConfig)
    battery: BatteryConfig = field(default_factory=BatteryConfig)
    # the simulated vehicles' drive ([simulation]; real vehicles bring their own)
    agv: AgvParams = field(default_factory=AgvParams)
    # [web] address: serve the HTTP API and the operator's page there (None: not served)
    web_address: tuple[str, int] | None = None
    plant_file: Path | None = None  # [plant] file, None for a sample plant
    config_file: Path | None = None  # the file read, None for the embedded default

    def input_files(self) -> dict[str, Path]:
        """The files a run reads, by the words an error names them with: a run must not
        write over one of them."""
        files = {"the plant file": self.plant_file}
        if self.orders is not None:
            files["the order file"] = self.orders.file
        files["the configuration file"] = self.config_file
        return {what: path for what, path in files.items() if path is not None}

    @property
    def level(self) -> str:
        """The thesis level this configuration exercises (for the summary)."""
        multi = any(len(s) > 1 for f, s in self.clusters.items() if f > 1)
        distinct = (
            len({tuple(r) for r in self.vehicle_recipes.values()}) > 1 or len(self.recipes) > 1
        )
        if distinct and multi and self.blockades:
            return "4"
        if self.blockades:
            return "3"
        return "2" if multi else "1"


def load_config(path: str | Path | None = None) -> FleetConfig:
    """Read a fleet configuration; ``None`` is the embedded default (``make run``)."""
    path = Path(path) if path is not None else DEFAULT_CONFIG
    source = path.name if path == DEFAULT_CONFIG else str(path)
    try:
        raw = read_limited(path, MAX_CONFIG_BYTES)
        # utf-8-sig: an editor on Windows may start the file with a byte order mark
        text = raw.decode("utf-8-sig")
    except FileProblem as exc:
        raise ConfigError(f"{source}: {exc}, not a fleet configuration") from None
    except OSError as exc:
        raise ConfigError(f"{source}: cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise ConfigError(f"{source}: line {line}: not UTF-8 text (byte {exc.start})") from None
    other = {  # files a configuration names, given in its place: say so, not a TOML error
        ".csv": ("an order file", "[orders] file"),
        ".json": ("an order or plant file", "[orders] file or [plant] file"),
        ".map": ("a plant file", "[plant] file"),
        ".nodes": ("a plant file", "[plant] file"),
    }.get(path.suffix.lower())
    if other is not None:
        raise ConfigError(
            f"{source}: {other[0]} ({path.suffix}), not a fleet configuration (TOML); a "
            f"configuration names it under {other[1]} (docs/fleet-config.md)"
        )
    cfg = parse_config(text, source, path.parent)
    cfg.config_file = None if path == DEFAULT_CONFIG else path
    return cfg


def parse_config(text: str, source: str = "<config>", base: Path | None = None) -> FleetConfig:
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    except ValueError:  # what the TOML reader passes on: an integer too long to convert
        raise ConfigError(f"{source}: unreadable TOML: a number with too many digits") from None
    except RecursionError:
        raise ConfigError(f"{source}: nested too deeply") from None
    if "plant" not in doc and {"nodes", "edges"} & doc.keys():
        raise ConfigError(
            f"{source}: a plant file, not a fleet configuration; a configuration names it: "
            '[plant] file = "..." (docs/fleet-config.md)'
        )
    top = TableReader(source, doc, "")
    plant, plant_file = _plant(
        TableReader(source, top.get("plant", dict), "plant."), base or Path(".")
    )
    runtime = TableReader(source, top.get("runtime", dict, {}), "runtime.")
    routing = TableReader(source, top.get("routing", dict, {}), "routing.")
    stations = TableReader(source, top.get("stations", dict, {}), "stations.")
    sequencer = TableReader(source, top.get("sequencer", dict, {}), "sequencer.")
    bus = TableReader(source, top.get("bus", dict, {}), "bus.")
    orders_table = top.get("orders", dict, None)
    orders = (
        None
        if orders_table is None
        else parse_orders(TableReader(source, orders_table, "orders."), base or Path("."), plant)
    )
    recipes = _recipes(source, top.get("recipes", list, []), plant, required=orders is None)
    clusters = _clusters(stations, plant)
    for recipe in recipes.values():
        for f in recipe.functions:
            if not clusters.get(f):
                raise ConfigError(
                    f"{source}: recipes: recipe {recipe.name!r} needs function {f}, "
                    "which no station provides (add it to stations.clusters)"
                )
    starts, vehicle_recipes, charges = _vehicles(
        source, top.get("vehicles", list), plant, recipes, orders is not None
    )
    cfg = FleetConfig(
        source=source,
        plant=plant,
        plant_file=plant_file,
        starts=starts,
        recipes=recipes,
        vehicle_recipes=vehicle_recipes,
        clusters=clusters,
        strategy=stations.get("strategy", str, "random"),
        seed=stations.integer("seed", 0, 0, 2**32 - 1),
        processing_s=stations.number("processing_s", 3.0, 0.0, 3600.0),
        rounds=sequencer.integer("rounds", 0, 0, 10**6),
        cycle_time=runtime.number("cycle_time_ms", 10.0, 0.1, 1000.0) / 1e3,
        watchdog=runtime.positive("watchdog_ms", 150.0, MAX_TIME * 1e3) / 1e3,
        gc_threshold=runtime.integer("gc_threshold", DEFAULT_YOUNG_THRESHOLD, 0, 10**9) or None,
        gc_full_between_scans=runtime.get("gc_full_between_scans", bool, True),
        duration_s=runtime.number("duration_s", 600.0, 0.001, 1e7),
        astar_budget=routing.integer("astar_budget", 4, 1, 10**6),
        lookahead=routing.integer("lookahead", 2, 1, 3),
        wait_replan_s=routing.number("wait_replan_s", 5.0, 0.0, 3600.0),
        occupied_penalty=routing.number("occupied_penalty", 0.0, 0.0, 1e9),
        contraflow_penalty=routing.number("contraflow_penalty", 3.0, 0.0, 1e9),
        highway_factor=routing.number("highway_factor", HIGHWAY_FACTOR, 1.0, 1e6),
        traffic=routing.get("traffic", str, "reactive"),
        bus_interface=bus.get("interface", str, "virtual"),
        bus_channel=bus.get("channel", str, "agv"),
        status_period_s=bus.number("status_period_s", 0.1, 0.001, 30.0),
        stale_after_s=bus.number("stale_after_s", 0.5, 0.01, 300.0),
        blockades=_blockades(source, top.get("blockades", list, []), plant),
    )
    cfg.orders = orders
    cfg.order_vehicles = [v for v in sorted(starts) if v not in vehicle_recipes]
    cfg.dispatch = parse_dispatch(TableReader(source, top.get("dispatch", dict, {}), "dispatch."))
    cfg.battery = parse_battery(TableReader(source, top.get("battery", dict, {}), "battery."))
    cfg.battery.start = charges
    cfg.agv = _simulation(TableReader(source, top.get("simulation", dict, {}), "simulation."))
    cfg.faults = _faults(TableReader(source, top.get("faults", dict, {}), "faults."), cfg.starts)
    time_windows = top.get("time_windows", dict, None)
    cfg.time_windows = _time_windows(TableReader(source, time_windows or {}, "time_windows."))
    cfg.web_address = _web(TableReader(source, top.get("web", dict, {}), "web."))
    if cfg.traffic not in TRAFFIC_MODES:
        raise routing.fail(
            "traffic", f"must be one of {', '.join(TRAFFIC_MODES)}, got {cfg.traffic!r}"
        )
    if cfg.strategy not in STRATEGIES:
        raise stations.fail(
            "strategy", f"must be one of {', '.join(STRATEGIES)}, got {cfg.strategy!r}"
        )
    cfg.time_windows_given = time_windows is not None
    if cfg.status_period_s >= cfg.stale_after_s:
        # a vehicle reporting this seldom would read as stale between two of its reports
        raise _out_of_order(
            bus,
            ("status_period_s", cfg.status_period_s),
            ("stale_after_s", cfg.stale_after_s),
            "must be less than",
            "every vehicle would turn stale between its reports",
        )
    for reader in (runtime, routing, stations, sequencer, bus, top):
        reader.finish()
    if cfg.bus_interface == MODBUS:
        try:
            modbus_endpoint(cfg.bus_channel)
        except ConfigError as exc:
            raise bus.fail("channel", str(exc)) from None
    elif (problem := interface_problem(cfg.bus_interface)) is not None:
        raise bus.fail("interface", f"{problem}, or modbus")
    elif not all(bus_channels(cfg.bus_channel)):
        raise bus.fail("channel", "an empty channel between commas")
    if (problem := link_problem(cfg.bus_interface, cfg.bus_channel, max(cfg.starts))) is not None:
        raise bus.fail("channel", problem)
    problems = standing_steps(cfg) + stranded_starts(cfg)
    if problems:
        raise ConfigError(f"{source}: vehicles: {problems[0]}")
    return cfg


def check_config(cfg: FleetConfig) -> None:
    """The checks a configuration file gets, for a FleetConfig built or changed in code
    (``FleetProgram`` runs them): the first problem is a ConfigError naming the field, not
    a KeyError deep in a block or a silent fallback. Cheap, and nothing is changed. A
    recipe step completed where the vehicle stands stays allowed here: a script may park
    a vehicle at its one station on purpose."""
    where = f"{cfg.source}: "
    if cfg.traffic not in TRAFFIC_MODES:
        raise ConfigError(
            f"{where}traffic: must be one of {', '.join(TRAFFIC_MODES)}, got {cfg.traffic!r}"
        )
    for name, value, least in (
        ("cycle_time", cfg.cycle_time, 0.0),
        ("watchdog", cfg.watchdog, 0.0),
        ("astar_budget", cfg.astar_budget, 1),
    ):
        if isinstance(value, bool) or not isinstance(value, int | float) or not value >= least:
            raise ConfigError(f"{where}{name}: must be a number >= {least}, got {value!r}")
    for name, kind in (
        ("starts", dict),
        ("recipes", dict),
        ("vehicle_recipes", dict),
        ("clusters", dict),
        ("order_vehicles", list | tuple | set | frozenset),
        ("goal_vehicles", list | tuple | set | frozenset),
    ):
        value = getattr(cfg, name)
        if not isinstance(value, kind):
            raise ConfigError(
                f"{where}{name}: must be a {'dict' if kind is dict else 'list'}, got "
                f"{type(value).__name__}"
            )
    if not cfg.starts:
        raise ConfigError(f"{where}starts: at least one vehicle is needed")
    if cfg.traffic == "time_windows" and cfg.time_windows.planner not in planner_names():
        raise ConfigError(
            f"{where}time_windows.planner: {_unknown_planner(cfg.time_windows.planner)}"
        )
    if cfg.dispatch.strategy not in strategy_names():
        raise ConfigError(
            f"{where}dispatch.strategy: must be one of {', '.join(strategy_names())}, got "
            f"{cfg.dispatch.strategy!r} (a strategy of one's own: register_strategy)"
        )
    top = VEHICLES_PER_BUS * MAX_BUSES
    seen: dict[int, int] = {}
    for v, start in cfg.starts.items():
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= top:
            raise ConfigError(f"{where}starts: vehicle ids are integers 1..{top}, got {v!r}")
        if start not in cfg.plant.index:
            raise ConfigError(f"{where}starts: vehicle {v}: node {start!r} is not in the plant")
        if start in seen:
            raise ConfigError(
                f"{where}starts: vehicle {v}: node {start} is already vehicle {seen[start]}'s start"
            )
        seen[start] = v
    for name in ("order_vehicles", "goal_vehicles"):
        for v in getattr(cfg, name):
            if v not in cfg.starts:
                raise ConfigError(f"{where}{name}: vehicle {v!r} has no start")
    if both := set(cfg.order_vehicles) & set(cfg.goal_vehicles):
        raise ConfigError(
            f"{where}goal_vehicles: vehicle {min(both)} takes orders (order_vehicles): one job "
            "a vehicle"
        )
    if cfg.orders is not None and not cfg.order_vehicles:
        raise ConfigError(
            f"{where}orders: given, but no vehicle takes orders: every [[vehicles]] entry names "
            "its recipes; leave recipes out of those that should take orders"
        )
    for v in cfg.starts:
        if v not in cfg.order_vehicles and v not in cfg.goal_vehicles:
            if v not in cfg.vehicle_recipes:
                raise ConfigError(
                    f"{where}vehicle_recipes: vehicle {v} has no recipes, takes no orders "
                    "(order_vehicles) and no goals (goal_vehicles)"
                )
    for function, stations in cfg.clusters.items():
        for node in stations:
            if node not in cfg.plant.index:
                raise ConfigError(
                    f"{where}clusters: function {function!r}: station {node!r} is not a node "
                    "of the plant"
                )
    for v, names in cfg.vehicle_recipes.items():
        if v not in cfg.starts:
            raise ConfigError(f"{where}vehicle_recipes: vehicle {v} has no start")
        for name in names:
            if name not in cfg.recipes:
                known = ", ".join(cfg.recipes) or "none"
                raise ConfigError(
                    f"{where}vehicle_recipes: vehicle {v}: unknown recipe {name!r} ({known})"
                )
    for recipe in cfg.recipes.values():
        for f in recipe.functions:
            if not cfg.clusters.get(f):
                raise ConfigError(
                    f"{where}recipes: {recipe.name!r} needs function {f}, which no station "
                    "provides (clusters)"
                )
    for k, blockade in enumerate(cfg.blockades):
        try:
            cfg.plant.arcs_between(blockade.a, blockade.b)
        except TopologyError as exc:
            raise ConfigError(f"{where}blockades[{k}]: {exc}") from None
        until = blockade.until_s
        if not (0 <= blockade.at_s and (until is None or until > blockade.at_s)):
            raise ConfigError(
                f"{where}blockades[{k}]: at_s must be >= 0 and until_s after it, got "
                f"{blockade.at_s!r}..{until!r}"
            )
    problems = stranded_starts(cfg)
    if problems:
        raise ConfigError(f"{where}vehicles: {problems[0]}")


def idle_settings(cfg: FleetConfig) -> list[str]:
    """Settings of the configuration that the run as configured (after any command-line
    overrides) does not use: the operator would believe something tuned that does not run.
    Not an error, since one configuration serves both traffic modes (``--traffic``)."""
    if cfg.time_windows_given and cfg.traffic != "time_windows":
        return [
            f"{cfg.source}: [time_windows] is given but traffic is {cfg.traffic!r}: its "
            'settings apply only with traffic = "time_windows"'
        ]
    return []


def _out_of_order(
    r: TableReader,
    low: tuple[str, float],
    high: tuple[str, float],
    relation: str,
    why: str,
) -> ConfigError:
    """The error for two settings of one table in the wrong order, in seconds, named at the
    one the file gives (the other may be its default, which the message then says)."""

    def described(key: str, value: float) -> str:
        return f"{key} = {value:g} s" + ("" if key in r.table else " (the default)")

    key = low[0] if low[0] in r.table or high[0] not in r.table else high[0]
    return r.fail(key, f"{described(*low)} {relation} {described(*high)}: {why}")


def _unknown_planner(name: object) -> str:
    return (
        f"must be one of {', '.join(planner_names())}, got {name!r} (a planner of one's "
        "own: register_planner, before the configuration is read)"
    )


def _time_windows(r: TableReader) -> TimeWindowsConfig:
    horizon_s = r.number("horizon_s", 20.0, 0.1, 3600.0)
    cfg = TimeWindowsConfig(
        gap_s=r.number("gap_s", 0.5, 0.001, 60.0),
        horizon_s=horizon_s,
        window_s=r.number("window_s", max(30.0, horizon_s), horizon_s, 86400.0),
        replan_s=r.number("replan_s", 2.0, 0.01, 3600.0),
        plan_budget=r.integer("plan_budget", 200, 1, 10**8),
        wait_free_s=r.number("wait_free_s", 15.0, 0.01, 3600.0),
        wait_occupied_s=r.number("wait_occupied_s", 30.0, 0.01, 3600.0),
        path_heat=r.get("path_heat", bool, False),
        plan_order=r.get("plan_order", str, "release"),
        planner=r.get("planner", str, "sipp"),
    )
    if cfg.planner not in planner_names():
        raise r.fail("planner", _unknown_planner(cfg.planner))
    if cfg.plan_order not in PLAN_ORDERS:
        raise r.fail(
            "plan_order", f"must be one of {', '.join(PLAN_ORDERS)}, got {cfg.plan_order!r}"
        )
    if cfg.wait_free_s > cfg.wait_occupied_s:
        # T_w1 is the patience with a vehicle still on its way, T_w2 with one standing on
        # the node: waiting longer for one that moves than for one that stands is backwards
        raise _out_of_order(
            r,
            ("wait_free_s", cfg.wait_free_s),
            ("wait_occupied_s", cfg.wait_occupied_s),
            "must not exceed",
            "a vehicle on its way would be waited for longer than one standing on the node",
        )
    if cfg.replan_s >= horizon_s:
        # a plan is booked horizon_s ahead and made again every replan_s: with a longer
        # gap the vehicles reach the end of their plans and stand until the next round
        raise r.fail(
            "replan_s",
            f"must be less than horizon_s ({horizon_s:g} s), got {cfg.replan_s:g}: the "
            "vehicles would stand at the end of their plans between rounds",
        )
    r.finish()
    return cfg


def _web(r: TableReader) -> tuple[str, int] | None:
    text = r.get("address", str, None)
    r.finish()
    if text is None:
        return None
    try:
        return host_port(text)
    except ValueError as exc:
        raise r.fail("address", str(exc)) from None


def host_port(
    text: str, example: str = "127.0.0.1:8080", form: str = "HOST:PORT"
) -> tuple[str, int]:
    """``HOST:PORT`` (an IPv6 host in brackets) as (host, port); ValueError naming what is
    wrong, with the ``form`` and an ``example`` to follow."""
    host, sep, port = text.rpartition(":")
    bracketed = host.startswith("[") and host.endswith("]") and len(host) > 1
    if bracketed:
        host = host[1:-1]
    if (
        not sep
        or not host
        or not (port.isascii() and port.isdigit())
        or len(port) > 5
        or not 0 <= int(port) <= 65535
        or any(c in host for c in "[]")
        or any(c.isspace() for c in host)
    ):
        raise ValueError(f"expected {form}, e.g. {example}, got {text!r}")
    if ":" in host or bracketed:
        try:
            ipaddress.IPv6Address(host)
        except ValueError:
            raise ValueError(
                f"{host!r} is no IPv6 address (brackets hold one), in {text!r}"
            ) from None
        if not bracketed:
            raise ValueError(f"an IPv6 host goes in brackets, e.g. [{host}]:{port}, got {text!r}")
    return host, int(port)


def _plant(reader: TableReader, base: Path) -> tuple[Plant, Path | None]:
    """The plant, and the file it was read from (None for a sample)."""
    sample = reader.get("sample", str, None)
    file = reader.get("file", str, None)
    reader.finish()
    if (sample is None) == (file is None):
        raise reader.fail("sample", "give exactly one of plant.sample and plant.file")
    if sample is not None:
        if sample not in SAMPLES:
            raise reader.fail(
                "sample", f"unknown sample plant {sample!r} (one of {', '.join(SAMPLES)})"
            )
        return SAMPLES[sample](), None
    path = Path(file)
    if not path.is_absolute():
        path = base / path
    try:
        plant = load(path)
    except TopologyError as exc:
        raise ConfigError(f"{reader.source}: plant.file: {exc}") from None
    problem = link_node_problem(plant)
    if problem is not None:
        raise ConfigError(f"{reader.source}: plant.file: {path}: {problem}")
    return plant, path


def link_node_problem(plant: Plant) -> str | None:
    """Why vehicles could not name the plant's nodes on their link, or None: a node id
    there is 16 bits and 65535 means "no node", so a vehicle standing on node 65535 would
    report none, and one on 70000 could not report at all (docs/protocol.md)."""
    highest = int(plant.ids.max()) if plant.n else 0
    if highest <= MAX_NODE_ID:
        return None
    return (
        f"node {highest}: the vehicle link names nodes 0..{MAX_NODE_ID} "
        f"(16 bits, {MAX_NODE_ID + 1} means no node); number the plant's nodes within it"
    )


def _node(reader: TableReader, key: str, plant: Plant) -> int:
    node = reader.get(key, int)
    if node not in plant.index:
        raise reader.fail(key, f"node {node} is not in plant {plant.name!r}")
    return node


def _recipes(source: str, items: list, plant: Plant, required: bool) -> dict[str, Recipe]:
    if not items and required:
        raise ConfigError(f"{source}: recipes: at least one [[recipes]] entry is needed")
    recipes: dict[str, Recipe] = {}
    for k, item in enumerate(items):
        if not isinstance(item, dict):
            raise ConfigError(f"{source}: recipes[{k}]: expected a table")
        r = TableReader(source, item, f"recipes[{k}].")
        name = r.get("name", str)
        functions = r.get("functions", list)
        r.finish()
        problem = text_problem(name) if name else "must not be empty"
        if problem:  # the dashboard, the events and recipes.csv show it
            raise r.fail("name", problem)
        if name in recipes:
            raise r.fail("name", f"recipe {name!r} defined twice")
        if not functions or not all(
            isinstance(f, int) and not isinstance(f, bool) and f >= 0 for f in functions
        ):
            raise r.fail(
                "functions", f"expected a non-empty list of function ids >= 0, got {functions!r}"
            )
        recipes[name] = Recipe(name, tuple(functions))
    return recipes


def _clusters(reader: TableReader, plant: Plant) -> dict[int, list[int]]:
    clusters: dict[int, list[int]] = {}
    for node in plant.nodes:
        for f in node.functions:
            clusters.setdefault(f, []).append(node.id)
    given = reader.get("clusters", dict, {})
    spelt: dict[int, str] = {}  # how each function id was written, to name a second spelling
    for key, stations in given.items():
        function = parse_int(key) if key.isascii() and key.isdigit() else None
        if function is None:
            raise reader.fail(f"clusters.{key}", "function ids are integers >= 0")
        if function in spelt:
            raise reader.fail(
                f"clusters.{key}", f"function {function} again (given as {spelt[function]!r})"
            )
        spelt[function] = key
        if (
            not isinstance(stations, list)
            or not stations
            or not all(isinstance(s, int) and not isinstance(s, bool) for s in stations)
        ):
            raise reader.fail(
                f"clusters.{key}", f"expected a non-empty list of node ids, got {stations!r}"
            )
        seen: set[int] = set()
        for s in stations:
            if s not in plant.index:
                raise reader.fail(f"clusters.{key}", f"node {s} is not in plant {plant.name!r}")
            if s in seen:
                raise reader.fail(f"clusters.{key}", f"node {s} is listed twice")
            seen.add(s)
        clusters[function] = list(stations)
    return clusters


def _vehicles(
    source: str, items: list, plant: Plant, recipes: dict[str, Recipe], orders: bool
) -> tuple[dict[int, int], dict[int, list[str]], dict[int, float]]:
    """Start nodes, the recipes of the vehicles that run recipes (with orders configured,
    a vehicle without ``recipes`` takes orders), and start charges in %."""
    if not items:
        raise ConfigError(f"{source}: vehicles: at least one [[vehicles]] entry is needed")
    starts: dict[int, int] = {}
    chosen: dict[int, list[str]] = {}
    charges: dict[int, float] = {}
    names = list(recipes)
    for k, item in enumerate(items):
        if not isinstance(item, dict):
            raise ConfigError(f"{source}: vehicles[{k}]: expected a table")
        r = TableReader(source, item, f"vehicles[{k}].")
        vid = r.integer("id", ..., 1, VEHICLES_PER_BUS * MAX_BUSES)
        start = _node(r, "start", plant)
        own = r.get("recipes", list, None)
        charge = r.number("battery", 100.0, 0.0, 100.0)
        r.finish()
        if vid in starts:
            raise r.fail("id", f"vehicle {vid} defined twice")
        if start in starts.values():
            other = next(v for v, s in starts.items() if s == start)
            raise r.fail("start", f"node {start} is already vehicle {other}'s start")
        area = plant.node(start).area
        other = next((v for v, s in starts.items() if area and plant.node(s).area == area), None)
        if other is not None:
            raise r.fail(
                "start",
                f"node {start} is in single-vehicle area {area!r}, where vehicle {other} "
                f"starts (node {starts[other]}): one vehicle per area",
            )
        if charge != 100.0:
            charges[vid] = charge
        if own is None and orders:
            starts[vid] = start  # takes transport orders
            continue
        if own is None:
            # every vehicle runs all recipes, each starting at a different one (level 4)
            own = names[len(starts) % len(names) :] + names[: len(starts) % len(names)]
        if not own or not all(isinstance(name, str) for name in own):
            raise r.fail("recipes", "must be a non-empty list of recipe names")
        for name in own:
            if name not in recipes:
                raise r.fail("recipes", f"unknown recipe {name!r} (defined: {', '.join(names)})")
        starts[vid] = start
        chosen[vid] = list(own)
    return starts, chosen, charges


def _faults(reader: TableReader, starts: dict[int, int]) -> dict[int, Faults]:
    """``[faults]``: link rates for every vehicle, and ``[[faults.vehicles]]`` entries that
    override them or make one vehicle die, stall or lose its battery at a given time."""
    rates = {
        key: reader.number(key, 0.0, 0.0, 1.0)
        for key in ("drop_rate", "corrupt_rate", "spoof_rate", "delay_rate")
    }
    items = reader.get("vehicles", list, [])
    reader.finish()
    if not any(rates.values()) and not items:
        return {}
    faults = {v: Faults(**rates) for v in starts}
    given: dict[int, int] = {}  # vehicle id -> the entry that gave it
    for k, item in enumerate(items):
        if not isinstance(item, dict):
            raise ConfigError(f"{reader.source}: faults.vehicles[{k}]: expected a table")
        r = TableReader(reader.source, item, f"faults.vehicles[{k}].")
        vid = r.integer("id", ..., 1, VEHICLES_PER_BUS * MAX_BUSES)
        if vid not in starts:
            raise r.fail("id", f"no vehicle {vid} in [[vehicles]]")
        if vid in given:  # the later entry would replace the earlier one without a word
            raise r.fail("id", f"vehicle {vid} is already given in faults.vehicles[{given[vid]}]")
        given[vid] = k
        own = {key: r.number(key, rates[key], 0.0, 1.0) for key in rates}
        times = {
            name: r.get(key, float, None)
            for key, name in (
                ("dead_after_s", "dead_after"),
                ("stall_after_s", "stall_after"),
                ("battery_failure_after_s", "battery_failure_after"),
            )
        }
        r.finish()
        for key, value in times.items():
            if value is not None and value < 0:
                raise r.fail(f"{key}_s", f"must be >= 0, got {value}")
        faults[vid] = Faults(**own, **times)
    return faults


def _simulation(r: TableReader) -> AgvParams:
    """``[simulation]``: the simulated vehicles' drive (defaults: the thesis' model AGVs)."""
    d = AgvParams()
    params = AgvParams(
        max_speed=r.number("max_speed", d.max_speed, 0.01, 10.0),
        accel=r.number("accel", d.accel, 0.01, 10.0),
        decel=r.number("decel", d.decel, 0.01, 10.0),
        turn_90=r.number("turn_90_s", d.turn_90, 0.0, 60.0),
        turn_180=r.number("turn_180_s", d.turn_180, 0.0, 60.0),
        length=r.number("length", d.length, 0.01, 20.0),
        sensor_range=r.number("sensor_range", d.sensor_range, 0.0, 20.0),
    )
    r.finish()
    return params


def _blockades(source: str, items: list, plant: Plant) -> list[Blockade]:
    out = []
    for k, item in enumerate(items):
        if not isinstance(item, dict):
            raise ConfigError(f"{source}: blockades[{k}]: expected a table")
        r = TableReader(source, item, f"blockades[{k}].")
        a, b = _node(r, "from", plant), _node(r, "to", plant)
        at = r.number("at_s", 0.0, 0.0)
        until = r.get("until_s", float, None)
        r.finish()
        if not plant.arc_index.get((a, b)) and not plant.arc_index.get((b, a)):
            raise r.fail("to", f"no routable segment between nodes {a} and {b}")
        if until is not None and until <= at:
            raise r.fail("until_s", f"must be after at_s ({at}), got {until}")
        out.append(Blockade(a, b, at, until))
    return out


def first_vehicles(cfg: FleetConfig, n: int) -> None:
    """Keep only the first ``n`` vehicles (by id): a fleet-size experiment on one config."""
    ids = sorted(cfg.starts)
    if not 1 <= n <= len(ids):
        raise ConfigError(
            f"--vehicles-count: must be 1..{len(ids)} (the vehicles of {cfg.source}), got {n}"
        )
    keep = set(ids[:n])
    cfg.vehicles_left_out = set(ids) - keep
    if cfg.order_vehicles and not keep.intersection(cfg.order_vehicles):
        raise ConfigError(
            f"--vehicles-count {n}: the first {n} vehicles of {cfg.source} all run recipes, "
            f"so nobody would take its transport orders (vehicles {', '.join(map(str, cfg.order_vehicles))} do)"
        )
    cfg.starts = {v: s for v, s in cfg.starts.items() if v in keep}
    cfg.vehicle_recipes = {v: r for v, r in cfg.vehicle_recipes.items() if v in keep}
    cfg.order_vehicles = [v for v in cfg.order_vehicles if v in keep]
    cfg.battery.start = {v: c for v, c in cfg.battery.start.items() if v in keep}
    cfg.faults = {v: f for v, f in cfg.faults.items() if v in keep}
