"""Order files (CSV and JSON) and the per-order history CSV of a run (docs/orders.md).

An order file is what a warehouse system exports, so it is checked as strictly as a plant
file: ASCII decimal numbers only (no ``nan``, ``inf``, ``1_0`` or other scripts' digits), known
columns or keys only, and every problem is one line naming the file, the line (CSV) or the
order (JSON), the field and what is wrong. JSON is read as strictly as CSV: the same
integers (at most 18 digits), finite numbers only (no ``NaN``, ``Infinity`` or ``1e999``), no
key twice in an object, and ``null`` only where it means the documented default (never for
``id``, ``get`` or ``put``). The checks that need no plant run here
(``check_order``: get = put, end before start, negative times; and no id twice in a file);
the stations and vehicles are checked when the orders are added to the run's OrderBook.

Size limits: an order costs about 2 KB once it has run (its history and seven sections), so
the 100,000 orders a file may hold take some 200 MB; a CSV row is about 50 bytes and a JSON
order about 140 (as ``write_orders`` writes them), so 20 MiB holds that many in either format.
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from plc_runtime.files import FileProblem, read_limited
from topology.formats.numbers import (
    MAX_DIGITS,
    TOO_LONG,
    not_an_integer,
    parse_float,
    parse_int,
    shown,
)

from .orders import SECTIONS, OrderError, TransportOrder, check_order

MAX_FILE_BYTES = 20 * 2**20  # 20 MiB
MAX_ORDERS = 100_000
COLUMNS = ("id", "get", "put", "start_s", "end_s", "priority", "vehicle")
REQUIRED = ("id", "get", "put")
HISTORY_COLUMNS = (
    "id",
    "get",
    "put",
    "vehicle",
    "state",
    "created_s",
    "finished_s",
    *(f"{section}_{edge}_s" for section in SECTIONS for edge in ("start", "end")),
)
LIMITS_DOC = "docs/orders.md, Size limits"


class OrderFileError(ValueError):
    """An order file cannot be read or written. ``str()`` is the whole one-line message:
    ``orders.csv:4: field 'end_s': end 10.0 s is before the start 60.0 s``."""


# ----- reading ---------------------------------------------------------------------------------
def load_orders(path: str | Path) -> list[TransportOrder]:
    """The orders of a ``.csv`` or ``.json`` file, RAW and checked on their own (no plant)."""
    return [order for _where, order in located_orders(path)]


def located_orders(path: str | Path) -> list[tuple[str, TransportOrder]]:
    """:func:`load_orders`, each order with where it stands in the file (``FILE:LINE`` of a
    CSV, ``FILE: order K`` of a JSON list), so a check against the plant can name it."""
    path = Path(path)
    kind = path.suffix.lower()
    if kind not in (".csv", ".json"):
        raise OrderFileError(
            f"{path}: unknown order file format {kind or '(none)'!r}, use .csv or .json"
        )
    text = _read_text(path)
    return _parse_csv(text, str(path)) if kind == ".csv" else _parse_json(text, str(path))


def _read_text(path: Path) -> str:
    try:
        raw = read_limited(path, MAX_FILE_BYTES)  # bounded: a huge file or a device never ends
    except FileProblem as exc:
        limit = (
            f", the limit for order files ({LIMITS_DOC})" if str(exc).startswith("larger") else ""
        )
        raise OrderFileError(f"{path}: {exc}{limit}") from None
    except OSError as exc:
        raise OrderFileError(f"{path}: cannot read order file: {exc.strerror or exc}") from None
    if b"\0" in raw:
        raise OrderFileError(f"{path}: binary data, not an order file")
    try:
        return raw.decode("utf-8-sig")  # a spreadsheet's CSV export starts with a BOM
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise OrderFileError(f"{path}:{line}: not UTF-8 text (byte {exc.start})") from None


def _parse_csv(text: str, source: str) -> list[tuple[str, TransportOrder]]:
    reader = csv.reader(io.StringIO(text, newline=""), strict=True)
    try:
        header = _header(reader, source)
        orders: list[tuple[str, TransportOrder]] = []
        first_line: dict[str, int] = {}
        while True:
            line = reader.line_num + 1  # a quoted cell may span lines: report where a row starts
            row = next(reader, None)
            if row is None:
                return orders
            if not any(cell.strip() for cell in row):
                continue  # blank line
            where = f"{source}:{line}"
            if len(row) != len(header):
                raise OrderFileError(f"{where}: {len(row)} cells, the header has {len(header)}")
            if len(orders) == MAX_ORDERS:
                raise OrderFileError(
                    f"{where}: more than {MAX_ORDERS:,} orders, the limit of an order file ({LIMITS_DOC})"
                )
            order = _csv_order(dict(zip(header, (c.strip(" ") for c in row), strict=True)), where)
            if order.id in first_line:
                raise OrderFileError(
                    f"{where}: field 'id': {shown(order.id)} is used again (first on line {first_line[order.id]})"
                )
            first_line[order.id] = line
            orders.append((where, order))
    except csv.Error as exc:
        raise OrderFileError(f"{source}:{reader.line_num}: unreadable CSV: {exc}") from None


def _header(reader: Any, source: str) -> list[str]:
    """The column names of the first non-blank line: known, none twice, the required there."""
    for row in reader:
        names = [cell.strip() for cell in row]
        if not any(names):
            continue
        where = f"{source}:{reader.line_num}"
        for name in names:
            if not name:
                raise OrderFileError(
                    f"{where}: an empty column name (a trailing comma, or two commas in a row?)"
                )
            if name not in COLUMNS:
                raise OrderFileError(
                    f"{where}: unknown column {shown(name)} (columns: {','.join(COLUMNS)})"
                )
            if names.count(name) > 1:
                raise OrderFileError(f"{where}: column {name!r} appears twice")
        for name in REQUIRED:
            if name not in names:
                raise OrderFileError(
                    f"{where}: missing column {name!r} (required: {','.join(REQUIRED)})"
                )
        return names
    raise OrderFileError(f"{source}: empty, expected the header {','.join(COLUMNS)}")


def _csv_order(cells: dict[str, str], where: str) -> TransportOrder:
    values: dict[str, Any] = {}
    for name, text in cells.items():
        if name == "id":
            values[name] = text  # check_order says what is wrong with it
        elif text == "":
            if name in REQUIRED:
                raise OrderFileError(f"{where}: field {name!r}: empty")
        elif name.endswith("_s"):
            number = parse_float(text)
            if number is None:
                raise OrderFileError(
                    f"{where}: field {name!r}: not a finite decimal number: {shown(text)}"
                )
            values[name] = number
        else:
            number = parse_int(text)
            if number is None:
                problem = not_an_integer(text)
                raise OrderFileError(f"{where}: field {name!r}: {problem}: {shown(text)}")
            values[name] = number
    return _checked(TransportOrder(**values), where)


class _NonStandard:
    """``NaN``, ``Infinity`` or ``-Infinity``: Python's json reads them, but they are not JSON
    numbers, and an ``end_s`` of ``Infinity`` must not pass for "no deadline"."""

    def __init__(self, name: str) -> None:
        self.name = name


class _Object(dict):
    """A JSON object that remembers a key it had twice: json keeps the last value silently,
    and an order with two ids is a broken export, not a choice."""

    twice: str | None = None


def _object(pairs: list[tuple[str, Any]]) -> _Object:
    obj = _Object()
    for key, value in pairs:
        if key in obj and obj.twice is None:
            obj.twice = key
        obj[key] = value
    return obj


def _parse_json(text: str, source: str) -> list[tuple[str, TransportOrder]]:
    try:
        data = json.loads(text, parse_constant=_NonStandard, object_pairs_hook=_object)
    except json.JSONDecodeError as exc:
        raise OrderFileError(
            f"{source}:{exc.lineno}: invalid JSON: {exc.msg} (column {exc.colno})"
        ) from None
    except (ValueError, RecursionError) as exc:  # a 5000-digit integer, nesting thousands deep
        raise OrderFileError(f"{source}: unreadable JSON: {str(exc)[:80]}") from None
    if isinstance(data, _Object):
        if data.twice is not None:
            raise OrderFileError(f"{source}: key {shown(data.twice)} appears twice")
        if set(data) != {"orders"}:
            keys = f"the keys {', '.join(map(shown, sorted(data)))}" if data else "an empty object"
            raise OrderFileError(
                f'{source}: expected a list of orders or {{"orders": [...]}}, got {keys}'
            )
        data = data["orders"]
    if not isinstance(data, list):
        raise OrderFileError(f"{source}: expected a list of orders, got {_json_shown(data)}")
    if len(data) > MAX_ORDERS:
        raise OrderFileError(
            f"{source}: {len(data):,} orders, more than the {MAX_ORDERS:,} an order file may hold ({LIMITS_DOC})"
        )
    orders: list[tuple[str, TransportOrder]] = []
    first: dict[str, int] = {}
    for k, item in enumerate(data, start=1):
        where = f"{source}: order {k}"
        if not isinstance(item, _Object):
            raise OrderFileError(f"{where}: expected an object, got {_json_shown(item)}")
        if item.twice is not None:
            raise OrderFileError(f"{where}: key {shown(item.twice)} appears twice")
        if isinstance(item.get("id"), str):
            where += f" (id {shown(item['id'])})"
        for key in item:
            if key not in COLUMNS:
                raise OrderFileError(
                    f"{where}: unknown key {shown(key)} (keys: {', '.join(COLUMNS)})"
                )
        for key in REQUIRED:
            if key not in item:
                raise OrderFileError(f"{where}: field {key!r}: missing")
        values = {
            key: _json_field(key, value, f"{where}: field {key!r}")
            for key, value in item.items()
            if value is not None or key in REQUIRED  # null: the default (docs/orders.md)
        }
        order = _checked(TransportOrder(**values), where)
        if order.id in first:
            raise OrderFileError(
                f"{where}: field 'id': used again (first by order {first[order.id]})"
            )
        first[order.id] = k
        orders.append((f"{source}: order {k}", order))
    return orders


_INTEGERS = {
    "get": "must be a station node id (an integer >= 0)",
    "put": "must be a station node id (an integer >= 0)",
    "priority": "must be an integer",
    "vehicle": "must be a vehicle id (an integer)",
}


def _json_field(name: str, value: Any, where: str) -> Any:
    """One key's value as the order field, or OrderFileError for what JSON can say and the
    field cannot hold: null for a required field, a bool, list or object, a float where an
    integer is meant, a number too large for a float or (like CSV) for 18 digits. The rest
    (ranges, get = put, the time window) is ``check_order``'s."""
    got = _json_shown(value)
    if value is None:
        raise OrderFileError(f"{where}: required, got null")
    if name == "id":
        if not isinstance(value, str):
            raise OrderFileError(f"{where}: must be a non-empty string, got {got}")
        return value
    if name in _INTEGERS:
        if not isinstance(value, int) or isinstance(value, bool):
            raise OrderFileError(f"{where}: {_INTEGERS[name]}, got {got}")
        if len(str(abs(value))) > MAX_DIGITS:
            raise OrderFileError(f"{where}: {TOO_LONG}: {shown(str(value))}")
        return value
    number = None
    if isinstance(value, int | float) and not isinstance(value, bool):
        try:
            number = float(value)
        except OverflowError:  # an integer of 310 digits and more
            pass
    if number is None or not math.isfinite(number):
        hint = " (null: no deadline)" if name == "end_s" else ""
        raise OrderFileError(f"{where}: must be a finite number of seconds{hint}, got {got}")
    return number


