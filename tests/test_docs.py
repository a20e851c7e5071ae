"""Every fenced code block of README.md and docs/*.md runs, as a reader would run it.

The pages are discovered (README.md and every docs/*.md), so a new page or block is covered
without touching this file. A block's language decides what is done with it:

``python``  executed in a fresh namespace, in a temporary folder laid out like a clone. Each
            block must run on its own: a reader copies one snippet, not the page.
``toml``    parsed. A fleet configuration (it has a ``[plant]`` table) is loaded with
            ``fleet.config.parse_config`` and run for a short simulated time without conflict;
            a plant (``[[nodes]]``) is loaded with the plant loader and driven (below).
``nodes``   a compass node list (docs/plant-format.md): loaded as a ``.nodes`` file, driven.
``sh``      every command run by bash in a temporary folder laid out like a clone (symlinks
            to the repository's entries, git-ignored ones left out so outputs such as ``out/``
            land in the temporary folder), with the running venv's ``bin`` first on PATH,
            under a timeout. Its exit code must be 0.

Any other language fails: a block nobody checks is a block that rots.

Driving a plant: one vehicle starts at the entry with one recipe, every function a station
provides and then the exit's function, and must complete it. So a documented plant has to be
usable for what plants are for, and an exit must carry a function for a recipe to end there.

Conventions of ``sh`` blocks (all visible to the reader, none is a hidden test directive):

* a trailing ``\\`` joins lines; ``# ...`` is a comment (kept for the markers below);
* a command whose comment says ``until Ctrl-C`` runs until it has printed something and
  ``SETTLE_S`` more seconds have passed, then gets SIGINT and must exit 0 or 130;
* a line ending in ``&`` starts a server in the background, as in a shell: the block's
  following lines run while it is up, after its loopback ``HOST:PORT`` accepts connections;
  then it gets SIGINT and must exit 0 or 130. A port named that way is replaced in the whole
  block by a free one, so a port in use on the test machine cannot fail the block;
* ``make TARGET`` is checked with ``make -n TARGET`` (the target exists and expands), not
  run: ``make test`` runs this test suite (it would recurse), and every target may
  (re)install the venv, which a test must not do;
* ``plc-runtime run`` gets ``--watchdog 5000`` unless it names one: a busy test machine
  must not fault a scan (the commands' behaviour is under test, not the machine's speed);
* long runs are shortened by the explicit substitutions of ``SHORTEN``.

What the machine must have is checked, never assumed, and a command is skipped only when it is
really missing, with the reason: ``socketcan:IFACE`` needs that interface; commands that set
up the host's network (``modprobe``, ``ip link``) need the kernel modules they load, and then
run together in a private network namespace so the host stays as it is; ``udp_multicast:``
runs in a private network namespace with multicast on loopback (netns.py), so no frame leaves
the machine; ``sudo`` needs root (as root it is dropped: same effect, and sudo need not be
installed); external tools (``EXTERNAL_TOOLS``) must be installed.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from netns import unavailable as netns_unavailable

from blocks.jobs.recipe import Recipe
from fleet.cli import main
from fleet.config import FleetConfig, parse_config
from fleet.program import FleetProgram
from fleet.report import CONFLICT_MONITORS
from topology import Plant, load

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

SHORTEN = [  # (pattern, replacement): long runs cut to seconds; every entry must still match
    (r"^plc-runtime run$", "plc-runtime run --duration 60"),  # the default job's 600 s
    (r"--duration 3600\b", "--duration 20"),
    (r"--duration 600\b", "--duration 60"),
    (r"--duration 60\b", "--duration 5"),
    (r"--duration 10\b", "--duration 1"),
    # benchmarks take minutes: only their command line is checked here, parsed by the
    # script's own parser (tests/options_only.py); their reduced runs are make bench-quick
    # and tests/test_bench_quick.py
    (r"(bench/\w+\.py)\b", r"tests/options_only.py \1"),
]
EXTERNAL_TOOLS = {
    "mbpoll": "Debian package mbpoll; .ci/run installs it",
    "curl": "Debian package curl; .ci/run installs it",
}
WATCHDOG_MS = 5000
SETTLE_S = 1.0  # after its first output, how long an until-Ctrl-C command runs before SIGINT
START_TIMEOUT_S = 60.0  # for a server's port, or an until-Ctrl-C command's first output
COMMAND_TIMEOUT_S = 180.0
PLANT_DRIVE_S = 300.0  # simulated seconds for one vehicle to drive a documented plant
CONFIG_RUN_S = 30.0  # simulated seconds a documented fleet configuration runs
INTERRUPTED = (0, 130)


# ----- finding the blocks --------------------------------------------------------------------
@dataclass
class Block:
    page: Path
    line: int  # 1-based line of the opening fence
    language: str
    text: str

    @property
    def where(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


@dataclass
class Command:
    line: int
    text: str  # the shell command, comment removed, continuations joined
    comment: str
    background: bool = False


@dataclass
class Unit:
    """What one test runs: a non-shell block, or shell commands that belong together."""

    block: Block
    commands: list[Command] = field(default_factory=list)

    @property
    def where(self) -> str:
        line = self.commands[0].line if self.commands else self.block.line
        return f"{self.block.page.relative_to(ROOT)}:{line}"


FENCE = re.compile(r"^(\s*)(`{3,}|~{3,})\s*([\w+-]*)[^\n]*$")


def blocks(page: Path) -> Iterator[Block]:
    """The fenced blocks of a Markdown page (indented fences, as in list items, included)."""
    lines = page.read_text(encoding="utf-8").splitlines()
    k = 0
    while k < len(lines):
        opening = FENCE.match(lines[k])
        if not opening:
            k += 1
            continue
        indent, fence, language = opening.groups()
        body = []
        end = k + 1
        while end < len(lines) and not (
            lines[end].strip().startswith(fence) and not lines[end].strip().strip(fence[0])
        ):
            body.append(lines[end][len(indent) :] if lines[end].startswith(indent) else lines[end])
            end += 1
        assert end < len(lines), f"{page.name}:{k + 1}: unclosed code fence"
        yield Block(page, k + 1, language, "\n".join(body) + "\n")
        k = end + 1


def split_comment(line: str) -> tuple[str, str]:
    """(command, comment): ``#`` starts a comment at a word start outside quotes."""
    quote = None
    for i, ch in enumerate(line):
        if quote:
            if ch == quote:
                quote = None
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (i == 0 or line[i - 1].isspace()):
            return line[:i].rstrip(), line[i + 1 :].strip()
    return line.rstrip(), ""


