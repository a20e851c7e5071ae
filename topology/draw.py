"""Drawing a plant with matplotlib: the plant alone, routes on it, or a fleet's driven routes.

The plant is drawn in greys, so that colour always means a vehicle (or, in the heat map,
usage). One-way lanes carry a small arrow. A non-routable lane (the return lane from an
exit back to an entry) is drawn dashed around the outside of the plant, so it neither hides
nor crosses the lanes it would otherwise run along. Large plants (hundreds of nodes) are
drawn without node ids and transit dots, which would only cover the lanes.

Up to ``HEATMAP_ABOVE`` vehicles each get a colour of their own: the last ``recent``
segments a vehicle drove thick, with an arrow each, so where it came from and which way it
went can be read off; the ``earlier`` segments before those thin and fading with age; the
route it still plans dashed; where it is now a disc with its number. Beyond that, colours
can no longer be told apart and the routes cover the whole plant, so the picture becomes a
heat map: how often each segment was driven, all vehicles together, with a colour bar.

The axes hug the plant's bounding box and the figure takes the plant's aspect, so the plant
fills the picture instead of floating in white margins.
"""

from __future__ import annotations

from collections.abc import Container, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.axes import Axes
from matplotlib.cm import ScalarMappable
from matplotlib.collections import LineCollection
from matplotlib.colors import ListedColormap, LogNorm, Normalize, to_hex, to_rgba
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import FancyArrowPatch
from matplotlib.path import Path as PolyPath

from .errors import TopologyError
from .model import Plant
from .usage import Segment, segment_key, segment_usage

HEATMAP_ABOVE = 20  # more vehicles than this: a segment-usage heat map instead of routes
LABEL_LIMIT = 400  # more nodes than this: no node ids, no transit dots
DPI = 110
LANE = "#c4c4c4"
LANE_ARROW = "#9a9a9a"
HIGHWAY_ARROW = "#c9c9c9"  # a preferred direction: fainter than a one-way lane's arrow
RETURN_LANE = "#7a7a7a"
BLOCKADE = "black"
LIFTED = "#a0a0a0"
INK = "#444444"  # the key's stand-in for "any vehicle's colour"
# rarely driven: orange, busiest: dark violet (plasma without its pale yellow end, reversed,
# so a segment driven once still stands out from the grey of the unused lanes)
HEAT_MAP = ListedColormap(matplotlib.colormaps["plasma"](np.linspace(0.82, 0.0, 256)), "usage")

# role -> (face colour, edge colour, marker, area): neutral, colour is for vehicles
ROLE_STYLE = {
    "transit": ("#a8a8a8", "none", "o", 12),
    "station": ("white", "#333333", "s", 60),
    "entry": ("white", "#333333", ">", 80),
    "exit": ("#333333", "#333333", ">", 80),
    "charger": ("#888888", "#333333", "P", 80),
    "parking": ("#d0d0d0", "#333333", "h", 60),
    "queue": ("white", "#777777", "D", 30),
}

Point = tuple[float, float]
Colour = str | tuple[float, float, float, float]
Vehicles = Mapping[str, tuple[Sequence[int], Sequence[int]]]


@dataclass(frozen=True)
class Picture:
    """A rendered drawing, before it is saved: the figure, its plant axes and what it shows.

    ``mode``: ``plant`` (the plant, optionally with routes), ``vehicles`` (per-vehicle
    routes) or ``heatmap``. ``usage``: in the heat map, the times each segment (node pair,
    lower id first) was driven."""

    figure: Figure
    axes: Axes
    mode: str
    usage: dict[Segment, int]


# Names come from plant files: "$" in one would start matplotlib's math mode, and a name
# such as "hall $\nosuchmacro$" would fail the drawing. Text is drawn as written.
LITERAL_TEXT = {"text.parse_math": False}


TITLE_CHARS = 120  # a longer line of the title is cut: the figure would grow with it


