"""Order files: CSV and JSON read as documented, every bad file one line naming the file, the
line or order, and the field; files written by write_orders read back to the same orders;
the history CSV has the seed's columns."""

import csv
import json
import math
import os
from pathlib import Path

import pytest

from blocks.dispatch import order_file
from blocks.dispatch.order_file import (
    COLUMNS,
    HISTORY_COLUMNS,
    OrderFileError,
    load_orders,
    write_history,
    write_orders,
)
from blocks.dispatch.orders import SECTIONS, OrderBook, OrderState, TransportOrder

FIELDS = ("id", "get", "put", "start_s", "end_s", "priority", "vehicle")


def fields(order: TransportOrder) -> tuple:
    return tuple(getattr(order, f) for f in FIELDS)


def write(tmp_path, name: str, content: str | bytes):
    path = tmp_path / name
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content, encoding="utf-8", newline="")
    return path


def error_of(path) -> str:
    with pytest.raises(OrderFileError) as err:
        load_orders(path)
    message = str(err.value)
    assert "\n" not in message and message.startswith(str(path)), message
    return message


# ----- good files --------------------------------------------------------------------------
def test_csv_with_every_column_and_defaults_for_empty_cells(tmp_path):
    path = write(
        tmp_path,
        "orders.csv",
        "id,get,put,start_s,end_s,priority,vehicle\n"
        "o1,10,20,0,600,0,\n"
        "o2,11,21,30.5,,2,3\n"
        "\n"
        '"o,3",12,22,,,,\n',
    )
    orders = load_orders(path)
    assert [fields(o) for o in orders] == [
        ("o1", 10, 20, 0.0, 600.0, 0, None),
        ("o2", 11, 21, 30.5, math.inf, 2, 3),
        ("o,3", 12, 22, 0.0, math.inf, 0, None),
    ]
    assert all(o.state is OrderState.RAW and o.history == [] for o in orders)


def test_csv_needs_only_the_required_columns_in_any_order_and_takes_bom_and_crlf(tmp_path):
    path = write(tmp_path, "o.CSV", "\ufeffput, id ,get\r\n20,o1,10\r\n")
    assert [fields(o) for o in load_orders(path)] == [("o1", 10, 20, 0.0, math.inf, 0, None)]


def test_a_header_alone_is_an_empty_order_list(tmp_path):
    assert load_orders(write(tmp_path, "o.csv", "id,get,put\n")) == []
    assert load_orders(write(tmp_path, "o.json", "[]")) == []


def test_json_as_a_list_or_under_orders_with_null_as_default(tmp_path):
    items = [
        {"id": "o1", "get": 10, "put": 20, "start_s": 5, "end_s": None, "priority": 1},
        {"id": "o2", "get": 11, "put": 21, "vehicle": 4, "end_s": 900.5},
    ]
    expected = [
        ("o1", 10, 20, 5, math.inf, 1, None),
        ("o2", 11, 21, 0.0, 900.5, 0, 4),
    ]
    plain = write(tmp_path, "a.json", json.dumps(items))
    wrapped = write(tmp_path, "b.json", json.dumps({"orders": items}))
    assert [fields(o) for o in load_orders(plain)] == expected
    assert [fields(o) for o in load_orders(wrapped)] == expected


@pytest.mark.parametrize("name", ["round.csv", "round.json"])
def test_written_orders_read_back_the_same(tmp_path, name):
    orders = [
        TransportOrder("o1", 10, 20, start_s=0.1 + 0.2, end_s=1e-5 + 1234.5678901234),
        TransportOrder("o 2", 11, 21, start_s=3600.0, priority=-2, vehicle=7),
        TransportOrder('o"3,', 12, 22, start_s=1e6, end_s=1e6),
    ]
    path = tmp_path / name
    assert write_orders(path, orders) == 3
    back = load_orders(path)
    assert [fields(o) for o in back] == [fields(o) for o in orders]  # floats exact
    again = tmp_path / f"again-{name}"
    write_orders(again, back)
    assert again.read_text() == path.read_text()


def test_loaded_orders_go_into_a_book(tmp_path):
    path = write(tmp_path, "o.csv", "id,get,put\no1,10,20\no2,20,10\n")
    b = OrderBook({10: "a", 20: "b"})
    for o in load_orders(path):
        b.add(o, 0.0)
    assert b.counts()["DISPATCHABLE"] == 2


