"""The files a fleet run leaves behind (fleet.report.write_all): the data is written even
when the drawing of the routes fails."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fleet_scenarios import ONE_DRILL

from fleet import report
from fleet.config import parse_config
from fleet.program import FleetProgram
from plc_runtime.clock import VirtualClock
from plc_runtime.errors import ConfigError


@pytest.fixture(scope="module")
def program() -> FleetProgram:
    cfg = parse_config(ONE_DRILL)
    cfg.watchdog = 5.0  # behaviour, not wall time: a busy machine must not fault a scan
    program = FleetProgram(cfg, clock=VirtualClock())
    try:
        program.rt.start()
        program.rt.step(round(2 / cfg.cycle_time))
    finally:
        program.close()
    return program


def failing_draw(exc: BaseException):
    def draw(*args, **kwargs):
        raise exc

    return draw


def test_a_failed_drawing_keeps_the_data_and_says_why(program, tmp_path, monkeypatch):
    monkeypatch.setattr(
        "topology.draw.draw",
        failing_draw(TypeError("set_text(): incompatible function arguments.\n" + "x\n" * 50)),
    )
    result = report.summary(program, wall_s=1.0)
    (tmp_path / "routes.png").write_bytes(b"an earlier run's drawing")
    with pytest.warns(RuntimeWarning) as caught:
        files = report.write_all(program, tmp_path, result)
    (warning,) = caught
    assert str(warning.message) == (
        f"{tmp_path / 'routes.png'}: routes drawing not written: "
        "TypeError: set_text(): incompatible function arguments."
    )
    written = json.loads((tmp_path / "summary.json").read_text())
    assert written["routes_error"] == "TypeError: set_text(): incompatible function arguments."
    assert written["files"] == files and set(files) == {"summary", "recipes"}
    assert (tmp_path / "recipes.csv").read_text().startswith("vehicle,recipe,")
    assert not (tmp_path / "routes.png").exists()

    monkeypatch.undo()  # drawn after all: summary.json names it
    again = tmp_path / "again"
    files = report.write_all(program, again, report.summary(program, wall_s=1.0))
    assert files["routes"] == str(again / "routes.png")
    assert json.loads((again / "summary.json").read_text())["files"] == files


def test_the_data_is_written_before_the_drawing(program, tmp_path, monkeypatch):
    """A drawing takes seconds on a large plant; a Ctrl-C in it must not cost the data."""
    monkeypatch.setattr("topology.draw.draw", failing_draw(KeyboardInterrupt()))
    with pytest.raises(KeyboardInterrupt):
        report.write_all(program, tmp_path, report.summary(program, wall_s=1.0))
    written = json.loads((tmp_path / "summary.json").read_text())
    assert set(written["files"]) == {"summary", "recipes"}
    assert (tmp_path / "recipes.csv").exists()


@pytest.mark.parametrize("failing", ["write_csv", "_write_summary"])
def test_results_that_cannot_be_written_whole_leave_the_folder_as_it_was(
    program, tmp_path, monkeypatch, failing
):
    """A full disk half-way through the results: the earlier run's files stay whole (they
    were cut short in place), none of this run's is left beside them, and the error says
    which file failed and why."""
    earlier = {"summary.json": '{"earlier": true}\n', "recipes.csv": "vehicle,recipe\n1,r\n"}
    for name, text in earlier.items():
        (tmp_path / name).write_text(text)
    real = getattr(report, failing)

    def disk_full(*args, **kwargs):
        real(*args, **kwargs)  # part of it reached the disk
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(report, failing, disk_full)
    with pytest.raises(report.ResultsNotWritten) as caught:
        report.write_all(program, tmp_path, report.summary(program, wall_s=1.0))
    name = "recipes.csv" if failing == "write_csv" else "summary.json"
    assert str(caught.value) == (
        f"--out {tmp_path}: the results were not written ({name}: No space left on device); "
        "the folder keeps the files it held"
    )
    assert {p.name: p.read_text() for p in tmp_path.iterdir()} == earlier


def test_a_drawing_that_cannot_be_saved_names_the_os_reason(program, tmp_path, monkeypatch):
    monkeypatch.setattr(
        "topology.draw.draw", failing_draw(PermissionError(13, "Permission denied"))
    )
    result = report.summary(program, wall_s=1.0)
    with pytest.warns(RuntimeWarning, match="routes.png: routes drawing not written: Permission"):
        report.write_all(program, tmp_path, result)
    assert result["routes_error"] == "Permission denied"


def test_names_are_drawn_as_written_not_as_math(tmp_path):
    """A "$" in a name would start matplotlib's math mode, and an unknown macro in it
    failed the drawing."""
    from topology import Edge, Node, Plant
    from topology.draw import draw

    plant = Plant.build(
        [Node(0, role="entry", functions=(0,)), Node(1, x=1.0, role="exit", functions=(1,))],
        [Edge(0, 1, 1.0)],
        name="hall $\\nosuchmacro$",
    )
    out = draw(plant, tmp_path / "plant.png", title="hall $\\frac{1$")
    assert out.stat().st_size > 0


def test_a_folder_in_the_way_of_a_staged_name_is_refused_before_the_run(tmp_path):
    """Something that is no file under a staged name (recipes.csv.partial/) would fail the
    writing at the end of the run: the output folder is refused before it starts."""
    (tmp_path / "recipes.csv.partial" / "x").mkdir(parents=True)
    with pytest.raises(ConfigError, match="recipes.csv.partial, where recipes.csv is written"):
        report.claim_out_dir(tmp_path)


def test_a_rename_that_fails_half_way_says_which_files_are_this_runs(
    program, tmp_path, monkeypatch
):
    """The renames into place go data first, the summary last; one that fails after others
    did (something took a name during the run) says which files are this run's."""
    (tmp_path / "summary.json").write_text('{"earlier": true}\n')
    real_replace = report.os.replace

    def replace(src, dst):
        if Path(dst).name == "summary.json":
            raise OSError(21, "Is a directory")
        return real_replace(src, dst)

    monkeypatch.setattr(report.os, "replace", replace)
    with pytest.raises(report.ResultsNotWritten) as caught:
        report.write_all(program, tmp_path, report.summary(program, wall_s=1.0))
    assert str(caught.value).endswith(
        "(summary.json: Is a directory); only recipes.csv is this run's"
    )
    assert (tmp_path / "summary.json").read_text() == '{"earlier": true}\n'
    assert not list(tmp_path.glob("*.partial"))


