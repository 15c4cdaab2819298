"""PNG plots of a deployment, its detections, tracks and truth (matplotlib, Agg, no display).

Used by ``bintrack eval --plot`` and ``bintrack demo``. Positions are drawn in the dataset's
units; the optional second panel shows error over event time (s).
"""

from __future__ import annotations

from collections.abc import Collection, Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import shapely
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection, PatchCollection
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Polygon, Rectangle

from bintrack.formats import Dataset, Event, ObjectRow, TrackRow
from bintrack.deployment_model import Deployment, DiskSensor, LineSensor, MotionSensor, SectorSensor
from bintrack.sensing import reports_presence

if TYPE_CHECKING:
    from bintrack.evaluation.eval_report import Evaluation, Series
    from bintrack.evaluation.metrics import TruthPath

# Above this many range sensors, their disks would hide everything else.
MAX_RANGE_CIRCLES = 150

# Nor are they drawn when each point of the field lies, on average, in more than this many of
# them: the circles would be a grey mesh.
MAX_COVER = 3.0

DENSE_TRACK_ROWS = 400
# Sensors are neutral greys, so that every colour on the plot is a track's (and its truth's).
SENSOR_COLOUR = "0.7"
DETECTED_COLOUR = "0.3"
TRUTH_COLOUR = "black"  # a truth path no track follows
# tab10 without its grey (index 7): the tracks' colours, none of them a sensor's
TRACK_COLOURS = [colormaps["tab10"](i) for i in range(10) if i != 7]


def detected_sensors(deployment: Deployment, events: Iterable[Event],
                     truth: Mapping[str, TruthPath] | None = None) -> set[str]:
    """Ids of the sensors that reported present at least once in ``events``. With ``truth``,
    a range sensor (disk, sector) counts only for a report made while a true target was within
    its range: false alarms do not make a sensor "detected"."""
    sensors = deployment.by_id()
    found: set[str] = set()
    paths = list((truth or {}).values())
    for e in events:
        sensor = sensors.get(e.sensor)
        if sensor is None or e.sensor in found or not reports_presence(sensor, e.value):
            continue
        if paths and isinstance(sensor, (DiskSensor, SectorSensor)):
            near = [np.hypot(*(path.position(e.t) - (sensor.x, sensor.y))) for path in paths]
            if not any(d <= sensor.range * 1.05 for d in near if np.isfinite(d)):
                continue  # a false alarm: no target in range
        found.add(e.sensor)
    return found


def truth_of_tracks(tracks: Sequence[TrackRow], truth: Mapping[str, TruthPath]) -> dict[int, str]:
    """Track id -> the truth target it follows: a one-to-one assignment (Hungarian, scipy)
    minimising the mean distance (units) over the times both exist; pairs that never coexist
    are not matched."""
    from scipy.optimize import linear_sum_assignment

    ids = sorted({r.track for r in tracks})
    names = list(truth)
    if not ids or not names:
        return {}
    cost = np.full((len(ids), len(names)), 1e12)
    for i, track in enumerate(ids):
        rows = [r for r in tracks if r.track == track]
        t = np.array([r.t for r in rows])
        xy = np.array([(r.x, r.y) for r in rows])
        for j, name in enumerate(names):
            d = np.hypot(*(truth[name].position(t) - xy).T)
            d = d[np.isfinite(d)]
            if d.size:
                cost[i, j] = d.mean()
    rows_, cols = linear_sum_assignment(cost)
    return {ids[i]: names[j] for i, j in zip(rows_, cols) if cost[i, j] < 1e12}


def range_cover(deployment: Deployment) -> float:
    """How many range sensors (disk, sector) cover a point of the field on average: the sum of
    their disks' areas over the region's area."""
    region = deployment.region
    area = sum(np.pi * s.range ** 2 for s in deployment.sensors if isinstance(s, (DiskSensor, SectorSensor)))
    return float(area / max(region.width * region.height, 1e-12))