# ----- bad CSV -----------------------------------------------------------------------------
HEADER = "id,get,put,start_s,end_s,priority,vehicle\n"
BAD_CSV = [
    ("id,get,put,colour\n", ":1: unknown column 'colour'"),
    ("id,get,put,get\n", ":1: column 'get' appears twice"),
    ("id,get,put,\n", ":1: an empty column name (a trailing comma, or two commas in a row?)"),
    ("id,put\n", ":1: missing column 'get'"),
    ("", ": empty, expected the header id,get,put"),
    ("\n \n", ": empty, expected the header"),
    (HEADER + "o1,10,20\n", ":2: 3 cells, the header has 7"),
    (HEADER + "o1,10,20,0,600,0,,\n", ":2: 8 cells, the header has 7"),
    (HEADER + "o1,ten,20,,,,\n", ":2: field 'get': not an integer: 'ten'"),
    (HEADER + "o1,\u0663,20,,,,\n", ":2: field 'get': not an integer"),  # Arabic-Indic 3
    (HEADER + "o1,10,,,,,\n", ":2: field 'put': empty"),
    (HEADER + "o1,-10,20,,,,\n", ":2: field 'get': must be a station node id"),
    (HEADER + "o1,10,20,nan,,,\n", ":2: field 'start_s': not a finite decimal number: 'nan'"),
    (HEADER + "o1,10,20,,inf,,\n", ":2: field 'end_s': not a finite decimal number: 'inf'"),
    (HEADER + "o1,10,20,1_0,,,\n", ":2: field 'start_s': not a finite decimal number"),
    (HEADER + "o1,10,20,1e999,,,\n", ":2: field 'start_s': not a finite decimal number"),
    (HEADER + "o1,10,20,-5,,,\n", ":2: field 'start_s': must be a finite number of seconds >= 0"),
    (HEADER + "o1,10,20,60,10,,\n", ":2: field 'end_s': end 10.0 s is before the start 60.0 s"),
    (HEADER + "o1,10,10,,,,\n", ":2: field 'put': Put station 10 is the Get station"),
    (HEADER + "o1,10,20,,,1.5,\n", ":2: field 'priority': not an integer: '1.5'"),
    (HEADER + "o1,10,20,,,,AGV-3\n", ":2: field 'vehicle': not an integer: 'AGV-3'"),
    (HEADER + ",10,20,,,,\n", ":2: field 'id': must be a non-empty string"),
    (HEADER + "x" * 65 + ",10,20,,,,\n", ":2: field 'id': longer than 64 characters"),
    (
        HEADER + "o1,10,20,,,,\n\no1,11,21,,,,\n",
        ":4: field 'id': 'o1' is used again (first on line 2)",
    ),
    (
        HEADER + 'o1,10,20,,,,\n"o\n2",10,20,,,,,\n',
        ":3: 8 cells, the header has 7",
    ),  # line it starts
    (HEADER + 'o1,10,20,,,,\n"o1"x,10,20,,,,\n', ":3: unreadable CSV"),
    # a quoted cell keeps what it holds: only the spaces around a cell are formatting
    (HEADER + '"o1\n",10,20,,,,\n', ":2: field 'id': has control characters"),
    (HEADER + '"o1\t",10,20,,,,\n', ":2: field 'id': has control characters"),
    (HEADER + '"o1\x1f",10,20,,,,\n', ":2: field 'id': has control characters"),
    (
        HEADER + "o1," + "9" * 200 + ",20,,,,\n",
        ":2: field 'get': not an integer of at most 18 digits: '999999",
    ),
]


@pytest.mark.parametrize(("content", "words"), BAD_CSV)
def test_a_bad_csv_file_is_one_line_naming_line_and_field(tmp_path, content, words):
    path = write(tmp_path, "orders.csv", content)
    message = error_of(path)
    assert f"{path}{words}" in message, message
    assert len(message) < 200 + len(str(path))