def _shortened(text: str) -> str:
    """Each line of a title cut to ``TITLE_CHARS`` characters, with an ellipsis."""
    return "\n".join(
        line if len(line) <= TITLE_CHARS else line[: TITLE_CHARS - 1] + "\u2026"
        for line in text.split("\n")
    )


def draw(
    plant: Plant,
    out: str | Path,
    routes: Sequence[Sequence[int]] = (),
    title: str | None = None,
    blocked: Sequence[Segment] = (),
    vehicles: Vehicles | None = None,
    lifted: Sequence[Segment] = (),
    recent: int = 8,
    earlier: int = 40,
    usage: Mapping[Segment, int] | None = None,
) -> Path:
    """Write a PNG of the plant (see ``render`` for the arguments)."""
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise TopologyError("the drawing is a PNG: give a file name ending in .png", str(out))
    with matplotlib.rc_context(LITERAL_TEXT):
        picture = render(plant, routes, title, blocked, vehicles, lifted, recent, earlier, usage)
        picture.figure.savefig(out, dpi=DPI, bbox_inches="tight", pad_inches=0.1)
    return out


def render(
    plant: Plant,
    routes: Sequence[Sequence[int]] = (),
    title: str | None = None,
    blocked: Sequence[Segment] = (),
    vehicles: Vehicles | None = None,
    lifted: Sequence[Segment] = (),
    recent: int = 8,
    earlier: int = 40,
    usage: Mapping[Segment, int] | None = None,
) -> Picture:
    """Draw the plant into a new figure (not registered with pyplot: nothing to close).

    ``routes``: node-id lists, each in its own colour. ``blocked``: segments closed now;
    ``lifted``: segments closed during the run and open again. ``vehicles``: label ->
    (driven, planned) node lists; the label's last word (its number) is written on the
    vehicle's disc. ``recent`` and ``earlier``: how many driven segments are drawn thick and
    how many before them fading (the heat map counts every driven segment). ``usage``: the
    heat map's counts, keyed as ``segment_usage`` keys them, when the caller kept them
    while the vehicles drove (a long run's driven lists keep only their newest nodes);
    without it they are counted from the driven lists."""
    if recent < 1 or earlier < 0:
        raise TopologyError(f"recent must be >= 1 and earlier >= 0, got {recent} and {earlier}")
    with matplotlib.rc_context(LITERAL_TEXT):
        return _render(plant, routes, title, blocked, vehicles, lifted, recent, earlier, usage)


