"""The plc-runtime command line: JSON summary, exit codes and one-line errors."""

import json
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import WIDE_WATCHDOG_NS

from fleet.cli import main
from plc_runtime import Runtime
from plc_runtime.errors import ConfigError

SCRIPT = Path(sys.executable).parent / "plc-runtime"


def test_run_json_summary(capsys):
    assert main(["run", "--program", "demo", "--cycles", "300", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["cycles"] == 300 and summary["state"] == "RUN"
    assert summary["sim_time_s"] == pytest.approx(3.0)
    assert set(summary["tasks"]) == {"main", "slow"}
    assert summary["tasks"]["slow"]["cycles"] == 30
    assert summary["tags"]["flash_count"] == 3  # the demo lamp flashes at 1 Hz
    for key in ("p50", "p99", "max", "mean", "min", "last"):
        assert key in summary["tasks"]["main"]["exec_us"]


def test_duration_and_retain_file(tmp_path, capsys):
    retain = tmp_path / "demo.retain"
    assert (
        main(["run", "--program", "demo", "--duration", "2.5", "--json", "--retain", str(retain)])
        == 0
    )
    first = json.loads(capsys.readouterr().out)
    assert first["cycles"] == 250
    assert (
        main(["run", "--program", "demo", "--duration", "2", "--json", "--retain", str(retain)])
        == 0
    )
    second = json.loads(capsys.readouterr().out)
    assert (
        second["tags"]["flash_count"] == first["tags"]["flash_count"] + 2
    )  # retained across processes


@pytest.mark.parametrize("program", [["--program", "demo"], ["--out", "o"]])
def test_a_retain_file_another_run_uses_is_refused_and_left_alone(
    program, tmp_path, capsys, monkeypatch
):
    """Two runs saving into one retain file would write their values over each other's: a
    lifetime counter lost one run's time without a word. The second is refused in one line
    and nothing of the first's file is touched; the lock goes with the run."""
    import fcntl

    retain = tmp_path / "cc.retain"
    monkeypatch.chdir(tmp_path)
    args = ["run", *program, "--cycles", "5", "--retain", str(retain)]
    assert main(args) == 0
    saved = retain.read_bytes()
    capsys.readouterr()
    with open(tmp_path / "cc.retain.lock", "ab") as other:  # another run, holding it
        fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert main(args) == 2
        assert capsys.readouterr().err == (
            f"plc-runtime: error: retain file {retain}: another run is using it; give another "
            "file\n"
        )
        assert retain.read_bytes() == saved
    assert main(args) == 0  # the lock was let go
    assert not (tmp_path / "cc.retain.lock").exists()


@pytest.mark.parametrize("program", [["--program", "demo"], ["--out", "o"]])
@pytest.mark.parametrize("content", [b"[plant]\nsample = 'model-plant'\n", b"PLCRETAI"])
def test_a_retain_file_that_is_no_retain_file_is_refused_and_left_alone(
    program, content, tmp_path, capsys, monkeypatch
):
    """A configuration named as the retain file by mistake: refused before the run in one
    line, the file as it was, not moved aside and replaced by retain data."""
    mistaken = tmp_path / "mycfg.toml"
    mistaken.write_bytes(content)
    monkeypatch.chdir(tmp_path)
    assert main(["run", *program, "--cycles", "5", "--retain", str(mistaken)]) == 2
    assert capsys.readouterr().err == (
        f"plc-runtime: error: retain file {mistaken}: not a retain file (a text file that "
        "does not begin with PLCRETAIN); it was left as it is: give a new file name, or the "
        "file of an earlier run\n"
    )
    assert [p.name for p in tmp_path.glob("mycfg.toml*")] == ["mycfg.toml"]
    assert mistaken.read_bytes() == content


def test_an_empty_retain_file_is_a_cold_start(tmp_path, capsys):
    """An empty file (one mktemp made) holds nothing to keep: the run starts cold and
    saves into it."""
    retain = tmp_path / "empty.retain"
    retain.write_bytes(b"")
    assert main(["run", "--program", "demo", "--cycles", "5", "--retain", str(retain)]) == 0
    assert retain.read_bytes().startswith(b"PLCRETAIN ")


def test_the_python_api_refuses_a_retain_file_that_is_no_retain_file(tmp_path):
    """FleetProgram(cfg, retain_file=...) checks the file as the command line does: a
    configuration named by mistake is refused and left as it is."""
    from fleet.config import load_config
    from fleet.program import FleetProgram

    mistaken = tmp_path / "mycfg.toml"
    mistaken.write_text("[plant]\n")
    with pytest.raises(ConfigError, match="not a retain file"):
        FleetProgram(load_config(), retain_file=mistaken)
    assert mistaken.read_text() == "[plant]\n" and not list(tmp_path.glob("*.rejected"))


def test_a_run_refused_before_it_starts_makes_no_out_folder(tmp_path, capsys, monkeypatch):
    """Refused because another run holds the retain file: the --out folder the run would
    have made (with its parents) is not left behind, empty, to be mistaken for results."""
    import fcntl

    monkeypatch.chdir(tmp_path)
    with open(tmp_path / "cc.retain.lock", "ab") as other:  # another run, holding it
        fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)
        args = ["run", "--out", "new/out", "--cycles", "5", "--retain", "cc.retain"]
        assert main(args) == 2
    assert "another run is using it" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cc.retain.lock"]
    # a path through "..": the folder it names may be the user's own, empty: kept
    (tmp_path / "mine").mkdir()
    with open(tmp_path / "cc.retain.lock", "ab") as other:
        fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)
        args = ["run", "--out", "new/../mine", "--cycles", "5", "--retain", "cc.retain"]
        assert main(args) == 2
    assert (tmp_path / "mine").is_dir()


