"""A deterministic generator of warehouse worlds: a map_server map plus a fleet config.

Layout (map frame, meters; ``x`` east, ``y`` north; 0.1 m cells; 0.2 m walls all around)::

    north wall
    ─────────────────────────────────────────────────────────────
          c c       c c       c c       c c      north chargers (when the south side is full)
     w_n ── a1_n ── a2_n ── ... ── aK_n ── e_n      north corridor
      │  ██  │  ██  │  ██      ██   │  ██  │
      w_2   a1_2   a2_2   ...      aK_2   e_2   D   D = drop-off (east wall)
      │  ██  │  ██  │  ██      ██   │  ██  │   D   ██ = shelf rows (1 m deep)
      w_1   a1_1   a2_1   ...      aK_1   e_1       aisles 2 m wide between shelves
      │  ██  │  ██  │  ██      ██   │  ██  │
     w_s ── a1_s ── a2_s ── a3_s ─ a4_s ── e_s      south corridor
      │   C C   C C   C C   C C │   C C   C C │    C = chargers, 1 m off the corridor
      │ P P P P P P P P P P P P │ P P P P P P │    parking row (facing the lane)
     w_p1 ─────────────────── a4_p1 ──────── e_p1   parking lane
      │ P P P P P P P P P P P P │ P P P P P P │    parking row
      │ P P P P P P P P P P P P │ P P P P P P │    (next pair of rows, back to back)
     w_p2 ─────────────────── a4_p2 ──────── e_p2   parking lane
      │ P P P P P P P P P P P P │ P P P P P P │
    ─────────────────────────────────────────────────────────────
    south wall

Roadmap nodes sit on the aisle center lines (``a<i>_s`` / ``a<i>_n`` at the corridor center lines,
``a<i>_<j>`` in between, one per shelf bay of about 5 m) and the west / east corridors. Every edge
keeps 1 m from shelves and walls: robots of radius 0.3 m can use it, two can pass in an aisle. Stations are pick poses in the
aisles (``pick_a<i>_<j>_e`` / ``_w``, 0.4 m off the center line, facing the shelf) and
drop-off poses (``drop<k>``) at the east wall.

Chargers stand 1 m off the south corridor (and, when more are needed, the north one), two
in every gap between aisle ends, each with its own way in and out (no charger is reached
through another charger or through a lane other robots patrol). Parking spots come in pairs
of rows facing a parking lane (``<col>_p<k>``) that connectors (``w_p*``, ``e_p*`` and one
under every fourth aisle) join to the south corridor, so every spot can be reached without
passing another spot. Robots start with batteries spread over [0.6, 1.0]
(:func:`start_battery`). Patrol routes loop up one aisle and down the next (``aisles_<i>_<i+1>``;
with an odd aisle count the last aisle loops with the east corridor, ``aisle_<K>_east``),
plus one ``perimeter`` loop: every loop runs clockwise (shared corridors are driven one way).

The default (``n_robots <= 49``) warehouse is 30 m x 20 m with 7 aisles and two parking rows of
25 spots; larger fleets get more aisles, longer shelves and more parking rows. Deterministic.
Command line: ``python -m fleet.warehouse --robots N --out DIR`` (``--help``; ``--shipped``: the shipped configs).
"""

from __future__ import annotations

import argparse
import bisect
import math
import random
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from fleet.errors import ConfigError
from fleet.maps import FREE, OCCUPIED, OccupancyGrid, save_map

RESOLUTION = 0.1  # m per cell
WALL = 0.2  # m, wall thickness
SHELF_DEPTH = 1.0  # m, a shelf row seen from above (double-sided rack)
AISLE_WIDTH = 2.0  # m, free width between two shelf rows
CORRIDOR_HALF = 1.5  # m from a corridor center line to the nearest shelf
PARK_DX = 1.0  # m between parking spots in a row
PARK_LANE = 1.0  # m from a parking lane to the spots on either side of it
PAIR_DY = 3.0  # m from one pair of parking rows (and their lane) to the next
PARK_MARGIN = 0.8  # m from a parking spot to the west / east / south inner wall face
CHARGER_OFFSET = 1.0  # m from a corridor center line to the chargers beside it
CHARGERS_PER_ROBOT = 1.0 / 3.0  # default charger count per robot
CONNECTOR_EVERY = 4  # a parking connector under every this many aisles
BAY = 5.0  # m, roadmap node spacing target along aisles
PICK_OFFSET = 0.4  # m, pick poses sit this far off the aisle center line toward the shelf
DEFAULT_ROBOT_RADIUS = 0.3  # m