# ----- bad JSON ----------------------------------------------------------------------------
GOOD = {"id": "o7", "get": 10, "put": 20}
BAD_JSON = [
    ('[{"id": "o1", "get": 10,,}]', ":1: invalid JSON"),
    ('[\n{"id": "o1",\n "get": 10 "put": 20}]', ":3: invalid JSON: Expecting ',' delimiter"),
    ("[" * 100_000 + "]" * 100_000, ": unreadable JSON"),
    ('[{"id": "o1", "get": 1' + "0" * 5000 + ', "put": 20}]', ": unreadable JSON"),
    ({"orders": [], "version": 2}, ': expected a list of orders or {"orders": [...]}'),
    ({"order": []}, ": expected a list of orders or"),
    ("42", ": expected a list of orders, got 42"),
    ({"orders": {}}, ": expected a list of orders, got an object"),
    ({}, ': expected a list of orders or {"orders": [...]}, got an empty object'),
    (
        {"b": 1, "a\x1b": 2},
        ": expected a list of orders or {\"orders\": [...]}, got the keys 'a\\x1b', 'b'",
    ),
    ([GOOD, "o8"], ": order 2: expected an object, got 'o8'"),
    ([GOOD | {"colour": "red"}], ": order 1 (id 'o7'): unknown key 'colour'"),
    ([{"id": "o7", "get": 10}], ": order 1 (id 'o7'): field 'put': missing"),
    ([{"get": 10, "put": 20}], ": order 1: field 'id': missing"),
    ([GOOD | {"id": 7}], ": order 1: field 'id': must be a non-empty string"),
    ([GOOD | {"get": "10"}], ": order 1 (id 'o7'): field 'get': must be a station node id"),
    ([GOOD | {"get": True}], ": order 1 (id 'o7'): field 'get': must be a station node id"),
    ([GOOD | {"get": 20}], ": order 1 (id 'o7'): field 'put': Put station 20 is the Get"),
    ([GOOD | {"start_s": "0"}], ": order 1 (id 'o7'): field 'start_s': must be a finite"),
    (
        '[{"id": "o7", "get": 10, "put": 20, "start_s": NaN}]',
        ": order 1 (id 'o7'): field 'start_s'",
    ),
    ('[{"id": "o7", "get": 10, "put": 20, "end_s": NaN}]', ": order 1 (id 'o7'): field 'end_s'"),
    ([GOOD | {"start_s": 60, "end_s": 59.5}], ": order 1 (id 'o7'): field 'end_s': end 59.5 s"),
    ([GOOD | {"priority": 0.5}], ": order 1 (id 'o7'): field 'priority': must be an integer"),
    ([GOOD | {"vehicle": "3"}], ": order 1 (id 'o7'): field 'vehicle': must be a vehicle id"),
    ([GOOD, GOOD], ": order 2 (id 'o7'): field 'id': used again (first by order 1)"),
    # null is the default only where there is one
    ([GOOD | {"id": None}], ": order 1: field 'id': required, got null"),
    ([GOOD | {"get": None}], ": order 1 (id 'o7'): field 'get': required, got null"),
    ([GOOD | {"put": None}], ": order 1 (id 'o7'): field 'put': required, got null"),
    # numbers a float cannot hold, and JSON's non-numbers
    (
        '[{"id": "o7", "get": 10, "put": 20, "start_s": 1' + "0" * 320 + "}]",
        ": order 1 (id 'o7'): field 'start_s': must be a finite number of seconds, got 1000",
    ),
    (
        '[{"id": "o7", "get": 10, "put": 20, "end_s": 1' + "0" * 320 + "}]",
        ": order 1 (id 'o7'): field 'end_s': must be a finite number of seconds (null: no dead",
    ),
    (
        '[{"id": "o7", "get": 10, "put": 20, "end_s": 1e999}]',
        ": order 1 (id 'o7'): field 'end_s': must be a finite number of seconds (null: no "
        "deadline), got inf",
    ),
    (
        '[{"id": "o7", "get": 10, "put": 20, "end_s": Infinity}]',
        ": order 1 (id 'o7'): field 'end_s': must be a finite number of seconds (null: no "
        "deadline), got Infinity",
    ),
    (
        '[{"id": "o7", "get": 10, "put": 20, "priority": -Infinity}]',
        ": order 1 (id 'o7'): field 'priority': must be an integer, got -Infinity",
    ),
    # a key twice: json.loads would keep the last silently
    ('[{"id": "h17", "id": "h18", "get": 10, "put": 20}]', ": order 1: key 'id' appears twice"),
    ('[{"id": "o7", "get": 10, "put": 20, "get": 11}]', ": order 1: key 'get' appears twice"),
    ('{"orders": [], "orders": []}', ": key 'orders' appears twice"),
    # bools, floats and containers where an integer, a number or a string is meant
    ([GOOD | {"get": 10.0}], ": order 1 (id 'o7'): field 'get': must be a station node id (an "),
    (
        [GOOD | {"put": [20] * 10_000}],
        ": order 1 (id 'o7'): field 'put': must be a station node id (an integer >= 0), got a list",
    ),
    (
        [GOOD | {"vehicle": {"id": 3}}],
        ": order 1 (id 'o7'): field 'vehicle': must be a vehicle id (an integer), got an object",
    ),
    (
        [GOOD | {"vehicle": False}],
        ": order 1 (id 'o7'): field 'vehicle': must be a vehicle id (an integer), got false",
    ),
    (
        [GOOD | {"priority": True}],
        ": order 1 (id 'o7'): field 'priority': must be an integer, got true",
    ),
    (
        [GOOD | {"priority": 10**18}],
        ": order 1 (id 'o7'): field 'priority': not an integer of at most 18 digits: '1000",
    ),
    (
        [GOOD | {"start_s": False}],
        ": order 1 (id 'o7'): field 'start_s': must be a finite number of seconds, got false",
    ),
    (
        [GOOD | {"start_s": [0]}],
        ": order 1 (id 'o7'): field 'start_s': must be a finite number of seconds, got a list",
    ),
    (
        [GOOD | {"end_s": {"s": 1}}],
        ": order 1 (id 'o7'): field 'end_s': must be a finite number of seconds (null: no ",
    ),
    (
        [GOOD | {"id": ["o7"] * 10_000}],
        ": order 1: field 'id': must be a non-empty string, got a list",
    ),
    (
        [GOOD | {"id": "x" * 10_000}],
        ": order 1 (id 'xxxxxxxxxxxxxxxxxxxx...'): field 'id': longer than 64",
    ),
]


