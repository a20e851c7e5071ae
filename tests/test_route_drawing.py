"""The drawing of a fleet's routes (routes.png): what the picture shows is checked on the
matplotlib figure before it is saved, against values computed here from the routes."""

from __future__ import annotations

import dataclasses
from collections import Counter

import numpy as np
import pytest
from fleet_scenarios import ONE_DRILL
from matplotlib.collections import LineCollection
from matplotlib.colors import to_hex

from fleet.config import parse_config
from fleet.program import FleetProgram
from plc_runtime.clock import VirtualClock
from topology import TopologyError, grid, model_plant, warehouse
from topology.draw import HEATMAP_ABOVE, draw, render, vehicle_colours
from topology.usage import SegmentUsage, segment_usage

# model plant: 0 entry, 23 wash (left edge), 1..5 top crossings, 15..18 top stations,
# 6..9 middle crossings, 10..14 bottom crossings, 19..22 bottom stations, 24 exit;
# 24 -> 0 is the return lane
FLEET = {
    "AGV 1": ([0, 23, 1, 15, 2, 16, 3], [3, 7, 8, 9, 24]),
    "AGV 2": ([9, 24, 0, 6, 7], [7, 3, 17, 4]),
    "AGV 3": ([14, 19, 13, 20, 12], []),
}


def legend_texts(picture) -> list[str]:
    return [t.get_text() for legend in picture.figure.legends for t in legend.get_texts()]


def test_fleet_picture_names_vehicles_return_lane_and_blockades():
    plant = model_plant()
    picture = render(plant, vehicles=FLEET, blocked=[(7, 8), (8, 7)], lifted=[(2, 6)])
    assert picture.mode == "vehicles"
    texts = legend_texts(picture)
    for entry in (
        "AGV 1: at 3 -> 24",
        "AGV 2: at 7 -> 4",
        "AGV 3: at 12",
        "vehicle now",
        "return lane (not routed)",
        "blocked segment (1)",  # both directions of one segment: one blockade
        "blockade lifted during the run (1)",
        "planned",
    ):
        assert entry in texts, (entry, texts)
    assert any(t.startswith("driven: last 8 segments") for t in texts)
    # each vehicle's disc stands on its last driven node, in its legend colour
    vehicle_legend = picture.figure.legends[0]
    colours = {
        t.get_text().split(":")[0]: to_hex(h.get_color())
        for t, h in zip(vehicle_legend.get_texts(), vehicle_legend.legend_handles, strict=True)
    }
    discs = {t.get_text(): t for t in picture.axes.texts if t.get_bbox_patch() is not None}
    for label, (driven, _planned) in FLEET.items():
        disc = discs[label.split()[-1]]
        node = plant.node(driven[-1])
        assert disc.xy == pytest.approx((node.x, -node.y))
        assert to_hex(disc.get_bbox_patch().get_facecolor()) == colours[label]


def test_a_fleet_picture_names_the_blockades_even_when_none_is_in_force():
    texts = legend_texts(render(model_plant(), vehicles=FLEET))
    assert "blocked segment: none now" in texts
    assert not any("lifted" in t for t in texts)


def test_recent_segments_thick_and_opaque_older_ones_faint():
    plant = grid(10, 3, obstacles=0.0)  # node y * 10 + x, one metre apart
    rows = list(range(10)) + list(range(29, 19, -1))  # 0 -> 9, a jump 9 -> 29, 29 -> 20
    picture = render(plant, vehicles={"AGV 1": (rows, [])}, recent=5, earlier=40)
    lines = [c for c in picture.axes.collections if isinstance(c, LineCollection)]
    widths = {float(c.get_linewidths()[0]) for c in lines}
    thick = [c for c in lines if c.get_linewidths()[0] == max(widths)]
    faint = [c for c in lines if c.get_linewidths()[0] < max(widths) and len(c.get_segments())]
    faint = [c for c in faint if to_hex(c.get_colors()[0]) == vehicle_colours(1)[0]]
    # the last five steps (x 5 -> 0 on row 2, drawn at y = -2)
    (strong,) = thick
    midpoints = sorted(round(float(np.mean(s[:, 0])), 1) for s in strong.get_segments())
    assert midpoints == [0.5, 1.5, 2.5, 3.5, 4.5]
    assert all(np.mean(s[:, 1]) == pytest.approx(-2.0, abs=0.2) for s in strong.get_segments())
    assert min(strong.get_colors()[:, 3]) > 0.9
    # the thirteen before them (the jump is no segment, so it is not drawn)
    (older,) = faint
    assert len(older.get_segments()) == 9 + 4
    alphas = older.get_colors()[:, 3]
    assert max(alphas) <= 0.45 and list(alphas) == sorted(alphas)  # fading with age