def test_a_summary_that_cannot_be_written_again_after_the_drawing_stays_whole(
    program, tmp_path, monkeypatch
):
    """The disk fills with the drawing: the summary written with the data stays, whole,
    and a warning says it was not written again."""
    real_write = report._write_summary
    calls = []

    def second_fails(result, files, to):
        calls.append(to)
        if len(calls) == 2:
            to.write_text('{"cut')
            raise OSError(28, "No space left on device")
        return real_write(result, files, to)

    monkeypatch.setattr(report, "_write_summary", second_fails)
    with pytest.warns(RuntimeWarning, match="summary.json: not written again after the drawing"):
        report.write_all(program, tmp_path, report.summary(program, wall_s=1.0))
    written = json.loads((tmp_path / "summary.json").read_text())
    assert set(written["files"]) == {"summary", "recipes"}
    assert not list(tmp_path.glob("*.partial"))


def test_an_output_folder_replaced_by_a_file_is_a_results_error(program, tmp_path):
    out = tmp_path / "out"
    out.write_text("a user's file where the folder was\n")
    with pytest.raises(report.ResultsNotWritten, match="the folder keeps the files it held"):
        report.write_all(program, out, report.summary(program, wall_s=1.0))
    assert out.read_text() == "a user's file where the folder was\n"


def test_a_staged_name_that_is_a_link_is_replaced_not_written_through(program, tmp_path):
    """A leftover recipes.csv.partial that links to another file (the run's own input, say)
    is removed and written anew; the file it linked to is untouched."""
    precious = tmp_path / "precious.csv"
    precious.write_text("an input of the run\n")
    out = tmp_path / "out"
    out.mkdir()
    (out / "recipes.csv.partial").symlink_to(precious)
    report.write_all(program, out, report.summary(program, wall_s=1.0))
    assert precious.read_text() == "an input of the run\n"
    assert not (out / "recipes.csv").is_symlink()
    assert (out / "recipes.csv").read_text().startswith("vehicle,")


def test_something_under_the_name_of_an_old_order_history_does_not_fail_the_results(
    program, tmp_path
):
    """A run without orders removes an earlier run's orders.csv; a folder of that name
    (no history) stays, and the results are written all the same."""
    (tmp_path / "orders.csv" / "x").mkdir(parents=True)
    files = report.write_all(program, tmp_path, report.summary(program, wall_s=1.0))
    assert set(files) >= {"summary", "recipes"} and (tmp_path / "orders.csv").is_dir()


def test_a_lock_whose_folder_went_away_is_released_without_an_error(tmp_path):
    from plc_runtime.files import lock_file, release_lock

    folder = tmp_path / "out"
    folder.mkdir()
    lock = lock_file(folder / ".lock", "cannot", "busy")
    (folder / ".lock").unlink()
    folder.rmdir()
    folder.write_text("a file now")  # the lock's path is no path any more
    release_lock(lock)
    assert lock.closed