def commands(block: Block) -> list[Command]:
    out: list[Command] = []
    pending, start, notes = "", 0, []
    for number, raw in enumerate(block.text.splitlines(), start=block.line + 1):
        text, comment = split_comment(raw)
        if not pending:
            start = number
        if comment:
            notes.append(comment)
        if text.endswith("\\"):
            pending += text[:-1] + " "
            continue
        text = (pending + text).strip()
        pending = ""
        if not text:
            notes = []
            continue
        background = text.endswith("&") and not text.endswith("&&")
        out.append(Command(start, text.rstrip("&").strip(), " ".join(notes), background))
        notes = []
    return out


def units() -> list[Unit]:
    out: list[Unit] = []
    for page in PAGES:
        for block in blocks(page):
            if block.language != "sh":
                out.append(Unit(block))
                continue
            cmds = commands(block)
            if any(_host_setup(c.text) for c in cmds):
                out.append(Unit(block, cmds))  # one script, in one namespace
                continue
            k = 0
            while k < len(cmds):
                if cmds[k].background:  # a server and the lines that use it
                    out.append(Unit(block, cmds[k:]))
                    break
                out.append(Unit(block, [cmds[k]]))
                k += 1
    return out


# ----- what a command needs ------------------------------------------------------------------
def _host_setup(text: str) -> bool:
    return bool(re.search(r"\b(modprobe|ip link)\b", text))


