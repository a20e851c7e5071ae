"""The fleet endpoints of the HTTP API (fleet/web) against a running controller on 127.0.0.1:
plant, vehicles, blockades, the watch table with write and force, statistics, events, the
live stream, the page's files, the rate limit and the ``[web]`` configuration key.

Every error path is checked with what it must leave unchanged. The orders' own endpoints
are tested in test_order_api.py. Where a test waits for the running scan, it polls with a
wall-clock deadline far beyond what the simulated time needs, and asserts no duration.
"""

from __future__ import annotations

import argparse
import http.client
import json
import time
from pathlib import Path

import pytest
from web_controller import ROOT, TOKEN, WAIT_WALL_S, Controller, eventually

from fleet.config import load_config, parse_config
from fleet.web.feed import LiveFeed
from fleet.web.guard import Guard, client_key
from fleet.web.options import web_options
from plc_runtime.errors import ConfigError

API = "/api/v1"
RECIPES_ONLY = ROOT / "examples" / "workshop.toml"
JSON = {"Content-Type": "application/json"}
FORM = {"Content-Type": "application/x-www-form-urlencoded"}
VND = {"Content-Type": "application/vnd.foo+json"}
LATIN1 = {"Content-Type": "application/json; charset=latin-1"}
QUOTED = {"Content-Type": 'application/json; charset="UTF-8"'}


@pytest.fixture(scope="module")
def ctl():
    with Controller() as controller:
        yield controller


def segment_of(ctl: Controller) -> tuple[int, int]:
    """A segment of the plant that no test closes for good."""
    edge = ctl.call("GET", f"{API}/plant").body["edges"][0]
    return edge["a"], edge["b"]


def is_closed(ctl: Controller, a: int, b: int) -> bool:
    """Whether both directions of a-b are closed in the program's routing constraints."""
    closed = set(ctl.program.blockades.blocked_segments())
    return (a, b) in closed and (b, a) in closed


# ----- the schema -------------------------------------------------------------------------------
def test_openapi_describes_the_fleet_endpoints_and_which_need_the_token(ctl):
    paths = ctl.call("GET", "/openapi.json").body["paths"]
    expected = {
        f"{API}/plant": {"get"},
        f"{API}/vehicles": {"get"},
        f"{API}/vehicles/{{vehicle}}": {"get"},
        f"{API}/blockades": {"get"},
        f"{API}/blockades/{{a}}/{{b}}": {"put", "delete"},
        f"{API}/tags": {"get"},
        f"{API}/tags/values": {"get"},
        f"{API}/tags/{{name}}": {"get", "put"},
        f"{API}/tags/{{name}}/force": {"put", "delete"},
        f"{API}/stats": {"get"},
        f"{API}/events": {"get"},
        f"{API}/stream": {"get"},
    }
    for path, methods in expected.items():
        assert set(paths[path]) == methods, path
        for method in methods:
            needs_token = "security" in paths[path][method]
            assert needs_token == (method != "get"), (path, method)
    assert "text/event-stream" in paths[f"{API}/stream"]["get"]["responses"]["200"]["content"]
    assert "/" not in paths  # the page is not part of the API


# ----- plant and vehicles -------------------------------------------------------------------------
def test_plant_is_the_configured_one(ctl):
    plant = ctl.program.cfg.plant
    body = ctl.call("GET", f"{API}/plant").body
    assert body["name"] == plant.name
    assert [n["id"] for n in body["nodes"]] == [n.id for n in plant.nodes]
    assert {(n["x"], n["y"]) for n in body["nodes"]} == {(n.x, n.y) for n in plant.nodes}
    assert len(body["edges"]) == len(plant.edges)
    assert set(body["stations"]) == set(plant.with_role("station"))
    assert set(body["chargers"]) == set(plant.with_role("charger"))
    assert body["queues"] == {str(s): list(q) for s, q in plant.queues.items()}
    assert [(e["a"], e["b"], e["bidirectional"], e["highway"]) for e in body["edges"]] == [
        (e.source, e.target, e.bidirectional, e.highway) for e in plant.edges
    ]