def _render(
    plant: Plant,
    routes: Sequence[Sequence[int]],
    title: str | None,
    blocked: Sequence[Segment],
    vehicles: Vehicles | None,
    lifted: Sequence[Segment],
    recent: int,
    earlier: int,
    counted: Mapping[Segment, int] | None,
) -> Picture:
    """``render``'s figure, with every text taken literally (``LITERAL_TEXT``)."""
    vehicles = dict(vehicles or {})
    mode = "heatmap" if len(vehicles) > HEATMAP_ABOVE else "vehicles" if vehicles else "plant"
    geo = _Geometry(plant)
    x0, x1, y0, y1 = geo.limits
    axes_w, axes_h = _axes_inches(x1 - x0, y1 - y0, geo.large)
    side = {"heatmap": 1.3, "vehicles": 3.6 if len(vehicles) > 10 else 2.5, "plant": 1.8}[mode]
    fig = Figure(figsize=(axes_w + side, axes_h + 1.4), layout="constrained")
    ax = fig.add_subplot()
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.axis("off")
    heading = _shortened(title or f"{plant.name}: {plant.n} nodes, {len(plant.edges)} edges")
    if mode == "heatmap":
        heading += f"\nhow often each segment was driven (over {HEATMAP_ABOVE} vehicles: no routes)"
    ax.set_title(heading, fontsize=11)
    _draw_lanes(ax, geo)
    _draw_nodes(ax, geo)
    key = _role_handles(geo)
    key += _draw_blockades(ax, geo, blocked, lifted, always=mode != "plant")
    if any(geo.around.values()):
        key.append(_line(RETURN_LANE, "return lane (not routed)", ls="--", lw=1.2))
    usage: dict[Segment, int] = {}
    if mode == "heatmap":
        if counted is None:
            usage = segment_usage(plant, (driven for driven, _ in vehicles.values()))
        else:
            usage = {segment: n for segment, n in counted.items() if n > 0}
        _draw_usage(fig, ax, geo, usage)
        here = [geo.pos[d[-1]] for d, _ in vehicles.values() if d]
        if here:
            ax.scatter(*zip(*here, strict=True), s=28, c="white", edgecolors="black", zorder=6)
        key.append(_line("white", f"vehicle now ({len(here)})", lw=0, marker="o", mec="black"))
        fig.legend(handles=key, loc="outside lower center", ncols=4, fontsize=8, frameon=False)
    elif mode == "vehicles":
        fleet = _draw_vehicles(ax, geo, vehicles, recent, earlier)
        key = [
            _line(INK, f"driven: last {recent} segments, arrow = direction", lw=3),
            _line(INK, f"driven: {earlier} segments before, fading", lw=1.5, alpha=0.3),
            _line(INK, "planned", ls="--", lw=1.8),
            _line("#dddddd", "vehicle now", lw=0, marker="o", ms=10, mec="black"),
            *key,
        ]
        fig.legend(
            handles=fleet,
            loc="outside right upper",
            ncols=2 if len(fleet) > 10 else 1,
            fontsize=8,
            title="vehicle: now at -> goal",
            title_fontsize=8,
            frameon=False,
        )
        fig.legend(handles=key, loc="outside lower center", ncols=4, fontsize=8, frameon=False)
    else:
        key = _draw_routes(ax, geo, routes) + key
        fig.legend(handles=key, loc="outside right upper", fontsize=8, frameon=False)
    for artist in (*ax.collections, *ax.patches, *ax.lines, *ax.texts):
        artist.set_in_layout(False)  # inside the axes by the margin; measuring them is slow
    return Picture(fig, ax, mode, usage)


def vehicle_colours(count: int) -> list[str]:
    """``count`` distinct colours: tab10 up to ten, then tab20's dark shades before its
    light ones (up to twenty); beyond that, evenly spaced hues (only routes need those)."""
    if count <= 10:
        return [to_hex(c) for c in matplotlib.colormaps["tab10"].colors][:count]
    if count <= 20:
        tab20 = [to_hex(c) for c in matplotlib.colormaps["tab20"].colors]
        return (tab20[0::2] + tab20[1::2])[:count]
    return [to_hex(c) for c in matplotlib.colormaps["hsv"](np.linspace(0, 1, count, False))]