def _program(text: str) -> str:
    words = text.split()
    return words[1] if words[0] == "sudo" and len(words) > 1 else words[0]


def _module_available(name: str) -> str | None:
    """None if kernel module ``name`` is loaded or can be loaded, else why not."""
    if Path("/sys/module", name).exists():
        return None
    if not shutil.which("modprobe"):
        return f"the {name} kernel module is not loaded and there is no modprobe to load it"
    probe = subprocess.run(["modprobe", "-n", name], capture_output=True, text=True, check=False)
    if probe.returncode != 0:
        return (
            f"no {name} kernel module on this machine (modprobe -n {name}: {probe.stderr.strip()})"
        )
    return None


def skip_reason(unit: Unit) -> str | None:
    for cmd in unit.commands:
        text = cmd.text
        if text.startswith("sudo ") and os.geteuid() != 0:
            return f"{text!r} needs root"
        for module in re.findall(r"\bmodprobe\s+(?:-\S+\s+)*(\w+)", text):
            if reason := _module_available(module):
                return reason
        for iface in re.findall(r"\bsocketcan:(\w+)", text):
            if not Path("/sys/class/net", iface).exists():
                return f"SocketCAN interface {iface} does not exist here (docs/protocol.md sets it up; it needs the vcan kernel module)"
        if ("udp_multicast:" in text or _host_setup(text)) and (reason := netns_unavailable()):
            return f"a private network namespace is needed: {reason}"
        tool = _program(text)
        if tool in EXTERNAL_TOOLS and not shutil.which(tool):
            return f"{tool} is not installed ({EXTERNAL_TOOLS[tool]})"
    return None


# ----- the temporary clone ---------------------------------------------------------------------
def clone_folder(tmp: Path) -> Path:
    """A folder laid out like a clone: symlinks to the repository's entries and its venv, none
    to git-ignored ones (out/, *.retain, caches), so what commands write stays here."""
    names = sorted(p.name for p in ROOT.iterdir() if p.name not in (".git", ".venv"))
    ignored = set()
    if shutil.which("git") and (ROOT / ".git").exists():
        check = subprocess.run(
            ["git", "-C", str(ROOT), "check-ignore", *names],
            capture_output=True,
            text=True,
            check=False,
        )
        ignored = set(check.stdout.split())
    for name in names:
        if name not in ignored:
            (tmp / name).symlink_to(ROOT / name)
    (tmp / ".venv").symlink_to(sys.prefix)
    return tmp


def environment() -> dict[str, str]:
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    return env


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def shorten(text: str) -> str:
    """``SHORTEN`` applied to the command as written, in one pass: a replacement is never
    shortened again (``--duration 600`` becomes 60, not 5)."""
    edits = sorted(
        (m.start(), m.end(), m.expand(replacement))
        for pattern, replacement in SHORTEN
        for m in re.finditer(pattern, text)
    )
    out, pos = [], 0
    for start, end, new in edits:
        if start >= pos:
            out += [text[pos:start], new]
            pos = end
    return "".join(out) + text[pos:]


def prepare(text: str) -> str:
    """The command as the test runs it: shortened, watchdog widened, sudo dropped as root."""
    text = shorten(text)
    if re.match(r"plc-runtime run\b", text) and "--watchdog" not in text:
        text = text.replace("plc-runtime run", f"plc-runtime run --watchdog {WATCHDOG_MS}", 1)
    if text.startswith("sudo "):
        text = text[len("sudo ") :]
    make = re.fullmatch(r"make\s+(\S+)", text)
    if make:  # not run: make test is this suite (recursion); every target may reinstall .venv
        text = f"make -n {make.group(1)}"
    return text


