"""plc-runtime plant validate / plant show / route."""

import json
from pathlib import Path

import pytest

from fleet.cli import main
from topology import model_plant
from topology.formats import dump_toml


def run_json(capsys, *args):
    code = main(list(args))
    return code, json.loads(capsys.readouterr().out)


def test_route_json_contract(capsys):
    code, result = run_json(capsys, "route", "model-plant", "--from", "0", "--to", "24", "--json")
    assert code == 0
    assert {"route", "cost", "expansions", "cycles", "no_route"} <= set(result)
    assert result["route"] == [0, 6, 7, 8, 9, 24] and result["cost"] == pytest.approx(5.0)
    assert result["expansions"] == 6 and result["cycles"] == 6 and result["no_route"] is False


def test_route_budget_and_blockades(capsys):
    _, free = run_json(
        capsys, "route", "warehouse", "--from", "0", "--to", "1067", "--budget", "4", "--json"
    )
    assert free["cycles"] == -(-free["expansions"] // 4)  # ceil: the budget is used fully
    _, blocked = run_json(
        capsys,
        "route",
        "model-plant",
        "--from",
        "0",
        "--to",
        "24",
        "--block",
        "7-8",
        "--block",
        "8-9",
        "--json",
    )
    pairs = set(zip(blocked["route"], blocked["route"][1:], strict=False))
    assert not pairs & {(7, 8), (8, 7), (8, 9), (9, 8)} and blocked["cost"] > 5.0


def test_no_route_exits_1(capsys):
    code, result = run_json(capsys, "route", "model-plant", "--from", "24", "--to", "0", "--json")
    assert code == 1 and result["no_route"] is True and result["route"] == []


def test_route_reads_any_format(tmp_path, capsys):
    path = tmp_path / "plant.toml"
    path.write_text(dump_toml(model_plant()))
    code, result = run_json(capsys, "route", str(path), "--from", "0", "--to", "15", "--json")
    assert code == 0 and result["route"] == [0, 23, 1, 15]
    grid_map = tmp_path / "g.map"
    grid_map.write_text("type octile\nheight 2\nwidth 3\nmap\n...\n.@.\n")
    code, result = run_json(
        capsys,
        "route",
        str(grid_map),
        "--from",
        "3",
        "--to",
        "5",
        "--heuristic",
        "manhattan",
        "--json",
    )
    assert result["route"] == [3, 0, 1, 2, 5] and result["cost"] == 4.0


@pytest.mark.parametrize(
    "args,message",
    [
        (
            ["route", "model-plant", "--from", "0", "--to", "99"],
            "--to 99: no such node in model-plant",
        ),
        (
            ["route", "model-plant", "--from", "0", "--to", "24", "--block", "1-9"],
            "no routable segment between nodes 1 and 9",
        ),
        (
            ["route", "model-plant", "--from", "0", "--to", "24", "--block", "x"],
            "--block 'x': expected two node ids",
        ),
        (["route", "missing.toml", "--from", "0", "--to", "1"], "missing.toml: no such file"),
        (["plant", "validate", "missing.json"], "missing.json: no such file"),
    ],
)
def test_errors_are_one_line(capsys, args, message):
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_validate_reports_warnings_and_errors(tmp_path, capsys):
    path = tmp_path / "p.toml"
    path.write_text(
        "edges = [{from = 0, to = 1, length = 1.0, directed = true}, {from = 1, to = 2, length = 1.0, directed = true}]\n"
        '[[nodes]]\nid = 0\nrole = "entry"\n[[nodes]]\nid = 1\nrole = "station"\n[[nodes]]\nid = 2\n'
    )
    assert main(["plant", "validate", str(path)]) == 0
    out = capsys.readouterr().out
    assert (
        "valid plant" in out and "warning: target 1 cannot be reached from 1 node(s), e.g. 2" in out
    )
    path.write_text(path.read_text().replace("length = 1.0, directed = true}]", "length = -1.0}]"))
    assert main(["plant", "validate", str(path)]) == 2
    assert (
        "edges[1] (1 -> 2): length must be a finite number >= 0 (at most 1e+12), got -1.0"
        in capsys.readouterr().err
    )


def test_a_duplicate_edge_in_the_documented_example_is_named(tmp_path, capsys):
    """The example of docs/plant-format.md with one of its edges pasted again at the end."""
    page = (Path(__file__).parent.parent / "docs" / "plant-format.md").read_text()
    example = page.split("```toml\n", 1)[1].split("```", 1)[0]
    assert "[[edges]]\nfrom = 0\nto = 3\n" in example
    path = tmp_path / "p.toml"
    path.write_text(example + "\n[[edges]]\nfrom = 0\nto = 3\nlength = 1.2\n")
    warning = "edges[4] joins nodes 0 and 3 both ways, as edges[1] does: a copy? drop one of them"
    assert main(["plant", "validate", str(path)]) == 0
    assert f"{path}: warning: {warning}" in capsys.readouterr().out
    code, summary = run_json(capsys, "plant", "show", str(path), "--json")
    assert code == 0 and summary["warnings"] == [warning]


def test_show_json_and_png(tmp_path, capsys):
    png = tmp_path / "plant.png"
    code, summary = run_json(capsys, "plant", "show", "model-plant", "--png", str(png), "--json")
    assert code == 0 and summary["nodes"] == 25 and summary["targets"] == 10
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