@pytest.mark.parametrize(("content", "words"), BAD_JSON)
def test_a_bad_json_file_is_one_line_naming_the_order_and_field(tmp_path, content, words):
    text = content if isinstance(content, str) else json.dumps(content)
    path = write(tmp_path, "orders.json", text)
    message = error_of(path)
    assert f"{path}{words}" in message, message
    assert len(message) < 200 + len(str(path))


def test_json_null_takes_the_default_of_every_optional_field(tmp_path):
    nulls = {"start_s": None, "end_s": None, "priority": None, "vehicle": None}
    path = write(tmp_path, "o.json", json.dumps([GOOD | nulls]))
    assert [fields(o) for o in load_orders(path)] == [("o7", 10, 20, 0.0, math.inf, 0, None)]


def test_json_times_are_floats_as_in_csv(tmp_path):
    path = write(tmp_path, "o.json", json.dumps([GOOD | {"start_s": 5, "end_s": 10**300}]))
    (order,) = load_orders(path)
    assert (type(order.start_s), type(order.end_s), order.end_s) == (float, float, 1e300)


INTEGERS = [0, -1, 10**18 - 1, -(10**18 - 1), 10**18, -(10**18), 10**40]


@pytest.mark.parametrize("field", ["get", "priority", "vehicle"])
@pytest.mark.parametrize("value", INTEGERS)
def test_csv_and_json_take_and_refuse_the_same_integers_alike(tmp_path, field, value):
    row = {"id": "o7", "get": 10, "put": 20} | {field: value}
    csv_path = write(tmp_path, "o.csv", HEADER + ",".join(str(row.get(c, "")) for c in FIELDS))
    json_path = write(tmp_path, "o.json", json.dumps([row]))
    outcomes = []
    for path, where in ((csv_path, f"{csv_path}:2: "), (json_path, f"{json_path}: order 1 ")):
        try:
            outcomes.append(fields(load_orders(path)[0]))
        except OrderFileError as err:
            outcomes.append(str(err).removeprefix(where).removeprefix("(id 'o7'): "))
    assert outcomes[0] == outcomes[1]
    if len(str(abs(value))) > 18:
        assert outcomes[0].startswith(f"field '{field}': not an integer of at most 18 digits")


# ----- files that are no order files ---------------------------------------------------------
def test_unreadable_files_are_one_line_errors(tmp_path):
    assert "cannot read order file" in error_of(tmp_path / "missing.csv")
    (tmp_path / "dir.json").mkdir()
    assert "not a regular file (a directory)" in error_of(tmp_path / "dir.json")
    os.mkfifo(tmp_path / "pipe.csv")  # (opening it would wait for a writer for ever)
    assert "not a regular file (a named pipe)" in error_of(tmp_path / "pipe.csv")
    (tmp_path / "zero.csv").symlink_to("/dev/zero")  # (it never ends)
    assert "not a regular file (a device)" in error_of(tmp_path / "zero.csv")
    assert "binary data" in error_of(write(tmp_path, "b.csv", b"id,get,put\n\0\n"))
    assert "u.csv:2: not UTF-8 text (byte 11)" in error_of(
        write(tmp_path, "u.csv", b"id,get,put\n\xff\n")
    )
    assert "unknown order file format '.xlsx'" in error_of(write(tmp_path, "o.xlsx", "id"))
    assert "unknown order file format '(none)'" in error_of(write(tmp_path, "orders", "id"))