@dataclass
class Process:
    text: str
    proc: subprocess.Popen
    log: Path

    def output(self) -> str:
        return self.log.read_text(errors="replace")[-3000:]

    def interrupt(self) -> int:
        """SIGINT (Ctrl-C) to the command's process group; its exit code."""
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGINT)
        try:
            return self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()
            pytest.fail(f"{self.text!r} did not stop within 30 s of SIGINT:\n{self.output()}")

    def kill(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()


def start(text: str, cwd: Path, isolated: bool) -> Process:
    log = cwd / f".command-{time.monotonic_ns()}.log"
    script = text
    if isolated:  # a private network namespace: lo up, multicast on loopback, nothing leaves
        script = f"ip link set lo up && ip route add 224.0.0.0/4 dev lo && {text}"
    argv = ["unshare", "-n", "bash", "-c", script] if isolated else ["bash", "-c", script]
    with log.open("wb") as out:
        proc = subprocess.Popen(
            argv,
            cwd=cwd,
            env=environment(),
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,  # its own process group: SIGINT reaches every process
        )
    return Process(text, proc, log)


def runs_on(proc: subprocess.Popen, seconds: float) -> bool:
    """Wait up to ``seconds`` for ``proc`` to end; True if it is still running. (Waiting on
    the process, not sleeping: an early exit is seen at once.)"""
    try:
        proc.wait(timeout=seconds)
    except subprocess.TimeoutExpired:
        return True
    return False


def wait_for_port(server: Process, port: int) -> None:
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                return
        except OSError:
            if not runs_on(server.proc, 0.1):
                pytest.fail(f"{server.text!r} exited {server.proc.returncode}:\n{server.output()}")
    pytest.fail(f"{server.text!r}: port {port} not open after {START_TIMEOUT_S} s")


def run_foreground(cmd: Command, text: str, cwd: Path, isolated: bool) -> None:
    process = start(text, cwd, isolated)
    try:
        if "until Ctrl-C" in cmd.comment:
            deadline = time.monotonic() + START_TIMEOUT_S
            while (
                not process.log.stat().st_size
                and time.monotonic() < deadline
                and runs_on(process.proc, 0.05)
            ):
                pass
            if not runs_on(process.proc, SETTLE_S):
                pytest.fail(f"{text!r} should run until Ctrl-C but ended:\n{process.output()}")
            code = process.interrupt()
            assert code in INTERRUPTED, f"{text!r} exited {code} on Ctrl-C:\n{process.output()}"
            return
        try:
            code = process.proc.wait(timeout=COMMAND_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            pytest.fail(f"{text!r} still running after {COMMAND_TIMEOUT_S} s:\n{process.output()}")
        assert code == 0, f"{text!r} exited {code}:\n{process.output()}"
    finally:
        process.kill()


def run_shell(unit: Unit, cwd: Path) -> None:
    texts = [prepare(c.text) for c in unit.commands]
    for port in {p for t in texts for p in re.findall(r"(?:127\.0\.0\.1|localhost):(\d+)", t)}:
        new = str(free_port())
        texts = [re.sub(rf"\b{port}\b", new, t) for t in texts]
    if _host_setup(" ".join(texts)):  # the whole block as one script, in its own namespace
        run_foreground(unit.commands[0], " && ".join(texts), cwd, isolated=True)
        return
    isolated = ["udp_multicast:" in t for t in texts]
    server = None
    try:
        for k, (cmd, text) in enumerate(zip(unit.commands, texts, strict=True)):
            if cmd.background:
                server = start(text, cwd, isolated[k])
                for port in re.findall(r"(?:127\.0\.0\.1|localhost):(\d+)", text):
                    wait_for_port(server, int(port))
            else:
                run_foreground(cmd, text, cwd, isolated[k])
        if server is not None:
            code = server.interrupt()
            assert code in INTERRUPTED, f"{server.text!r} exited {code}:\n{server.output()}"
    finally:
        if server is not None:
            server.kill()


# ----- TOML and plants -----------------------------------------------------------------------
def drive_plant(plant: Plant, where: str) -> None:
    """One vehicle from the entry through every station function and on to the exit."""
    for exit_node in plant.with_role("exit"):
        assert plant.node(exit_node).functions, (
            f"{where}: exit node {exit_node} provides no function, so no recipe can end there "
            "(give it functions = [1])"
        )
    clusters: dict[int, list[int]] = {}
    for node in plant.nodes:
        for f in node.functions:
            clusters.setdefault(f, []).append(node.id)
    station_functions = [f for n in plant.nodes if n.role == "station" for f in n.functions]
    exit_functions = [f for n in plant.nodes if n.role == "exit" for f in n.functions]
    steps = list(dict.fromkeys(station_functions)) + exit_functions[:1]
    if not steps:
        return  # nothing to drive to: a bare graph (a grid map) is only loaded
    entries = list(plant.with_role("entry")) or [plant.nodes[0].id]
    cfg = FleetConfig(
        source=where,
        plant=plant,
        starts={1: entries[0]},
        recipes={"tour": Recipe("tour", tuple(steps))},
        vehicle_recipes={1: ["tour"]},
        clusters=clusters,
        rounds=1,
        watchdog=5.0,
    )
    program = FleetProgram(cfg)
    try:
        program.rt.start()
        done = program.rt.run_until(
            lambda: bool(program.completed), max_cycles=round(PLANT_DRIVE_S / cfg.cycle_time)
        )
        assert done, f"{where}: one vehicle did not complete the recipe {steps} on this plant"
    finally:
        program.close()


def check_toml(block: Block, tmp: Path) -> None:
    doc = tomllib.loads(block.text)
    if "nodes" in doc:
        path = tmp / "plant.toml"
        path.write_text(block.text, encoding="utf-8")
        drive_plant(load(path), block.where)
    elif "plant" in doc:
        cfg = parse_config(block.text, block.where, tmp)
        cfg.watchdog = 5.0
        program = FleetProgram(cfg)
        try:
            program.rt.start()
            program.rt.run(duration=CONFIG_RUN_S)
            assert program.rt.state == "RUN", program.rt.fault_reason
            assert program.monitor.head_on == 0 and program.monitor.node == 0
        finally:
            program.close()


UNITS = units()


# ----- the tests -----------------------------------------------------------------------------
def test_every_page_is_found_and_has_blocks():
    assert ROOT / "README.md" in PAGES and len(PAGES) >= 2
    assert {u.block.language for u in UNITS} >= {"python", "sh", "toml"}


INDENTED_COMMAND = re.compile(r"^ {4,}(\.venv/bin/|plc-runtime |make |python |curl |mbpoll )")


def test_no_command_hides_in_an_indented_block():
    """Markdown shows four indented spaces as code too, but only fenced blocks are run
    here: a command written that way would never be checked."""
    hidden = []
    for page in PAGES:
        fenced = {k for b in blocks(page) for k in range(b.line, b.line + b.text.count("\n") + 1)}
        for k, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1):
            if k not in fenced and INDENTED_COMMAND.match(line):
                hidden.append(f"{page.relative_to(ROOT)}:{k}: {line.strip()}")
    assert not hidden, "fence these commands (```sh):\n" + "\n".join(hidden)


def test_benchmark_options_are_parsed_by_the_script_itself(tmp_path):
    """A documented bench command is checked by its script's own parser: an option it does
    not take fails (``--help`` would have ended the parse before reaching it)."""
    script = ROOT / "tests" / "options_only.py"
    bench = ROOT / "bench" / "allocation.py"
    ok = subprocess.run(
        [sys.executable, script, bench, "--experiments", "buffer", "--seeds", "3"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert ok.returncode == 0, ok.stderr
    bad = subprocess.run(
        [sys.executable, script, bench, "--experiments", "buffer", "--no-such-option"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert bad.returncode == 2 and "unrecognized arguments: --no-such-option" in bad.stderr


def test_shortening_applies_each_substitution_once():
    assert shorten("plc-runtime run") == "plc-runtime run --duration 60"
    assert shorten("run --duration 600 --json") == "run --duration 60 --json"
    assert shorten("run --duration 60") == "run --duration 5"
    assert shorten("run --duration 6000") == "run --duration 6000"


def test_every_shortening_is_used():
    """A substitution that no command needs any more is removed, not left to rot."""
    texts = [c.text for u in UNITS for c in u.commands]
    for pattern, _ in SHORTEN:
        assert any(re.search(pattern, t) for t in texts), f"SHORTEN entry {pattern!r} unused"


def test_route_json_keys_are_the_documented_ones(capsys):
    """The README lists what ``route --json`` prints; scripts read those keys."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    start = readme.index("`--json` prints")
    documented = set(re.findall(r"`(\w+)`", readme[start : readme.index("Exit code", start)]))
    assert main(["route", "model-plant", "--from", "0", "--to", "24", "--json"]) == 0
    assert set(json.loads(capsys.readouterr().out)) == documented


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """One clone folder per block: a reader runs a block's lines in order, in one place (a
    retain file written by one line is there for the next)."""
    made: dict[tuple[Path, int], Path] = {}

    def folder(block: Block) -> Path:
        key = (block.page, block.line)
        if key not in made:
            made[key] = clone_folder(tmp_path_factory.mktemp("docs"))
        return made[key]

    return folder


@pytest.mark.parametrize("unit", UNITS, ids=lambda u: u.where)
def test_block(unit, folders, monkeypatch):
    block = unit.block
    cwd = folders(block)
    if block.language == "sh":
        if reason := skip_reason(unit):
            pytest.skip(reason)
        run_shell(unit, cwd)
    elif block.language == "python":
        monkeypatch.chdir(cwd)
        exec(compile(block.text, block.where, "exec"), {"__name__": "__docs__"})
    elif block.language == "toml":
        check_toml(block, cwd)
    elif block.language == "nodes":
        path = cwd / "plant.nodes"
        path.write_text(block.text, encoding="utf-8")
        drive_plant(load(path), block.where)
    else:
        pytest.fail(
            f"{block.where}: a ```{block.language or '(no language)'} block is not checked; "
            "use python, sh, toml or nodes (see tests/test_docs.py)"
        )


def test_every_summary_key_of_a_run_is_documented(tmp_path, capsys):
    """docs/fleet-config.md lists the keys of ``run --json`` as a contract for scripts: a
    run with transport orders and one with recipes print none it does not name."""
    page = (ROOT / "docs" / "fleet-config.md").read_text(encoding="utf-8")
    start = page.index("### Summary keys")
    after = re.search(r"\n#{1,3} ", page[start + 1 :])
    section = page[start : start + 1 + after.start()] if after else page[start:]
    documented = set(re.findall(r"`(\w+)`", section))
    examples = ROOT / "examples"
    printed: set[str] = set()
    for config in (examples / "workshop-orders.toml", examples / "workshop.toml"):
        args = ["run", str(config), "--duration", "5", "--json", "--out", str(tmp_path / "o")]
        assert main(args) == 0
        run = json.loads(capsys.readouterr().out)
        assert run["conflict_monitor"] in CONFLICT_MONITORS
        printed |= set(run)
    assert printed - documented == set()


def test_every_conflict_monitor_value_is_documented_exactly():
    """Scripts compare the summary's ``conflict_monitor`` string: the Summary keys table
    names each value the runs print, letter for letter."""
    page = (ROOT / "docs" / "fleet-config.md").read_text(encoding="utf-8")
    row = next(line for line in page.splitlines() if line.startswith("| `conflict_monitor` |"))
    documented = set(re.findall(r"`([^`]+)`", row)) - {"conflict_monitor"}
    assert documented == set(CONFLICT_MONITORS)
