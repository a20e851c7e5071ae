"""The fleet program from the command line and its configuration file: the JSON summary
contract, the output folder, errors that name the file and key, the real-time run with the
vehicles in their own process."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import pytest
from netns import realtime_run, unavailable

from fleet.cli import main
from fleet.config import DEFAULT_CONFIG, check_config, load_config, parse_config
from plc_runtime.errors import ConfigError

CONTRACT = {
    "cycles",
    "overruns",
    "state",
    "sim_time_s",
    "vehicles",
    "recipes_completed",
    "stations_visited",
    "replans",
    "waits",
    "deadlocks_resolved",
    "head_on_conflicts",
    "node_conflicts",
    "station_utilisation",
    "tasks",
}


def test_default_job_json_summary_and_output_files(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", "--duration", "90", "--json", "--out", str(out)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert CONTRACT <= set(summary)
    assert summary["state"] == "RUN" and summary["cycles"] == 9000
    assert summary["sim_time_s"] == pytest.approx(90.0)
    assert set(summary["vehicles"]) == {"1", "2", "3", "4"}
    assert summary["recipes_completed"] >= 2
    assert summary["head_on_conflicts"] == 0 and summary["node_conflicts"] == 0
    assert set(summary["tasks"]) == {"fleet", "plant"}
    assert json.loads((out / "summary.json").read_text())["cycles"] == 9000
    rows = list(csv.DictReader((out / "recipes.csv").open()))
    assert rows and {r["vehicle"] for r in rows} <= {"1", "2", "3", "4"}
    done = [r for r in rows if r["recipe_finished_s"]]
    assert len({(r["vehicle"], r["round"]) for r in done}) == summary["recipes_completed"]
    for r in rows:
        assert float(r["dispatched_s"]) <= float(r["arrived_s"]) <= float(r["done_s"])
    assert (out / "routes.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_traffic_mode_is_overridden_on_the_command_line(tmp_path, capsys):
    args = ["run", "--duration", "30", "--json", "--out", str(tmp_path / "out")]
    assert main([*args, "--traffic", "time_windows"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["traffic"]["mode"] == "time_windows" and summary["traffic"]["rounds"] > 0
    assert summary["head_on_conflicts"] == summary["node_conflicts"] == 0
    with pytest.raises(SystemExit) as exc:
        main([*args, "--traffic", "timed"])
    assert exc.value.code == 2 and "invalid choice: 'timed'" in capsys.readouterr().err


def test_config_file_on_the_command_line(tmp_path, capsys):
    cfg = tmp_path / "fleet.toml"
    cfg.write_text(
        DEFAULT_CONFIG.read_text().replace('strategy = "random"', 'strategy = "least_utilised"')
    )
    assert main(["run", str(cfg), "--cycles", "500", "--json", "--out", str(tmp_path / "o")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["config"] == str(cfg) and summary["cycles"] == 500


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (("start = 10", "start = 99"), "vehicles[1].start: node 99 is not in plant 'model-plant'"),
        (("start = 10", "start = 0"), "vehicles[1].start: node 0 is already vehicle 1's start"),
        (("cycle_time_ms = 10", "cycle_time_ms = 0"), "runtime.cycle_time_ms: must be in"),
        (
            ("watchdog_ms = 150", "watchdog_ms = 0"),
            "runtime.watchdog_ms: must be > 0 and <= 6e+06, got 0",
        ),
        (
            ("watchdog_ms = 150", "watchdog_ms = 6000000.5"),
            "runtime.watchdog_ms: must be > 0 and <= 6e+06, got 6000000.5",
        ),
        (('strategy = "random"', 'strategy = "best"'), "stations.strategy: must be one of"),
        (
            ("functions = [6, 5, 1]", "functions = [6, 9, 1]"),
            "needs function 9, which no station provides",
        ),
        (("lookahead = 2", "lookahead = 2\nspeed = 3"), "routing.speed: unknown key"),
        (("until_s = 300", "until_s = 100"), "blockades[0].until_s: must be after at_s"),
        (("to = 8", "to = 9"), "blockades[0].to: no routable segment between nodes 7 and 9"),
        (("[plant]", "[plant\n"), "fleet.toml: "),
        (  # a required key misspelled: the misspelling is named too
            ("start = 10", "strat = 10"),
            "vehicles[1].start: missing (is 'strat', given, a misspelling of it?)",
        ),
    ],
)
def test_bad_configuration_names_the_file_and_key(tmp_path, change, message):
    text = DEFAULT_CONFIG.read_text()
    assert change[0] in text
    path = tmp_path / "fleet.toml"
    path.write_text(text.replace(change[0], change[1], 1))
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    assert message in str(exc.value) and str(path) in str(exc.value)


def test_orders_no_vehicle_takes_say_what_to_change_in_the_file(tmp_path):
    """Every vehicle names its recipes, so none is left for the orders: the message says
    what to write in the file, not the name of a field inside the program."""
    text = re.sub(
        r"(\[\[vehicles\]\]\nid = \d+\nstart = \d+\n)",
        r'\1recipes = ["wash-inspect"]\n',
        DEFAULT_CONFIG.read_text(),
    )
    (tmp_path / "orders.csv").write_text("id,get,put\n")
    path = tmp_path / "fleet.toml"
    path.write_text(text + '\n[orders]\nfile = "orders.csv"\n')
    with pytest.raises(ConfigError) as exc:
        check_config(load_config(path))  # as a run does, before it starts
    assert str(exc.value) == (
        f"{path}: orders: given, but no vehicle takes orders: every [[vehicles]] entry names "
        "its recipes; leave recipes out of those that should take orders"
    )


@pytest.mark.parametrize("ms", [0.5, 10000, 6e6])
def test_the_watchdog_takes_in_the_file_what_the_command_line_takes(tmp_path, ms):
    """A long watchdog for batch runs is as good in the file as with --watchdog, up to the
    runtime's own limit."""
    path = tmp_path / "fleet.toml"
    path.write_text(DEFAULT_CONFIG.read_text().replace("watchdog_ms = 150", f"watchdog_ms = {ms}"))
    assert load_config(path).watchdog == ms / 1e3


