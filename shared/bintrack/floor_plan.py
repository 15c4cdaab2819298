"""A deployment's floor plan as geometry: which points of the floor people can stand on (not
inside an obstacle). Pure: shapely, no I/O.
"""

from __future__ import annotations

import numpy as np
import shapely

from bintrack.deployment_model import FloorPlan


class FloorShape:
    """The obstacles of ``plan`` as one shape (deployment units)."""

    def __init__(self, plan: FloorPlan):
        shapes = [shapely.Polygon(area.vertices()) for area in plan.obstacles]
        for k, shape in enumerate(shapes):
            if not shape.is_valid:
                raise ValueError(f"floor plan: obstacle {k + 1}'s polygon crosses itself")
        self.obstacles = shapely.union_all(shapes) if shapes else None
        if self.obstacles is not None:
            shapely.prepare(self.obstacles)

    def free(self, points: np.ndarray) -> np.ndarray:
        """Per point (n × 2, units): True where someone can stand, outside every obstacle (an
        obstacle's border counts as free)."""
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        if self.obstacles is None:
            return np.ones(len(points), dtype=bool)
        return ~shapely.contains_xy(self.obstacles, points[:, 0], points[:, 1])
