"""The generic ``run`` machinery of a command line built on the runtime.

A program is a function that builds a :class:`Runtime` from a clock, a cycle time, a
watchdog and a retain file. :func:`run_program` runs it headless: on the virtual clock as
fast as it can (the default), paced for people to watch with ``--speed X``, or on the wall
clock with ``--realtime``. On a terminal it
shows a live status screen; at the end it prints a summary (``--json``: one JSON object on
stdout). Errors are one line on stderr and a non-zero exit code. An application adds its
own commands and programs around this.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import time
import unicodedata
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, NoReturn

from rich.console import Console
from rich.live import Live
from rich.table import Table

from .clock import PacedClock, VirtualClock, WallClock
from .files import release_lock
from .io import IoDriver
from .retain import claim_retain_file
from .runtime import MAX_TIME, Runtime

EXIT_FAULT = 1
EXIT_ERROR = 2
EXIT_INTERRUPTED = 130
REDRAW_INTERVAL = 0.25  # seconds of wall time between two redraws of the live screen


class CliError(Exception):
    """A usage error to report as one line."""


MAX_DURATION_S = 1e7  # some 116 days, as a configuration's duration_s
MAX_CYCLES = 10**10
MIN_SPEED, MAX_SPEED = 1e-3, 1e6  # simulated seconds per wall second


def positive(kind: type, least: float | None = None, most: float | None = None) -> Any:
    """An argparse type: a finite number of ``kind`` greater than 0 (``least`` > 0 instead,
    where given), and at most ``most`` where given (a typo of a few digits must not ask for a run of
    centuries, or a pace at which no cycle ever ends)."""

    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            number = "a whole number" if kind is int else "a number"
            hint = as_digits(text) if kind is int else ""
            raise argparse.ArgumentTypeError(f"not {number}: {text!r}{hint}") from None
        if least is not None and not (math.isfinite(value) and value >= least):
            # one message for every value refused below, not "> 0" for 0 and ">= 1" for 0.5
            raise argparse.ArgumentTypeError(f"must be a finite number >= {least:g}: {text!r}")
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"must be a finite number > 0: {text!r}")
        if most is not None and value > most:
            raise argparse.ArgumentTypeError(f"must be at most {most:g}: {text!r}")
        return value

    return parse


def path_name(text: str) -> str:
    """An argparse type: a file or folder name, not empty (an empty one would name the
    current folder, and a run would write its files there unasked)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty name")
    return text


def non_negative(text: str) -> float:
    """An argparse type: a finite number >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0: {text!r}")
    return value


def whole(text: str) -> int:
    """An argparse type: a whole number >= 0 (a count or a seed)."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 0: {text!r}{as_digits(text)}")
    return value


def as_digits(text: str) -> str:
    """A hint for a whole number written as a float (``1e9``, ``100.0``), which ``int``
    refuses: the same number in digits, so the message does not read as if it were none."""
    try:
        value = float(text)
    except ValueError:
        return ""
    if not (math.isfinite(value) and value.is_integer()):
        return ""
    return f" (write it as digits: {int(value)})"


MIN_CYCLE_S, MAX_CYCLE_S = 0.0001, 1.0  # a scan cycle's range, as a configuration's


def cycle_seconds(text: str) -> float:
    """An argparse type: a cycle time in seconds within the range a configuration allows
    (a value of 50 is almost always 50 ms meant, which in seconds would run no cycle)."""
    value = positive(float)(text)
    if not MIN_CYCLE_S <= value <= MAX_CYCLE_S:
        raise argparse.ArgumentTypeError(
            f"is in seconds, {MIN_CYCLE_S:g} to {MAX_CYCLE_S:g} (e.g. 0.05 for 50 ms), got {text!r}"
        )
    return value


def duration_cycles(duration_s: float, cycle_time_s: float, source: str = "--duration") -> int:
    """The cycles a run of ``duration_s`` takes; CliError naming ``source`` (where the
    duration came from) if it is shorter than one."""
    cycles = round(duration_s / cycle_time_s)
    if cycles < 1:
        raise CliError(f"{source} {duration_s:g} s is shorter than one cycle ({cycle_time_s:g} s)")
    return cycles