def test_vehicles_list_every_vehicle_with_what_the_controller_knows(ctl):
    eventually(
        lambda: all(v["node"] is not None for v in ctl.call("GET", f"{API}/vehicles").body),
        "every vehicle's node",
    )
    body = ctl.call("GET", f"{API}/vehicles").body
    assert [v["id"] for v in body] == ctl.program.vehicles
    for v in body:
        assert v["node"] in ctl.program.cfg.plant.index
        assert isinstance(v["state"], str) and isinstance(v["released"], list)
        assert 0 <= v["battery"] <= 100
    one = ctl.call("GET", f"{API}/vehicles/{body[0]['id']}")
    assert one.status == 200 and one.body["id"] == body[0]["id"]


def test_a_driving_vehicle_shows_its_released_and_planned_route(ctl):
    def moving():
        return [v for v in ctl.call("GET", f"{API}/vehicles").body if v["released"]]

    v = eventually(moving, "a vehicle with a released route")[0]
    route = [v["node"], *v["released"], *v["planned"]]
    arcs = ctl.program.cfg.plant.arc_index
    assert all((a, b) in arcs for a, b in zip(route, route[1:], strict=False)), route


@pytest.mark.parametrize(
    ("path", "status", "field"),
    [(f"{API}/vehicles/99", 404, "vehicle"), (f"{API}/vehicles/x", 422, "vehicle")],
)
def test_an_unknown_vehicle_is_a_json_error(ctl, path, status, field):
    reply = ctl.call("GET", path)
    assert (reply.status, reply.body["field"]) == (status, field)
    assert reply.body["error"]


# ----- blockades --------------------------------------------------------------------------------
def test_a_blockade_is_set_and_cleared_with_the_token_and_logged(ctl):
    a, b = segment_of(ctl)
    last = ctl.call("GET", f"{API}/events?limit=1").body["last"]
    closed = ctl.call("PUT", f"{API}/blockades/{b}/{a}", token=TOKEN)
    assert closed.status == 200
    assert closed.body == {"a": min(a, b), "b": max(a, b), "closed": True}
    assert [min(a, b), max(a, b)] in ctl.call("GET", f"{API}/blockades").body
    assert [min(a, b), max(a, b)] in ctl.call("GET", f"{API}/plant").body["blockades"]
    assert is_closed(ctl, a, b)

    def logged():
        events = ctl.call("GET", f"{API}/events?after={last}").body["events"]
        return [e for e in events if e["kind"] == "blockade"]

    assert eventually(logged, "the blockade's event")[0]["text"] == (
        f"segment {min(a, b)}-{max(a, b)} closed"
    )
    reopened = ctl.call("DELETE", f"{API}/blockades/{a}/{b}", token=TOKEN)
    assert reopened.body["closed"] is False
    assert [min(a, b), max(a, b)] not in ctl.call("GET", f"{API}/blockades").body


@pytest.mark.parametrize(
    ("method", "path", "token", "status", "field"),
    [
        ("PUT", "{a}/{b}", None, 401, None),
        ("PUT", "{a}/{b}", "wrong-token-0123456789", 403, None),
        ("DELETE", "{a}/{b}", None, 401, None),
        ("PUT", "9999/{b}", TOKEN, 404, "a"),
        ("PUT", "{a}/9999", TOKEN, 404, "b"),
        ("PUT", "{a}/{a}", TOKEN, 404, "b"),
        ("PUT", "{a}/x", TOKEN, 422, "b"),
        ("PUT", "{a}/70000", TOKEN, 422, "b"),
    ],
)
def test_a_bad_blockade_request_is_refused_and_closes_nothing(
    ctl, method, path, token, status, field
):
    a, b = segment_of(ctl)
    epoch = ctl.program.blockades.epoch
    reply = ctl.call(method, f"{API}/blockades/" + path.format(a=a, b=b), token=token)
    assert (reply.status, reply.body["field"]) == (status, field), reply.body
    assert reply.body["error"]
    assert ctl.program.blockades.epoch == epoch
    assert ctl.call("GET", f"{API}/blockades").body == []