def beam_segment(a: float, b: float, region) -> np.ndarray | None:
    """The part of the beam a·x + b·y = 1 inside ``region`` as two points (units), or None."""
    norm2 = a * a + b * b
    if norm2 == 0:
        return None
    foot = np.array([a, b]) / norm2  # the line's point closest to the origin
    direction = np.array([-b, a]) / np.sqrt(norm2)
    corners = np.array([(region.xmin, region.ymin), (region.xmax, region.ymax),
                        (region.xmin, region.ymax), (region.xmax, region.ymin)])
    reach = np.hypot(*(corners - foot).T).max() + 1.0
    beam = shapely.LineString([foot - reach * direction, foot + reach * direction])
    inside = beam.intersection(shapely.box(region.xmin, region.ymin, region.xmax, region.ymax))
    if inside.is_empty or inside.geom_type != "LineString":
        return None
    return np.asarray(inside.coords)


def _draw_sensors(ax, deployment: Deployment, detected: Collection[str]) -> None:
    point_sensors = [s for s in deployment.sensors if getattr(s, "x", None) is not None]
    range_sensors = [s for s in deployment.sensors if isinstance(s, (DiskSensor, SectorSensor))]
    if 0 < len(range_sensors) <= MAX_RANGE_CIRCLES and range_cover(deployment) <= MAX_COVER:
        for hit, alpha in ((False, 0.15), (True, 0.4)):
            chosen = [s for s in range_sensors if (s.id in detected) == hit]
            if chosen:
                ax.add_collection(PatchCollection(
                    [Circle((s.x, s.y), s.range) for s in chosen], facecolor="none",
                    edgecolor=DETECTED_COLOUR if hit else SENSOR_COLOUR, linewidth=0.6, alpha=alpha))
    beams: dict[bool, list[np.ndarray]] = {False: [], True: []}
    for s in deployment.sensors:
        if isinstance(s, LineSensor) and s.a is not None:
            segment = beam_segment(s.a, s.b, deployment.region)
            if segment is not None:
                beams[s.id in detected].append(segment)
    for hit, segments in beams.items():
        if segments:
            ax.add_collection(LineCollection(segments, colors=DETECTED_COLOUR if hit else SENSOR_COLOUR,
                                             linewidths=0.8, linestyles=":",
                                             label="beams, crossed" if hit else "beams"))
    for hit in (False, True):
        for motion in (False, True):
            group = [s for s in point_sensors if (s.id in detected) == hit and isinstance(s, MotionSensor) == motion]
            if group:
                ax.scatter([s.x for s in group], [s.y for s in group], s=14 if hit else 6,
                           marker="^" if motion else "o", color=DETECTED_COLOUR if hit else SENSOR_COLOUR,
                           zorder=2, linewidths=0,
                           label=("motion sensors" if motion else "sensors") + (", saw a target" if hit else ""))


def _draw_floor_plan(ax, deployment: Deployment) -> None:
    """The floor plan's obstacles (grey) and doors (brown squares), where the deployment has one."""
    plan = deployment.floor_plan
    if plan is None:
        return
    if plan.obstacles:
        ax.add_collection(PatchCollection([Polygon(area.vertices(), closed=True) for area in plan.obstacles],
                                          facecolor="0.88", edgecolor="0.7", linewidth=0.6, zorder=0,
                                          label="obstacles"))
    if plan.doors:
        xs, ys = zip(*plan.doors)
        ax.scatter(xs, ys, marker="s", s=40, color="#8d6e63", zorder=1, label="doors")


def _colours(n: int) -> list:
    if n <= len(TRACK_COLOURS):
        return TRACK_COLOURS[:n]
    cmap = colormaps["tab20"]
    return [cmap(i % cmap.N) for i in range(n)]


