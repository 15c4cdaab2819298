"""The sector tracker of paper 000 §III: the arc tracker (paper 001) with directional sensors.

A node's disk is divided into s equal sectors numbered clockwise from the boundary at angle
``offset`` (DESIGN §6, :class:`bintrack.sensing.SectorModel`); its b = ⌈log2(s+1)⌉-bit status
is the sector holding the target, or −1 (absent). A node reports on entering or leaving its disk
and on every change of sector (§II); a disk sensor is a node with one sector.

* **Neighbour-sector match (§III.B.1).** For a node and a neighbour, three kinds of points on
  the node's sensing circle: (1) where it meets the neighbour's circle, (2) where it meets the
  neighbour's sector boundaries (radii of length R_n), (3) the node's own sector boundaries
  (the paper needs those inside the neighbour's disk; all of them are taken, so that the pieces
  also split by the node's own sector). Sorted by angle they cut the circle into arcs; the
  midpoint of each arc says which sector of the node and which sector of the neighbour (or
  none) it lies in (:func:`neighbour_sector_match`; :func:`border_match` does it for one
  sector's arc and all neighbours at once).
* **Neighbour lists (§III.B.2).** For each of its sectors j a node keeps, per neighbour whose
  disk meets sector j's arc, the arc of sector j inside each of the neighbour's sectors and
  inside its disk (:meth:`SectorTracker.sector_neighbours`); the statuses are the tracker's.
* **Location estimate (§III.B.3, eq. 1).** When the node's presence changes (it enters or
  leaves the disk, whichever sector), the target is on the arc of the sector it crosses:
  FA starts as that arc, 2π/s; "&" with the arc inside the sector each present neighbour
  reports, "−" with the arc inside each absent neighbour's disk (a neighbour reporting sector k
  says that all its other sectors are absent, which the "&" covers). A split FA (Fig. 4(d)) is
  resolved by the most recent estimate; the estimate is the midpoint of the chosen arc, with
  ``arc`` its central angle and ``weight`` 2π/arc, as in paper 001. All of this, the velocity
  (§3.2.3 of paper 001) and the handling of simultaneous transitions are the arc tracker's
  (:class:`~bintrack.trackers.arc.arc_tracker.ArcTracker`), which this class extends.

Decisions beyond the paper's text:

* A change of sector inside the disk is a message that updates the neighbours' lists but makes
  no estimate: §III.B estimates "at the moment at which the node discovers the change in the
  target's presence within its sensing range (no matter which sector the target enters or
  exits)", FA is initialised to "the sensing border of a sector", an arc of the circle, and
  Fig. 2 has arcs A1…A4 only at the four disk crossings although X also changes sector twice.
  ``SectorTracker(…, radial=True)`` (not the registered tracker) also estimates at a change
  to an adjacent sector: the target is then on the boundary radius between the two sectors, and
  the same match (the radius cut by the neighbours' circles and boundaries) and eq. 1 give FA
  on that radius (:class:`Border`); s = 2 (either of two radii) and non-adjacent changes give no
  estimate.
* The neighbour lists of a node's sector are built the first time that sector is crossed and
  kept; the paper builds them all at deployment, with the same result.
* Paper 000 assumes ideal sensing: ``range_in`` is ignored (the circle is ``range``), and the
  counter rule of paper 001 §5.6 is not applied; if reports are inconsistent, eq. 1's empty
  results fall back as in :func:`bintrack.trackers.arc.arcs.combine`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bintrack.trackers.arc.arcs import TOL, ArcSet, combine, overlap_matrix, union
from bintrack.geometry import TWO_PI, normalize_angle
from bintrack.deployment_model import Deployment, SectorSensor
from bintrack.sensing import SectorModel
from bintrack.trackers.arc.arc_tracker import ArcTracker

ABSENT = -1


def sector_model(sensor) -> SectorModel:
    """The directional model of a disk or sector sensor; a disk sensor is one sector (s = 1)."""
    if isinstance(sensor, SectorSensor):
        return SectorModel.from_sensor(sensor)
    return SectorModel(sensor.x, sensor.y, sensor.range, sensor.inner_range, sensor.detection_law, 1, 0.0)


def status_bits(sectors: int) -> int:
    """b = ⌈log2(s + 1)⌉: bits of a status that names one of s sectors or absence (paper 000 §II)."""
    return int(sectors).bit_length()


def sector_arc(model: SectorModel, k: int) -> ArcSet:
    """The arc (rad) of the node's sensing circle that borders its sector k: 2π/s long, the
    initial FA of eq. 1 (paper 000 §III.B.3); the full circle for s = 1."""
    return Border.arc(model, k).initial()


# A sector boundary inside the disk (a radius of length R, the border crossed at a change of
# sector) is parametrised like an arc: the point at distance r from the centre has the
# parameter α = π·r/R in [0, π], so the interval algebra of ArcSet (which never wraps on
# [0, π]) serves as FA, and a piece of parameter length ℓ is ℓ·R/π long.
RADIUS_SPAN = math.pi


@dataclass(frozen=True)
class Sensors:
    """The geometry of several sector models as arrays, for vectorised status tests."""

    centre: np.ndarray  # (n, 2), units
    range: np.ndarray  # (n,), units
    sectors: np.ndarray  # (n,)
    offset: np.ndarray  # (n,), rad

    @classmethod
    def of(cls, models: list[SectorModel]) -> Sensors:
        return cls(np.array([m.centre for m in models], dtype=float).reshape(-1, 2),
                   np.array([m.range for m in models], dtype=float), np.array([m.sectors for m in models], dtype=int),
                   np.array([m.offset for m in models], dtype=float))

    def status(self, points: np.ndarray, which: np.ndarray) -> np.ndarray:
        """Status of sensor ``which[p]`` for a target at ``points[p]``: its sector (numbered
        clockwise from the offset, as :meth:`SectorModel.status`) or −1 outside its disk."""
        rel = points - self.centre[which]
        width = TWO_PI / self.sectors[which]
        clockwise = normalize_angle(self.offset[which] - np.arctan2(rel[:, 1], rel[:, 0]))
        sector = np.minimum(np.floor_divide(clockwise, width).astype(int), self.sectors[which] - 1)
        return np.where(np.hypot(rel[:, 0], rel[:, 1]) < self.range[which], sector, ABSENT)

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Every sector boundary (a radius of length R): (index of its sensor, angle in rad)."""
        counts = np.where(self.sectors > 1, self.sectors, 0)
        owner = np.repeat(np.arange(len(counts)), counts)
        k = np.arange(len(owner)) - np.repeat(np.cumsum(counts) - counts, counts)
        return owner, self.offset[owner] - k * TWO_PI / self.sectors[owner]

    def take(self, index: np.ndarray) -> Sensors:
        """The sensors at ``index``."""
        return Sensors(self.centre[index], self.range[index], self.sectors[index], self.offset[index])


