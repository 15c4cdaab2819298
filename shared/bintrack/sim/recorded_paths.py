"""A recording's people walked again through its (fitted) sensors: the truth of a dataset as
trajectories, simulated with the deployment's sensor models (for real PIR sensors, the hold time
and motion-dependent pd of :func:`bintrack.sim.sampling.pir_samples`), to compare real and
simulated sensor statistics."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable

from bintrack.formats import TruthRow
from bintrack.deployment_model import Deployment
from bintrack.sim.engine import Scenario
from bintrack.sim.trajectories import LinearSegment, Trajectory


def truth_trajectories(rows: Iterable[TruthRow]) -> tuple[Trajectory, ...]:
    """Each target's truth rows (time order) as a path of straight segments between them; a
    target with one row stands still for an instant."""
    by_target: dict[str, list[TruthRow]] = defaultdict(list)
    for row in rows:
        by_target[row.target].append(row)
    out = []
    for target, points in by_target.items():
        points.sort(key=lambda r: r.t)
        segments = []
        for a, b in zip(points, points[1:]):
            dt = b.t - a.t
            if dt <= 0:
                continue
            segments.append(LinearSegment(a.t, b.t, a.x, a.y, (b.x - a.x) / dt, (b.y - a.y) / dt))
        if not segments:
            segments = [LinearSegment(points[0].t, points[0].t, points[0].x, points[0].y, 0.0, 0.0)]
        out.append(Trajectory(target, tuple(segments)))
    return tuple(out)


def recording_scenario(deployment: Deployment, truth: Iterable[TruthRow], window: tuple[float, float]) -> Scenario:
    """The scenario of ``deployment``'s sensors sampling within ``window`` (s) while the targets
    of ``truth`` walk their recorded paths."""
    return Scenario(name=deployment.name, deployment=deployment, sensors=tuple(deployment.sensors),
                    trajectories=truth_trajectories(truth), window=window, truth_step=None)