def plot_scene(path: Path | str, deployment: Deployment, *, tracks: Sequence[TrackRow] = (),
               objects: Sequence[ObjectRow] = (), truth: Mapping[str, TruthPath] | None = None,
               detected: Collection[str] = (), title: str = "", series: Sequence[Series] = ()) -> Path:
    """Write a PNG to ``path``: sensors (dots; disk ranges as faint circles when there are at
    most :data:`MAX_RANGE_CIRCLES` overlapping at most :data:`MAX_COVER` deep; known laser beams as dotted lines), sensors in ``detected``
    darker (both grey), estimated tracks (one colour per track id), line-sensor objects (entry ▲
    to exit ▼), truth paths (dashed, each in the colour of the track that follows it, black if
    none does) and ``title``. With ``series``, a second panel shows each
    error over time. Returns the path written."""
    path = Path(path)
    region = deployment.region
    # the map keeps the region's aspect; the legend goes to its right
    map_height = float(np.clip(7.0 * region.height / region.width, 2.5, 8.0)) + 1.0
    heights = [map_height, 2.5] if series else [map_height]
    fig = Figure(figsize=(10, sum(heights)), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(heights), 1, height_ratios=heights, squeeze=False)[:, 0]
    ax = axes[0]
    margin = 0.03 * max(region.width, region.height)
    ax.set_xlim(region.xmin - margin, region.xmax + margin)
    ax.set_ylim(region.ymin - margin, region.ymax + margin)
    ax.set_aspect("equal")
    ax.set_xlabel(f"x ({deployment.units})")
    ax.set_ylabel(f"y ({deployment.units})")
    ax.add_patch(Rectangle((region.xmin, region.ymin), region.width, region.height, fill=False,
                           edgecolor="0.3", linewidth=1.0))
    _draw_floor_plan(ax, deployment)
    _draw_sensors(ax, deployment, set(detected))

    track_ids = sorted({r.track for r in tracks})
    colour_of = dict(zip(track_ids, _colours(len(track_ids))))
    followed = {name: track for track, name in truth_of_tracks(tracks, truth or {}).items()}
    for name, path_ in (truth or {}).items():
        track = followed.get(name)
        colour = colour_of[track] if track is not None else TRUTH_COLOUR
        label = f"truth {name}" + (f" (track {track})" if track is not None else "")
        ax.plot(path_.xy[:, 0], path_.xy[:, 1], linestyle="--", color=colour, linewidth=2.0, alpha=0.8,
                label=label if len(truth) <= 10 else None, zorder=3)

    for track in track_ids:
        rows = sorted((r for r in tracks if r.track == track), key=lambda r: r.t)
        label = f"track {track}" if len(track_ids) <= 10 else ("tracks" if track == track_ids[0] else None)
        # a dense track is drawn as points: lines between its jumps would hide everything else
        dense = len(rows) > DENSE_TRACK_ROWS
        ax.plot([r.x for r in rows], [r.y for r in rows], color=colour_of[track], linewidth=0 if dense else 1.0,
                marker=".", markersize=2 if dense else 3, alpha=0.5 if dense else 1.0, label=label, zorder=4)

    for obj, colour in zip(objects, _colours(len(objects))):
        ax.plot([obj.entry_x, obj.exit_x], [obj.entry_y, obj.exit_y], color=colour, linewidth=1.0, zorder=4)
        ax.plot([obj.entry_x], [obj.entry_y], marker="^", color=colour, zorder=5)
        ax.plot([obj.exit_x], [obj.exit_y], marker="v", color=colour, zorder=5)
    if objects:
        ax.plot([], [], marker="^", color="0.3", linestyle="-", label="objects: entry ▲, exit ▼")

    if title:
        ax.set_title(title)
    if ax.get_legend_handles_labels()[1]:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")

    if series:
        err_ax = axes[1]
        for s in series:
            order = np.argsort(s.t, kind="stable")
            err_ax.plot(np.asarray(s.t)[order], np.asarray(s.values)[order], marker="." if s.joined else "o",
                        markersize=3 if s.joined else 5, linewidth=0.8 if s.joined else 0, label=s.label)
        err_ax.set_xlabel("t (s)")
        err_ax.set_ylabel("error")
        err_ax.set_ylim(bottom=0)
        err_ax.grid(True, alpha=0.3)
        err_ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")

    tmp = path.with_name(path.name + ".tmp")
    fig.savefig(tmp, format="png", dpi=100)
    tmp.replace(path)
    return path


def plot_evaluation(path: Path | str, dataset: Dataset, evaluation: Evaluation, *, error_panel: bool = True) -> Path:
    """Plot ``evaluation`` of a result on ``dataset`` (reads its events for the detections):
    title with the headline figure, second panel of error over time unless ``error_panel`` is
    False. Returns the PNG path written."""
    return plot_scene(
        path,
        dataset.deployment,
        tracks=evaluation.tracks,
        objects=evaluation.objects,
        truth=evaluation.truth,
        detected=detected_sensors(dataset.deployment, dataset.events(), evaluation.truth),
        title=f"{dataset.deployment.name}: {evaluation.headline()}",
        series=evaluation.series if error_panel else (),
    )