def add_run_options(run: argparse.ArgumentParser) -> None:
    """The options every program shares: how long, which clock, cycle and watchdog, retain."""
    length = run.add_mutually_exclusive_group()
    length.add_argument(
        "--cycles", type=positive(int, most=MAX_CYCLES), help="number of base cycles to run"
    )
    length.add_argument(
        "--duration",
        type=positive(float, most=MAX_DURATION_S),
        help="seconds to run (simulated; wall-clock with --realtime)",
    )
    clock = run.add_mutually_exclusive_group()
    clock.add_argument(
        "--realtime", action="store_true", help="run on the wall clock instead of the virtual clock"
    )
    clock.add_argument(
        "--speed",
        type=positive(float, least=MIN_SPEED, most=MAX_SPEED),
        metavar="X",
        help="simulate at X simulated seconds per wall second (1 = real time) instead of as "
        "fast as possible; the run is the same as on the virtual clock, only paced",
    )
    run.add_argument(
        "--cycle-time",
        type=cycle_seconds,
        help="base cycle time in seconds, e.g. 0.05 (default: the program's)",
    )
    run.add_argument(
        "--watchdog",
        type=positive(float, most=MAX_TIME * 1e3),
        help="maximum cycle time in ms (default: the program's)",
    )
    run.add_argument(
        "--spin",
        type=non_negative,
        default=0.0,
        help="realtime: spin the last SPIN ms before each deadline",
    )
    run.add_argument(
        "--rt", action="store_true", help="realtime: SCHED_FIFO, 1 ns timer slack, GC in idle slack"
    )
    run.add_argument(
        "--retain", metavar="FILE", type=path_name, help="retain file (kept across runs)"
    )
    run.add_argument(
        "--json", action="store_true", help="print the summary as one JSON object on stdout"
    )


def one_line_warning(message: Warning | str, category: type, *args: Any, **kwargs: Any) -> None:
    """``warnings.showwarning`` for a command line: one line on stderr, no source line."""
    print(f"plc-runtime: warning: {terminal_text(str(message))}", file=sys.stderr)


# What a terminal must not be given raw: control characters (ESC starts an escape
# sequence), lone surrogates (not text; printing one fails), line and paragraph separators,
# and the bidirectional controls that show the text after them reordered (the embeddings,
# overrides and isolates, and the marks LRM, RLM and ALM, which reorder what stands beside
# them: a name could show as another). Other characters
# that are not "printable" in Python's sense (no-break spaces, joiners, soft hyphens) are
# parts of names and paths and stay as they are.
_UNSAFE_CATEGORIES = frozenset(("Cc", "Cs", "Zl", "Zp"))
_BIDI_CONTROLS = frozenset(
    map(chr, [*range(0x202A, 0x202F), *range(0x2066, 0x206A), 0x200E, 0x200F, 0x061C])
)


def terminal_text(text: str) -> str:
    """``text`` safe to print on a terminal: every character of the kinds above but a
    newline written as its escape. Messages quote what files and clients gave (a key, a
    name, a path), and an ESC among it would start an escape sequence on the operator's
    screen."""
    if text.isprintable():
        return text
    return "".join(
        char.encode("unicode_escape").decode()
        if char != "\n"
        and (unicodedata.category(char) in _UNSAFE_CATEGORIES or char in _BIDI_CONTROLS)
        else char
        for char in text
    )


def one_line(text: str, most: int | None = None) -> str:
    """``text`` as part of one line on a terminal: ``terminal_text`` with its newlines as
    escapes too (text from a client or a file could forge a second line), cut at ``most``
    characters if given."""
    text = terminal_text(text).replace("\n", "\\n")
    return text if most is None or len(text) <= most else text[:most] + "..."


class OneLineParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line on stderr, as every other error
    of the command line is: the message and where to find the options, not the whole usage
    (``--help`` shows it), with what the user typed escaped."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {one_line(message)} (see {self.prog} --help)\n")


ProgramBuilder = Callable[..., Runtime]
"""``build(clock=, cycle_time=, watchdog=, retain_file=) -> Runtime`` (a runtime in STOP)."""