def test_a_configuration_saved_with_a_byte_order_mark_loads(tmp_path):
    """Editors on Windows may save UTF-8 with a BOM, which TOML itself does not allow; the
    configuration reads as without it, and its errors keep their lines."""
    path = tmp_path / "fleet.toml"
    path.write_bytes(DEFAULT_CONFIG.read_bytes())
    plain = load_config(path)
    path.write_bytes(b"\xef\xbb\xbf" + DEFAULT_CONFIG.read_bytes())
    assert load_config(path) == plain
    path.write_bytes(b"\xef\xbb\xbf[plant\n")
    with pytest.raises(ConfigError, match=r"\(at line 1, column 7\)"):
        load_config(path)


def test_an_output_folder_holds_one_runs_results(tmp_path, capsys):
    """Another run writing into the same folder is refused before anything runs, and an
    earlier run's orders.csv does not stay beside the results of a run without orders."""
    import fcntl

    out = tmp_path / "out"
    out.mkdir()
    (out / "orders.csv").write_text(  # an earlier run's order history
        "id,get,put,vehicle,state,created_s\nfrom-an-earlier-run,20,21,1,FINISHED,0\n"
    )
    with open(out / ".plc-runtime.lock", "ab") as other:  # another run, holding the lock
        fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert main(["run", "--cycles", "10", "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err == (
            f"plc-runtime: error: --out {out}: another run is writing its results there; "
            "give another folder\n"
        )
        assert (out / "orders.csv").exists()  # refused: nothing touched
    assert main(["run", "--cycles", "10", "--json", "--out", str(out)]) == 0
    assert "orders" not in json.loads(capsys.readouterr().out)["files"]
    assert not (out / "orders.csv").exists()
    assert main(["run", "--cycles", "10", "--out", str(out)]) == 0  # the lock was let go


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["run", "--bus", "bogus:x"], "--bus 'bogus:x': unknown CAN interface 'bogus' (python"),
        (["run", "--dispatch", "dhht"], "--dispatch: default.toml has no vehicles taking"),
        (["run", "--program", "demo", "--out", "o"], "--out: for the fleet program, not 'demo'"),
        (["run", "PLANT"], "a plant file, not a fleet configuration; a configuration names"),
        (["tags", "PLANT"], "a plant file, not a fleet configuration; a configuration names"),
        (["plant", "show", "CONFIG"], "(this looks like a fleet configuration: its plant is"),
        (["plant", "validate", "."], ": a folder, not a plant file"),
        (["run", "--out", "FILE"], "a file, not a folder"),
        (["vehicles", "--plant", "model-plant", "--bus", "vcan:0"], "unknown CAN interface"),
        (["run", "ORDERS"], "an order file (.csv), not a fleet configuration (TOML); a"),
        (["run", "--out", ""], "argument --out: an empty name"),
        (["plant", "show", "model-plant", "--png", ""], "argument --png: an empty file name"),
        (["plant", "show", "model-plant", "--png", "NOFOLDER/p.png"], "--png "),
        (["route", "model-plant", "--from", "0", "--to", "24", "--cell-size", "5"], "--cell-size"),
        (
            ["route", "model-plant", "--from", "0", "--to", "2", "--highway-factor", "0"],
            ">= 1: '0'",
        ),
    ],
    ids=[
        "bus",
        "dispatch",
        "demo-out",
        "run-plant",
        "tags-plant",
        "show-config",
        "dir",
        "out",
        "vehicles-bus",
        "run-orders",
        "empty-out",
        "empty-png",
        "png-folder",
        "cell-size",
        "highway-factor",
    ],  # fmt: skip
)
def test_mistaken_inputs_are_named_for_what_they_are(args, message, tmp_path, capsys):
    """A plant where a configuration belongs (and the other way round), a folder for a
    file, an interface python-can does not have, an option that would be ignored: one
    line that says what it is."""
    examples = DEFAULT_CONFIG.parent.parent / "examples"
    (tmp_path / "FILE").write_text("")
    known = {
        "PLANT": examples / "plants" / "workshop.toml",
        "CONFIG": DEFAULT_CONFIG,
        "ORDERS": examples / "orders" / "workshop.csv",
        "NOFOLDER/p.png": tmp_path / "no" / "p.png",
    }
    args = [str(known.get(a, tmp_path / a if a in ("FILE", ".") else a)) for a in args]
    try:
        code = main([*args, *(["--cycles", "1"] if args[0] == "run" else [])])
    except SystemExit as exc:  # a usage error found by the argument parser
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
    assert not any(tmp_path.glob("*.png")) and not (tmp_path / "no").exists()