# ----- the plant ---------------------------------------------------------------------
class _Geometry:
    """Where everything goes: node positions (y up), which segments run around the plant
    (node pairs joined by non-routable edges only: ``around`` maps them to that edge's
    direction, every other segment to None), the typical segment length (markers, offsets
    and margins scale with it) and the axes limits."""

    def __init__(self, plant: Plant) -> None:
        self.plant = plant
        self.large = plant.n > LABEL_LIMIT
        self.pos: dict[int, Point] = {n.id: (n.x, -n.y) for n in plant.nodes}  # files: y down
        self.around: dict[Segment, Segment | None] = {}
        for e in plant.edges:
            key = segment_key(e.source, e.target)
            if e.routable:
                self.around[key] = None
            else:
                self.around.setdefault(key, (e.source, e.target))
        lengths = [self._length(a, b) for a, b in self.around]
        self.typical = float(np.median([d for d in lengths if d > 0] or [1.0]))
        xs, ys = np.array(list(self.pos.values()) or [(0.0, 0.0)]).T
        self.box = (float(xs.min()), float(xs.max()), float(ys.min()), float(ys.max()))
        self.gap = 0.45 * self.typical  # how far outside the nodes a return lane runs

    def _length(self, a: int, b: int) -> float:
        return float(np.hypot(*np.subtract(self.pos[a], self.pos[b])))

    @property
    def limits(self) -> tuple[float, float, float, float]:
        """The nodes' bounding box, widened by the return lanes' way round, plus a third of a
        typical segment: room for the markers, no more."""
        x0, x1, y0, y1 = self.box
        points = [(x0, y0), (x1, y1)]
        for edge in self.around.values():
            if edge:
                points += self.detour(*edge, 0.3 * self.typical)
        xs, ys = np.array(points).T
        margin = 0.35 * self.typical
        return xs.min() - margin, xs.max() + margin, ys.min() - margin, ys.max() + margin

    def line(self, a: int, b: int, shift: float = 0.0) -> list[Point]:
        """The points a step a -> b is drawn through, ``shift`` sideways (a vehicle's lane)."""
        if self.around[segment_key(a, b)]:
            return self.detour(a, b, shift)
        return list(_offset(self.pos[a], self.pos[b], shift))

    def detour(self, a: int, b: int, shift: float = 0.0) -> list[Point]:
        """The way round of segment a-b, from a to b: the same way whichever direction it
        is driven, laid out from the direction of its non-routable edge."""
        edge = self.around[segment_key(a, b)] or (a, b)
        way = self._round(*edge, shift)
        return way if edge == (a, b) else way[::-1]

    def _round(self, a: int, b: int, shift: float) -> list[Point]:
        """A way from a to b outside the nodes' bounding box: out to the side of the box
        nearest to a, round the corners (the shorter way) to the side nearest to b, in to b."""
        x0, x1, y0, y1 = self.box
        g = self.gap + shift
        outer = (x0 - g, x1 + g, y0 - g, y1 + g)
        sa, sb = self._side(self.pos[a]), self._side(self.pos[b])
        ends = [_onto(self.pos[a], sa, outer), _onto(self.pos[b], sb, outer)]
        corners = {  # the corner after each side, going round clockwise (y up)
            "top": (outer[1], outer[3]),
            "right": (outer[1], outer[2]),
            "bottom": (outer[0], outer[2]),
            "left": (outer[0], outer[3]),
        }
        order = ["top", "right", "bottom", "left"]
        ways = []
        for step in (1, -1):  # clockwise, anticlockwise
            side, via = sa, []
            while side != sb:
                if step == 1:
                    via.append(corners[side])
                nxt = order[(order.index(side) + step) % 4]
                if step == -1:
                    via.append(corners[nxt])
                side = nxt
            way = [self.pos[a], ends[0], *via, ends[1], self.pos[b]]
            ways.append((float(np.hypot(*np.diff(np.array(way), axis=0).T).sum()), way))
        return min(ways, key=lambda w: round(w[0], 9))[1]  # a tie: clockwise, whatever the shift

    def _side(self, p: Point) -> str:
        x0, x1, y0, y1 = self.box
        gaps = {"left": p[0] - x0, "right": x1 - p[0], "bottom": p[1] - y0, "top": y1 - p[1]}
        return min(gaps, key=gaps.__getitem__)


def _onto(p: Point, side: str, outer: tuple[float, float, float, float]) -> Point:
    """``p`` moved straight out onto ``side`` of the rectangle ``outer``."""
    x0, x1, y0, y1 = outer
    return {"left": (x0, p[1]), "right": (x1, p[1]), "bottom": (p[0], y0), "top": (p[0], y1)}[side]


def _axes_inches(width: float, height: float, large: bool) -> tuple[float, float]:
    """The plant's size on paper: as large as fits the page, in the plant's aspect."""
    max_w, max_h = (12.0, 9.0) if large else (9.0, 6.0)
    scale = min(max_w / width, max_h / height)
    return max(width * scale, 3.0), max(height * scale, 1.5)


