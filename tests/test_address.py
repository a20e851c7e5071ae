import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from plc_runtime import (
    AddressError,
    ConfigError,
    ProcessImage,
    TagTable,
    ValueRangeError,
    parse_address,
)


@pytest.mark.parametrize(
    "text,area,size,offset,bit",
    [
        ("%IX0.3", "I", "X", 0, 3),
        ("%I1.7", "I", "X", 1, 7),
        ("%IB1", "I", "B", 1, -1),
        ("%QW4", "Q", "W", 8, -1),
        ("%MD2", "M", "D", 8, -1),
        ("%ML1", "M", "L", 8, -1),
        ("%qx2.0", "Q", "X", 2, 0),
    ],
)
def test_parse_valid(text, area, size, offset, bit):
    a = parse_address(text)
    assert (a.area, a.size, a.byte_offset, a.bit) == (area, size, offset, bit)


@pytest.mark.parametrize(
    "text", ["%IX0.8", "%IX0", "%IW0.1", "%ZW0", "IX0.0", "%I", "%MW-1", "", "%MX1.2.3"]
)
def test_parse_invalid_names_the_address(text):
    with pytest.raises(AddressError) as err:
        parse_address(text)
    assert repr(text) in str(err.value)


@pytest.mark.parametrize(
    "text",
    [
        "%MW\u0669\u0660\u0660",  # Arabic-Indic 900: int() reads it, \d matches it
        "%MW\uff19",  # fullwidth 9
        "%MX1.\u0663",  # Arabic-Indic 3 as the bit
        "%\u0131X0.0",  # dotless i: str.upper() makes it I
    ],
)
def test_only_ascii_digits_and_letters_make_an_address(text):
    """What merely resembles an address is an error naming it, not the address it
    resembles (an Arabic-Indic %MW900 would otherwise open %MW900 for writes)."""
    with pytest.raises(AddressError) as err:
        parse_address(text)
    assert str(err.value) == (f"invalid IEC address {text!r}: ASCII letters and digits (0-9) only")


@pytest.mark.parametrize("text", ["%MW900\n", "%IX0.3\n", "\t%MW1"])
def test_an_address_is_matched_whole(text):
    """A line break or tab is no part of an address (``$`` alone would let a trailing
    newline through); only spaces around it are ignored."""
    with pytest.raises(AddressError, match="expected %<area><size><index>"):
        parse_address(text)
    assert parse_address(" %MW900 ").byte_offset == 1800


def test_out_of_range_names_address_and_area():
    img = ProcessImage({"I": 16, "Q": 16, "M": 16})
    with pytest.raises(AddressError, match=r"%IW8: outside the I area \(16 bytes"):
        img.read("%IW8")
    with pytest.raises(AddressError, match="%MD4"):
        img.write("%MD4", 1)
    img.read("%IW7")  # last word fits


def test_sizes_overlap_little_endian():
    img = ProcessImage()
    img.write("%MW1", 0x1234)
    img.apply_quiet_point()
    assert img.read("%MB2") == 0x34 and img.read("%MB3") == 0x12
    assert img.read("%MX3.4") is True  # 0x12 = 0b0001_0010
    assert img.read("%MD0") == 0x1234 << 16


def test_value_range_is_checked_at_the_call():
    img = ProcessImage()
    with pytest.raises(ValueRangeError, match=r"%QW0: 70000 is outside the WORD range 0..65535"):
        img.write("%QW0", 70000)
    with pytest.raises(ValueRangeError, match="BOOL"):
        img.write("%QX0.0", 2)
    with pytest.raises(ValueRangeError, match="integer"):
        img.write("%MB0", 1.5)
    assert img.pending_writes == 0  # nothing invalid was queued


def test_tags_typed_access():
    tags = TagTable()
    tags.add("speed", "%MD2", "REAL")
    tags.add("offset", "%MW0", "INT")
    img = ProcessImage(tags=tags)
    img.write("speed", 1.5)
    img.write("offset", -2)
    img.apply_quiet_point()
    assert img.read("speed") == 1.5
    assert img.read("offset") == -2
    assert img.read("%MW0") == 65534  # the raw WORD view of the same bytes
    with pytest.raises(AddressError, match="unknown tag 'nope'"):
        img.read("nope")