def run_program(
    args: argparse.Namespace,
    name: str,
    build: ProgramBuilder,
    drivers: Iterable[IoDriver] = (),
    cycle_time: float = 0.010,
    watchdog_ms: float = 150.0,
) -> int:
    """Run a program built by ``build`` as the options in ``args`` say; the exit code."""
    if not args.realtime and (args.rt or args.spin):
        raise CliError("--rt and --spin only apply with --realtime")
    lock = claim_retain_file(args.retain) if args.retain is not None else None
    try:
        return _run_program(args, name, build, drivers, cycle_time, watchdog_ms)
    finally:
        if lock is not None:
            release_lock(lock)


def _run_program(
    args: argparse.Namespace,
    name: str,
    build: ProgramBuilder,
    drivers: Iterable[IoDriver],
    cycle_time: float,
    watchdog_ms: float,
) -> int:
    rt = build(
        clock=make_clock(args),
        cycle_time=args.cycle_time if args.cycle_time is not None else cycle_time,
        watchdog=(args.watchdog if args.watchdog is not None else watchdog_ms) / 1e3,
        retain_file=args.retain,
    )
    total = (
        args.cycles
        if args.cycles is not None
        else (duration_cycles(args.duration, rt.cycle_time) if args.duration is not None else None)
    )
    for driver in drivers:
        rt.add_driver(driver)
    rt.start()
    live = sys.stdout.isatty() and not args.json
    wall_start = time.monotonic()
    with stop_on_signals(rt) as stopped:
        try:
            drive(
                rt,
                total,
                live,
                announce=f"plc-runtime: running {name} until Ctrl-C" if total is None else None,
            )
        except KeyboardInterrupt:  # the second Ctrl-C: abort at once, but still stop cleanly
            rt.stop()
            print(f"plc-runtime: interrupted in cycle {rt.ticks}; runtime stopped", file=sys.stderr)
            return EXIT_INTERRUPTED
    wall = time.monotonic() - wall_start
    final_state = rt.state
    result = summary(rt, name, final_state, wall)
    rt.stop()
    if args.json:
        print(json.dumps(result))
    else:
        Console().print(summary_table(result))
    if stopped.number == signal.SIGTERM:  # a supervisor must see it did not end by itself
        print(f"plc-runtime: {stopped.what} in cycle {rt.ticks}", file=sys.stderr)
        return stopped.exit_code
    return EXIT_FAULT if final_state == "FAULT" else 0


def make_clock(args: argparse.Namespace) -> VirtualClock | WallClock:
    """The clock the options ask for: wall (``--realtime``), paced (``--speed``) or virtual."""
    if args.realtime:
        return WallClock(spin=args.spin / 1e3, rt=args.rt)
    if args.speed is not None:
        return PacedClock(args.speed)
    return VirtualClock()


def clock_kind(clock: VirtualClock | WallClock) -> str:
    """``virtual`` (as fast as possible), ``paced`` (simulated, at a speed) or ``wall``."""
    return str(clock.status()["clock"])


def clock_speed(clock: VirtualClock | WallClock) -> float:
    """Simulated seconds per wall second of a clock that keeps pace with the wall."""
    return float(getattr(clock, "speed", 1.0))


def _paced(rt: Runtime) -> bool:
    return clock_kind(rt.clock) != "virtual"


@dataclass
class StopSignal:
    """The signal that asked a run to stop, if one did."""

    number: int | None = None

    @property
    def what(self) -> str:
        """How an operator's message names it: ``interrupted``, ``stopped by SIGTERM``."""
        if self.number == signal.SIGINT:
            return "interrupted"
        return f"stopped by {signal.Signals(self.number or 0).name}"

    @property
    def exit_code(self) -> int:
        """128 + the signal's number, as a shell reports a process ended by it."""
        return 128 + (self.number or 0)


@contextmanager
def stop_on_signals(rt: Runtime) -> Iterator[StopSignal]:
    """Ctrl-C and SIGTERM finish the current cycle and stop the runtime cleanly (outputs to
    their safe state, drivers closed, results written). A service manager or ``docker stop``
    ends a process with SIGTERM, so that must end a run as an operator's Ctrl-C does, not
    kill it half-way and leave its child processes running. A second Ctrl-C aborts."""
    got = StopSignal()

    def on_signal(number: int, _frame: object) -> None:
        if got.number is None:
            got.number = number
        rt.request_stop()
        if number == signal.SIGINT:
            signal.signal(signal.SIGINT, signal.default_int_handler)

    with _handling_stops(on_signal):
        yield got