def test_a_blockade_on_a_route_makes_the_vehicle_go_round(ctl):
    """Close a segment a vehicle is about to drive (released or planned beyond its next
    node): its route changes and never uses the closed segment while it is closed."""
    plant = ctl.program.cfg.plant

    def candidate():
        for v in ctl.call("GET", f"{API}/vehicles").body:
            route = [*v["released"], *v["planned"]]
            for x, y in zip(route[1:], route[2:], strict=False):
                both = (x, y) in plant.arc_index and (y, x) in plant.arc_index
                if both and not is_closed(ctl, x, y):
                    return v["id"], x, y
        return None

    vehicle, x, y = eventually(candidate, "a vehicle with two segments ahead")
    assert ctl.call("PUT", f"{API}/blockades/{x}/{y}", token=TOKEN).status == 200
    try:

        def rerouted():
            v = ctl.call("GET", f"{API}/vehicles/{vehicle}").body
            route = [v["node"], *v["released"], *v["planned"]]
            pairs = set(zip(route, route[1:], strict=False))
            return (x, y) not in pairs and (y, x) not in pairs

        eventually(rerouted, f"agv{vehicle}'s route without segment {x}-{y}")
    finally:
        ctl.call("DELETE", f"{API}/blockades/{x}/{y}", token=TOKEN)


# ----- the watch table: read, write, force --------------------------------------------------------
def test_tags_are_listed_with_their_access(ctl):
    tags = {t["name"]: t for t in ctl.call("GET", f"{API}/tags").body}
    assert tags["agv1.hold"]["writable"] and not tags["agv1.node"]["writable"]
    assert tags["agv1.node"]["address"] == "%MW64"
    assert len(tags) == len(ctl.program.rt.image.tags)


def test_watch_reads_values_as_the_image_holds_them(ctl):
    eventually(lambda: ctl.call("GET", f"{API}/tags/agv1.node").body["value"] != 0xFFFF, "a node")
    rows = ctl.call("GET", f"{API}/tags/values?names=agv1.node,fleet.vehicles").body
    assert [r["name"] for r in rows] == ["agv1.node", "fleet.vehicles"]
    assert rows[1]["value"] == len(ctl.program.vehicles)
    assert rows[0]["value"] in ctl.program.cfg.plant.index
    assert not rows[0]["forced"] and rows[0]["forced_value"] is None


@pytest.mark.parametrize(
    ("path", "status", "field"),
    [
        (f"{API}/tags/values?names=agv1.node,nope", 404, "names[1]"),
        (f"{API}/tags/nope", 404, "name"),
        (f"{API}/tags/values?names=" + ",".join(["agv1.node"] * 201), 422, "names"),
        (f"{API}/tags/values", 422, "names"),
    ],
)
def test_a_bad_watch_request_is_a_json_error(ctl, path, status, field):
    reply = ctl.call("GET", path)
    assert (reply.status, reply.body["field"]) == (status, field), reply.body


def test_a_writable_tag_is_written_forced_and_unforced(ctl):
    """agv2.hold: written 1, the vehicle is held; forced 1 and written 0, the force wins;
    unforced, the forced value stays (nobody else writes it) until 0 is written."""
    written = ctl.call("PUT", f"{API}/tags/agv2.hold", {"value": 1}, token=TOKEN)
    assert written.status == 200 and written.body["value"] == 1
    eventually(lambda: ctl.call("GET", f"{API}/vehicles/2").body["held"], "agv2 held")
    forced = ctl.call("PUT", f"{API}/tags/agv2.hold/force", {"value": 1}, token=TOKEN)
    assert forced.body["forced"] and forced.body["forced_value"] == 1
    assert ctl.program.rt.image.forces == {"agv2.hold": 1}
    assert ctl.call("PUT", f"{API}/tags/agv2.hold", {"value": 0}, token=TOKEN).status == 200
    cycles = ctl.program.rt.ticks
    eventually(lambda: ctl.program.rt.ticks > cycles + 2, "two more scans")
    assert ctl.call("GET", f"{API}/tags/agv2.hold").body["value"] == 1  # the force wins
    assert ctl.call("GET", f"{API}/vehicles/2").body["held"]
    unforced = ctl.call("DELETE", f"{API}/tags/agv2.hold/force", token=TOKEN)
    assert not unforced.body["forced"] and ctl.program.rt.image.forces == {}
    cycles = ctl.program.rt.ticks
    eventually(lambda: ctl.program.rt.ticks > cycles + 2, "two more scans")
    assert ctl.call("GET", f"{API}/tags/agv2.hold").body["value"] == 1
    assert ctl.call("GET", f"{API}/vehicles/2").body["held"]
    ctl.call("PUT", f"{API}/tags/agv2.hold", {"value": 0}, token=TOKEN)
    eventually(lambda: not ctl.call("GET", f"{API}/vehicles/2").body["held"], "agv2 released")