@dataclass(frozen=True)
class Layout:
    """Dimensions of a generated warehouse (meters). Derived by :func:`plan_layout`."""

    aisles: int
    shelf_len: float
    parking_rows: int
    width: float
    height: float
    x_west: float  # west corridor center line
    x_shelf0: float  # west face of the first shelf row
    x_east: float  # east corridor center line
    y_south: float  # south corridor center line
    y_shelf0: float  # south end of the shelf rows
    y_north: float  # north corridor center line

    @property
    def pairs(self) -> int:
        """Pairs of parking rows (each pair faces one parking lane)."""
        return (self.parking_rows + 1) // 2

    def connectors(self) -> list[tuple[str, float]]:
        """``(column name, x)`` of the connectors from the south corridor down to the parking
        lanes: the west and east corridors and every :data:`CONNECTOR_EVERY`-th aisle."""
        mids = [(f"a{i}", self.aisle_x(i)) for i in range(CONNECTOR_EVERY, self.aisles, CONNECTOR_EVERY)]
        return [("w", self.x_west), *mids, ("e", self.x_east)]

    def spot_xs(self) -> list[float]:
        """``x`` of the parking spots of a row: every :data:`PARK_DX` m from the west margin,
        except where a connector passes (closer than 1 m)."""
        x0 = WALL + PARK_MARGIN
        n = int(math.floor((self.width - 2 * x0) / PARK_DX + 1e-9)) + 1
        xs = [x0 + s * PARK_DX for s in range(n)]
        cx = sorted(x for _, x in self.connectors())  # the two nearest connectors decide:
        near = [cx[max(0, k - 1) : k + 1] for k in (bisect.bisect_left(cx, x) for x in xs)]
        return [x for x, cs in zip(xs, near, strict=True) if all(abs(x - c) >= 1.0 - 1e-9 for c in cs)]

    @property
    def spots_per_row(self) -> int:
        """Parking spots in one row."""
        return len(self.spot_xs())

    @property
    def parking_capacity(self) -> int:
        return self.spots_per_row * self.parking_rows

    def lane_y(self, k: int) -> float:
        """``y`` of parking lane ``k`` (0 = nearest the south corridor)."""
        front_row = self.y_south - CHARGER_OFFSET - PARK_DX
        return front_row - PARK_LANE - PAIR_DY * k

    def row_ys(self) -> list[float]:
        """``y`` of the parking rows, nearest the south corridor first: the rows of pair
        ``k`` lie :data:`PARK_LANE` north and south of lane ``k``."""
        out: list[float] = []
        for k in range(self.pairs):
            out.append(self.lane_y(k) + PARK_LANE)
            if len(out) < self.parking_rows:
                out.append(self.lane_y(k) - PARK_LANE)
        return out

    @property
    def bays(self) -> int:
        """Roadmap nodes strictly inside each aisle."""
        return max(1, round(self.shelf_len / BAY))

    def charger_sites(self) -> list[tuple[float, float, float]]:
        """Where chargers may stand, ``(x, y, theta)``: 1 m and 2 m east of each corridor
        node along the south corridor (1 m south of it), then the same along the north
        corridor; every site is at least 1 m from corridor nodes, connectors and the spots."""
        cols = [self.x_west] + [self.aisle_x(i) for i in range(1, self.aisles + 1)] + [self.x_east]
        xs = []
        for xa, xb in zip(cols, cols[1:], strict=False):
            xs += [x for x in (xa + 1.0, xa + 2.0) if xb - x >= 1.0 - 1e-9]
        south = [(x, self.y_south - CHARGER_OFFSET, -math.pi / 2) for x in xs]
        north = [(x, self.y_north + CHARGER_OFFSET, math.pi / 2) for x in xs]
        return south + north

    @property
    def charger_capacity(self) -> int:
        return len(self.charger_sites())

    def aisle_x(self, i: int) -> float:
        """Center line of aisle ``i`` (1-based)."""
        return self.x_shelf0 + SHELF_DEPTH + (i - 1) * (SHELF_DEPTH + AISLE_WIDTH) + AISLE_WIDTH / 2

    def bay_y(self, j: int) -> float:
        """``y`` of the ``j``-th (1-based) interior aisle node."""
        return self.y_shelf0 + self.shelf_len * (j - 0.5) / self.bays