@contextmanager
def signals_noted(got: StopSignal) -> Iterator[StopSignal]:
    """While a run's results are written, Ctrl-C and SIGTERM are noted in ``got`` and do
    nothing else: a second Ctrl-C would cut the writing short and leave the results half
    written. The writing is bounded (the data, then one drawing); SIGKILL still ends the
    process."""

    def note(number: int, _frame: object) -> None:
        if got.number is None:
            got.number = number

    with _handling_stops(note):
        yield got


@contextmanager
def _handling_stops(handler: Callable[[int, object], None]) -> Iterator[None]:
    """SIGINT and SIGTERM go to ``handler`` inside, to what they went to before after."""
    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, before in previous.items():
            signal.signal(sig, before)


def drive(
    rt: Runtime,
    total: int | None,
    live: bool,
    announce: str | None,
    render: Any = None,
) -> None:
    """Run in chunks of about a tenth of a second so the screen and Ctrl-C stay responsive.

    ``announce`` goes to stderr once the first chunk has run, so a supervising process
    knows the program is in its cyclic phase."""
    chunk = max(1, round(0.1 * clock_speed(rt.clock) / rt.cycle_time)) if _paced(rt) else 2000
    done = 0
    # No auto-refresh: rich would redraw from a background thread, and a second Python
    # thread in the scan's process costs milliseconds of lateness (GIL hand-over). The
    # screen is redrawn here, between chunks, in the idle time before the next release.
    render = render or (lambda: _status_table(rt, total))
    display = Live(render(), auto_refresh=False, transient=True) if live else None
    drawn = time.monotonic()
    if display:
        display.start()
    try:
        while rt.state == "RUN" and (total is None or done < total):
            n = chunk if total is None else min(chunk, total - done)
            ran = rt.run(cycles=n)
            done += ran
            if announce:
                print(announce, file=sys.stderr, flush=True)
                announce = None
            if display and time.monotonic() - drawn >= REDRAW_INTERVAL:
                display.update(render(), refresh=True)
                drawn = time.monotonic()
            if ran < n:
                break
    finally:
        if display:
            display.stop()


# Columns of the statistics tables: header -> how to show it from ScanStats.to_dict()
_COLUMNS = {
    "cycles": lambda d: str(d["cycles"]),
    "exec last us": lambda d: f"{d['exec_us']['last']:.1f}",
    "exec mean us": lambda d: f"{d['exec_us']['mean']:.1f}",
    "exec p99 us": lambda d: f"{d['exec_us']['p99']:.1f}",
    "exec max us": lambda d: f"{d['exec_us']['max']:.1f}",
    "late p99 us": lambda d: f"{d['lateness_us']['p99']:.1f}",
    "late max us": lambda d: f"{d['lateness_us']['max']:.1f}",
    "overruns": lambda d: str(d["overruns"]),
    "omitted": lambda d: str(d["omitted"]),
}
_LIVE_COLUMNS = [
    "cycles",
    "exec last us",
    "exec max us",
    "exec p99 us",
    "late p99 us",
    "overruns",
    "omitted",
]
_SUMMARY_COLUMNS = [
    "cycles",
    "exec mean us",
    "exec p99 us",
    "exec max us",
    "late p99 us",
    "late max us",
    "overruns",
    "omitted",
]


def _stats_table(
    title: str, rows: dict[str, dict[str, Any]], columns: list[str], tight: bool = False
) -> Table:
    """The statistics of ``rows`` in ``columns``; ``tight``: each column exactly as wide as
    its longest number or header word, the headers wrapped at their spaces."""
    table = Table(title=title)
    table.add_column("task")
    for header in columns:
        width = _column_width(rows, header) if tight else None
        table.add_column(header, justify="right", width=width)
    for name, d in rows.items():
        table.add_row(name, *(_COLUMNS[header](d) for header in columns))
    return table


def _task_width(rows: dict[str, dict[str, Any]]) -> int:
    return max(len("task"), *(len(name) for name in rows))