@pytest.mark.parametrize(
    "args,message",
    [
        (("x", "%MW0", "REAL"), "needs a D-sized address"),
        (("x", "%MW0", "FLOAT"), "unknown data type"),
        (("9x", "%MW0"), "not a valid identifier"),
        (("x\n", "%MW0"), "not a valid identifier"),
        (("x", "%QW0", "INT"), None),
    ],
)
def test_tag_declaration_errors(args, message):
    table = TagTable()
    if message is None:
        table.add(*args)
        with pytest.raises(ConfigError, match="declared twice"):
            table.add(*args)
    else:
        with pytest.raises(ConfigError, match=message):
            table.add(*args)


def test_retain_only_on_markers():
    with pytest.raises(ConfigError, match="only marker"):
        TagTable().add("x", "%QW0", retain=True)


def test_tag_file_errors_name_file_and_tag(tmp_path):
    path = tmp_path / "tags.toml"
    path.write_text(
        '[tags.speed]\naddress = "%MD2"\ntype = "REAL"\n[tags.bad]\naddress = "%MW0"\ntype = "REAL"\n'
    )
    with pytest.raises(ConfigError, match=r"tags.toml: \[tags.bad\]: .*D-sized"):
        TagTable.from_toml(path)
    path.write_text("[tags.x\naddress=")
    with pytest.raises(ConfigError, match="tags.toml: invalid TOML"):
        TagTable.from_toml(path)
    path.write_bytes(b"\xff\xfe\x00binary")
    with pytest.raises(ConfigError, match="not a UTF-8 text file"):
        TagTable.from_toml(path)
    path.write_text('[tags.lamp]\naddress = "%QX0.0"\ncomment = "the lamp"\n')
    table = TagTable.from_toml(path)
    assert table.get("lamp").type.name == "BOOL"


@given(
    st.sampled_from(["I", "Q", "M"]), st.sampled_from(["B", "W", "D", "L"]), st.integers(0, 4000)
)
def test_parse_roundtrip(area, size, index):
    a = parse_address(f"%{area}{size}{index}")
    assert a.byte_offset == index * {"B": 1, "W": 2, "D": 4, "L": 8}[size]


def test_tag_added_after_the_image_is_range_checked():
    img = ProcessImage({"I": 16, "Q": 16, "M": 16})
    img.tags.add("far", "%MW100", "INT")
    with pytest.raises(AddressError, match=r"tag far \(%MW100\): outside the M area"):
        img.write("far", 1)
    assert img.pending_writes == 0


def test_write_many_is_applied_together_or_not_at_all():
    img = ProcessImage()
    with pytest.raises(ValueRangeError):
        img.write_many({"%MW0": 1, "%MW1": -1})
    assert img.pending_writes == 0
    img.write_many({"%MW0": 0x1111, "%MW1": 0x2222})
    assert img.pending_writes == 1
    img.apply_quiet_point()
    assert img.read("%MD0") == 0x22221111


FIELD_TAGS = {
    "flag": ("%IX0.0", "BOOL"),
    "b": ("%IB1", "BYTE"),
    "s": ("%IB2", "SINT"),
    "w": ("%IW2", "WORD"),
    "i": ("%IW3", "INT"),
    "dw": ("%ID4", "DWORD"),
    "di": ("%ID5", "DINT"),
    "r": ("%ID6", "REAL"),
    "li": ("%IL4", "LINT"),
    "lr": ("%IL5", "LREAL"),
}
any_value = st.one_of(
    st.integers(-300, 70_000),
    st.integers(-(2**70), 2**70),
    st.booleans(),
    st.floats(),
    st.sampled_from([np.int16(-5), np.uint8(200), np.int64(2**40), np.float32(1.5), "7", None]),
)


@given(st.lists(st.tuples(st.sampled_from(sorted(FIELD_TAGS)), any_value), max_size=30))
def test_a_drivers_field_writer_stores_and_refuses_what_a_checked_write_does(writes):
    """The field writers take plain values without the generic check; whatever the value,
    they must store the same bytes as a checked write and raise the same error."""
    tags = TagTable()
    for name, (address, type_name) in FIELD_TAGS.items():
        tags.add(name, address, type_name)
    checked, direct = ProcessImage(tags=tags), ProcessImage(tags=tags)
    writers = {name: direct.field_writer(name) for name in FIELD_TAGS}
    for name, value in writes:
        try:
            checked.write(name, value)
            expected = None
        except ValueRangeError as exc:
            expected = str(exc)
        try:
            writers[name](value)
            got = None
        except ValueRangeError as exc:
            got = str(exc)
        assert got == expected
        checked.apply_quiet_point()
        assert checked.field_inputs.bytes.tobytes() == direct.field_inputs.bytes.tobytes()