@dataclass(frozen=True)
class Border:
    """A part of a node's boundary that the target crosses (paper 000 §III.B.3), parametrised by
    p in [0, span]: the arc of sector j's border (``kind`` "arc", p = angle − start, span 2π/s)
    or, beyond the paper, a sector boundary radius (``kind`` "radius", p = π·r/R, span π), so
    that FA is an :class:`ArcSet` on either (angles, or π·r/R on [0, π], which never wraps)."""

    kind: str
    centre: np.ndarray  # (2,), units
    radius: float  # R, units
    start: float  # rad: the arc's first angle, or the radius' direction
    span: float  # rad

    @classmethod
    def arc(cls, model: SectorModel, j: int) -> Border:
        """The border of sector j: the arc (offset − (j+1)·2π/s, offset − j·2π/s] of the circle."""
        return cls("arc", np.asarray(model.centre, dtype=float), model.range, model.sector_interval(j)[0], model.width)

    @classmethod
    def boundary(cls, model: SectorModel, m: int) -> Border:
        """Boundary radius m, at angle offset − m·2π/s, from the centre to the circle."""
        return cls("radius", np.asarray(model.centre, dtype=float), model.range,
                   float(model.boundary_angles()[m]), RADIUS_SPAN)

    def points(self, p: np.ndarray) -> np.ndarray:
        """The points (n, 2) at parameters ``p``."""
        if self.kind == "arc":
            return self.centre + self.radius * np.stack([np.cos(self.start + p), np.sin(self.start + p)], axis=1)
        return self.centre + np.outer(p * self.radius / self.span, (math.cos(self.start), math.sin(self.start)))

    def initial(self) -> ArcSet:
        """FA's initial value: the whole border (2π/s for an arc, eq. 1)."""
        return self.arcs([(0.0, self.span)])

    def arcs(self, pieces) -> ArcSet:
        """The ArcSet of parameter intervals [a, b] of this border."""
        if self.kind == "radius":
            return ArcSet.of_intervals(pieces)
        start = normalize_angle(self.start)
        return ArcSet.of_intervals([((start + a) % TWO_PI, (start + a) % TWO_PI + (b - a)) for a, b in pieces])

    def circle_cuts(self, centre: np.ndarray, radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(index, p) where the border meets the circles (``centre[i]``, ``radius[i]``)."""
        rel = centre - self.centre
        if self.kind == "arc":  # circle–circle points: direction ± the half-angle (type 1 of §III.B.1)
            d = np.hypot(rel[:, 0], rel[:, 1])
            with np.errstate(divide="ignore", invalid="ignore"):
                cos = (d * d + self.radius**2 - radius**2) / (2.0 * d * self.radius)
            ok = np.abs(cos) <= 1.0
            half = np.arccos(cos[ok])
            angle = np.arctan2(rel[ok, 1], rel[ok, 0])
            index = np.flatnonzero(ok)
            return np.concatenate([index, index]), self._angles(np.concatenate([angle - half, angle + half]))
        # the radius c + r·u, 0 ≤ r ≤ R, on each circle: r² − 2(u·rel)r + |rel|² − radius² = 0
        u = np.array([math.cos(self.start), math.sin(self.start)])
        b = rel @ u
        disc = b * b - (np.einsum("ij,ij->i", rel, rel) - radius**2)
        root = np.sqrt(np.maximum(disc, 0.0))
        r = np.concatenate([b - root, b + root])
        index = np.tile(np.arange(len(radius)), 2)
        ok = np.tile(disc >= 0.0, 2) & (r >= 0.0) & (r <= self.radius)
        return index[ok], r[ok] * self.span / self.radius

    def ray_cuts(self, origin: np.ndarray, angle: np.ndarray, length: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(index, p) where the border meets the radii from ``origin[i]`` at ``angle[i]`` of
        ``length[i]`` (the neighbours' sector boundaries: type 2 of §III.B.1)."""
        v = np.stack([np.cos(angle), np.sin(angle)], axis=1)
        rel = origin - self.centre
        index = np.arange(len(angle))
        if self.kind == "arc":  # |rel + t·v| = R, 0 ≤ t ≤ length
            b = np.einsum("ij,ij->i", v, rel)
            disc = b * b - (np.einsum("ij,ij->i", rel, rel) - self.radius**2)
            root = np.sqrt(np.maximum(disc, 0.0))
            t = np.concatenate([-b - root, -b + root])
            ok = np.tile(disc >= 0.0, 2) & (t >= 0.0) & (t <= np.tile(length, 2))
            points = np.tile(rel, (2, 1))[ok] + t[ok, None] * np.tile(v, (2, 1))[ok]
            return np.tile(index, 2)[ok], self._angles(np.arctan2(points[:, 1], points[:, 0]))
        # r·u = rel + t·v: two segments crossing
        u = np.array([math.cos(self.start), math.sin(self.start)])
        det = v[:, 0] * u[1] - v[:, 1] * u[0]  # cross(v, u)
        with np.errstate(divide="ignore", invalid="ignore"):
            r = (v[:, 0] * rel[:, 1] - v[:, 1] * rel[:, 0]) / det  # cross(v, rel) / cross(v, u)
            t = (u[0] * rel[:, 1] - u[1] * rel[:, 0]) / det  # cross(u, rel) / cross(v, u)
        ok = (det != 0.0) & (r >= 0.0) & (r <= self.radius) & (t >= 0.0) & (t <= length)
        return index[ok], r[ok] * self.span / self.radius

    def _angles(self, theta: np.ndarray) -> np.ndarray:
        """Parameters of the angles ``theta`` (rad) on an arc border, NaN off it."""
        p = normalize_angle(np.asarray(theta) - self.start)
        return np.where(p <= self.span, p, np.nan)


def border_match(border: Border, nbrs: Sensors) -> list[dict[int, ArcSet]]:
    """The neighbour-sector match of paper 000 §III.B.1 on one border of a node, for each of
    ``nbrs``: the points where the border meets the neighbour's circle (1) and its sector
    boundaries (2), with the border's own ends (3: the node's sector boundaries), sorted along
    the border, cut it into pieces; each piece's midpoint says which sector of the neighbour it
    is in, if any. Returns per neighbour {its sector k: the pieces of the border in k}."""
    n = len(nbrs.range)
    circle_index, circle_p = border.circle_cuts(nbrs.centre, nbrs.range)
    owner, angle = nbrs.rays()
    ray_index, ray_p = border.ray_cuts(nbrs.centre[owner], angle, nbrs.range[owner])
    index = np.concatenate([circle_index, owner[ray_index], np.arange(n), np.arange(n)])
    p = np.concatenate([circle_p, ray_p, np.zeros(n), np.full(n, border.span)])
    keep = ~np.isnan(p)
    index, p = index[keep], p[keep]
    order = np.lexsort((p, index))
    index, p = index[order], p[order]
    piece = (index[1:] == index[:-1]) & (p[1:] - p[:-1] > TOL)
    which, lo, hi = index[:-1][piece], p[:-1][piece], p[1:][piece]
    status = nbrs.status(border.points(0.5 * (lo + hi)), which)
    inside = status != ABSENT
    out: list[dict[int, list[tuple[float, float]]]] = [{} for _ in range(n)]
    for i, k, a, b in zip(which[inside].tolist(), status[inside].tolist(), lo[inside].tolist(), hi[inside].tolist()):
        out[i].setdefault(k, []).append((a, b))
    return [{k: border.arcs(pieces) for k, pieces in match.items()} for match in out]


def neighbour_sector_match(node: SectorModel, nbr: SectorModel) -> dict[tuple[int, int], ArcSet]:
    """Paper 000 §III.B.1 for one pair: {(j, k): the arcs (rad) of the node's circle in its
    sector j and in the neighbour's sector k}; the rest of the circle is outside the neighbour."""
    nbrs = Sensors.of([nbr])
    return {(j, k): arcs for j in range(node.sectors) for k, arcs in border_match(Border.arc(node, j), nbrs)[0].items()}


def match_angles(node: SectorModel, nbr: SectorModel) -> np.ndarray:
    """Angles (rad, [0, 2π), sorted) on ``node``'s circle of the three kinds of intersection
    points of paper 000 §III.B.1 with ``nbr``: (1) the circle–circle points, (2) the node's circle
    on the neighbour's sector boundaries, (3) the node's own sector boundaries (all of them)."""
    nbrs = Sensors.of([nbr])
    border = Border("arc", np.asarray(node.centre, dtype=float), node.range, 0.0, TWO_PI)
    owner, angle = nbrs.rays()
    cuts = [border.circle_cuts(nbrs.centre, nbrs.range)[1],
            border.ray_cuts(nbrs.centre[owner], angle, nbrs.range[owner])[1]]
    if node.sectors > 1:
        cuts.append(node.boundary_angles())
    return np.sort(normalize_angle(np.concatenate(cuts)))


def radius_match(node: SectorModel, m: int, nbr: SectorModel) -> dict[int, ArcSet]:
    """:func:`border_match` on the node's boundary radius m with one neighbour: {k: the pieces
    of the radius in the neighbour's sector k, as parameters π·r/R}."""
    return border_match(Border.boundary(node, m), Sensors.of([nbr]))[0]


def crossed_boundary(model: SectorModel, before: int, after: int) -> int | None:
    """The index m of the boundary radius (at angle offset − m·2π/s, rad) crossed when the status
    changes from sector ``before`` to the adjacent sector ``after`` (numbered clockwise); None if
    they are not adjacent, or for s = 2, where either of two radii may have been crossed."""
    s = model.sectors
    if s < 3 or before < 0 or after < 0:
        return None
    if after == (before + 1) % s:
        return (before + 1) % s
    if after == (before - 1) % s:
        return before
    return None


@dataclass(frozen=True)
class SectorNeighbour:
    """One neighbour in the list of one of the node's sectors j (paper 000 §III.B.2)."""

    node: int  # the neighbour's index
    sectors: dict[int, ArcSet]  # neighbour sector k → the arc of j's border inside it (rad)
    disk: ArcSet  # the arc of j's border inside the neighbour's disk (rad)


class SectorTracker(ArcTracker):
    """Paper 000 §III: distributed tracking with directional (sector) binary sensors.

    ``radial=True`` also estimates at a change between adjacent sectors (beyond the paper): the
    target is then on the boundary radius between them, and FA is the part of that radius
    consistent with the neighbours' statuses, by the same match and eq. 1; the estimate is its
    midpoint, with ``arc`` = its length / R."""

    name = "sector"

    def __init__(self, deployment: Deployment, radial: bool = False):
        super().__init__(deployment)
        self.ranges_in = self.net.ranges.copy()  # ideal sensing (paper 000 §I)
        self.radial = radial
        sensors = deployment.by_id()
        self.models = [sector_model(sensors[sid]) for sid in self.net.ids]
        self.directional = [isinstance(sensors[sid], SectorSensor) for sid in self.net.ids]
        self.sensors = Sensors.of(self.models)
        self.status = np.full(len(self.net), ABSENT, dtype=int)
        self.crossed = np.full(len(self.net), ABSENT, dtype=int)
        self.boundary = np.full(len(self.net), ABSENT, dtype=int)  # radius crossed at the last transition
        self._lists: dict[tuple[int, str, int], list[SectorNeighbour]] = {}

    def _apply(self, i: int, value: int) -> bool:
        """Record node ``i``'s status (sector or −1; a disk's 1/0 as sector 0/−1) and, at a
        crossing of its circle, the sector whose border it crosses (with ``radial``, at a change
        to an adjacent sector, the boundary radius crossed). Whether to estimate."""
        crossed = super()._apply(i, value)
        sector = (value if self.directional[i] else 0) if self.present[i] else ABSENT
        before, self.status[i] = self.status[i], sector
        self.boundary[i] = ABSENT
        if crossed:
            self.crossed[i] = sector if sector >= 0 else before
        elif self.radial and sector != before and (m := crossed_boundary(self.models[i], before, sector)) is not None:
            self.boundary[i] = m
            return True
        return crossed

    def _crossing_batch(self, nodes: list[int]) -> bool:
        """The arc tracker's test for simultaneous crossings, on the nodes that crossed their
        circle (a crossing of a boundary radius is never part of a field's initial snapshot)."""
        return super()._crossing_batch([i for i in nodes if self.boundary[i] == ABSENT])

    def sector_neighbours(self, i: int, j: int) -> list[SectorNeighbour]:
        """Node ``i``'s neighbour list for its sector ``j`` (paper 000 §III.B.2): the neighbours
        whose disks meet j's border arc, with the neighbour-sector match of each. Built on first
        use and kept (the paper builds every list at deployment; the result is the same)."""
        key = (i, "sector", j)
        if key not in self._lists:
            border = sector_arc(self.models[i], j).arcs[0]
            nbrs, start, length = self.neighbour_arcs(i)[:3]
            meets = overlap_matrix(np.append(start, border.start), np.append(length, border.length))[-1, :-1]
            self._lists[key] = self._entries(Border.arc(self.models[i], j), nbrs[meets & (length > TOL)])
        return self._lists[key]

    def radius_neighbours(self, i: int, m: int) -> list[SectorNeighbour]:
        """Node ``i``'s neighbour list for its boundary radius m (``radial``): the neighbours
        whose disks meet that radius, with the match of each (:func:`border_match`)."""
        key = (i, "radius", m)
        if key not in self._lists:
            border = Border.boundary(self.models[i], m)
            nbrs = self.net.neighbours[i]
            u = np.array([math.cos(border.start), math.sin(border.start)])
            rel = self.net.positions[nbrs] - self.net.positions[i]
            along = np.clip(rel @ u, 0.0, border.radius)
            near = np.hypot(*(rel - along[:, None] * u).T) < self.net.ranges[nbrs]
            self._lists[key] = self._entries(border, nbrs[near])
        return self._lists[key]

    def _entries(self, border: Border, nbrs: np.ndarray) -> list[SectorNeighbour]:
        """List entries for ``border`` of the neighbours ``nbrs`` that meet it."""
        matches = border_match(border, self.sensors.take(nbrs))
        return [SectorNeighbour(int(n), inside, union(inside.values())) for n, inside in zip(nbrs, matches) if inside]

    def _combine(self, base: ArcSet, entries: list[SectorNeighbour]) -> tuple[ArcSet, np.ndarray]:
        """Eq. 1 over a neighbour list: "&" with the piece in each present neighbour's reported
        sector, "−" with the pieces in each absent neighbour's disk; and the present neighbours."""
        ins, outs, present = [], [], []
        for entry in entries:
            k = int(self.status[entry.node])
            if k == ABSENT:
                outs.append(entry.disk)
            else:
                ins.append(entry.sectors.get(k, ArcSet()))
                present.append(entry.node)
        return combine(base, ins, outs), np.array(present, dtype=int)

    def final_arcs(self, i: int) -> tuple[ArcSet, np.ndarray]:
        """FA of eq. 1 (paper 000 §III.B.3) at node ``i``'s last crossing of its circle, from the
        neighbours' current statuses, and the indices of the neighbours reporting presence."""
        j = int(self.crossed[i])
        return self._combine(sector_arc(self.models[i], j), self.sector_neighbours(i, j))

    def radius_arcs(self, i: int, m: int) -> ArcSet:
        """FA on node ``i``'s boundary radius m (parameter α = π·r/R, see :data:`RADIUS_SPAN`)."""
        return self._combine(Border.boundary(self.models[i], m).initial(), self.radius_neighbours(i, m))[0]

    def estimate(self, i: int) -> tuple[float, float, float, float]:
        """(x, y, arc, weight): on the circle as the arc tracker (``arc`` its central angle, rad),
        or at a radial crossing the midpoint of the chosen piece of the radius, ``arc`` = its
        length / R and ``weight`` = 2π/arc; a split FA resolved by the most recent estimate."""
        m = int(self.boundary[i])
        if m == ABSENT:
            return super().estimate(i)
        border = Border.boundary(self.models[i], m)
        fa = self.radius_arcs(i, m)
        reference = self._reference(i)
        if reference is None:
            piece = fa.longest()
        else:
            along = (reference - border.centre) @ (math.cos(border.start), math.sin(border.start))
            piece = fa.nearest(float(np.clip(along, 0.0, border.radius)) * border.span / border.radius)
        (x, y), = border.points(np.array([piece.start + 0.5 * piece.length]))
        arc = piece.length / border.span
        return float(x), float(y), arc, TWO_PI / arc
