"""The FunctionBlock base class and its variable declarations.

A block declares its interface at class level, like VAR_INPUT / VAR_OUTPUT / VAR in IEC
61131-3, so the runtime can reset it on a restart, keep its retentive part across a warm
restart and show it in monitoring:

    class Counter(FunctionBlock):
        enable = Input(False)
        count = Output(0)
        total = Static(0, retain=True)

Declared variables are plain instance attributes at run time (fast to read and write in
the scan); the declarations are only metadata. Nested blocks (a ``TON`` kept as an
attribute) are found automatically and treated as part of their parent's instance data.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, ClassVar

from .errors import ConfigError

_IMMUTABLE = (int, float, bool, str, bytes, tuple, frozenset, type(None))


@dataclass(slots=True)
class Var:
    """A declared block variable (see ``Input``, ``Output``, ``Static``)."""

    kind: str  # "input" | "output" | "static"
    default: Any
    retain: bool = False
    doc: str = ""
    name: str = ""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, instance: object, owner: type | None = None) -> Any:
        # Reached only on the class (instances shadow the declaration with their value).
        if instance is None:
            return self
        raise AttributeError(self.name)

    def initial(self) -> Any:
        return self.default if isinstance(self.default, _IMMUTABLE) else copy.deepcopy(self.default)


def Input(default: Any = None, *, doc: str = "") -> Any:  # noqa: N802 - reads like IEC VAR_INPUT
    """Declare an input: set by the caller before each call, read by the block."""
    return Var("input", default, False, doc)


def Output(default: Any = None, *, retain: bool = False, doc: str = "") -> Any:  # noqa: N802
    """Declare an output: written by the block, read by the caller after the call."""
    return Var("output", default, retain, doc)


def Static(default: Any = None, *, retain: bool = False, doc: str = "") -> Any:  # noqa: N802
    """Declare static (instance) state that persists from one scan to the next."""
    return Var("static", default, retain, doc)


class FunctionBlock:
    """Base of every block: a class with explicit inputs, outputs and static state.

    Override ``startup(ctx)`` (runs once in the startup phase, no cycle monitoring) and
    ``cycle(ctx)`` (runs once per scan of the block's task). Blocks read time only from
    ``ctx`` so they behave the same on the virtual and the wall clock.
    """

    _vars: ClassVar[dict[str, Var]] = {}
    _inputs: ClassVar[frozenset[str]] = frozenset()
    main_output: ClassVar[str | None] = None  # what __call__ returns; default: first output

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        declared: dict[str, Var] = {}
        for klass in reversed(cls.__mro__):
            for name, value in vars(klass).items():
                if isinstance(value, Var):
                    declared[name] = value
        cls._vars = declared
        cls._inputs = frozenset(n for n, v in declared.items() if v.kind == "input")
        if cls.main_output is None:
            cls.main_output = next((n for n, v in declared.items() if v.kind == "output"), None)
        elif cls.main_output not in declared:
            raise ConfigError(
                f"{cls.__name__}.main_output names undeclared variable {cls.main_output!r}"
            )

    def __new__(cls, *args: Any, **kwargs: Any) -> FunctionBlock:
        # Defaults are set here, not in __init__, so a subclass __init__ may assign
        # variables before (or without) calling super().__init__().
        self = super().__new__(cls)
        for name, var in cls._vars.items():
            object.__setattr__(self, name, var.initial())
        self._extra_retain: set[str] = set()
        return self

    def __init__(self) -> None:
        pass

    # ----- to be overridden ----------------------------------------------------------
    def startup(self, ctx: Any) -> None:
        """Called once when the runtime starts (like S7 OB100), before the first scan."""

    def cycle(self, ctx: Any) -> None:
        """Called once per scan of the block's task."""

    # ----- calling a block from another block ----------------------------------------
    def __call__(self, ctx: Any, **inputs: Any) -> Any:
        """Set inputs, run one cycle, return the main output (like an FB call in ST).

        Inputs are plain instance attributes, so the values are stored in one dictionary
        update once every name is known to be an input: a large program calls thousands of
        blocks per scan, and a check and ``setattr`` per argument cost more than the call."""
        if not inputs.keys() <= self._inputs:
            unknown = next(name for name in inputs if name not in self._inputs)
            raise ConfigError(f"{type(self).__name__} has no input {unknown!r}")
        self.__dict__.update(inputs)
        self.cycle(ctx)
        return getattr(self, self.main_output) if self.main_output else None

    # ----- interface and instance data -------------------------------------------------
    @classmethod
    def interface(cls) -> dict[str, list[str]]:
        """Declared variable names by kind, for monitoring and documentation."""
        result: dict[str, list[str]] = {"inputs": [], "outputs": [], "static": []}
        key = {"input": "inputs", "output": "outputs", "static": "static"}
        for name, var in cls._vars.items():
            result[key[var.kind]].append(name)
        return result

    def mark_retain(self, *names: str) -> None:
        """Make declared outputs/statics of this instance retentive (e.g. a counter's CV)."""
        for name in names:
            var = self._vars.get(name)
            if var is None or var.kind == "input":
                raise ConfigError(
                    f"{type(self).__name__}: {name!r} is not a declared output or static"
                )
            self._extra_retain.add(name)

    def declared_type(self, name: str) -> str:
        """Type name of a variable's declared default (part of the retain layout)."""
        return type(self._vars[name].default).__name__

    def retain_names(self) -> list[str]:
        return [n for n, v in self._vars.items() if v.retain or n in self._extra_retain]

    def reset_vars(self, keep: set[str] = frozenset()) -> None:  # type: ignore[assignment]
        """Re-initialise declared variables to their defaults, except those in ``keep``."""
        for name, var in self._vars.items():
            if name not in keep:
                setattr(self, name, var.initial())

    def children(self) -> Iterator[tuple[str, FunctionBlock]]:
        """Nested blocks held as attributes (directly or in a list/tuple), with their names."""
        for name, value in vars(self).items():
            if isinstance(value, FunctionBlock):
                yield name, value
            elif isinstance(value, list | tuple):
                for i, item in enumerate(value):
                    if isinstance(item, FunctionBlock):
                        yield f"{name}[{i}]", item

    def walk(self, path: str, _seen: set[int] | None = None) -> Iterator[tuple[str, FunctionBlock]]:
        """This block and every nested block, depth first, with dotted instance paths; each
        block once (a child may hold a reference back to its parent)."""
        seen = set() if _seen is None else _seen
        if id(self) in seen:
            return
        seen.add(id(self))
        yield path, self
        for name, child in self.children():
            yield from child.walk(f"{path}.{name}", seen)