def auto_aisles(n_robots: int) -> int:
    """Default aisle count for a fleet of ``n_robots``: 7 up to 49 robots, then ``ceil(sqrt(n))``."""
    return max(7, math.ceil(math.sqrt(max(n_robots, 1))))


def auto_shelf_len(n_robots: int) -> float:
    """Default shelf length (m): 10 m up to 49 robots, then growing with ``sqrt(n)``."""
    if n_robots <= 49:
        return 10.0
    return float(round(10.0 + math.sqrt(n_robots) / 4.0))


def plan_layout(
    n_robots: int, aisles: int | None = None, shelf_len: float | None = None, parking_rows: int | None = None
) -> Layout:
    """Dimensions for ``n_robots``. ``None`` arguments are chosen automatically.

    Raises :class:`ConfigError` (field ``n_robots``) if explicit ``aisles`` / ``parking_rows``
    leave fewer parking spots than robots, and (field ``aisles`` / ``shelf_len`` /
    ``parking_rows``) for out-of-range values.
    """
    src = "fleet.warehouse"
    if n_robots < 1:
        raise ConfigError(src, "n_robots", f"must be at least 1, got {n_robots}")
    k = auto_aisles(n_robots) if aisles is None else aisles
    if k < 1:
        raise ConfigError(src, "aisles", f"must be at least 1, got {k}")
    sl = auto_shelf_len(n_robots) if shelf_len is None else float(shelf_len)
    if sl < 3.0:
        raise ConfigError(src, "shelf_len", f"must be at least 3.0 m, got {sl}")
    sl = round(sl / RESOLUTION) * RESOLUTION
    x_west = WALL + PARK_MARGIN + CORRIDOR_HALF
    x_shelf0 = x_west + CORRIDOR_HALF
    x_shelf_end = x_shelf0 + (k + 1) * SHELF_DEPTH + k * AISLE_WIDTH
    x_east = x_shelf_end + CORRIDOR_HALF
    width = x_east + CORRIDOR_HALF + PARK_MARGIN + WALL
    probe = Layout(k, sl, 1, width, 0, x_west, x_shelf0, x_east, 0, 0, 0)
    rows = parking_rows
    if rows is None:
        rows = max(2, math.ceil(n_robots / probe.spots_per_row))
    if rows < 1:
        raise ConfigError(src, "parking_rows", f"must be at least 1, got {rows}")
    # the deepest lane's south row (present or not) keeps PARK_MARGIN from the south wall
    pairs = (rows + 1) // 2
    y_south = WALL + PARK_MARGIN + 2 * PARK_LANE + PAIR_DY * (pairs - 1) + PARK_DX + CHARGER_OFFSET
    y_shelf0 = y_south + CORRIDOR_HALF
    y_north = y_shelf0 + sl + CORRIDOR_HALF
    height = y_north + CORRIDOR_HALF + 0.3 + WALL
    lay = Layout(k, sl, rows, width, height, x_west, x_shelf0, x_east, y_south, y_shelf0, y_north)
    if lay.parking_capacity < n_robots:
        raise ConfigError(
            src,
            "n_robots",
            f"{n_robots} robots do not fit: {k} aisles and {rows} parking rows give "
            f"{lay.parking_capacity} parking spots (add aisles or parking rows)",
        )
    return lay


def _cells(v: float) -> int:
    return int(round(v / RESOLUTION))


def build_grid(lay: Layout) -> OccupancyGrid:
    """The occupancy grid of ``lay``: free floor, occupied walls and shelf rows. Origin (0, 0)."""
    w, h = _cells(lay.width), _cells(lay.height)
    cells = np.full((h, w), FREE, dtype=np.int8)
    t = _cells(WALL)
    cells[:t, :] = OCCUPIED
    cells[h - t :, :] = OCCUPIED
    cells[:, :t] = OCCUPIED
    cells[:, w - t :] = OCCUPIED
    y0, y1 = _cells(lay.y_shelf0), _cells(lay.y_shelf0 + lay.shelf_len)
    for s in range(lay.aisles + 1):
        x0 = _cells(lay.x_shelf0 + s * (SHELF_DEPTH + AISLE_WIDTH))
        cells[y0:y1, x0 : x0 + _cells(SHELF_DEPTH)] = OCCUPIED
    return OccupancyGrid(cells=cells, resolution=RESOLUTION, origin_x=0.0, origin_y=0.0)


