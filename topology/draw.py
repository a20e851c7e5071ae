"""Drawing a plant with matplotlib: node ids, roles, edge directions, optional routes.

One-way segments get an arrow, two-way segments a plain line, non-routable ones (a return
lane) a dashed grey line. Routes are drawn on top in colour. Large plants (hundreds of
nodes) are drawn without labels so the picture stays readable.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only: no display needed, no GUI thread
import matplotlib.pyplot as plt  # noqa: E402

from .errors import TopologyError  # noqa: E402
from .model import Plant  # noqa: E402

ROLE_STYLE = {
    "transit": ("#9e9e9e", "o", 30),
    "station": ("#1f77b4", "s", 90),
    "entry": ("#2ca02c", ">", 110),
    "exit": ("#d62728", ">", 110),
    "charger": ("#ff7f0e", "P", 100),
    "parking": ("#8c564b", "h", 80),
}
LABEL_LIMIT = 400


def draw(
    plant: Plant,
    out: str | Path,
    routes: Sequence[Sequence[int]] = (),
    title: str | None = None,
    blocked: Sequence[tuple[int, int]] = (),
    vehicles: Mapping[str, tuple[Sequence[int], Sequence[int]]] | None = None,
) -> Path:
    """Write a PNG of the plant; ``routes`` (node-id lists) on top, ``blocked`` segments in red.

    ``vehicles``: label -> (driven, planned) node lists, one colour per vehicle: the driven
    route solid (every vehicle slightly offset, so shared lanes stay readable), the route
    still planned dashed, ending in an arrow."""
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise TopologyError("the drawing is a PNG: give a file name ending in .png", str(out))
    pos = {n.id: (n.x, -n.y) for n in plant.nodes}  # y grows downwards in plant files (grid rows)
    span = max(1.0, max((abs(x) + abs(y) for x, y in pos.values()), default=1.0))
    size = 6 if plant.n <= LABEL_LIMIT else 10
    fig, ax = plt.subplots(figsize=(size * 1.4, size))
    for e in plant.edges:
        (x0, y0), (x1, y1) = pos[e.source], pos[e.target]
        if not e.routable:  # curved, so a return lane does not hide the lanes it runs along
            _arrow(
                ax, (x0, y0), (x1, y1), "#aaaaaa", linestyle="--", connectionstyle="arc3,rad=-0.35"
            )
        elif e.bidirectional:
            ax.plot([x0, x1], [y0, y1], "-", color="#555555", lw=1, zorder=1)
        else:
            _arrow(ax, (x0, y0), (x1, y1), "#555555")
    for role, (colour, marker, area) in ROLE_STYLE.items():
        members = [n for n in plant.nodes if n.role == role]
        if members:
            ax.scatter(
                [pos[n.id][0] for n in members],
                [pos[n.id][1] for n in members],
                c=colour,
                marker=marker,
                s=area if plant.n <= LABEL_LIMIT else area / 6,
                label=f"{role} ({len(members)})",
                zorder=3,
            )
    if plant.n <= LABEL_LIMIT:
        for n in plant.nodes:
            ax.annotate(
                str(n.id),
                pos[n.id],
                textcoords="offset points",
                xytext=(4, 4),
                fontsize=7,
                zorder=4,
            )
    for a, b in blocked:
        (x0, y0), (x1, y1) = pos[a], pos[b]
        ax.plot([x0, x1], [y0, y1], ":", color="#d62728", lw=3, zorder=2)
        ax.plot([(x0 + x1) / 2], [(y0 + y1) / 2], "x", color="#d62728", ms=10, mew=2.5, zorder=4)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, route in enumerate(routes):
        xs, ys = zip(*(pos[i] for i in route), strict=True) if route else ((), ())
        ax.plot(
            xs,
            ys,
            "-",
            color=colours[k % len(colours)],
            lw=3,
            alpha=0.6,
            zorder=2,
            label=f"route {k + 1}",
        )
    for k, (label, (driven, planned)) in enumerate((vehicles or {}).items()):
        colour = colours[k % len(colours)]
        shift = (k - (len(vehicles) - 1) / 2) * 0.025 * max(1.0, span / 10)
        for n, run in enumerate(_routable_runs(plant, driven)):
            xs, ys = zip(*(pos[i] for i in run), strict=True)
            ax.plot(
                [x + shift for x in xs],
                [y + shift for y in ys],
                "-",
                color=colour,
                lw=2,
                alpha=0.45,
                zorder=2,
                label=f"{label} driven" if n == 0 else None,
            )
        if len(planned) > 1:
            xs, ys = zip(*(pos[i] for i in planned), strict=True)
            ax.plot(xs, ys, "--", color=colour, lw=2.5, zorder=2, label=f"{label} planned")
            _arrow(ax, (xs[-2], ys[-2]), (xs[-1], ys[-1]), colour)
        if driven:
            x, y = pos[driven[-1]]
            ax.plot([x], [y], "s", color=colour, ms=9, mec="black", zorder=5)
    ax.set_title(title or f"{plant.name}: {plant.n} nodes, {len(plant.edges)} edges")
    ax.set_aspect("equal")
    ax.margins(0.05 * span / max(span, 1.0))
    ax.axis("off")
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8, frameon=False)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def _routable_runs(plant: Plant, path: Sequence[int]) -> list[list[int]]:
    """Split a driven path where it used a non-routable lane (drawn curved already)."""
    runs: list[list[int]] = []
    for a, b in zip(path, path[1:], strict=False):
        if (a, b) not in plant.arc_index:
            continue
        if runs and runs[-1][-1] == a:
            runs[-1].append(b)
        else:
            runs.append([a, b])
    return runs


def _arrow(
    ax, start: tuple[float, float], end: tuple[float, float], colour: str, **style: str
) -> None:
    props = {"arrowstyle": "-|>", "color": colour, "lw": 1, "shrinkA": 4, "shrinkB": 6, **style}
    ax.annotate("", xy=end, xytext=start, zorder=1, arrowprops=props)
