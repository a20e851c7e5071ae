"""The vehicle record layout is written by the links (io_drivers) and read by the fleet
blocks (blocks.traffic.records), which may not import each other: each side spells the
layout of docs/protocol.md out. These checks hold the two spellings together, field for
field, so that a change on one side fails here instead of misreading every vehicle."""

from __future__ import annotations

import blocks.traffic.records as blocks_side
import io_drivers.protocol as protocol
import io_drivers.vehicle_records as links_side

# byte offsets inside one 8-byte record, as docs/protocol.md gives them
INPUT_OFFSETS = {"current": 0, "next": 2, "state": 4, "battery": 5, "speed": 6, "flags": 7}
OUTPUT_OFFSETS = {"nodes": 0, "control": 6, "sequence": 7}


def test_the_record_size_and_flag_bits_agree():
    for name in (
        "RECORD",
        "ONLINE",
        "STALE",
        "FAULT",
        "CLEAR",
        "LINK_JUMPS",
        "LINK_JUMP_SHIFT",
        "GO_BIT",
        "COUNT_MASK",
    ):
        assert getattr(blocks_side, name) == getattr(links_side, name), name
    assert blocks_side.IN_RECORD.itemsize == blocks_side.OUT_RECORD.itemsize == links_side.RECORD


def test_the_wire_codes_agree():
    assert blocks_side.STATES == protocol.STATES
    assert blocks_side.NO_NODE == protocol.NO_NODE
    assert blocks_side.BATTERY_UNKNOWN == protocol.BATTERY_UNKNOWN
    # a route command carries as many nodes as the output record has words for
    assert blocks_side.OUT_RECORD.fields["nodes"][0].shape == (blocks_side.MAX_RELEASED,)


def test_the_fields_sit_where_the_links_write_them():
    got_in = {name: blocks_side.IN_RECORD.fields[name][1] for name in INPUT_OFFSETS}
    got_out = {name: blocks_side.OUT_RECORD.fields[name][1] for name in OUTPUT_OFFSETS}
    assert got_in == INPUT_OFFSETS
    assert got_out == OUTPUT_OFFSETS


def test_the_links_write_the_same_offsets(monkeypatch):
    """The links' writers and readers name their addresses relative to a record's base."""
    seen: list[str] = []

    class Recorder:
        def field_writer(self, address: str):
            seen.append(address)
            return lambda value: None

        def output_reader(self, address: str):
            seen.append(address)
            return lambda: 0

    base = 80  # vehicle 10's record at input_base 0
    links_side.InputWriters.at(Recorder(), base)
    writes = list(seen)
    seen.clear()
    links_side.VehicleRecords._output_readers(Recorder(), base)
    reads = list(seen)

    def offset(address: str) -> int:
        kind, number = address[2], int(address[3:])
        return (number * 2 if kind == "W" else number) - base

    assert [offset(a) for a in writes] == list(INPUT_OFFSETS.values())
    assert [offset(a) for a in reads] == [0, 2, 4, 6, 7]