@pytest.mark.parametrize(
    ("method", "path", "body", "token", "status", "field"),
    [
        ("PUT", "agv1.node", {"value": 3}, TOKEN, 403, "name"),
        ("PUT", "agv1.node/force", {"value": 3}, TOKEN, 403, "name"),
        ("DELETE", "fleet.vehicles/force", None, TOKEN, 403, "name"),
        ("PUT", "nope", {"value": 3}, TOKEN, 404, "name"),
        ("PUT", "agv1.hold", {"value": 1}, None, 401, None),
        ("PUT", "agv1.hold/force", {"value": 1}, "wrong-token-0123456789", 403, None),
        ("PUT", "agv1.hold", {"value": "1"}, TOKEN, 422, "value"),
        ("PUT", "agv1.hold", {"value": 70000}, TOKEN, 422, "value"),
        ("PUT", "agv1.hold", {"value": -1}, TOKEN, 422, "value"),
        ("PUT", "agv1.hold", {"value": 1, "extra": 2}, TOKEN, 422, "extra"),
        ("PUT", "agv1.hold", {}, TOKEN, 422, "value"),
    ],
)
def test_a_bad_write_is_refused_and_changes_nothing(ctl, method, path, body, token, status, field):
    before = ctl.call("GET", f"{API}/tags/values?names=agv1.hold,agv1.node").body
    reply = ctl.call(method, f"{API}/tags/{path}", body, token=token)
    assert (reply.status, reply.body["field"]) == (status, field), reply.body
    assert reply.body["error"] and reply.body["error"].count(", got ") <= 1, reply.body
    assert ctl.program.rt.image.forces == {}
    after = ctl.call("GET", f"{API}/tags/values?names=agv1.hold").body
    assert after[0]["value"] == before[0]["value"] == 0


@pytest.mark.parametrize(
    ("method", "path", "raw", "headers", "status", "error"),
    [
        ("PUT", "tags/agv1.hold", b'{"value": 1, "x": 2}', JSON, 422, "unknown (fields: value)"),
        ("PUT", "tags/agv1.hold", b"[1]", JSON, 422, "a JSON object with the fields value"),
        ("PUT", "tags/agv1.hold", b'{"value": 1}', {}, 415, "no Content-Type"),
        ("PUT", "tags/agv1.hold/force", b'{"value": 1}', FORM, 415, "x-www-form-urlencoded"),
        ("POST", "orders", b'{"id": "f", "get": 21, "put": 23}', FORM, 415, "Content-Type"),
        ("POST", "orders", b'{"id": "f", "get": 21, "put": 23}', VND, 415, "vnd.foo+json"),
        ("PUT", "tags/agv1.hold", b'{"value": 1}', LATIN1, 415, "charset=latin-1"),
        ("PUT", "tags/agv1.hold", '{"value": 1}'.encode("utf-16"), JSON, 400, "UTF-8"),
        ("PUT", "tags/agv1.hold", b'\xef\xbb\xbf{"value": 1}', JSON, 400, "byte order mark"),
    ],
)
def test_a_body_not_sent_as_the_routes_json_says_what_the_route_takes(
    ctl, method, path, raw, headers, status, error
):
    """Each route names its own body's fields, and a body sent as a form (``curl -d``
    alone) is told to send JSON, not that its fields are wrong."""
    reply = ctl.call(method, f"{API}/{path}", raw=raw, token=TOKEN, headers=headers)
    assert reply.status == status and error in reply.body["error"], reply.body
    assert "get" not in reply.body["error"] or path == "orders"
    assert ctl.program.rt.image.forces == {}
    assert ctl.call("GET", f"{API}/tags/agv1.hold").body["value"] == 0


