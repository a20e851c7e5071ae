"""Where a configuration's orders come from ([orders] file and [orders.generator]): a bad
generator is refused when the configuration is read, naming the generator's key, never
blamed on the order file and never allowed to fill the memory."""

from pathlib import Path

import pytest

from fleet.config import parse_config
from fleet.order_system import configured_orders
from plc_runtime.errors import ConfigError

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
CONFIG = f"""
[plant]
file = "{EXAMPLES / "plants" / "workshop.toml"}"

[orders]
file = "{EXAMPLES / "orders" / "workshop.csv"}"

[orders.generator]
duration_s = 3600
units = {{ a = 2, b = 3 }}   # saw and weld: stations
relations = [{{ source = "a", target = "b", rate_per_h = 10 }}]

[[vehicles]]
id = 1
start = 0
"""


def config_error(text: str) -> str:
    with pytest.raises(ConfigError) as err:
        configured_orders(parse_config(text, "test.toml"))
    message = str(err.value)
    assert "\n" not in message
    return message


def test_a_file_and_a_generator_give_their_orders_together():
    file_orders = len((EXAMPLES / "orders" / "workshop.csv").read_text().splitlines()) - 1
    orders = configured_orders(parse_config(CONFIG, "test.toml"))
    assert len(orders) == file_orders + 10
    # the generator's time window is generate_orders' default (docs/orders.md): 900 s
    generated = [o for o in orders if o.id.startswith("o0")]
    assert len(generated) == 10
    assert all(o.end_s - o.start_s == pytest.approx(900.0) for o in generated)


@pytest.mark.parametrize(
    ("change", "words"),
    [
        (
            ("a = 2", "a = 0"),
            "test.toml: orders.generator.units.a: function 0's node 0 is not a Get/Put station",
        ),
        (
            ("b = 3", "b = 1"),
            "test.toml: orders.generator.units.b: function 1's nodes 1, 2 are not Get/Put stations",
        ),
        (
            ("relations", "control = 0\nrelations"),
            "test.toml: orders.generator.control: function 0's node 0 is not a Get/Put station",
        ),
    ],
)
def test_a_unit_without_stations_is_the_generators_error_not_the_files(change, words):
    message = config_error(CONFIG.replace(*change))
    assert message.startswith(words), message
    assert "orders.file" not in message and "workshop.csv" not in message


def test_a_generator_beyond_the_order_limit_is_refused_before_generating():
    text = CONFIG.replace("duration_s = 3600", "duration_s = 10000000").replace(
        "rate_per_h = 10", "rate_per_h = 999999"
    )
    with pytest.raises(ConfigError) as err:
        parse_config(text, "test.toml")  # already when read: nothing is generated
    assert str(err.value).startswith(
        "test.toml: orders.generator: about 2,777,775,000 orders: more than 100,000, the limit"
    ), err.value


def test_the_limit_counts_the_scale_and_the_control_station():
    at_limit = CONFIG.replace("rate_per_h = 10", "rate_per_h = 100000")
    parse_config(at_limit, "test.toml")  # 100,000 orders: admitted
    for extra, count in (("scale = 1.01", "101,000"), ("control = 4", "102,000")):
        with pytest.raises(ConfigError, match=f"orders.generator: {count} orders: more than"):
            parse_config(at_limit.replace("relations", f"{extra}\nrelations"), "test.toml")


@pytest.mark.parametrize(
    ("change", "words"),
    [
        (("rate_per_h = 10", "rate = 10"), "relations[0].rate: unknown key (keys: source, "),
        (('source = "a", ', ""), "relations[0].source: missing"),
        (("relations = [{", "relations = [7, {"), "relations[0]: expected a table with"),
    ],
)
def test_a_relation_names_the_key_that_is_wrong(change, words):
    """A misspelled key of a relation is named, not the whole relation."""
    with pytest.raises(ConfigError) as err:
        parse_config(CONFIG.replace(*change), "test.toml")
    assert f"test.toml: orders.generator.{words}" in str(err.value)
