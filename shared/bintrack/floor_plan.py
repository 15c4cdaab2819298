"""A deployment's floor plan as geometry: which points of the floor people can stand on (not
inside an obstacle) and how far a point lies from the nearest door. Pure: shapely, no I/O.
"""

from __future__ import annotations

import math

import numpy as np
import shapely

from bintrack.deployment_model import FloorPlan


class FloorShape:
    """The obstacles of ``plan`` as one shape, and its doors (deployment units)."""

    def __init__(self, plan: FloorPlan):
        shapes = [shapely.Polygon(area.vertices()) for area in plan.obstacles]
        for k, shape in enumerate(shapes):
            if not shape.is_valid:
                raise ValueError(f"floor plan: obstacle {k + 1}'s polygon crosses itself")
        self.obstacles = shapely.union_all(shapes) if shapes else None
        if self.obstacles is not None:
            shapely.prepare(self.obstacles)
        self.doors = np.array(plan.doors, dtype=float).reshape(-1, 2)

    def free(self, points: np.ndarray) -> np.ndarray:
        """Per point (n × 2, units): True where someone can stand, outside every obstacle (an
        obstacle's border counts as free)."""
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        if self.obstacles is None:
            return np.ones(len(points), dtype=bool)
        return ~shapely.contains_xy(self.obstacles, points[:, 0], points[:, 1])

    def door_distance(self, x: float, y: float) -> float:
        """Distance (units) from (x, y) to the nearest door; infinite when the plan names none."""
        if not len(self.doors):
            return math.inf
        return float(np.min(np.hypot(self.doors[:, 0] - x, self.doors[:, 1] - y)))