def _json_shown(value: Any) -> str:
    """A JSON value for a message, short: a list of a million numbers must not flood it."""
    if value is None or isinstance(value, bool):
        return json.dumps(value)
    if isinstance(value, str):
        return shown(value)
    if isinstance(value, int | float):
        return shown(repr(value)).strip("'")
    if isinstance(value, _NonStandard):
        return value.name
    return "an object" if isinstance(value, dict) else "a list"


def _checked(order: TransportOrder, where: str) -> TransportOrder:
    try:
        check_order(order)
    except OrderError as exc:
        raise OrderFileError(f"{where}: field {exc.field!r}: {exc.problem}") from None
    return order


# ----- writing ---------------------------------------------------------------------------------
def write_orders(path: str | Path, orders: Iterable[TransportOrder]) -> int:
    """Write orders as an order file (``.csv`` or ``.json``, by the extension) that
    ``load_orders`` reads back to the same orders, e.g. a generated mix to replay with
    another strategy. Returns the number of orders."""
    path = Path(path)
    kind = path.suffix.lower()
    rows = [_order_row(order) for order in orders]
    if kind == ".csv":
        out = io.StringIO(newline="")
        writer = csv.writer(out, lineterminator="\n")
        writer.writerow(COLUMNS)
        writer.writerows(["" if row[c] is None else _cell(row[c]) for c in COLUMNS] for row in rows)
        text = out.getvalue()
    elif kind == ".json":
        text = (
            json.dumps(
                {"orders": [{k: v for k, v in row.items() if v is not None} for row in rows]},
                indent=1,
            )
            + "\n"
        )
    else:
        raise OrderFileError(
            f"{path}: unknown order file format {kind or '(none)'!r}, use .csv or .json"
        )
    _write_text(path, text)
    return len(rows)


