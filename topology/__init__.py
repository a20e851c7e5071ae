"""Plant topology: the graph of decision points and lane segments, its file formats, and the
sample plants. Imports nothing else of this project."""

from .errors import TopologyError
from .formats import load, load_scenarios, read_cells
from .model import PORTS, ROLES, TARGET_ROLES, Edge, Node, Plant, route_cost
from .samples import SAMPLES, grid, kiva, model_plant, warehouse

__all__ = [
    "PORTS",
    "ROLES",
    "SAMPLES",
    "TARGET_ROLES",
    "Edge",
    "Node",
    "Plant",
    "TopologyError",
    "grid",
    "kiva",
    "load",
    "load_scenarios",
    "model_plant",
    "read_cells",
    "route_cost",
    "warehouse",
]