def test_an_empty_token_is_named_empty(monkeypatch, capsys):
    monkeypatch.setenv("PLC_RUNTIME_TOKEN", "")
    assert main(["run", "--web", "127.0.0.1:0", "--cycles", "1"]) == 2
    assert capsys.readouterr().err == (
        "plc-runtime: error: PLC_RUNTIME_TOKEN is empty: give a token, or unset it for a new one\n"
    )


def test_two_vehicles_starting_in_one_single_vehicle_area_are_refused(tmp_path):
    examples = DEFAULT_CONFIG.parent.parent / "examples"
    plant = (examples / "plants" / "distribution-centre.toml").resolve()
    text = (examples / "distribution-centre.toml").read_text()
    text = text.replace('file = "plants/distribution-centre.toml"', f'file = "{plant}"')
    path = tmp_path / "fleet.toml"
    path.write_text(text.replace("start = 301", "start = 21").replace("start = 302", "start = 221"))
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    assert (
        f"{path}: vehicles[1].start: node 221 is in single-vehicle area 'receiving-1', "
        "where vehicle 1 starts (node 21): one vehicle per area"
    ) in str(exc.value)


def test_bad_configuration_is_one_line_on_the_cli(tmp_path, capsys):
    path = tmp_path / "fleet.toml"
    path.write_text('[plant]\nsample = "nowhere"\n')
    assert main(["run", str(path), "--cycles", "10"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "plant.sample: unknown sample plant 'nowhere'" in err[0]
    assert main(["run", str(tmp_path / "missing.toml")]) == 2
    assert "cannot read" in capsys.readouterr().err


def test_external_vehicles_need_a_bus_another_process_can_reach(capsys):
    assert main(["run", "--vehicles", "external", "--cycles", "10"]) == 2
    assert "cannot reach the in-process virtual bus" in capsys.readouterr().err


def test_parse_config_keeps_vehicle_recipes_distinct():
    cfg = parse_config(DEFAULT_CONFIG.read_text(), "default")
    firsts = [cfg.vehicle_recipes[v][0] for v in sorted(cfg.vehicle_recipes)]
    assert len(set(firsts)) == 4 and cfg.level == "4"


@pytest.mark.skipif(unavailable() is not None, reason=unavailable() or "")
def test_realtime_run_with_the_vehicles_in_their_own_process(tmp_path):
    """Wall clock, the vehicles a child process on udp_multicast inside a private network
    namespace; its conflict monitor reports back into the summary."""
    summary = realtime_run(
        f"--duration 12 --bus udp_multicast:239.74.163.9 --out {tmp_path / 'out'}"
    )
    assert summary["stations_visited"] >= 1
    assert summary["drivers"]["can"]["frames_in"] > 0
    assert Path(tmp_path / "out" / "routes.png").exists()


def test_a_signal_while_a_finished_run_writes_its_results_lets_them_finish(
    tmp_path, capsys, monkeypatch
):
    """Ctrl-C that comes only once the run has ended by itself, while its results are
    written: the writing finishes, the summary says not interrupted, and the exit code and
    the line on stderr say the same (they said interrupted, the summary did not)."""
    import os
    import signal

    from fleet.commands import run as run_command

    real_write_all = run_command.write_all

    def interrupted_while_writing(program, out, result):
        os.kill(os.getpid(), signal.SIGINT)  # the run's handler takes it: no exception
        return real_write_all(program, out, result)

    monkeypatch.setattr(run_command, "write_all", interrupted_while_writing)
    out = tmp_path / "out"
    assert main(["run", "--cycles", "20", "--json", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["interrupted"] is False
    assert json.loads((out / "summary.json").read_text())["interrupted"] is False
    assert captured.err.endswith(
        "plc-runtime: interrupted after the run had ended; its results are written whole\n"
    )


def test_ctrl_c_again_and_again_while_results_are_written_does_not_cut_them_short(
    tmp_path, capsys, monkeypatch
):
    """An impatient operator presses Ctrl-C twice, then SIGTERM comes, while a finished
    run's results are written: the writing finishes all the same (the second Ctrl-C raised
    in the middle of it and left the run's files half written beside an earlier run's)."""
    import os
    import signal

    from fleet import report
    from fleet.commands import run as run_command

    real_write_csv = report.write_csv

    def interrupted_while_writing(program, path):
        for number in (signal.SIGINT, signal.SIGINT, signal.SIGTERM):
            os.kill(os.getpid(), number)
        return real_write_csv(program, path)

    monkeypatch.setattr(report, "write_csv", interrupted_while_writing)
    out = tmp_path / "out"
    assert main(["run", "--cycles", "20", "--json", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    written = json.loads((out / "summary.json").read_text())
    assert written["interrupted"] is False and set(written["files"]) >= {"recipes", "routes"}
    assert (out / "recipes.csv").read_text().startswith("vehicle,")
    assert captured.err.endswith("its results are written whole\n")
    assert run_command.write_all is report.write_all


def test_ctrl_c_while_a_run_is_summed_up_does_not_lose_its_results(tmp_path, capsys, monkeypatch):
    """Ctrl-C, again and again, after the run has ended and before its results are written
    (the summary is being made): noted, and the results are written whole (a third Ctrl-C
    landed in the summary and nothing was written or printed)."""
    import os
    import signal

    from fleet.commands import run as run_command

    real_summary = run_command.summary

    def interrupted_while_summing_up(*args, **kwargs):
        for _ in range(3):
            os.kill(os.getpid(), signal.SIGINT)
        return real_summary(*args, **kwargs)

    monkeypatch.setattr(run_command, "summary", interrupted_while_summing_up)
    out = tmp_path / "out"
    assert main(["run", "--cycles", "20", "--json", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["interrupted"] is False
    assert json.loads((out / "summary.json").read_text())["cycles"] == 20
    assert captured.err.endswith("its results are written whole\n")


def test_results_that_cannot_be_written_are_shown_and_the_exit_code_says_so(
    tmp_path, capsys, monkeypatch
):
    """A full disk when the results are written: the summary still reaches stdout, one
    line on stderr says what was not written, exit code 2, no traceback."""
    from fleet import report

    def disk_full(program, path):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(report, "write_csv", disk_full)
    out = tmp_path / "out"
    assert main(["run", "--cycles", "20", "--json", "--out", str(out)]) == 2
    captured = capsys.readouterr()
    shown = json.loads(captured.out)
    assert shown["cycles"] > 0 and "files" not in shown
    assert captured.err.endswith(  # after the model plant's liveness warning
        f"\nplc-runtime: error: --out {out}: the results were not written (recipes.csv: No "
        "space left on device); the folder keeps the files it held\n"
    )
    assert "Traceback" not in captured.err
    assert not out.exists() or not any(out.iterdir())
