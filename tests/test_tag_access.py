"""Tags are read-only for clients unless declared writable: in code, in a tag file, and in
the fleet program, whose Modbus clients can write exactly its writable tags."""

import numpy as np
import pytest

from plc_runtime import ConfigError, TagTable, parse_address


def test_tags_are_read_only_for_clients_unless_declared_writable():
    table = TagTable()
    table.add("speed", "%MW0", "UINT")
    table.add("setpoint", "%MW1", "UINT", writable=True)
    assert not table.get("speed").writable and table.get("setpoint").writable
    assert [t.name for t in table.writable()] == ["setpoint"]


def test_tag_file_declares_writable_tags(tmp_path):
    path = tmp_path / "tags.toml"
    path.write_text(
        '[tags.setpoint]\naddress = "%MD2"\ntype = "REAL"\nwritable = true\n'
        '[tags.speed]\naddress = "%MD3"\ntype = "REAL"\n'
    )
    table = TagTable.from_toml(path)
    assert [t.name for t in table.writable()] == ["setpoint"]
    path.write_text('[tags.setpoint]\naddress = "%MD2"\nwritable = "yes"\n')
    with pytest.raises(ConfigError, match=r"tags.toml: \[tags.setpoint\]: 'writable' must be true"):
        TagTable.from_toml(path)
    path.write_text('[tags.setpoint]\naddress = "%MD2"\nwriteable = true\n')
    with pytest.raises(ConfigError, match=r"unknown key\(s\) writeable"):
        TagTable.from_toml(path)


# ----- the fleet program over Modbus ------------------------------------------------------------
def fleet_program():
    from fleet.config import load_config
    from fleet.program import FleetProgram

    cfg = load_config()  # the default job
    cfg.watchdog = 10.0  # a server thread runs beside the scans in the test below
    return FleetProgram(cfg)


def test_every_word_the_fleet_program_publishes_is_a_read_only_tag():
    """Run the default job and watch the marker area: each byte that changes belongs to a
    tag, and none of those tags is writable (a client cannot overwrite a status)."""
    program = fleet_program()
    image = program.rt.image
    owners: dict[int, set] = {}
    for tag in image.tags:
        a = tag.address
        if a.area == "M":
            for byte in range(a.byte_offset, a.byte_offset + a.nbytes):
                owners.setdefault(byte, set()).add(tag)
    markers = image.markers.bytes
    changed = np.zeros(len(markers), dtype=bool)
    try:
        program.rt.start()
        previous = markers.copy()
        for _ in range(3000):  # 30 s of the default job
            program.rt.step()
            changed |= markers != previous
            previous[:] = markers
    finally:
        program.close()
    published = np.flatnonzero(changed).tolist()
    for vehicle in program.controls:  # the watch saw the statuses move
        assert image.tags.get(f"agv{vehicle}.node").address.byte_offset in published
    untagged = [byte for byte in published if byte not in owners]
    assert not untagged, f"bytes of %M the program writes without a tag: {untagged[:10]}"
    writable = sorted({t.name for b in published for t in owners[b] if t.writable})
    assert not writable, f"the program writes tags a client may write: {writable}"


def test_modbus_writes_exactly_the_fleet_tags_declared_writable():
    """Every holding register, one FC6 write of 0 each (a no-op for every command word):
    what is accepted is exactly the registers of the writable tags, none below 1024."""
    from pymodbus.client import ModbusTcpClient

    from io_drivers.modbus_server import ModbusServer, map_entry

    program = fleet_program()
    server = ModbusServer(port=0)  # the default allow-list
    program.rt.add_driver(server)
    expected = set()
    for tag in program.rt.image.tags.writable():
        entry = map_entry(tag.address)  # every vehicle is served
        assert entry.bits is None  # a whole register: an HMI can write it
        expected.update(range(entry.first, entry.first + entry.count))
    client = ModbusTcpClient("127.0.0.1", port=0, timeout=5.0, retries=0)
    try:
        program.rt.start()
        client = ModbusTcpClient("127.0.0.1", port=server.port, timeout=5.0, retries=0)
        assert client.connect()
        accepted = {r for r in range(2048) if not client.write_register(r, 0).isError()}
    finally:
        client.close()
        program.close()
    cmd = map_entry(program.rt.image.tags.get("fleet.cmd.seq").address).first
    assert cmd in accepted and map_entry(parse_address("%MW0")).first not in accepted
    assert accepted == expected and min(accepted) >= 1024
    assert server.stats()["refused"] == 2048 - len(expected)
