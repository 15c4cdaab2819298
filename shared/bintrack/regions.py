"""Regions of a deployment (DESIGN §9, several machines): which region owns a point, which
sensors a region's base station takes (its own plus a border band, three sensing ranges wide by
default), and a field cut into a grid of rectangles. Pure: shapely geometry, no I/O.

A deployment without ``regions`` is one region, named :data:`WHOLE`, covering its field.
"""

from __future__ import annotations

import shapely

from bintrack.deployment_model import Deployment, Region, RegionArea

WHOLE = "all"


def grid_areas(field: Region, columns: int, rows: int) -> list[RegionArea]:
    """``field`` cut into ``columns`` × ``rows`` equal rectangles named ``r<row>c<column>``
    (row 0 at ymin), deployment units."""
    if columns < 1 or rows < 1:
        raise ValueError(f"a grid of regions needs at least 1×1, got {columns}×{rows}")
    w, h = field.width / columns, field.height / rows
    return [RegionArea(name=f"r{j}c{i}", xmin=field.xmin + i * w, ymin=field.ymin + j * h,
                       xmax=field.xmin + (i + 1) * w, ymax=field.ymin + (j + 1) * h)
            for j in range(rows) for i in range(columns)]


def grid_shape(count: int) -> tuple[int, int]:
    """(columns, rows) of the most square grid of exactly ``count`` regions."""
    if count < 1:
        raise ValueError(f"the number of regions must be at least 1, got {count}")
    rows = max(r for r in range(1, int(count ** 0.5) + 1) if count % r == 0)
    return count // rows, rows


class RegionMap:
    """The regions of ``deployment`` (or :data:`WHOLE`) and the sensors each one takes."""

    def __init__(self, deployment: Deployment):
        field = deployment.region
        areas = deployment.regions or [RegionArea(name=WHOLE, xmin=field.xmin, ymin=field.ymin,
                                                  xmax=field.xmax, ymax=field.ymax)]
        self.deployment = deployment
        self.names = [a.name for a in areas]
        self.shapes = {a.name: shapely.Polygon(a.vertices()) for a in areas}
        for name, shape in self.shapes.items():
            if not shape.is_valid:
                raise ValueError(f"region {name!r}: the polygon crosses itself")
            shapely.prepare(shape)

    def check(self, name: str) -> str:
        if name not in self.shapes:
            raise ValueError(f"unknown region {name!r} (the deployment has {', '.join(self.names)})")
        return name

    def owner(self, x: float, y: float) -> str:
        """The region that owns the point (x, y): the first that contains it (its border
        included), else the nearest one — every point has exactly one owner."""
        point = shapely.Point(x, y)
        for name, shape in self.shapes.items():
            if shape.covers(point):
                return name
        return min(self.names, key=lambda n: self.shapes[n].distance(point))

    def distance(self, name: str, x: float, y: float) -> float:
        """Distance from (x, y) to region ``name`` (0 inside), deployment units."""
        return float(self.shapes[name].distance(shapely.Point(x, y)))

    def home(self, sensor) -> str | None:
        """The region a sensor's position lies in; None for a sensor without a position."""
        x, y = getattr(sensor, "x", None), getattr(sensor, "y", None)
        return None if x is None or y is None else self.owner(x, y)

    def own_sensors(self, name: str) -> list[str]:
        """Ids of the sensors placed in region ``name`` (a sensor agent's shard); sensors with no
        position go to the first region."""
        self.check(name)
        return [s.id for s in self.deployment.sensors if (self.home(s) or self.names[0]) == name]

    def band(self, sensor) -> float:
        """How far outside its region a sensor is still taken by default: three sensing ranges
        (0 for a sensor without one). The fusion places a target in the cells within a range of
        it from every sensor covering those cells, up to two ranges away: with a band one range
        wide, a target near the border is placed from a part of them and lands metres off. The
        third range gives a person coming from a neighbouring region a track with some history
        before they cross the border (three chosen over two on ``benchmarks/region_merge.py``'s
        tuning seeds 10–13: the merge agrees with one base station over the whole field more
        closely in count, positions and identities; docs/regions.md)."""
        return 3.0 * float(getattr(sensor, "range", 0.0) or 0.0)

    def taken_sensors(self, name: str, band: float | None = None) -> list[str]:
        """Ids of the sensors region ``name``'s base station takes: those inside it and those
        within ``band`` of it (default: :meth:`band`, three of each sensor's sensing ranges);
        sensors with no position are always taken."""
        shape = self.shapes[self.check(name)]
        taken = []
        for s in self.deployment.sensors:
            x, y = getattr(s, "x", None), getattr(s, "y", None)
            width = self.band(s) if band is None else band
            if x is None or y is None or shape.distance(shapely.Point(x, y)) <= width:
                taken.append(s.id)
        return taken

    def takers(self, sensors: list[str]) -> dict[str, tuple[str, ...]]:
        """For each of ``sensors`` (ids), the regions whose base stations take it with the
        default band (:meth:`taken_sensors`): whom a sensor agent counts its transitions for."""
        wanted = set(sensors)
        takers: dict[str, list[str]] = {sid: [] for sid in sensors}
        for name in self.names:
            for sid in self.taken_sensors(name):
                if sid in wanted:
                    takers[sid].append(name)
        return {sid: tuple(names) for sid, names in takers.items()}

    def sub_deployment(self, name: str, band: float | None = None) -> Deployment:
        """The deployment a region's base station tracks on: the sensors it takes, in the whole
        field (so that the fusion's grid cells lie where the whole field's do)."""
        keep = set(self.taken_sensors(name, band))
        return self.deployment.model_copy(update={"sensors": [s for s in self.deployment.sensors if s.id in keep]})

    def neighbours(self, name: str, within: float = 0.0) -> list[str]:
        """The other regions at most ``within`` away from region ``name`` (touching ones at 0)."""
        shape = self.shapes[self.check(name)]
        return [n for n in self.names if n != name and shape.distance(self.shapes[n]) <= within + 1e-9]