@pytest.mark.parametrize(
    ("plant", "with_vehicles"),
    [
        (model_plant(), False),  # the legend beside the plant
        (model_plant(), True),  # vehicles beside, the key below
        (warehouse(), True),
        (grid(8, 5, obstacles=0.0), False),
    ],
    ids=["model-plant", "model-plant-fleet", "warehouse-fleet", "grid"],
)
def test_the_plant_fills_the_picture(plant, with_vehicles):
    vehicles = {"AGV 1": ([plant.nodes[0].id], [])} if with_vehicles else None
    picture = render(plant, vehicles=vehicles)
    xs = np.array([n.x for n in plant.nodes])
    ys = -np.array([n.y for n in plant.nodes])
    lengths = [
        np.hypot(*np.subtract(*(plant.positions[plant.idx(i)] for i in (e.source, e.target))))
        for e in plant.edges
    ]
    typical = float(np.median(lengths))
    (x0, x1), (y0, y1) = picture.axes.get_xlim(), picture.axes.get_ylim()
    room = typical * (1.2 if any(not e.routable for e in plant.edges) else 0.5)  # a way round
    assert xs.min() - room <= x0 < xs.min() and xs.max() < x1 <= xs.max() + room
    assert ys.min() - room <= y0 < ys.min() and ys.max() < y1 <= ys.max() + room
    picture.figure.draw_without_rendering()
    axes, page = picture.axes.get_window_extent(), picture.figure.bbox
    assert axes.width / page.width > 0.7 and axes.height / page.height > 0.6


def random_walks(plant, count: int, steps: int, seed: int) -> dict[str, tuple[list, list]]:
    """Walks along the plant's edges (any edge, any direction), standing still now and then,
    with one jump to a node that is no neighbour (a lost position)."""
    rng = np.random.default_rng(seed)
    neighbours: dict[int, list[int]] = {}
    for e in plant.edges:
        neighbours.setdefault(e.source, []).append(e.target)
        neighbours.setdefault(e.target, []).append(e.source)
    ids = plant.ids.tolist()
    walks = {}
    for v in range(count):
        path = [ids[int(rng.integers(len(ids)))]]
        for _ in range(steps):
            options = neighbours.get(path[-1]) or [path[-1]]
            path.append(
                path[-1] if rng.random() < 0.1 else options[int(rng.integers(len(options)))]
            )
        path.append(ids[int(rng.integers(len(ids)))])
        walks[f"AGV {v + 1}"] = (path, [])
    return walks


def counted_here(plant, walks) -> Counter:
    segments = {frozenset((e.source, e.target)) for e in plant.edges}
    counts = Counter()
    for path, _planned in walks.values():
        for a, b in zip(path, path[1:], strict=False):
            if a != b and frozenset((a, b)) in segments:
                counts[(min(a, b), max(a, b))] += 1
    return counts


@pytest.mark.parametrize("plant", [model_plant(), grid(9, 7, 0.15, seed=3)], ids=lambda p: p.name)
def test_counting_step_by_step_gives_the_heat_maps_counts(plant):
    """A controller keeps only its vehicles' newest nodes and counts each step as driven;
    the drawing counts whole paths. Standing still, jumps and both directions alike."""
    walks = random_walks(plant, 5, steps=60, seed=11)
    usage = SegmentUsage(plant)
    for path, _planned in walks.values():
        for a, b in zip(path, path[1:], strict=False):
            usage.step(a, b)
    assert usage.counts == counted_here(plant, walks) != {}
    assert segment_usage(plant, (path for path, _ in walks.values())) == usage.counts


@pytest.mark.parametrize("plant", [model_plant(), grid(9, 7, 0.15, seed=3)], ids=lambda p: p.name)
def test_more_than_20_vehicles_make_a_heat_map_of_segment_usage(plant):
    walks = random_walks(plant, HEATMAP_ABOVE + 1, steps=60, seed=7)
    picture = render(plant, vehicles=walks)
    assert picture.mode == "heatmap"
    expected = counted_here(plant, walks)
    assert picture.usage == dict(expected)
    # the coloured lines carry exactly those counts, segment by segment
    where = {(n.x, -n.y): n.id for n in plant.nodes}
    (usage,) = [c for c in picture.axes.collections if c.get_gid() == "segment-usage"]
    drawn = {}
    for segment, value in zip(usage.get_segments(), usage.get_array(), strict=True):
        a, b = (where[tuple(p)] for p in segment)
        drawn[(min(a, b), max(a, b))] = int(value)
    return_lanes = {
        (min(e.source, e.target), max(e.source, e.target)) for e in plant.edges if not e.routable
    }
    assert drawn == {k: v for k, v in expected.items() if k not in return_lanes}
    assert all(k in expected for k in return_lanes)  # counted too, drawn the way round
    # a colour bar, and the vehicles' positions are named in the key
    assert len(picture.figure.axes) == 2
    assert "times driven" in picture.figure.axes[1].get_ylabel()
    assert f"vehicle now ({HEATMAP_ABOVE + 1})" in legend_texts(picture)