def test_the_size_limits_are_checked(tmp_path, monkeypatch):
    monkeypatch.setattr(order_file, "MAX_ORDERS", 2)
    rows = "".join(f"o{k},10,20\n" for k in range(3))
    message = error_of(write(tmp_path, "many.csv", "id,get,put\n" + rows))
    assert ":4: more than 2 orders, the limit of an order file (docs/orders.md" in message
    assert len(load_orders(write(tmp_path, "two.csv", "id,get,put\no1,10,20\no2,10,20\n"))) == 2
    items = [{"id": f"o{k}", "get": 10, "put": 20} for k in range(3)]
    message = error_of(write(tmp_path, "many.json", json.dumps(items)))
    assert ": 3 orders, more than the 2 an order file may hold" in message
    monkeypatch.setattr(order_file, "MAX_FILE_BYTES", 20)
    message = error_of(write(tmp_path, "big.csv", "id,get,put\n" + "o1,10,20\n" * 2))
    assert "larger than 20 bytes, the limit for order files" in message


def test_the_documented_limits_are_the_real_ones():
    page = (Path(__file__).parent.parent / "docs" / "orders.md").read_text(encoding="utf-8")
    assert f"| file size | 20 MiB ({order_file.MAX_FILE_BYTES:,} bytes) |" in page
    assert f"| orders per file | {order_file.MAX_ORDERS:,} |" in page


def test_writing_to_a_bad_place_is_a_one_line_error(tmp_path):
    orders = [TransportOrder("o1", 10, 20)]
    with pytest.raises(OrderFileError, match="cannot write"):
        write_orders(tmp_path / "no" / "such.csv", orders)
    with pytest.raises(OrderFileError, match="cannot write"):
        write_history(tmp_path, orders)
    with pytest.raises(OrderFileError, match="unknown order file format '.txt'"):
        write_orders(tmp_path / "o.txt", orders)


# ----- the history -------------------------------------------------------------------------
def test_the_history_has_a_row_per_order_with_every_sections_times(tmp_path):
    book = OrderBook({10: "a", 20: "b", 30: "c"})
    done = book.add(TransportOrder("done", 10, 20), 1.0)
    done.assigned = 4
    book.transition(done, OrderState.BEING_PROCESSED, 2.0)
    times = {}
    t = 2.0
    for name in SECTIONS:
        if name == "Get_Queue":
            continue  # the Get station was free: no queue section
        book.start_section(done, name, t)
        times[name] = (t, t + 1.25)
        t += 1.25
        book.end_section(done, name, t)
    book.transition(done, OrderState.FINISHED, t)
    waiting = book.add(TransportOrder("waiting", 20, 30), 3.0)
    running = book.add(TransportOrder("running", 30, 10), 3.0)
    running.assigned = 5
    book.transition(running, OrderState.BEING_PROCESSED, 4.0)
    book.start_section(running, "Go_To_Cluster", 4.0)
    failed = book.add(TransportOrder("failed", 30, 20), 3.0)
    book.transition(failed, OrderState.UNROUTABLE, 5.5, "Put station cut off")

    path = tmp_path / "history.csv"
    assert write_history(path, book) == 4
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == HISTORY_COLUMNS
    assert HISTORY_COLUMNS[:7] == (
        "id",
        "get",
        "put",
        "vehicle",
        "state",
        "created_s",
        "finished_s",
    )
    assert HISTORY_COLUMNS[7:9] == ("Go_To_Cluster_start_s", "Go_To_Cluster_end_s")
    assert len(HISTORY_COLUMNS) == 7 + 2 * len(SECTIONS)
    row = rows[0]
    assert (row["id"], row["get"], row["put"], row["vehicle"], row["state"]) == (
        "done",
        "10",
        "20",
        "4",
        "FINISHED",
    )
    assert (row["created_s"], row["finished_s"]) == ("1.000", f"{t:.3f}")
    for name in SECTIONS:
        start, end = times.get(name, (None, None))
        expected = ("", "") if start is None else (f"{start:.3f}", f"{end:.3f}")
        assert (row[f"{name}_start_s"], row[f"{name}_end_s"]) == expected
    assert rows[1]["state"] == "DISPATCHABLE" and rows[1]["vehicle"] == ""
    assert rows[1]["finished_s"] == "" and rows[1]["Put_end_s"] == ""
    assert rows[2]["Go_To_Cluster_start_s"] == "4.000" and rows[2]["Go_To_Cluster_end_s"] == ""
    assert (rows[3]["state"], rows[3]["finished_s"]) == ("UNROUTABLE", "5.500")
    assert waiting.state is OrderState.DISPATCHABLE  # writing changes nothing


def test_the_order_file_columns_are_the_documented_ones():
    assert COLUMNS == FIELDS
