"""The ``kiva`` sample is RHCR's fulfilment map cell for cell.

The expected map is worked out here from the published layout, one cell at a time, and not
from the generator's code: a mistake in the generator must not be copied into the
expectation. The layout: 33 rows x 46 columns; rows 0, 4, .., 32 open; in the three rows of
each band between them, columns 7-16, 18-27 and 29-38 are endpoints in band rows 1 and 3 and
shelves (blocked) in band row 2; columns 1-2, 4-5, 40-41 and 43-44 are home cells."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse.csgraph import connected_components

from fleet.config import parse_config
from plc_runtime.errors import ConfigError
from topology import SAMPLES, Plant, kiva
from topology.validate import validate

WIDTH, HEIGHT = 46, 33
SHELF_COLUMNS = set(range(7, 17)) | set(range(18, 28)) | set(range(29, 39))
HOME_COLUMNS = {1, 2, 4, 5, 40, 41, 43, 44}


def expected_cell(x: int, y: int) -> str:
    """What cell (x, y) of the RHCR map is: "free", "endpoint", "shelf" or "home"."""
    band_row = y % 4
    if band_row == 0:
        return "free"
    if x in SHELF_COLUMNS:
        return "shelf" if band_row == 2 else "endpoint"
    if x in HOME_COLUMNS:
        return "home"
    return "free"


EXPECTED = {(x, y): expected_cell(x, y) for y in range(HEIGHT) for x in range(WIDTH)}


@pytest.fixture(scope="module")
def plant() -> Plant:
    return kiva()


def cell(node_id: int) -> tuple[int, int]:
    y, x = divmod(node_id, WIDTH)
    return x, y


def test_the_expected_map_has_the_published_counts():
    kinds = list(EXPECTED.values())
    assert kinds.count("endpoint") == 480  # 8 bands x 2 rows x 30 columns
    assert kinds.count("shelf") == 240
    assert kinds.count("home") == 192  # 8 columns x 24 rows


def test_size_and_passable_cells(plant):
    assert plant.name == "kiva-33x46"
    assert plant.n == HEIGHT * WIDTH - 240
    passable = {cell(i) for i in plant.ids.tolist()}
    assert all(0 <= x < WIDTH and 0 <= y < HEIGHT for x, y in passable)
    assert max(y for _, y in passable) == HEIGHT - 1 and max(x for x, _ in passable) == WIDTH - 1
    blocked = {c for c, kind in EXPECTED.items() if kind == "shelf"}
    assert passable == set(EXPECTED) - blocked
    for node in plant.nodes:  # positions in metres follow the 1 m cells
        assert (node.x, node.y) == cell(node.id)


def test_stations_are_the_endpoints(plant):
    stations = plant.with_role("station")
    assert len(stations) == 480
    for node_id in stations:
        x, y = cell(node_id)
        assert y % 4 in (1, 3) and x in SHELF_COLUMNS
        assert plant.node(node_id).functions == (2,)
    assert {cell(i) for i in stations} == {c for c, k in EXPECTED.items() if k == "endpoint"}
    assert plant.functions == {2: "pick"}
    assert sorted(plant.stations_for(2)) == sorted(stations)


def test_home_cells_are_parking(plant):
    parking = plant.with_role("parking")
    assert len(parking) == 192
    for node_id in parking:
        x, y = cell(node_id)
        assert y % 4 != 0 and x in HOME_COLUMNS
        assert plant.node(node_id).functions == ()
    assert {cell(i) for i in parking} == {c for c, k in EXPECTED.items() if k == "home"}
    roles = {node.role for node in plant.nodes}
    assert roles == {"transit", "station", "parking"}


def test_open_rows_are_entirely_free(plant):
    for y in range(0, HEIGHT, 4):
        for x in range(WIDTH):
            node_id = y * WIDTH + x
            assert node_id in plant.index, f"open row {y} blocked at column {x}"
            assert plant.node(node_id).role == "transit"


def test_every_shelf_cell_has_an_endpoint_above_and_below(plant):
    stations = set(plant.with_role("station"))
    shelves = [c for c, kind in EXPECTED.items() if kind == "shelf"]
    for x, y in shelves:
        assert y * WIDTH + x not in plant.index
        assert (y - 1) * WIDTH + x in stations and (y + 1) * WIDTH + x in stations


def test_every_endpoint_reaches_every_other(plant):
    n_components, labels = connected_components(plant.csr, directed=True, connection="strong")
    assert n_components == 1
    endpoints = [plant.idx(s) for s in plant.with_role("station")]
    assert len(set(labels[endpoints].tolist())) == 1


def test_neighbours_are_the_four_adjacent_passable_cells(plant):
    csr = plant.csr
    passable = {cell(i) for i in plant.ids.tolist()}
    for node in plant.nodes:
        x, y = cell(node.id)
        row = csr.indices[csr.indptr[plant.idx(node.id)] : csr.indptr[plant.idx(node.id) + 1]]
        got = {cell(int(plant.ids[j])) for j in row}
        want = {(x + dx, y + dy) for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1))} & passable
        assert got == want
    assert np.allclose(csr.data, 1.0)


def test_the_sample_registry_and_validation_accept_it(plant):
    assert list(SAMPLES) == ["model-plant", "warehouse", "grid", "kiva"]
    again = SAMPLES["kiva"]()
    assert again.fingerprint == plant.fingerprint
    assert again.warnings == ()
    assert validate(again) == []


def test_a_fleet_configuration_can_name_it():
    cfg = parse_config(
        """
[plant]
sample = "kiva"

[[recipes]]
name = "pick"
functions = [2]

[[vehicles]]
id = 1
start = 47   # home cell (1, 1)

[[vehicles]]
id = 2
start = 0
""",
        "kiva.toml",
    )
    assert cfg.plant.name == "kiva-33x46"
    assert len(cfg.clusters[2]) == 480
    assert cfg.starts == {1: 47, 2: 0}


def test_an_unknown_sample_names_kiva_among_the_known_ones():
    with pytest.raises(ConfigError, match="kiva"):
        parse_config('[plant]\nsample = "kiva2"\n', "x.toml")


OPEN_COLUMNS = [0, 3, 6, 17, 28, 39, 42, 45]  # the columns without shelf or home cells


def test_long_lanes_are_highways_alternating_like_one_way_streets(plant):
    """Every row along the shelves (all but the shelves' own rows) prefers east, west,
    east, ... from the top; the open columns south, north, ... from the left; the spurs
    into shelf faces and home cells prefer nothing. Every lane stays two-way."""
    lane_rows = [y for y in range(HEIGHT) if y % 4 != 2]
    east = {y: k % 2 == 0 for k, y in enumerate(lane_rows)}
    south = {x: k % 2 == 0 for k, x in enumerate(OPEN_COLUMNS)}
    assert [east[y] for y in (0, 1, 3, 4, 5)] == [True, False, True, False, True]
    for e in plant.edges:
        assert e.bidirectional and e.routable
        (xa, ya), (xb, yb) = cell(e.source), cell(e.target)
        if ya == yb and ya in east:
            assert e.highway and (xb > xa) == east[ya], e
        elif xa == xb and xa in south:
            assert e.highway and (yb > ya) == south[xa], e
        else:
            assert not e.highway, e
    assert int(plant.against_highway.sum()) == sum(e.highway for e in plant.edges)