def _draw_lanes(ax: Axes, geo: _Geometry) -> None:
    straight = []
    for e in geo.plant.edges:
        a, b = geo.pos[e.source], geo.pos[e.target]
        if geo.around[segment_key(e.source, e.target)]:
            ax.add_patch(_polyline(geo.detour(e.source, e.target), RETURN_LANE, 1.2, "--", True))
            continue
        straight.append((a, b))
        if not e.bidirectional:
            ax.add_patch(_head(a, b, LANE_ARROW, size=9, zorder=1))
        elif e.highway:
            ax.add_patch(_head(a, b, HIGHWAY_ARROW, size=6, zorder=1))
    ax.add_collection(LineCollection(straight, colors=LANE, linewidths=1.2, zorder=1))


def _draw_nodes(ax: Axes, geo: _Geometry) -> None:
    for role, (face, edge, marker, area) in ROLE_STYLE.items():
        members = [n.id for n in geo.plant.nodes if n.role == role]
        if members and not (geo.large and role == "transit"):
            ax.scatter(
                [geo.pos[i][0] for i in members],
                [geo.pos[i][1] for i in members],
                c=face,
                edgecolors=edge,
                marker=marker,
                s=area / 3 if geo.large else area,
                zorder=3,
            )
    if not geo.large:
        for n in geo.plant.nodes:
            ax.annotate(
                str(n.id),
                geo.pos[n.id],
                textcoords="offset points",
                xytext=(4, 4),
                fontsize=7,
                color="#555555",
                zorder=4,
            )


def _role_handles(geo: _Geometry) -> list[Line2D]:
    handles = []
    for role, (face, edge, marker, _area) in ROLE_STYLE.items():
        count = sum(n.role == role for n in geo.plant.nodes)
        if count and not (geo.large and role == "transit"):
            handles.append(
                _line(face, f"{role} ({count})", lw=0, marker=marker, ms=7, mec=edge, mew=1)
            )
    return handles


def _draw_blockades(
    ax: Axes, geo: _Geometry, blocked: Sequence[Segment], lifted: Sequence[Segment], always: bool
) -> list[Line2D]:
    """Draw the closed (black) and reopened (grey) segments, each with a cross, and return
    their legend entries. A fleet's picture names the blockades in its key even when none
    is in force, so a reader knows that none was left out."""
    closed = sorted({segment_key(a, b) for a, b in blocked})
    reopened = sorted({segment_key(a, b) for a, b in lifted} - set(closed))
    handles = []
    for segments, colour, text in (
        (closed, BLOCKADE, "blocked segment"),
        (reopened, LIFTED, "blockade lifted during the run"),
    ):
        for a, b in segments:
            (xa, ya), (xb, yb) = geo.pos[a], geo.pos[b]
            ax.plot([xa, xb], [ya, yb], ":", color=colour, lw=3, zorder=4)
            ax.plot(
                [(xa + xb) / 2], [(ya + yb) / 2], "X", color=colour, ms=10, mec="white", zorder=7
            )
        if segments or (always and colour == BLOCKADE):
            label = f"{text} ({len(segments)})" if segments else f"{text}: none now"
            handles.append(_line(colour, label, ls=":", lw=2.5, marker="X", ms=9, mec="white"))
    return handles


# ----- routes, vehicles, usage -------------------------------------------------------
def _draw_routes(ax: Axes, geo: _Geometry, routes: Sequence[Sequence[int]]) -> list[Line2D]:
    handles = []
    for colour, route in zip(vehicle_colours(len(routes)), routes, strict=True):
        steps = _steps(route, geo.around)
        _draw_steps(ax, geo, steps, [colour] * len(steps), 0.0, lw=3.0, heads=True)
        handles.append(_line(colour, f"route {len(handles) + 1}", lw=3))
    return handles


