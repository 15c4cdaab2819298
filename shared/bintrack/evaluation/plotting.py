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
from matplotlib.patches import Circle, Rectangle

from bintrack.formats import Dataset, Event, ObjectRow, TrackRow
from bintrack.messages import Deployment, DiskSensor, LineSensor, MotionSensor, SectorSensor
from bintrack.sensing import reports_presence

if TYPE_CHECKING:
    from bintrack.evaluation.eval_report import Evaluation, Series
    from bintrack.evaluation.metrics import TruthPath

# Above this many range sensors, their disks would hide everything else.
MAX_RANGE_CIRCLES = 150

DENSE_TRACK_ROWS = 400
SENSOR_COLOUR = "0.55"
DETECTED_COLOUR = "tab:orange"
TRUTH_COLOUR = "black"


def detected_sensors(deployment: Deployment, events: Iterable[Event]) -> set[str]:
    """Ids of the sensors that reported present at least once in ``events``."""
    sensors = deployment.by_id()
    return {e.sensor for e in events if e.sensor in sensors and reports_presence(sensors[e.sensor], e.value)}


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
    if 0 < len(range_sensors) <= MAX_RANGE_CIRCLES:
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
                ax.scatter([s.x for s in group], [s.y for s in group], s=18 if hit else 6,
                           marker="^" if motion else "o", color=DETECTED_COLOUR if hit else SENSOR_COLOUR,
                           zorder=2, linewidths=0,
                           label=("motion sensors" if motion else "sensors") + (", detected" if hit else ""))


def _colours(n: int) -> list:
    cmap = colormaps["tab10" if n <= 10 else "tab20"]
    return [cmap(i % cmap.N) for i in range(n)]


def plot_scene(path: Path | str, deployment: Deployment, *, tracks: Sequence[TrackRow] = (),
               objects: Sequence[ObjectRow] = (), truth: Mapping[str, TruthPath] | None = None,
               detected: Collection[str] = (), title: str = "", series: Sequence[Series] = ()) -> Path:
    """Write a PNG to ``path``: sensors (dots; disk ranges as faint circles when there are at
    most :data:`MAX_RANGE_CIRCLES`; known laser beams as dotted lines), sensors in ``detected``
    highlighted, estimated tracks (one colour per track id), line-sensor objects (entry ▲ to
    exit ▼), truth paths (dashed) and ``title``. With ``series``, a second panel shows each
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
    _draw_sensors(ax, deployment, set(detected))

    for i, path_ in enumerate((truth or {}).values()):
        ax.plot(path_.xy[:, 0], path_.xy[:, 1], linestyle="--", color=TRUTH_COLOUR, linewidth=1.6,
                label="truth" if i == 0 else None, zorder=6)

    track_ids = sorted({r.track for r in tracks})
    for track, colour in zip(track_ids, _colours(len(track_ids))):
        rows = sorted((r for r in tracks if r.track == track), key=lambda r: r.t)
        label = f"track {track}" if len(track_ids) <= 10 else ("tracks" if track == track_ids[0] else None)
        # a dense track is drawn as points: lines between its jumps would hide everything else
        dense = len(rows) > DENSE_TRACK_ROWS
        ax.plot([r.x for r in rows], [r.y for r in rows], color=colour, linewidth=0 if dense else 1.0,
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
        detected=detected_sensors(dataset.deployment, dataset.events()),
        title=f"{dataset.deployment.name}: {evaluation.headline()}",
        series=evaluation.series if error_panel else (),
    )
