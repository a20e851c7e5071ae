"""Hostile plant files at the command line: ``plant show``, ``plant validate`` and ``run``
refuse them with one line on stderr naming the file and the place, and print nothing of
them, so no escape sequence of a file reaches the operator's terminal."""

from __future__ import annotations

import pytest

from fleet.cli import main

PLANT = (
    '{{"name": "{name}", "nodes": [{{"id": 0, "role": "entry", "functions": [0]}}, '
    '{{"id": 1, "role": "exit", "functions": [1], "x": 1.0}}], '
    '"edges": [{{"from": 0, "to": 1, "length": 1.0}}]}}'
)
CASES = {
    "surrogate.json": (PLANT.format(name="\\ud800"), "name: the plant's name '\\ud800'"),
    "control.toml": (
        'name = "a\\u0000b\\u001b[31mred"\n[[nodes]]\nid = 0\nrole = "entry"\nfunctions = [0]\n'
        '[[nodes]]\nid = 1\nrole = "exit"\nfunctions = [1]\nx = 1.0\n'
        "[[edges]]\nfrom = 0\nto = 1\nlength = 1.0\n",
        "name: the plant's name 'a\\x00b\\x1b[31mred': character 2 (U+0000)",
    ),
    "duplicate.json": (
        '{"name": "x", "name": "y", "nodes": [], "edges": []}',
        "line 1, column 15: duplicate key 'name' in one object (first on line 1, column 2)",
    ),
    "junk.map": (
        "type octile\nheight 1\nwidth 3\nmap\n...\nthis is junk text!!\n",
        "line 6: text after the 1 row(s) that 'height 1' declares",
    ),
}


@pytest.mark.parametrize("command", ["show", "validate"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_plant_commands_refuse_with_one_located_line(tmp_path, capsys, command, name):
    content, message = CASES[name]
    path = tmp_path / name
    path.write_text(content, encoding="ascii")  # the hostile characters are escapes
    assert main(["plant", command, str(path)]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.startswith(f"plc-runtime: error: {path}: {message}")
    assert err.count("\n") == 1 and err[:-1].isprintable()


def test_run_refuses_a_plant_with_a_surrogate_before_running(tmp_path, capsys):
    """The plant's name is the drawing's title: unchecked, the run went to its end and
    failed there, writing no summary."""
    (tmp_path / "plant.json").write_text(PLANT.format(name="\\ud800"), encoding="ascii")
    config = tmp_path / "fleet.toml"
    config.write_text(
        '[plant]\nfile = "plant.json"\n[[recipes]]\nname = "out"\nfunctions = [1]\n'
        "[[vehicles]]\nid = 1\nstart = 0\n"
    )
    out = tmp_path / "out"
    assert main(["run", str(config), "--cycles", "20", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("plc-runtime: error: ") and err.count("\n") == 1
    assert f"{tmp_path / 'plant.json'}: name: the plant's name '\\ud800'" in err
    assert not out.exists()