def _column_width(rows: dict[str, dict[str, Any]], header: str, whole: bool = False) -> int:
    """The narrowest the column can be without cutting a number or a word of its header
    (``whole``: the header on one line)."""
    head = [len(header)] if whole else [len(word) for word in header.split()]
    return max(*head, *(len(_COLUMNS[header](d)) for d in rows.values()))


CELL_CHROME = 3  # a column's border and the padding each side


@dataclass
class StatsTables:
    """The statistics table, as rich draws it where the console is wide enough; else its
    columns at their narrowest, split over as many tables as it takes, each with the task
    names. Rich fits a table too wide for the console by cutting its cells, and a number
    cut short (the maximum scan time ``18044…``) reads as another one."""

    title: str
    rows: dict[str, dict[str, Any]]
    columns: list[str]
    caption: str | None = None

    def __rich_console__(self, console: Console, options: Any) -> Iterator[Table]:
        width = options.max_width
        whole = _table_width(self.rows, self.columns, whole=True) <= width
        groups = [self.columns] if whole else _column_groups(self.rows, self.columns, width)
        for k, group in enumerate(groups):
            table = _stats_table(self.title if k == 0 else "", self.rows, group, not whole)
            table.caption = self.caption if k == len(groups) - 1 else None
            yield table


def _table_width(rows: dict[str, dict[str, Any]], columns: list[str], whole: bool) -> int:
    widths = [_column_width(rows, header, whole) for header in columns]
    return 1 + _task_width(rows) + CELL_CHROME + sum(w + CELL_CHROME for w in widths)


def _column_groups(
    rows: dict[str, dict[str, Any]], columns: list[str], width: int
) -> list[list[str]]:
    """``columns`` in order, in groups whose tight table (with the task column) fits
    ``width``; a column too wide for any table is a group of its own."""
    groups: list[list[str]] = [[]]
    for header in columns:
        if groups[-1] and _table_width(rows, [*groups[-1], header], whole=False) > width:
            groups.append([])
        groups[-1].append(header)
    return groups


def task_table(title: str, rows: dict[str, dict[str, Any]], live: bool) -> StatsTables:
    return StatsTables(title, rows, _LIVE_COLUMNS if live else _SUMMARY_COLUMNS)


def _status_table(rt: Runtime, total: int | None) -> Table:
    of_total = f"/{total}" if total else ""
    title = (
        f"plc-runtime  state {rt.state}  cycle {rt.ticks}{of_total}  clock {rt.clock_time:.2f} s"
    )
    rows = {name: stats.to_dict() for name, stats in rt.stats.tasks.items()}
    return _stats_table(title, rows, _LIVE_COLUMNS)


def summary(rt: Runtime, program: str, state: str, wall: float) -> dict[str, Any]:
    stats = rt.stats.to_dict()
    return {
        "program": program,
        "cycles": stats["cycles"],
        "overruns": stats["overruns"],
        "omitted": stats["omitted"],
        "state": state,
        "fault_reason": stats["fault_reason"],
        "clock": clock_kind(rt.clock),
        "speed": clock_speed(rt.clock) if clock_kind(rt.clock) == "paced" else None,
        "sim_time_s": stats["clock_time_s"],
        "wall_time_s": round(wall, 3),
        "scans_per_s": round(stats["cycles"] / wall, 1) if wall > 0 else None,
        "tags": {tag.name: rt.image.read(tag.name) for tag in rt.image.tags},
        "scan": stats["scan"],
        "tasks": stats["tasks"],
    }


def summary_table(summary: dict[str, Any]) -> StatsTables:
    title = (
        f"{summary['program']}: {summary['state']} after {summary['cycles']} cycles, "
        f"{summary['sim_time_s']:.2f} s on the {summary['clock']} clock, {summary['wall_time_s']:.2f} s of wall time"
    )
    if summary["fault_reason"]:
        caption = f"FAULT: {summary['fault_reason']}"
    else:
        caption = "  ".join(f"{k}={v}" for k, v in summary["tags"].items())
    rows = {**summary["tasks"], "(scan)": summary["scan"]}
    return StatsTables(title, rows, _SUMMARY_COLUMNS, caption)