def _order_row(order: TransportOrder) -> dict[str, Any]:
    return {
        "id": order.id,
        "get": order.get,
        "put": order.put,
        "start_s": order.start_s,
        "end_s": order.end_s if math.isfinite(order.end_s) else None,
        "priority": order.priority,
        "vehicle": order.vehicle,
    }


def _cell(value: Any) -> str:
    return repr(float(value)) if isinstance(value, float) else str(value)


def write_history(path: str | Path, orders: Iterable[TransportOrder]) -> int:
    """The seed's order history as CSV, one row per order (``HISTORY_COLUMNS``): who ran it,
    its state, when it was created and reached its final state, and every section's start
    and end (empty where a section did not run or the order is still open). Times in
    simulated seconds to the millisecond. Returns the number of rows."""
    out = io.StringIO(newline="")
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(HISTORY_COLUMNS)
    count = 0
    for order in orders:
        row = [
            order.id,
            order.get,
            order.put,
            "" if order.assigned is None else order.assigned,
            order.state.value,
            _time(order.created_s),
            _time(order.finished_s),
        ]
        for section in SECTIONS:
            times = order.sections.get(section, [])
            row += [_time(times[0] if times else None), _time(times[1] if len(times) > 1 else None)]
        writer.writerow(row)
        count += 1
    _write_text(Path(path), out.getvalue())
    return count


def _time(value: float | None) -> str:
    return "" if value is None else f"{value:.3f}"


def _write_text(path: Path, text: str) -> None:
    try:
        with open(path, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
    except OSError as exc:
        raise OrderFileError(f"{path}: cannot write: {exc.strerror or exc}") from None
