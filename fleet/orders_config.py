"""The fleet configuration's order-related sections: ``[orders]`` (where transport orders
come from), ``[dispatch]`` (how they are allocated and executed) and ``[battery]`` (when
vehicles charge). docs/fleet-config.md documents every key; errors name the file and the
key, as everywhere in the configuration.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from blocks.dispatch.charging import ChargePolicy
from blocks.dispatch.generator import SEED_RELATIONS, WINDOW_S, Relation, order_counts
from blocks.dispatch.orders import KEEP_FINAL_S
from blocks.dispatch.strategies import strategy_names
from plc_runtime.errors import ConfigError
from topology import Plant

from .config_reader import TableReader

ESTIMATE_METHODS = ("median", "mean")


@dataclass
class GeneratorConfig:
    """The seed's order generator: ``units`` maps a unit name to the function id whose
    stations make up the unit."""

    duration_s: float
    seed: int
    window_s: float
    units: dict[str, int]
    control: int | None
    relations: tuple[Relation, ...]
    scale: float = 1.0  # multiplies every relation's rate


@dataclass
class OrdersConfig:
    file: Path | None = None
    generator: GeneratorConfig | None = None
    lead_s: float = 600.0  # an order is known this long before its start (the seed's WMS)
    keep_final_s: float = KEEP_FINAL_S  # a final order leaves the book this long after


@dataclass
class DispatchConfig:
    strategy: str = "two_stage"
    buffer_s: float = 38.0
    deviation: float = 0.3
    next_order: bool = True
    bottleneck_s: float = 0.0
    outlier: float = 1.5
    estimate: str = "median"
    budget: int = 500
    interval_s: float = 1.0
    get_s: float = 10.0
    put_s: float = 10.0
    mean_speed: float = 1.0
    park: bool = True
    capacity_per_h: float = 60.0
    out_of_service_s: float = 60.0


@dataclass
class BatteryConfig:
    enabled: bool = True
    critical: float = 15.0
    good: float = 35.0
    sufficient: float = 60.0
    full: float = 95.0
    top_up: bool = True
    top_up_below: float | None = None  # None: ChargePolicy's default, 10 below full
    start: dict[int, float] = field(default_factory=dict)  # vehicle -> start charge %

    def policy(self) -> ChargePolicy:
        levels = (self.critical, self.good, self.sufficient, self.full)
        return ChargePolicy(
            *levels, enabled=self.enabled, top_up=self.top_up, top_up_below=self.top_up_below
        )


def parse_orders(reader: TableReader, base: Path, plant: Plant) -> OrdersConfig:
    file = reader.get("file", str, None)
    lead = reader.number("lead_s", 600.0, 0.0, 1e7)
    given_keep = "keep_final_s" in reader.table
    keep = reader.number("keep_final_s", KEEP_FINAL_S, 0.0, 1e9)
    table = reader.get("generator", dict, None)
    reader.finish()
    path = None
    if file is not None:
        path = Path(file)
        if not path.is_absolute():
            path = base / path
    generator = None
    if table is not None:
        generator = _generator(TableReader(reader.source, table, "orders.generator."), plant)
    if path is None and generator is None and not given_keep:
        raise reader.fail(
            "file", "give orders.file, [orders.generator], or both (or only keep_final_s)"
        )
    return OrdersConfig(path, generator, lead, keep)


def _generator(r: TableReader, plant: Plant) -> GeneratorConfig:
    functions = {f for n in plant.nodes for f in n.functions}
    units = r.get("units", dict)
    for name, f in units.items():
        if not isinstance(f, int) or isinstance(f, bool) or f not in functions:
            raise r.fail(
                f"units.{name}", f"expected a function id of plant {plant.name!r}, got {f!r}"
            )
        _check_stations(r, f"units.{name}", plant, f)
    control = r.get("control", int, None)
    if control is not None:
        if control not in functions:
            raise r.fail("control", f"function {control} is not provided by any node of the plant")
        _check_stations(r, "control", plant, control)
    items = r.get("relations", list, None)
    relations = (
        SEED_RELATIONS
        if items is None
        else tuple(_relation(r, k, it) for k, it in enumerate(items))
    )
    for rel in relations:
        for name in (rel.source, rel.target):
            if name not in units:
                raise r.fail("units", f"relation {rel.source} -> {rel.target} needs unit {name!r}")
    cfg = GeneratorConfig(
        duration_s=r.number("duration_s", 3600.0, 1.0, 1e7),
        seed=r.integer("seed", 0, 0, 2**32 - 1),
        window_s=r.number("window_s", WINDOW_S, 0.0, 1e7),
        units=dict(units),
        control=control,
        relations=tuple(relations),
        scale=r.number("scale", 1.0, 0.0, 1e3),
    )
    r.finish()
    rates = [Relation(rel.source, rel.target, rel.rate_per_h * cfg.scale) for rel in relations]
    try:
        order_counts(rates, cfg.duration_s, control is not None)
    except ValueError as exc:
        raise ConfigError(f"{r.source}: orders.generator: {exc}") from None
    return cfg


def _check_stations(r: TableReader, key: str, plant: Plant, function: int) -> None:
    """The generator makes orders from and to every node of a unit's function, so each must
    be a Get/Put station: checked here, where the key that chose them can be named, not when
    the orders reach the book."""
    stations = set(plant.with_role("station"))
    others = [n for n in plant.stations_for(function) if n not in stations]
    if others:
        listed = ", ".join(map(str, others[:5])) + (", ..." if len(others) > 5 else "")
        nodes = (
            f"node {listed} is not a Get/Put station"
            if len(others) == 1
            else f"nodes {listed} are not Get/Put stations"
        )
        raise r.fail(
            key,
            f"function {function}'s {nodes} "
            "(generated orders fetch and deliver at every node of the function)",
        )


RELATION_KEYS = ("source", "target", "rate_per_h")


def _relation(r: TableReader, k: int, item: object) -> Relation:
    if not isinstance(item, dict):
        raise r.fail(f"relations[{k}]", "expected a table with source, target and rate_per_h")
    unknown = sorted(str(key) for key in set(item) - set(RELATION_KEYS))
    if unknown:
        raise r.fail(
            f"relations[{k}].{unknown[0]}", "unknown key (keys: source, target, rate_per_h)"
        )
    for key in RELATION_KEYS:
        if key not in item:
            raise r.fail(f"relations[{k}].{key}", "missing")
    rate = item["rate_per_h"]
    if not isinstance(rate, int | float) or isinstance(rate, bool) or not 0 <= rate < 1e6:
        raise r.fail(f"relations[{k}].rate_per_h", f"expected a number >= 0, got {rate!r}")
    return Relation(str(item["source"]), str(item["target"]), float(rate))


def parse_dispatch(r: TableReader) -> DispatchConfig:
    cfg = DispatchConfig(
        strategy=r.get("strategy", str, "two_stage"),
        buffer_s=r.number("buffer_s", 38.0, 0.0, 3600.0),
        deviation=r.number("deviation", 0.3, 0.0, 100.0),
        next_order=r.get("next_order", bool, True),
        bottleneck_s=r.number("bottleneck_s", 0.0, 0.0, 3600.0),
        outlier=r.number("outlier", 1.5, 1.0, 100.0),
        estimate=r.get("estimate", str, "median"),
        budget=r.integer("budget", 500, 1, 10**7),
        interval_s=r.number("interval_s", 1.0, 0.0, 3600.0),
        get_s=r.number("get_s", 10.0, 0.0, 3600.0),
        put_s=r.number("put_s", 10.0, 0.0, 3600.0),
        mean_speed=r.number("mean_speed", 1.0, 0.01, 100.0),
        park=r.get("park", bool, True),
        capacity_per_h=r.number("capacity_per_h", 60.0, 0.001, 1e6),
        out_of_service_s=r.number("out_of_service_s", 60.0, 0.0, 86400.0),
    )
    if cfg.strategy not in strategy_names():
        raise r.fail(
            "strategy", f"must be one of {', '.join(strategy_names())}, got {cfg.strategy!r}"
        )
    if cfg.estimate not in ESTIMATE_METHODS:
        raise r.fail(
            "estimate", f"must be one of {', '.join(ESTIMATE_METHODS)}, got {cfg.estimate!r}"
        )
    r.finish()
    return cfg


def parse_battery(r: TableReader) -> BatteryConfig:
    cfg = BatteryConfig(
        enabled=r.get("enabled", bool, True),
        critical=r.number("critical", 15.0, 0.0, 100.0),
        good=r.number("good", 35.0, 0.0, 100.0),
        sufficient=r.number("sufficient", 60.0, 0.0, 100.0),
        full=r.number("full", 95.0, 0.0, 100.0),
        top_up=r.get("top_up", bool, True),
        top_up_below=r.get("top_up_below", float, None),
    )
    r.finish()
    try:
        cfg.policy()
    except ValueError as exc:
        raise ConfigError(f"{r.source}: battery: {exc}") from None
    return cfg