def _draw_vehicles(
    ax: Axes, geo: _Geometry, vehicles: Vehicles, recent: int, earlier: int
) -> list[Line2D]:
    """Every vehicle's routes, offset sideways per vehicle so shared lanes show each of them;
    returns the vehicles' legend entries."""
    spacing = min(0.08, 0.5 / len(vehicles)) * geo.typical
    handles = []
    here: dict[int, list[tuple[str, str]]] = {}  # node -> the discs of the vehicles there
    for k, (colour, (label, (driven, planned))) in enumerate(
        zip(vehicle_colours(len(vehicles)), vehicles.items(), strict=True)
    ):
        shift = (k - (len(vehicles) - 1) / 2) * spacing
        steps = _steps(driven, geo.around)
        strong = steps[-recent:]
        seen = {segment_key(a, b) for a, b in strong}
        faint = []  # newest first, each segment once (overlaps would add up to opaque)
        for a, b in reversed(steps[-recent - earlier : -recent] if earlier else []):
            if segment_key(a, b) not in seen:
                seen.add(segment_key(a, b))
                faint.append((a, b))
        faint.reverse()
        ages = [to_rgba(colour, 0.1 + 0.3 * (i + 1) / len(faint)) for i in range(len(faint))]
        _draw_steps(ax, geo, faint, ages, shift, lw=1.5, heads=False)
        _draw_steps(ax, geo, strong, [to_rgba(colour, 0.95)] * len(strong), shift, 3.2, True)
        ahead = _steps(planned, geo.around)
        for j, (a, b) in enumerate(ahead):  # dashed, an arrow into the goal
            last = j == len(ahead) - 1
            ax.add_patch(_polyline(geo.line(a, b, shift), colour, 1.8, "--", last, zorder=2))
        node = driven[-1] if driven else planned[0] if planned else None
        where = "not reported" if node is None else f"at {node}"
        goal = f" -> {planned[-1]}" if len(planned) > 1 else ""
        if node is not None:
            here.setdefault(node, []).append((colour, (label.split() or [str(k + 1)])[-1]))
        handles.append(
            _line(colour, f"{label}: {where}{goal}", lw=3, marker="o", ms=8, mec="black")
        )
    for node, discs in here.items():
        for j, (colour, text) in enumerate(discs):
            _disc(ax, geo.pos[node], colour, text, nudge=(j - (len(discs) - 1) / 2) * 16.0)
    return handles


def _steps(path: Sequence[int], segments: Container[Segment]) -> list[Segment]:
    """The steps of a path that are plant segments (see ``segment_usage``)."""
    return [
        (a, b)
        for a, b in zip(path, path[1:], strict=False)
        if a != b and segment_key(a, b) in segments
    ]


def _draw_steps(
    ax: Axes,
    geo: _Geometry,
    steps: Sequence[Segment],
    colours: Sequence[Colour],
    shift: float,
    lw: float,
    heads: bool,
) -> None:
    lines, line_colours = [], []
    for (a, b), colour in zip(steps, colours, strict=True):
        points = geo.line(a, b, shift)
        if len(points) > 2:  # the way round, outside the plant
            ax.add_patch(_polyline(points, colour, lw, "-", heads))
            continue
        lines.append(points)
        line_colours.append(colour)
        if heads:
            ax.add_patch(_head(*points, colour, size=5 * lw, zorder=2.5))
    if lines:
        ax.add_collection(
            LineCollection(lines, colors=line_colours, linewidths=lw, capstyle="round", zorder=2)
        )