@pytest.mark.parametrize(
    ("path", "field"),
    [("orders?offest=200&limit=1", "offest"), ("events?afterr=5", "afterr")],
)
def test_a_query_parameter_the_request_does_not_take_is_refused(ctl, path, field):
    """A typo is not ignored: the client would be served what it did not ask for."""
    reply = ctl.call("GET", f"{API}/{path}")
    assert reply.status == 422 and reply.body["field"] == field, reply.body
    assert "not a parameter of this request" in reply.body["error"]


def test_a_quoted_utf_8_charset_is_json_too(ctl):
    reply = ctl.call(
        "PUT", f"{API}/tags/agv2.hold", raw=b'{"value": 0}', token=TOKEN, headers=QUOTED
    )
    assert reply.status == 200, reply.body


def test_a_write_with_a_query_parameter_it_does_not_take_is_refused_and_changes_nothing(ctl):
    reply = ctl.call("PUT", f"{API}/tags/agv2.hold?dry_run=1", {"value": 1}, token=TOKEN)
    assert reply.status == 422 and reply.body["field"] == "dry_run", reply.body
    assert "not a parameter of this request (none)" in reply.body["error"]
    assert ctl.call("GET", f"{API}/tags/agv2.hold").body["value"] == 0


def test_a_request_that_takes_no_parameters_ignores_one_as_a_cache_would_add():
    """The page, the plant and the like take none: a link with ``?v=2`` is still served."""
    with Controller() as ctl:
        assert ctl.call("GET", f"{API}/plant?v=2").status == 200
        assert ctl.call("GET", f"{API}/plant?v=2&v=3").status == 200  # ignored, however often
        conn = http.client.HTTPConnection("127.0.0.1", ctl.port, timeout=30)
        try:
            conn.request("GET", "/?v=2")
            page = conn.getresponse()
            assert page.status == 200 and b"<html" in page.read().lower()
        finally:
            conn.close()


@pytest.mark.parametrize("name", ["Authorization", "Content-Type"])
def test_a_header_given_twice_is_refused_whichever_comes_first(ctl, name):
    """With two tokens, one check could read one and another the other: a wrong token
    before or after the right one is 400, and nothing is written."""
    value = {"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"}[name]
    other = {"Authorization": "Bearer wrong-token-xxxxxxxxxx", "Content-Type": "text/plain"}[name]
    for pair in ((value, other), (other, value)):
        conn = http.client.HTTPConnection("127.0.0.1", ctl.port, timeout=30)
        try:
            conn.putrequest("PUT", f"{API}/tags/agv3.hold")
            for v in pair:
                conn.putheader(name, v)
            if name != "Authorization":
                conn.putheader("Authorization", f"Bearer {TOKEN}")
            else:
                conn.putheader("Content-Type", "application/json")
            conn.putheader("Content-Length", "12")
            conn.endheaders(b'{"value": 1}')
            reply = conn.getresponse()
            body = json.loads(reply.read())
        finally:
            conn.close()
        assert reply.status == 400, body
        assert body["error"] == f"header '{name.lower()}' given more than once"
    assert ctl.call("GET", f"{API}/tags/agv3.hold").body["value"] == 0


# ----- statistics and events ----------------------------------------------------------------------
def test_stats_are_the_runtimes(ctl):
    body = ctl.call("GET", f"{API}/stats").body
    assert body["state"] == "RUN" and body["cycles"] > 0
    assert set(body["tasks"]) == {"fleet", "plant"}
    assert {"p50", "p99", "max"} <= set(body["scan"]["exec_us"])
    assert body["drivers"]["web"]["port"] == ctl.port
    assert body["fleet"]["vehicles"] == len(ctl.program.vehicles)
    assert body["fleet"]["head_on_conflicts"] == 0 and body["fleet"]["node_conflicts"] == 0


