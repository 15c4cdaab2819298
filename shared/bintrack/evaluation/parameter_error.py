"""The parameter error of the adaptive basis algorithm's estimates (paper 003 §6, eq. 31)."""

from __future__ import annotations

import numpy as np


def parameter_error(lines: np.ndarray, objects: np.ndarray, true_lines: np.ndarray, true_objects: np.ndarray) -> float:
    """Jp of eq. 31: the mean squared error over the 2m beam parameters (a, b) and the 4n object
    parameters (vx, x0, vy, y0), both in the same (real-world) frame and clock."""
    m, n = len(true_lines), len(true_objects)
    total = float(((np.asarray(lines) - true_lines) ** 2).sum() + ((np.asarray(objects) - true_objects) ** 2).sum())
    return total / (2 * m + 4 * n)
