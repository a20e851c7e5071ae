"""Write ``random-32-32.map``: a 32 x 32 grid with about 10 % random obstacles, in the
MovingAI 2D grid benchmark format (docs/plant-format.md), the project's own stand-in for the
community's ``random-32-32-10`` benchmark map, whose data is not ours to ship.

Obstacles are drawn cell by cell from Python's ``random.Random(seed).random()``, whose
sequence for a given integer seed the standard library promises never to change, so the file
is the same on every machine and Python version (tests/test_examples.py re-runs this script
and compares bytes). Free cells that the obstacles cut off from the largest 4-connected area
are filled in as well: every free cell of the map can reach every other, so any two free
cells make a valid ``plc-runtime route`` example.

    python examples/plants/make_random_map.py [--out FILE] [--seed N]
"""

from __future__ import annotations

import argparse
import random
from collections import deque
from pathlib import Path

WIDTH = HEIGHT = 32
OBSTACLES = 0.10
SEED = 1
DEFAULT_OUT = Path(__file__).with_name("random-32-32.map")


def random_grid(width: int, height: int, obstacles: float, seed: int) -> list[list[bool]]:
    """Rows of cells, True where passable, row by row from the top-left cell."""
    rng = random.Random(seed)
    return [[rng.random() >= obstacles for _ in range(width)] for _ in range(height)]


def keep_largest_area(grid: list[list[bool]]) -> list[list[bool]]:
    """The grid with every free cell outside the largest 4-connected free area blocked."""
    height, width = len(grid), len(grid[0])
    area = [[-1] * width for _ in range(height)]
    sizes: list[int] = []
    for y0 in range(height):
        for x0 in range(width):
            if not grid[y0][x0] or area[y0][x0] >= 0:
                continue
            label, size = len(sizes), 0
            area[y0][x0] = label
            queue = deque([(x0, y0)])
            while queue:
                x, y = queue.popleft()
                size += 1
                for nx, ny in ((x + 1, y), (x - 1, y), (x, y + 1), (x, y - 1)):
                    if 0 <= nx < width and 0 <= ny < height and grid[ny][nx] and area[ny][nx] < 0:
                        area[ny][nx] = label
                        queue.append((nx, ny))
            sizes.append(size)
    largest = max(range(len(sizes)), key=sizes.__getitem__)
    return [[area[y][x] == largest for x in range(width)] for y in range(height)]


def map_text(grid: list[list[bool]]) -> str:
    """The MovingAI .map text: header, then one line per row ('.' free, '@' blocked)."""
    rows = ["".join("." if free else "@" for free in row) for row in grid]
    return f"type octile\nheight {len(grid)}\nwidth {len(grid[0])}\nmap\n" + "\n".join(rows) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="file to write")
    parser.add_argument("--seed", type=int, default=SEED)
    args = parser.parse_args()
    grid = keep_largest_area(random_grid(WIDTH, HEIGHT, OBSTACLES, args.seed))
    args.out.write_text(map_text(grid), encoding="utf-8")


if __name__ == "__main__":
    main()