def _draw_usage(fig: Figure, ax: Axes, geo: _Geometry, usage: Mapping[Segment, int]) -> None:
    """Each driven segment coloured (and widened) by its count. A log scale when the counts
    span more than a factor of 20, so a few hot aisles do not wash out everything else."""
    if not usage:
        return
    low, high = min(usage.values()), max(usage.values())
    norm = LogNorm(low, high) if high > 20 * low else Normalize(0, high)
    lines, counts = [], []
    for (a, b), count in sorted(usage.items(), key=lambda item: item[1]):  # busiest on top
        if geo.around[(a, b)]:
            ax.add_patch(_polyline(geo.detour(a, b), HEAT_MAP(norm(count)), 3.0, "-", False))
        else:
            lines.append((geo.pos[a], geo.pos[b]))
            counts.append(count)
    if lines:
        values = np.array(counts, dtype=float)
        collection = LineCollection(
            lines,
            cmap=HEAT_MAP,
            norm=norm,
            linewidths=1.5 + 3.0 * np.clip(norm(values), 0, 1),
            capstyle="round",
            zorder=2,
        )
        collection.set_array(values)
        collection.set_gid("segment-usage")
        ax.add_collection(collection)
    bar = fig.colorbar(ScalarMappable(norm, HEAT_MAP), ax=ax, shrink=0.8, pad=0.01, aspect=30)
    bar.set_label("times driven, all vehicles (both directions)")


# ----- small drawing helpers ---------------------------------------------------------
def _offset(a: Point, b: Point, shift: float) -> tuple[Point, Point]:
    """The segment a-b moved ``shift`` sideways, to the same side whichever way it runs
    (the normal taken from its lower-left end)."""
    (xa, ya), (xb, yb) = sorted((a, b))
    length = float(np.hypot(xb - xa, yb - ya)) or 1.0
    nx, ny = -(yb - ya) / length * shift, (xb - xa) / length * shift
    return (a[0] + nx, a[1] + ny), (b[0] + nx, b[1] + ny)


def _head(a: Point, b: Point, colour: Colour, size: float, zorder: float = 2) -> FancyArrowPatch:
    """An arrow head alone, six tenths of the way from a to b, pointing to b."""
    tip = (a[0] + (b[0] - a[0]) * 0.6, a[1] + (b[1] - a[1]) * 0.6)
    tail = (a[0] + (b[0] - a[0]) * 0.59, a[1] + (b[1] - a[1]) * 0.59)
    return FancyArrowPatch(
        tail,
        tip,
        arrowstyle="-|>",
        mutation_scale=size,
        color=colour,
        lw=0.5,
        shrinkA=0,
        shrinkB=0,
        zorder=zorder,
    )


def _polyline(
    points: Sequence[Point], colour: Colour, lw: float, ls: str, head: bool, zorder: float = 2
) -> FancyArrowPatch:
    """A line through ``points``, with an arrow head at the end if ``head``."""
    return FancyArrowPatch(
        path=PolyPath(points),
        arrowstyle="-|>" if head else "-",
        mutation_scale=4 * lw + 6,
        color=colour,
        lw=lw,
        linestyle=ls,
        joinstyle="round",
        capstyle="round",
        zorder=zorder,
    )


def _disc(ax: Axes, at: Point, colour: str, text: str, nudge: float) -> None:
    """A vehicle's current node: a disc in its colour with its number in black or white,
    whichever reads better on that colour; ``nudge`` (points) sets discs that share a node
    side by side, joined to the node by a short line."""
    r, g, b, _ = to_rgba(colour)
    ink = "black" if 0.299 * r + 0.587 * g + 0.114 * b > 0.55 else "white"
    ax.annotate(
        text,
        at,
        xytext=(nudge, 0),
        textcoords="offset points",
        ha="center",
        va="center",
        fontsize=7,
        fontweight="bold",
        color=ink,
        bbox={"boxstyle": "circle,pad=0.35", "fc": colour, "ec": "black", "lw": 1.2},
        arrowprops={"arrowstyle": "-", "color": "black", "lw": 0.8, "shrinkA": 0, "shrinkB": 0}
        if nudge
        else None,
        zorder=8,
    )


def _line(colour: Colour, label: str, **style: object) -> Line2D:
    """A legend entry (an artist not added to any axes)."""
    return Line2D([], [], color=colour, label=label, **style)