def test_every_vehicle_gets_a_distinct_colour():
    for count in range(1, HEATMAP_ABOVE + 1):
        assert len(set(vehicle_colours(count))) == count
    plant = warehouse()
    starts = plant.ids[:: plant.n // HEATMAP_ABOVE][:HEATMAP_ABOVE].tolist()
    fleet = {f"AGV {k + 1}": ([s], []) for k, s in enumerate(starts)}
    picture = render(plant, vehicles=fleet)
    assert picture.mode == "vehicles"  # 20 vehicles still get their routes drawn
    handles = picture.figure.legends[0].legend_handles
    assert len({to_hex(h.get_color()) for h in handles}) == HEATMAP_ABOVE


def test_draw_writes_the_png(tmp_path):
    out = draw(model_plant(), tmp_path / "routes.png", vehicles=FLEET, blocked=[(7, 8)])
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(TopologyError, match="recent must be >= 1"):
        draw(model_plant(), tmp_path / "routes.png", vehicles=FLEET, recent=0)


def test_a_long_name_is_cut_in_the_title_not_a_reason_to_fail():
    """The longest name a plant may have: the title's line is cut with an ellipsis, the
    page stays the width of the plant's picture."""
    picture = render(dataclasses.replace(model_plant(), name="x" * 1024))
    title = picture.axes.get_title()
    assert len(title.split("\n")[0]) == 120 and title.endswith("\u2026")
    assert picture.figure.get_size_inches()[0] == render(model_plant()).figure.get_size_inches()[0]


def test_the_fleet_report_hands_over_whole_routes_and_lifted_blockades(tmp_path, monkeypatch):
    import fleet.report as report

    cfg = parse_config(
        ONE_DRILL
        + """
        [[vehicles]]
        id = 2
        start = 10
        [[blockades]]
        from = 7
        to = 8
        at_s = 1
        until_s = 2
        [[blockades]]
        from = 8
        to = 13
        at_s = 1
        """
    )
    cfg.watchdog = 5.0  # behaviour, not wall time: a busy machine must not fault a scan
    program = FleetProgram(cfg, clock=VirtualClock())
    try:
        program.rt.start()
        program.rt.step(round(10 / cfg.cycle_time))
    finally:
        program.close()
    calls = []
    monkeypatch.setattr("topology.draw.draw", lambda plant, path, **kw: calls.append(kw) or path)
    report.write_drawing(program, tmp_path / "routes.png")
    (kwargs,) = calls
    for v in (1, 2):  # the routes kept: the drawing picks the newest segments itself
        assert kwargs["vehicles"][f"AGV {v}"][0] == program.recorder.driven[v]
    assert len(program.recorder.driven[1]) > 3
    texts = legend_texts(render(cfg.plant, **kwargs))
    assert "blocked segment (1)" in texts and "blockade lifted during the run (1)" in texts


def test_segments_an_operator_closes_and_reopens_are_in_the_summary_and_drawing(
    tmp_path, monkeypatch
):
    """The blockade command of the Modbus map (and the web API, which does the same) changes
    the plant as the configured schedule does, so the run's report lists it the same way."""
    import fleet.report as report
    from fleet.tags import CLOSE, REOPEN

    cfg = parse_config(ONE_DRILL)
    cfg.watchdog = 5.0  # behaviour, not wall time: a busy machine must not fault a scan
    program = FleetProgram(cfg, clock=VirtualClock())
    image = program.rt.image
    try:
        program.rt.start()
        for seq, (code, a, b, seconds) in enumerate(
            [(CLOSE, 7, 8, 1), (CLOSE, 13, 8, 1), (REOPEN, 8, 7, 2)], start=1
        ):
            image.write_many(
                {"fleet.cmd.a": a, "fleet.cmd.b": b, "fleet.cmd.code": code, "fleet.cmd.seq": seq}
            )
            program.rt.step(round(seconds / cfg.cycle_time))
        result = report.summary(program, wall_s=1.0)
    finally:
        program.close()
    assert [(c["event"], c["segment"]) for c in result["blockades"]] == [
        ("closed", [7, 8]),
        ("closed", [8, 13]),
        ("reopened", [7, 8]),
    ]
    assert [c["time_s"] for c in result["blockades"]] == pytest.approx([0.0, 1.0, 2.0], abs=0.1)
    calls = []
    monkeypatch.setattr("topology.draw.draw", lambda plant, path, **kw: calls.append(kw) or path)
    report.write_drawing(program, tmp_path / "routes.png")
    (kwargs,) = calls
    assert kwargs["lifted"] == [(7, 8)]
    assert {(min(a, b), max(a, b)) for a, b in kwargs["blocked"]} == {(8, 13)}