def _r(v: float) -> float:
    """Round to mm so the YAML is readable and stable."""
    out = round(v, 3)
    return 0.0 if out == 0 else out


def _pose(x: float, y: float, th: float) -> list[float]:
    return [_r(x), _r(y), round(th, 6)]


#: One entry of a config list in file form: a charger, station, route, task or robot.
Entry = dict[str, object]


@dataclass(frozen=True)
class World:
    """Everything of a generated warehouse but the map, in config-file form (map frame, m)."""

    nodes: dict[str, list[float]]  # roadmap node name -> [x, y]
    edges: list[list[str]]  # roadmap edges [a, b]
    chargers: list[Entry]
    stations: list[Entry]
    routes: list[Entry]
    tasks: list[Entry]
    parking: list[list[float]]  # poses [x, y, theta]
    robots: list[Entry]


def build_world(
    lay: Layout, n_robots: int, chargers: int | None = None, tasks: int | None = None, seed: int = 1
) -> World:
    """Everything but the map, as plain data (the sections of a fleet config).

    ``chargers`` and ``tasks`` default as in :func:`generate_warehouse`; ``seed`` picks the
    task shelves. Raises :class:`ConfigError` if more chargers are requested than
    :meth:`Layout.charger_sites` offers.
    """
    nodes, edges = roadmap_of(lay)
    stations, drops = stations_of(lay)
    parking = parking_of(lay)
    return World(
        nodes=nodes,
        edges=edges,
        chargers=chargers_of(lay, n_robots, chargers),
        stations=stations,
        routes=routes_of(lay.aisles),
        tasks=tasks_of(stations, drops, max(4, n_robots // 2) if tasks is None else tasks, seed),
        parking=parking,
        robots=robots_of(parking, n_robots),
    )


def roadmap_of(lay: Layout) -> tuple[dict[str, list[float]], list[list[str]]]:
    """Nodes (name -> [x, y]) and edges along the aisles, the four corridors, the parking
    connectors (``<col>_p<k>`` below the south corridor node ``<col>_s``) and the parking
    lanes between them."""
    m = lay.bays
    ys = [lay.y_south] + [lay.bay_y(j) for j in range(1, m + 1)] + [lay.y_north]
    suffix = ["s"] + [str(j) for j in range(1, m + 1)] + ["n"]
    columns = (
        [("w", lay.x_west)]
        + [(f"a{i}", lay.aisle_x(i)) for i in range(1, lay.aisles + 1)]
        + [("e", lay.x_east)]
    )
    nodes: dict[str, list[float]] = {}
    edges: list[list[str]] = []
    for prefix, x in columns:
        for sfx, y in zip(suffix, ys, strict=True):
            nodes[f"{prefix}_{sfx}"] = [_r(x), _r(y)]
        for a, b in zip(suffix, suffix[1:], strict=False):
            edges.append([f"{prefix}_{a}", f"{prefix}_{b}"])
    for end in ("s", "n"):
        for (pa, _), (pb, _) in zip(columns, columns[1:], strict=False):
            edges.append([f"{pa}_{end}", f"{pb}_{end}"])
    conn = lay.connectors()
    for k in range(lay.pairs):
        y = lay.lane_y(k)
        for col, x in conn:
            nodes[f"{col}_p{k + 1}"] = [_r(x), _r(y)]
            edges.append([f"{col}_s" if k == 0 else f"{col}_p{k}", f"{col}_p{k + 1}"])
        for (ca, _), (cb, _) in zip(conn, conn[1:], strict=False):
            edges.append([f"{ca}_p{k + 1}", f"{cb}_p{k + 1}"])
    return nodes, edges


def chargers_of(lay: Layout, n_robots: int, chargers: int | None, sides: int = 1) -> list[Entry]:
    """``chargers`` chargers (default ``max(2, ceil(n / 3))``, at most the sites there are)
    on :meth:`Layout.charger_sites`, spread evenly along the corridor: south sites first, then
    north ones (``sides=2``: half on each). Raises :class:`ConfigError` (field ``chargers``)."""
    sites = lay.charger_sites()
    cap = len(sites)
    want = max(2, math.ceil(n_robots * CHARGERS_PER_ROBOT))
    n_ch = min(cap, want) if chargers is None else chargers
    if not 1 <= n_ch <= cap:
        raise ConfigError(
            "fleet.warehouse", "chargers", f"must be between 1 and {cap} for this layout, got {n_ch}"
        )
    half = cap // 2
    south, north = sites[:half], sites[half:]
    n_south = min(n_ch, half) if sides < 2 else max(n_ch - half, (n_ch + 1) // 2)
    chosen = _spread(south, n_south) + _spread(north, n_ch - n_south)
    return [{"name": f"charger{c + 1}", "pose": _pose(x, y, th)} for c, (x, y, th) in enumerate(chosen)]


def _spread(items: list[tuple[float, float, float]], n: int) -> list[tuple[float, float, float]]:
    """``n`` of ``items`` evenly spread over the list (in list order; none for ``n <= 0``)."""
    return [items[(2 * j + 1) * len(items) // (2 * n)] for j in range(max(0, n))]


def stations_of(lay: Layout) -> tuple[list[Entry], list[str]]:
    """Pick stations on both sides of every aisle node, then the drop-offs at the east wall;
    and the drop-off names."""
    stations: list[Entry] = []
    for i in range(1, lay.aisles + 1):
        x = lay.aisle_x(i)
        for j in range(1, lay.bays + 1):
            y = lay.bay_y(j)
            stations.append({"name": f"pick_a{i}_{j}_w", "pose": _pose(x - PICK_OFFSET, y, math.pi)})
            stations.append({"name": f"pick_a{i}_{j}_e", "pose": _pose(x + PICK_OFFSET, y, 0.0)})
    drop_x = lay.width - WALL - PARK_MARGIN
    drops = [f"drop{j}" for j in range(1, lay.bays + 1)]
    for j, name in enumerate(drops, start=1):
        stations.append({"name": name, "pose": _pose(drop_x, lay.bay_y(j), 0.0)})
    return stations, drops


def routes_of(aisles: int) -> list[Entry]:
    """Up one aisle and down the next, the last odd aisle with the east corridor, the perimeter."""
    k = aisles
    routes: list[Entry] = []
    for p in range(k // 2):
        up, down = 2 * p + 1, 2 * p + 2
        routes.append(
            {"name": f"aisles_{up}_{down}", "waypoints": [f"a{up}_s", f"a{up}_n", f"a{down}_n", f"a{down}_s"]}
        )
    if k % 2:
        routes.append({"name": f"aisle_{k}_east", "waypoints": [f"a{k}_s", f"a{k}_n", "e_n", "e_s"]})
    routes.append({"name": "perimeter", "waypoints": ["w_s", "w_n", "e_n", "e_s"]})
    return routes


def tasks_of(stations: list[Entry], drops: list[str], n_tasks: int, seed: int) -> list[Entry]:
    """``n_tasks`` picking tasks: a pick station drawn with ``random.Random(seed)``, the
    drop-offs in turn."""
    rng = random.Random(seed)
    picks = [str(s["name"]) for s in stations if str(s["name"]).startswith("pick_")]
    return [
        {"name": f"pick{t + 1}", "shelf": rng.choice(picks), "drop": drops[t % len(drops)], "dwell_s": 5.0}
        for t in range(n_tasks)
    ]


def parking_of(lay: Layout) -> list[list[float]]:
    """Parking poses, row by row from the south wall, each facing its parking lane."""
    parking: list[list[float]] = []
    lanes = [lay.lane_y(k) for k in range(lay.pairs)]
    for y in sorted(lay.row_ys()):
        lane = min(lanes, key=lambda ly: abs(ly - y))
        th = math.pi / 2 if lane > y else -math.pi / 2
        parking += [_pose(x, y, th) for x in lay.spot_xs()]
    return parking


def robots_of(parking: list[list[float]], n_robots: int) -> list[Entry]:
    """Robots on the parking spots, filling the row nearest the corridor first so that nobody
    starts boxed in; batteries from :func:`start_battery`."""
    order = sorted(range(len(parking)), key=lambda q: (-parking[q][1], q))
    return [
        {"name": f"robot{r + 1}", "start": parking[order[r]], "battery": start_battery(r)}
        for r in range(n_robots)
    ]


def start_battery(index: int) -> float:
    """The start battery of the ``index``-th robot (0-based): spread over [0.6, 1.0] by the
    golden ratio, so robots of a generated fleet do not all need a charger at once (with
    equal batteries and equal drain the whole fleet would come to the chargers together)."""
    return round(1.0 - 0.4 * ((index * 0.6180339887498949) % 1.0), 2)


def _flow(v: object) -> str:
    """Render a scalar / flat list / flat dict in YAML flow style."""
    if isinstance(v, list):
        return "[" + ", ".join(_flow(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{key}: {_flow(x)}" for key, x in v.items()) + "}"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def render_config(name: str, map_rel: str, world: World, lay: Layout, seed: int, command: str) -> str:
    """The fleet config YAML text (hand-readable: one node, edge, pose or task per line)."""
    L = [
        f"# Generated by `{command}`; edit freely.",
        f"# Warehouse {lay.width:g} m x {lay.height:g} m: {lay.aisles} aisles, shelves {lay.shelf_len:g} m long,",
        f"# {lay.parking_rows} parking rows of {lay.spots_per_row} spots. Map frame, meters, radians.",
        f"name: {name}",
        f"map: {map_rel}",
        "roadmap:",
        "  nodes:",
    ]
    L += [f"    {n}: {_flow(xy)}" for n, xy in world.nodes.items()]
    L.append("  edges:")
    L += [f"    - {_flow(e)}" for e in world.edges]
    sections = (("chargers", world.chargers), ("stations", world.stations), ("routes", world.routes))
    for section, items in (*sections, ("tasks", world.tasks)):
        L += [f"{section}:", *(f"  - {_flow(item)}" for item in items)] if items else [f"{section}: []"]
    L.append("parking:                          # free start spots used by load_config(robots=N)")
    L += [f"  - {_flow(p)}" for p in world.parking]
    L.append("robots:")
    L += [f"  - {_flow(r)}" for r in world.robots]
    L += [
        "robot_model:",
        f"  radius: {DEFAULT_ROBOT_RADIUS}",
        "  max_linear_speed: 1.0",
        "  max_angular_speed: 1.5",
        "  max_linear_accel: 0.8",
        "  max_angular_accel: 3.0",
        "battery:",
        "  drain_per_m: 0.004",
        "  drain_per_s: 0.0005",
        "  charge_per_s: 0.02",
        "  low: 0.1",
        "  resume: 0.95",
        "  initial: 1.0",
        "sim:",
        "  step_s: 0.05",
        "  stuck_time_s: 8.0",
        f"  seed: {seed}",
        "agent:",
        "  tick_hz: 10.0",
        "coordinator:",
        "  stuck_reassign_s: 30.0",
        "  status_timeout_s: 3.0",
        "bus:",
        "  endpoint: tcp/127.0.0.1:7447",
    ]
    return "\n".join(L) + "\n"


def generate_warehouse(
    out_dir: str | Path,
    name: str,
    n_robots: int,
    *,
    aisles: int | None = None,
    shelf_len: float | None = None,
    chargers: int | None = None,
    parking_rows: int | None = None,
    tasks: int | None = None,
    seed: int = 1,
    map_name: str | None = None,
    charger_sides: int = 1,
) -> Path:
    """Write a warehouse world and return the path of its fleet config.

    Writes ``out_dir/<name>.yaml`` (the fleet config, format in ``docs/config.md``) and
    ``out_dir/maps/<map_name>.yaml`` + ``.pgm`` (map_server map, 0.1 m cells, origin (0, 0);
    ``map_name`` defaults to ``name``). ``n_robots`` robots start on the parking rows, the
    row nearest the south corridor first.

    ``aisles`` (default grows with ``n_robots``, at least 7), ``shelf_len`` (m, default 10 m
    up to 49 robots), ``parking_rows`` (default: enough for ``n_robots``, at least 2) shape
    the map; ``chargers`` (default ``max(2, ceil(n/3))``, ``charger_sides=2``: half of them on
    the north corridor) and ``tasks`` (picking tasks, default ``max(4, n // 2)``) only change
    the config. ``seed`` picks the task shelves and is written as ``sim.seed``. Same arguments,
    same bytes. Raises :class:`ConfigError` naming the argument when robots or chargers do not fit.
    """
    lay = plan_layout(n_robots, aisles, shelf_len, parking_rows)
    world = build_world(lay, n_robots, chargers, tasks, seed)
    world = replace(world, chargers=chargers_of(lay, n_robots, chargers, charger_sides))
    out = Path(out_dir)
    (out / "maps").mkdir(parents=True, exist_ok=True)
    map_name = map_name or name
    save_map(build_grid(lay), out / "maps" / f"{map_name}.yaml")
    cmd = f"python -m fleet.warehouse --robots {n_robots} --name {name}"
    for flag, val in (
        ("--aisles", aisles),
        ("--shelf-len", shelf_len),
        ("--chargers", chargers),
        ("--parking-rows", parking_rows),
        ("--tasks", tasks),
    ):
        if val is not None:
            cmd += f" {flag} {val:g}" if isinstance(val, float) else f" {flag} {val}"
    if seed != 1:
        cmd += f" --seed {seed}"
    if map_name != name:
        cmd += f" --map-name {map_name}"
    path = out / f"{name}.yaml"
    path.write_text(render_config(name, f"maps/{map_name}.yaml", world, lay, seed, cmd))
    return path


def generate_shipped(out_dir: str | Path = "configs") -> list[Path]:
    """Regenerate the configs shipped in ``configs/``: 6-robot patrol, 30-robot patrol and
    6-robot picking, all on ``maps/warehouse.yaml``."""
    return [
        generate_warehouse(out_dir, "warehouse_patrol", 6, tasks=4, map_name="warehouse"),
        generate_warehouse(out_dir, "warehouse_patrol_30", 30, tasks=4, map_name="warehouse"),
        generate_warehouse(out_dir, "warehouse_picking", 6, tasks=24, map_name="warehouse"),
    ]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m fleet.warehouse",
        description="Generate a warehouse world: a map_server map (maps/<name>.yaml + .pgm) and a fleet "
        "config (<name>.yaml) with roadmap, chargers, stations, patrol routes, picking tasks and robots. "
        "The size grows with --robots; the same arguments always give the same files.",
        epilog="Example: python -m fleet.warehouse --robots 100 --out out/w100  ·  "
        "python -m fleet.warehouse --shipped --out configs  (regenerate the shipped configs)",
    )
    p.add_argument("--robots", type=int, default=6, help="number of robots (default 6)")
    p.add_argument("--out", default="configs", help="output directory (default configs)")
    p.add_argument("--name", default=None, help="config name (default warehouse_<robots>)")
    p.add_argument("--map-name", default=None, help="map file stem under maps/ (default: --name)")
    p.add_argument("--aisles", type=int, default=None, help="aisle count (default grows with robots, min 7)")
    p.add_argument("--shelf-len", type=float, default=None, help="shelf row length in m (default 10)")
    p.add_argument("--parking-rows", type=int, default=None, help="parking rows (default: enough, min 2)")
    p.add_argument("--chargers", type=int, default=None, help="charger count (default max(2, robots/5))")
    p.add_argument("--tasks", type=int, default=None, help="picking tasks (default max(4, robots/2))")
    p.add_argument("--seed", type=int, default=1, help="seed for task choice and sim.seed (default 1)")
    p.add_argument("--shipped", action="store_true", help="regenerate the three shipped configs into --out")
    a = p.parse_args(argv)
    try:
        if a.shipped:
            paths = generate_shipped(a.out)
        else:
            paths = [
                generate_warehouse(
                    a.out,
                    a.name or f"warehouse_{a.robots}",
                    a.robots,
                    aisles=a.aisles,
                    shelf_len=a.shelf_len,
                    chargers=a.chargers,
                    parking_rows=a.parking_rows,
                    tasks=a.tasks,
                    seed=a.seed,
                    map_name=a.map_name,
                )
            ]
    except ConfigError as e:
        print(e)
        return 2
    for path in paths:
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