def test_a_test_runtime_keeps_its_limit_but_enforces_a_wide_one():
    """tests/conftest.py: a busy machine must not fault an unmarked test's scan; the limit
    given is still what the runtime reports."""
    rt = Runtime(cycle_time=0.01, watchdog=0.15)
    assert rt.watchdog == 0.15 and rt._alarm.limit_ns == rt._watchdog_ns == WIDE_WATCHDOG_NS


@pytest.mark.watchdog
def test_fault_gives_exit_code_1(capsys):
    assert (
        main(["run", "--program", "demo", "--cycles", "10", "--json", "--watchdog", "0.001"]) == 1
    )
    summary = json.loads(capsys.readouterr().out)
    assert summary["state"] == "FAULT" and "watchdog" in summary["fault_reason"]


def test_usage_errors_are_one_line(capsys):
    assert main(["run", "--program", "demo", "--rt"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["plc-runtime: error: --rt and --spin only apply with --realtime"]
    with pytest.raises(SystemExit) as exc:
        main(["run", "--program", "demo", "--cycles", "-3"])
    assert exc.value.code == 2
    assert "must be a finite number > 0" in capsys.readouterr().err


def test_console_script_realtime():
    out = subprocess.run(
        [
            str(SCRIPT),
            "run",
            "--program",
            "demo",
            "--cycles",
            "20",
            "--cycle-time",
            "0.005",
            "--realtime",
            "--json",
            "--watchdog",
            "5000",  # a busy machine must not fault a wall-clock run
        ],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert out.returncode == 0, out.stderr
    summary = json.loads(out.stdout)
    assert summary["clock"] == "wall" and summary["cycles"] == 20
    assert summary["wall_time_s"] >= 18 * 0.005  # absolute deadlines: never faster than real time


@pytest.mark.parametrize(("sig", "code"), [("SIGINT", 0), ("SIGTERM", 143)])
def test_ctrl_c_or_sigterm_finishes_the_cycle_and_prints_the_summary(sig, code):
    """Ctrl-C is how a run without a cycle count ends: exit code 0. SIGTERM (a service
    manager stopping it) ends it as cleanly, and the exit code says it was stopped."""
    proc = subprocess.Popen(
        [str(SCRIPT), "run", "--program", "demo", "--json", "--watchdog", "5000"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert "until Ctrl-C" in proc.stderr.readline()  # it is running now
        proc.send_signal(getattr(subprocess.signal, sig))
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == code, err
    summary = json.loads(out)
    assert summary["state"] == "RUN" and summary["cycles"] > 0
    assert ("stopped by SIGTERM in cycle" in err) == (sig == "SIGTERM")


def test_retain_problems_are_one_line_warnings(tmp_path, capsys):
    """A retain file damaged after its header: a cold start, said in one line."""
    retain = tmp_path / "demo.retain"
    retain.write_text("PLCRETAIN damaged\n")
    assert (
        main(["run", "--program", "demo", "--cycles", "5", "--json", "--retain", str(retain)]) == 0
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(
        "plc-runtime: warning: retain data not used, cold start:"
    )


def test_demo_flashes_at_exactly_one_hertz(capsys):
    assert main(["run", "--program", "demo", "--duration", "100", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["tags"]["flash_count"] == 100


@pytest.mark.parametrize(
    "args",
    [
        ["--duration", "inf"],
        ["--duration", "nan"],
        ["--realtime", "--spin", "nan"],
        ["--cycles", "1.5"],
    ],
)
def test_non_finite_numbers_are_usage_errors(args, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["run", "--program", "demo", *args])
    assert exc.value.code == 2
    assert "Traceback" not in capsys.readouterr().err


@pytest.mark.parametrize("value", ["1e-320", "50", "2"])
def test_a_cycle_time_outside_the_configurations_range_is_a_usage_error(value, capsys):
    """50 is 50 ms meant: in seconds it would run no cycle of a 5 s run, silently."""
    with pytest.raises(SystemExit) as exc:
        main(["run", "--program", "demo", "--cycle-time", value, "--duration", "5"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--cycle-time: is in seconds, 0.0001 to 1 (e.g. 0.05 for 50 ms)" in err


@pytest.mark.parametrize("program", ["demo", "fleet"])
def test_a_run_shorter_than_one_cycle_is_refused(program, tmp_path, capsys):
    args = ["run", "--program", program, "--cycle-time", "0.5", "--duration", "0.1"]
    out = ["--out", str(tmp_path / "out")] if program == "fleet" else []  # (the fleet's)
    assert main([*args, *out]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == "plc-runtime: error: --duration 0.1 s is shorter than one cycle (0.5 s)"
    assert not (tmp_path / "out").exists()


def test_a_configured_run_shorter_than_one_cycle_names_the_key(tmp_path, capsys):
    cfg = tmp_path / "short.toml"
    cfg.write_text(
        '[plant]\nsample = "model-plant"\n[runtime]\ncycle_time_ms = 50\nduration_s = 0.01\n'
        '[[recipes]]\nname = "r"\nfunctions = [2, 1]\n[[vehicles]]\nid = 1\nstart = 0\n'
    )
    assert main(["run", str(cfg), "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"plc-runtime: error: {cfg}: runtime.duration_s 0.01 s is shorter than one cycle (0.05 s)"
    )