def test_events_page_by_their_number(ctl):
    a, b = segment_of(ctl)
    before = ctl.call("GET", f"{API}/events?limit=1").body["last"]
    for i, method in enumerate(("PUT", "DELETE")):  # an event each
        ctl.call(method, f"{API}/blockades/{a}/{b}", token=TOKEN)
        eventually(
            lambda m=method, i=i: (
                is_closed(ctl, a, b) == (m == "PUT")
                and ctl.call("GET", f"{API}/events?limit=1").body["last"] >= before + i + 1
            ),
            "the events",
        )
    body = ctl.call("GET", f"{API}/events?limit=500").body
    seqs = [e["seq"] for e in body["events"]]
    assert seqs == list(range(body["first"], body["first"] + len(seqs)))
    later = ctl.call("GET", f"{API}/events?after={seqs[-2]}").body["events"]
    assert later[0]["seq"] == seqs[-1] and later[0] == body["events"][-1]
    assert ctl.call("GET", f"{API}/events?limit=501").status == 422
    assert ctl.call("GET", f"{API}/events?after=-1").body["field"] == "after"


# ----- the stream -------------------------------------------------------------------------------
def read_snapshots(port: int, n: int, wall_s: float = WAIT_WALL_S) -> tuple[list[dict], float]:
    """The first ``n`` snapshots of a new stream, and the wall seconds they took."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=wall_s)
    try:
        conn.request("GET", f"{API}/stream")
        reply = conn.getresponse()
        assert reply.status == 200
        assert reply.getheader("content-type").startswith("text/event-stream")
        snapshots, event, started = [], None, time.monotonic()
        while len(snapshots) < n:
            line = reply.fp.readline().decode().rstrip("\n")
            if line.startswith("event: "):
                event = line.removeprefix("event: ")
            elif line.startswith("data: "):
                assert event == "snapshot"
                snapshots.append(json.loads(line.removeprefix("data: ")))
        return snapshots, time.monotonic() - started
    finally:
        conn.close()


def test_the_stream_pushes_vehicles_and_orders_at_a_bounded_rate(ctl):
    snapshots, took_s = read_snapshots(ctl.port, 12)
    # at most 10 a second, less the tenth of a period the publisher allows for the scan's
    # phase (the first may be one published before this client came)
    assert len(snapshots) - 2 <= took_s / (0.9 * 0.1)
    times = [s["sim_time_s"] for s in snapshots]
    assert times == sorted(times) and times[-1] > times[0]
    first, last = snapshots[0], snapshots[-1]
    # the first is whole; the others name the vehicles that changed (the whole one again
    # after a snapshot this client missed)
    assert first["full"] and [v["id"] for v in first["vehicles"]] == ctl.program.vehicles
    assert first["orders"]["resync"]
    for s in snapshots[1:]:
        ids = [v["id"] for v in s["vehicles"]]
        assert ids == sorted(set(ids)) and set(ids) <= set(ctl.program.vehicles)
        assert s["full"] or not s["orders"]["resync"]
    assert set(last["orders"]["counts"]) >= {"DISPATCHABLE", "BEING_PROCESSED", "FINISHED"}
    assert last["fleet"]["vehicles"] == len(ctl.program.vehicles)
    assert "speed_cm_s" not in first["vehicles"][0]


def test_the_stream_sends_the_orders_that_changed(ctl):
    conn = http.client.HTTPConnection("127.0.0.1", ctl.port, timeout=WAIT_WALL_S)
    try:
        conn.request("GET", f"{API}/stream")
        reply = conn.getresponse()
        order = {"id": "stream-1", "get": 21, "put": 23}
        assert ctl.call("POST", f"{API}/orders", order, token=TOKEN).status == 201
        seen: dict[str, str] = {}
        deadline = time.monotonic() + WAIT_WALL_S * 2
        while seen.get("stream-1") != "FINISHED" and time.monotonic() < deadline:
            line = reply.fp.readline().decode()
            if line.startswith("data: "):
                orders = json.loads(line.removeprefix("data: "))["orders"]
                seen |= {o["id"]: o["state"] for o in orders["changed"]}
                if orders["resync"]:  # missed one (a busy machine): as a client, read it
                    seen["stream-1"] = ctl.call("GET", f"{API}/orders/stream-1").body["state"]
        assert seen.get("stream-1") == "FINISHED"
    finally:
        conn.close()


def test_a_client_that_does_not_read_holds_back_nobody(ctl):
    """A stream nobody reads: the others get their snapshots and the scan goes on (the
    feed keeps the newest snapshot only, never a queue per client)."""
    stalled = http.client.HTTPConnection("127.0.0.1", ctl.port, timeout=WAIT_WALL_S)
    try:
        stalled.request("GET", f"{API}/stream")
        assert stalled.getresponse().status == 200  # and never read from again
        cycles = ctl.program.rt.ticks
        snapshots, _ = read_snapshots(ctl.port, 20)
        assert snapshots[-1]["cycles"] > cycles
    finally:
        stalled.close()


def test_streams_are_limited_and_their_places_given_back():
    with Controller(max_streams=2) as ctl:
        first = http.client.HTTPConnection("127.0.0.1", ctl.port, timeout=WAIT_WALL_S)
        second = http.client.HTTPConnection("127.0.0.1", ctl.port, timeout=WAIT_WALL_S)
        try:
            for conn in (first, second):
                conn.request("GET", f"{API}/stream")
                assert conn.getresponse().status == 200
            eventually(lambda: ctl.web.feed.streams == 2, "two streams")
            third = ctl.call("GET", f"{API}/stream")
            assert third.status == 503 and "stream" in third.body["error"]
            assert ctl.call("GET", f"{API}/stats").status == 200  # the rest still answers
        finally:
            first.close()
        eventually(lambda: ctl.web.feed.streams == 1, "a place given back")
        second.close()
        snapshots, _ = read_snapshots(ctl.port, 1)
        assert snapshots


def test_the_feed_copies_nothing_while_nobody_listens():
    """No client, no snapshot: the scan pays nothing for the stream."""
    cfg = load_config(RECIPES_ONLY)
    from fleet.program import FleetProgram

    program = FleetProgram(cfg)
    try:
        feed = LiveFeed(program)
        program.rt.start()
        program.rt.step(20)
        assert feed.due_snapshot() is None and feed.published == 0
    finally:
        program.close()


# ----- a run without transport orders ------------------------------------------------------------
def test_a_recipe_fleet_is_served_and_refuses_orders():
    with Controller(config=RECIPES_ONLY) as ctl:
        assert len(ctl.call("GET", f"{API}/vehicles").body) == len(ctl.program.vehicles)
        assert ctl.call("GET", f"{API}/orders").body == {
            "total": 0,
            "offset": 0,
            "orders": [],
            "next_offset": 0,
            "added": 0,
        }
        assert ctl.call("GET", f"{API}/orders/x").status == 404
        added = ctl.call("POST", f"{API}/orders", {"id": "a", "get": 1, "put": 2}, token=TOKEN)
        assert added.status == 409 and "no vehicle of this run takes" in added.body["error"]
        snapshot = read_snapshots(ctl.port, 1)[0][0]
        assert "orders" not in snapshot and snapshot["vehicles"]


# ----- the page ---------------------------------------------------------------------------------
def test_the_page_and_its_files_are_served_with_a_strict_policy(ctl):
    conn = http.client.HTTPConnection("127.0.0.1", ctl.port, timeout=30)
    try:
        for path, kind in (("/", "text/html"), ("/static/app.js", "javascript")):
            conn.request("GET", path)
            reply = conn.getresponse()
            body = reply.read()
            assert reply.status == 200 and kind in reply.getheader("content-type"), path
            assert "default-src 'self'" in reply.getheader("content-security-policy")
            assert body
        for path in ("/static/../server.py", "/static/%2e%2e/server.py", "/static/nope.js"):
            conn.request("GET", path)
            reply = conn.getresponse()
            reply.read()
            assert reply.status == 404, path
    finally:
        conn.close()


# ----- the rate limit ---------------------------------------------------------------------------
def test_the_rate_is_limited_per_client_with_a_json_error():
    """A bucket of ``max_rate`` requests a second: with the guard's clock held still, the
    first 3 pass, the 4th gets 429 with Retry-After, and the scan is not asked."""
    with Controller(max_rate=3) as ctl:
        ctl.web.guard.clock = lambda: 1000.0
        replies = [ctl.call("GET", f"{API}/plant") for _ in range(4)]
        assert [r.status for r in replies] == [200, 200, 200, 429]
        assert "3 per second" in replies[3].body["error"]
        assert replies[3].headers["retry-after"] == "1"
        ctl.web.guard.clock = lambda: 1001.0  # a second later: the bucket is full again
        assert ctl.call("GET", f"{API}/plant").status == 200


def test_the_token_bucket_refills_at_the_rate():
    guard = Guard(None, token="t" * 16, where="test", loopback=True, max_rate=2)
    now = [0.0]
    guard.clock = lambda: now[0]
    scope = {"client": ("127.0.0.1", 1), "method": "GET", "path": "/"}
    other = {"client": ("192.0.2.7", 1), "method": "GET", "path": "/"}
    assert [guard._admit(scope) for _ in range(3)] == [True, True, False]
    assert guard._admit(other)  # per client address
    now[0] = 0.5  # half a second: one token back
    assert [guard._admit(scope) for _ in range(2)] == [True, False]
    now[0] = 10.0  # never more than a second's worth
    assert [guard._admit(scope) for _ in range(3)] == [True, True, False]


def test_every_loopback_address_is_one_client_and_an_ipv6_64_is_one():
    """A local process may send from any address of 127.0.0.0/8: were each its own client,
    it would get as many allowances of the rate (and of the log's warnings) as it likes."""
    with Controller(max_rate=3) as ctl:
        ctl.web.guard.clock = lambda: 1000.0
        statuses = []
        for k in range(4):
            conn = http.client.HTTPConnection(
                "127.0.0.1", ctl.port, timeout=30, source_address=(f"127.0.0.{k + 1}", 0)
            )
            try:
                conn.request("GET", f"{API}/plant")
                reply = conn.getresponse()
                reply.read()
                statuses.append(reply.status)
            finally:
                conn.close()
        assert statuses == [200, 200, 200, 429]
    one, two = ("2001:db8:1:2::1", 5), ("2001:db8:1:2:ffff::9", 6)
    assert client_key({"client": one}) == client_key({"client": two}) == "2001:db8:1:2::/64"
    assert client_key({"client": ("2001:db8:1:3::1", 5)}) != client_key({"client": one})
    assert client_key({"client": ("::ffff:192.0.2.7", 1)}) == "192.0.2.7"
    assert client_key({"client": ("::1", 1)}) == client_key({"client": ("127.9.9.9", 1)})


# ----- the configuration key ---------------------------------------------------------------------
def config_with(web: str) -> str:
    text = (ROOT / "examples" / "workshop.toml").read_text()
    return text + f"\n[web]\n{web}\n"


def test_web_address_comes_from_the_configuration_unless_given():
    cfg = parse_config(config_with('address = "127.0.0.1:8089"'), "fleet.toml", ROOT / "examples")
    assert cfg.web_address == ("127.0.0.1", 8089)
    args = argparse.Namespace(web=None, web_token=TOKEN)
    assert (web_options(args, cfg).host, web_options(args, cfg).port) == ("127.0.0.1", 8089)
    args.web = "127.0.0.1:0"
    assert web_options(args, cfg).port == 0
    plain = load_config(RECIPES_ONLY)
    assert plain.web_address is None
    assert web_options(argparse.Namespace(web=None, web_token=None), plain) is None


@pytest.mark.parametrize(
    ("web", "message"),
    [
        ('address = "8080"', "fleet.toml: web.address: expected HOST:PORT"),
        ('address = "127.0.0.1:70000"', "fleet.toml: web.address: expected HOST:PORT"),
        ("address = 8080", "fleet.toml: web.address: expected a string"),
        ('port = "8080"', "fleet.toml: web.port: unknown key"),
    ],
)
def test_a_bad_web_key_names_the_file_and_key(web, message):
    with pytest.raises(ConfigError, match=f"^{message}"):
        parse_config(config_with(web), "fleet.toml", Path(ROOT / "examples"))
