"""Checks that raise :class:`~fleet.errors.ConfigError` naming the file and the field: types,
ranges, names, and poses on the map (inside it, clear of obstacles by the robot radius)."""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Mapping
from typing import Any

import yaml

from fleet.errors import ConfigError
from fleet.maps import OccupancyGrid
from fleet.types import Pose2D

NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


NAMESPACE_RE = re.compile(r"^/[A-Za-z][A-Za-z0-9_]*$")


class _Validator:
    """Type checks that raise ConfigError naming ``file`` and the field."""

    def __init__(self, file: str) -> None:
        self.file = file

    def keys(self, d: Mapping[Any, Any], prefix: str, allowed: tuple[str, ...]) -> None:
        for key in d:
            if key not in allowed:
                f = f"{prefix}.{key}" if prefix else str(key)
                raise ConfigError(self.file, f, f"unknown key{_suggest(str(key), allowed)}")

    def section(
        self, sec: Any, f: str, allowed: tuple[str, ...], required: tuple[str, ...] = ()
    ) -> dict[str, Any]:
        if sec is None:
            sec = {}
        if not isinstance(sec, dict):
            raise ConfigError(self.file, f, f"must be a mapping, got {_tname(sec)}")
        self.keys(sec, f, allowed)
        for key in required:
            if key not in sec:
                raise ConfigError(self.file, f"{f}.{key}", "missing required field")
        return sec

    def list(self, sec: Any, f: str) -> list[Any]:
        if sec is None:
            return []
        if not isinstance(sec, list):
            raise ConfigError(self.file, f, f"must be a list, got {_tname(sec)}")
        return sec

    def string(self, val: Any, f: str) -> str:
        if not isinstance(val, str) or not val:
            raise ConfigError(self.file, f, f"must be a non-empty string, got {val!r}")
        return val

    def name(self, val: Any, f: str) -> str:
        s = self.string(val, f)
        if not NAME_RE.match(s):
            raise ConfigError(self.file, f, f"must be a letter then letters, digits or _, got {s!r}")
        return s

    def number(self, val: Any, f: str, what: str = "a number") -> float:
        if not _is_number(val):
            raise ConfigError(self.file, f, f"must be {what}, got {val!r}")
        return float(val)

    def positive(self, val: Any, f: str) -> float:
        x = self.number(val, f, "a positive number")
        if x <= 0:
            raise ConfigError(self.file, f, f"must be a positive number, got {x!r}")
        return x

    def non_negative(self, val: Any, f: str) -> float:
        x = self.number(val, f, "a number >= 0")
        if x < 0:
            raise ConfigError(self.file, f, f"must be a number >= 0, got {x!r}")
        return x

    def fraction(self, val: Any, f: str) -> float:
        x = self.number(val, f, "a fraction in [0, 1]")
        if not 0.0 <= x <= 1.0:
            raise ConfigError(self.file, f, f"must be a fraction in [0, 1], got {x!r}")
        return x

    def integer(self, val: Any, f: str) -> int:
        if not isinstance(val, int) or isinstance(val, bool):
            raise ConfigError(self.file, f, f"must be an integer, got {val!r}")
        return val


class _Placer:
    """Pose parsing plus the map checks (inside the map, clear of obstacles by the radius)."""

    def __init__(self, v: _Validator, grid: OccupancyGrid, radius: float) -> None:
        self.v, self.grid, self.radius = v, grid, radius

    def pose(self, val: Any, f: str) -> Pose2D:
        if not (isinstance(val, (list, tuple)) and len(val) == 3 and all(_is_number(x) for x in val)):
            raise ConfigError(
                self.v.file, f, f"must be a pose [x, y, theta] of numbers (m, m, rad), got {val!r}"
            )
        pose = Pose2D(float(val[0]), float(val[1]), float(val[2]))
        self.check(pose, f)
        return pose

    def check(self, pose: Pose2D, f: str) -> None:
        if not self.grid.in_bounds(pose.x, pose.y):
            xmin, xmax, ymin, ymax = self.grid.extent
            raise ConfigError(
                self.v.file,
                f,
                f"pose ({pose.x:g}, {pose.y:g}) is off the map (x in [{xmin:g}, {xmax:g}), y in [{ymin:g}, {ymax:g}))",
            )
        if not self.grid.is_free(pose.x, pose.y, self.radius):
            raise ConfigError(
                self.v.file,
                f,
                f"pose ({pose.x:g}, {pose.y:g}) is inside an obstacle or within robot_model.radius "
                f"({self.radius:g} m) of one",
            )

    def check_segment(self, a: tuple[float, float], b: tuple[float, float], f: str, what: str) -> None:
        (ax, ay), (bx, by) = a, b
        n = max(1, math.ceil(math.hypot(bx - ax, by - ay) / self.grid.resolution))
        for k in range(n + 1):
            x, y = ax + (bx - ax) * k / n, ay + (by - ay) * k / n
            if not self.grid.is_free(x, y, self.radius):
                raise ConfigError(
                    self.v.file,
                    f,
                    f"{what} passes through an obstacle at ({x:.2f}, {y:.2f}) "
                    f"(clearance robot_model.radius = {self.radius:g} m)",
                )


class _NearIndex:
    """A uniform hash grid for "is any stored point closer than d" queries (d <= cell)."""

    def __init__(self, cell: float) -> None:
        self.cell = cell
        self.buckets: dict[tuple[int, int], list[tuple[float, float, int]]] = {}

    def _key(self, x: float, y: float) -> tuple[int, int]:
        return (math.floor(x / self.cell), math.floor(y / self.cell))

    def add(self, x: float, y: float, idx: int) -> None:
        self.buckets.setdefault(self._key(x, y), []).append((x, y, idx))

    def closer_than(self, x: float, y: float, d: float) -> int | None:
        cx, cy = self._key(x, y)
        best: tuple[float, int] | None = None
        for i in (-1, 0, 1):
            for j in (-1, 0, 1):
                for px, py, idx in self.buckets.get((cx + i, cy + j), ()):
                    dd = math.hypot(px - x, py - y)
                    if dd < d - 1e-9 and (best is None or (dd, idx) < best):
                        best = (dd, idx)
        return None if best is None else best[1]


def _is_number(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _tname(v: object) -> str:
    return "nothing" if v is None else type(v).__name__


def _suggest(word: str, options: Any) -> str:
    match = difflib.get_close_matches(word, [str(o) for o in options], n=1)
    return f" (did you mean {match[0]!r}?)" if match else ""


def _yaml_problem(e: yaml.YAMLError) -> str:
    mark = getattr(e, "problem_mark", None) or getattr(e, "context_mark", None)
    problem = getattr(e, "problem", None) or str(e).splitlines()[0]
    if mark is not None:
        return f"line {mark.line + 1}, column {mark.column + 1}: {problem}"
    return str(problem)
