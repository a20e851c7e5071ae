"""Errors of plant files and plant models: one message naming the file, line or key."""


class TopologyError(ValueError):
    """A plant file or plant model is invalid. ``str()`` is the whole, user-facing message."""

    def __init__(self, message: str, source: str | None = None, where: str | None = None) -> None:
        self.source = source  # file name, or None for a model built in code
        self.where = where  # "line 12", "edges[3]", "node 7", ...
        self.message = message  # what is wrong there
        prefix = ": ".join(p for p in (source, where) if p)
        super().__init__(f"{prefix}: {message}" if prefix else message)
