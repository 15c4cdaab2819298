"""The arc tracker of paper 001: §3.2 (ideal binary sensing), §3.3 (imperfect), §5.6 (faults).

At a node's own transition (the target enters or leaves its disk) the target is on the node's
sensing circle. Each neighbour (a node whose disk meets the node's disk, §2) covers one arc of
that circle, the central angle between the two circle–circle intersection points (§3.2.1; the
full circle if its disk contains the circle). The arc the target crosses is eq. 1,

    FA = 2π & (arcs of neighbours reporting 1) − (arcs of neighbours reporting 0),

and the estimate is FA's midpoint on the circle (§3.2.2), with ``arc`` its central angle (rad)
and ``weight`` = |circle|/|arc| = 2π/arc (eq. 2). Each estimate reaches the node's neighbours,
which time it on their own clocks (``clock_offset``, ``clock_skew``); a node's velocity, sent
with its estimates, comes from the accurate estimates it has heard (§3.2.3, :mod:`bintrack.trackers.arc.velocity`).

Decisions beyond the paper's text:

* **Faulty "1" reports (§5.6).** Before "&", each "1" neighbour counts the other "1"
  neighbours whose arcs its arc does not meet; the neighbours with the highest count > 0 are
  deleted together and the counts recomputed, until every count is 0. Pairwise meeting arcs
  can still have no common point on a circle (three arcs longer than 2π/3); then FA is the
  part of the circle inside the most surviving "1" arcs.
* **Faulty "0" reports (§5.6, Fig. 23).** If "−" empties FA, FA is the part of the "1" result
  inside the fewest "0" arcs: a "0" neighbour whose arc covers the whole "1" result (the
  contradiction of Fig. 23(a)) is thereby ignored.
* **Split FA (Fig. 3(d)).** The piece nearest the most recent estimate made by the node or a
  neighbour (angularly, which on a circle is also nearest in the plane); with no estimate yet,
  the longest piece.
* **FA the full circle** (no neighbour information): the point of the circle nearest the most
  recent estimate, else the node's own position; ``arc`` = 2π, ``weight`` = 1.
* **Simultaneous transitions that are not crossings.** Transitions sharing an event time
  are estimated after all their statuses are applied. If they are crossings, the target is on
  every transitioning node's circle at once; when those circles have no common point (three or
  more circles in general position never do), the batch is a snapshot of the field's state
  (the target appearing inside several disks, as a simulation does at a trajectory's start),
  not boundary crossings: the statuses are applied and no estimate is made. (Sensors sampled
  in lockstep, ``period`` set, can report true crossings together; those batches are dropped too.)
* A "1" neighbour whose disk cannot meet the node's circle (ring) is a faulty report and dropped.
* A status change that keeps presence (a sector sensor moving between sectors) is no crossing.

Imperfect model (§3.3, sensors with ``range_in`` = R_in < ``range`` = R_out). At node i's
transition the target is in i's ring R_in,i ≤ ρ ≤ R_out,i; a "1" means inside the neighbour's
R_out disk, a "0" outside its R_in disk (the worst case). The "1" angle of a neighbour is the set of
directions in which i's ring meets its R_out disk (Fig. 5: the wider of the R_in and R_out
intersection angles, or the tangent directions when the tangent points lie in the ring); the
"0" angle is the set of directions in which i's ring lies wholly inside its R_in disk (Fig. 6: the
narrower of the two intersection angles; none when the ring's inner edge is outside that disk,
Fig. 6(c)). Both are arcs centred on the neighbour's direction, and for R_in = R_out they reduce to
the ideal model's arc. FA is combined as above. The ring section's inner radius is the distance
of the furthest pairwise intersection point of surviving "1" neighbours' R_out circles that lies
in the chosen arc and in the ring (Fig. 7), else R_in; the estimate is the section's centre in
polar terms (mid-angle, mid-radius) and the weight is |ring|/|ring section| (eq. 4). For the
simultaneous-transition test above, the common point is sought in all transitioning rings.
"""

from __future__ import annotations

import math

import numpy as np

from bintrack.trackers.arc.arcs import TOL, Arc, ArcSet, combine, overlap_matrix
from bintrack.trackers.arc.velocity import LocalClock, VelocityEstimator
from bintrack.geometry import TWO_PI, normalize_angle
from bintrack.bus_payloads import LocalEstimate, Transition
from bintrack.deployment_model import Deployment
from bintrack.trackers.base import DiskNetwork, SimultaneousTransitions

# A point is on a circle (in a ring) if within this fraction of the radius (batch common point).
_ON_CIRCLE_REL = 1e-6


def counter_deletion(meets: np.ndarray) -> np.ndarray:
    """Paper 001 §5.6: which "1" reports survive, given whether their arcs meet pairwise.

    ``meets`` is a symmetric boolean n×n matrix. Each report's counter is the number of others
    its arc does not meet; the reports with the highest counter > 0 are deleted together and
    counters recomputed among the survivors, until all are 0. Returns the survivor mask.
    """
    conflict = ~np.asarray(meets, dtype=bool)
    np.fill_diagonal(conflict, False)
    alive = np.ones(len(conflict), dtype=bool)
    while alive.any():
        counts = (conflict & alive[:, None] & alive[None, :]).sum(axis=1)
        top = counts.max()
        if top == 0:
            break
        alive &= counts != top
    return alive


def _crossing_angle(d: np.ndarray, rho: float, r: np.ndarray) -> np.ndarray:
    """Angle (rad) between the line of centres and the intersection points of a circle of radius
    ``rho`` (at the node) with circles of radii ``r`` at distances ``d``; NaN where they do not cross."""
    with np.errstate(divide="ignore", invalid="ignore"):
        cos = (d * d + rho * rho - r * r) / (2.0 * d * rho)
        return np.where(np.abs(cos) <= 1.0, np.arccos(np.clip(cos, -1.0, 1.0)), np.nan)


def presence_half_angle(d: np.ndarray, r_in: float, r_out: float, r_nbr: np.ndarray) -> np.ndarray:
    """Half-angle (rad) of the directions, about each neighbour's direction, in which the node's
    ring r_in ≤ ρ ≤ r_out meets the neighbour's disk of radius ``r_nbr`` at distance ``d``
    (a "1" report, §3.2.1 / Fig. 5); π for all directions, NaN for none."""
    d, r_nbr = np.asarray(d, dtype=float), np.asarray(r_nbr, dtype=float)
    tangent = np.sqrt(np.maximum(d * d - r_nbr * r_nbr, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        at_tangent = np.where((d > r_nbr) & (tangent >= r_in) & (tangent <= r_out), np.arcsin(r_nbr / d), np.nan)
    half = np.fmax(np.fmax(_crossing_angle(d, r_in, r_nbr), _crossing_angle(d, r_out, r_nbr)), at_tangent)
    return np.where(r_nbr - d >= r_in, math.pi, half)


def absence_half_angle(d: np.ndarray, r_in: float, r_out: float, r_nbr_in: np.ndarray) -> np.ndarray:
    """Half-angle (rad) of the directions, about each neighbour's direction, in which the node's
    whole ring r_in ≤ ρ ≤ r_out lies inside the neighbour's disk of radius ``r_nbr_in`` at distance
    ``d`` (excluded by a "0" report, §3.2.1 / Fig. 6); π for all directions, NaN for none."""
    d, r_nbr_in = np.asarray(d, dtype=float), np.asarray(r_nbr_in, dtype=float)
    reaches = (d - r_nbr_in <= r_in) & (d + r_nbr_in >= r_out)
    half = np.fmin(_crossing_angle(d, r_in, r_nbr_in), _crossing_angle(d, r_out, r_nbr_in))
    return np.where(d + r_out <= r_nbr_in, math.pi, np.where(reaches, half, np.nan))


def circle_pair_points(c1: np.ndarray, r1: np.ndarray, c2: np.ndarray, r2: np.ndarray) -> np.ndarray:
    """Intersection points (k, 2) of circles (c1[n], r1[n]) and (c2[n], r2[n]), pair by pair."""
    delta = c2 - c1
    d = np.hypot(delta[:, 0], delta[:, 1])
    ok = (d > 0) & (d <= r1 + r2) & (d >= np.abs(r1 - r2))
    c1, r1, r2, delta, d = c1[ok], r1[ok], r2[ok], delta[ok], d[ok]
    along = (d * d + r1 * r1 - r2 * r2) / (2.0 * d)
    half = np.sqrt(np.maximum(r1 * r1 - along * along, 0.0))
    unit = delta / d[:, None]
    mid = c1 + along[:, None] * unit
    normal = np.c_[unit[:, 1], -unit[:, 0]] * half[:, None]
    return np.concatenate([mid + normal, mid - normal])


class ArcTracker:
    """Paper 001 §3.2–3.3 (ideal and imperfect binary sensing), with §5.6 fault tolerance."""

    name = "arc"

    def __init__(self, deployment: Deployment):
        self.net = DiskNetwork(deployment, self.name)
        inner = {s.id: s.inner_range for s in deployment.sensors if s.id in self.net.index}
        self.ranges_in = np.array([inner[sid] for sid in self.net.ids], dtype=float)
        self.present = np.zeros(len(self.net), dtype=bool)
        self.last_t = np.full(len(self.net), -np.inf)
        self.last_xy = np.zeros((len(self.net), 2))
        self.pending = SimultaneousTransitions()
        self._table: dict[int, tuple[np.ndarray, ...]] = {}
        sensors = deployment.by_id()
        self.clocks = [LocalClock(sensors[sid].clock_offset, sensors[sid].clock_skew) for sid in self.net.ids]
        self.velocity = [VelocityEstimator() for _ in self.net.ids]

    # ------------------------------------------------------------------ push interface

    def update(self, transition: Transition) -> list[LocalEstimate]:
        out = self._estimates(self.pending.due(transition.t))
        i = self.net.index.get(transition.sensor)
        if i is not None and self._apply(i, transition.value):
            self.pending.hold(transition)
        return out

    def _apply(self, i: int, value: int) -> bool:
        """Record node ``i``'s new status ``value``; whether it is a crossing of i's circle
        (presence changed), the transitions that are estimated."""
        now = self.net.is_present(i, value)
        crossed = now != self.present[i]
        self.present[i] = now
        return bool(crossed)

    def flush(self, t: float) -> list[LocalEstimate]:
        return self._estimates(self.pending.flush(t))

    # ------------------------------------------------------------------ geometry

    def neighbour_arcs(self, i: int) -> tuple[np.ndarray, ...]:
        """Node ``i``'s neighbour table (§3.2.1, §3.3.1): neighbour indices, the start and
        length (rad) of the arc each one's "1" confines the target to, and the start and length of
        the arc each one's "0" excludes (length 0: the report says nothing about i's ring)."""
        if i not in self._table:
            nbrs = self.net.neighbours[i]
            delta = self.net.positions[nbrs] - self.net.positions[i]
            d = np.hypot(delta[:, 0], delta[:, 1])
            r_in, r_out = self.ranges_in[i], self.net.ranges[i]
            centre = np.arctan2(delta[:, 1], delta[:, 0])
            row = [nbrs]
            for half in (presence_half_angle(d, r_in, r_out, self.net.ranges[nbrs]),
                         absence_half_angle(d, r_in, r_out, self.ranges_in[nbrs])):
                half = np.nan_to_num(half, nan=0.0)
                full = half >= math.pi
                row += [np.where(full, 0.0, normalize_angle(centre - half)), np.where(full, TWO_PI, 2.0 * half)]
            self._table[i] = tuple(row)
        return self._table[i]

    def final_arcs(self, i: int) -> tuple[ArcSet, np.ndarray]:
        """FA of eq. 1 for node ``i`` from its neighbours' current statuses, faults handled (§5.6),
        and the indices of the "1" neighbours that survived the counter rule."""
        nbrs, one_start, one_len, zero_start, zero_len = self.neighbour_arcs(i)
        ones = self.present[nbrs] & (one_len > TOL)  # a "1" that cannot meet i's ring is a fault
        survive = counter_deletion(overlap_matrix(one_start[ones], one_len[ones]))
        in_arcs = [ArcSet([Arc(s, l)]) for s, l in zip(one_start[ones][survive], one_len[ones][survive])]
        zeros = ~self.present[nbrs] & (zero_len > TOL)
        out_arcs = [ArcSet([Arc(s, l)]) for s, l in zip(zero_start[zeros], zero_len[zeros])]
        return combine(ArcSet.full(), in_arcs, out_arcs), nbrs[ones][survive]

    def _reference(self, i: int) -> np.ndarray | None:
        """The most recent estimate (x, y) of node ``i`` or a neighbour, if any."""
        nodes = self.net.neighbourhood(i)
        k = nodes[np.argmax(self.last_t[nodes])]
        return None if self.last_t[k] == -np.inf else self.last_xy[k]

    def _inner_edge(self, i: int, piece: Arc, ones: np.ndarray) -> float:
        """Inner radius of the ring section (Fig. 7): the furthest pairwise intersection of the
        "1" neighbours' R_out circles within the arc ``piece`` and the ring, else R_in."""
        r_in, r_out = self.ranges_in[i], self.net.ranges[i]
        if r_in >= r_out or len(ones) < 2:
            return r_in
        a, b = np.triu_indices(len(ones), k=1)
        pos, rad = self.net.positions, self.net.ranges
        points = circle_pair_points(pos[ones[a]], rad[ones[a]], pos[ones[b]], rad[ones[b]]) - pos[i]
        rho = np.hypot(points[:, 0], points[:, 1])
        inside = (rho > r_in) & (rho < r_out) & ArcSet([piece]).contains(np.arctan2(points[:, 1], points[:, 0]))
        return float(rho[inside].max()) if inside.any() else r_in

    def estimate(self, i: int) -> tuple[float, float, float, float]:
        """(x, y, arc, weight) at a transition of node ``i``: the centre of the chosen arc (ideal
        model, on the circle) or ring section (imperfect), its central angle (rad) and eq. 2 / eq. 4."""
        centre, r_in, r_out = self.net.positions[i], self.ranges_in[i], self.net.ranges[i]
        fa, ones = self.final_arcs(i)
        reference = self._reference(i)
        ref_angle = None if reference is None else math.atan2(reference[1] - centre[1], reference[0] - centre[0])
        if fa.is_full:
            piece = fa.arcs[0]
            if reference is None or np.allclose(reference, centre):
                return float(centre[0]), float(centre[1]), TWO_PI, 1.0
            theta = ref_angle
        else:
            piece = fa.longest() if ref_angle is None else fa.nearest(ref_angle)
            theta = piece.midpoint
        inner = self._inner_edge(i, piece, ones)
        rho = 0.5 * (inner + r_out)
        if r_in < r_out:
            weight = (r_out**2 - r_in**2) * TWO_PI / (piece.length * (r_out**2 - inner**2))
        else:
            weight = TWO_PI / piece.length
        return float(centre[0] + rho * math.cos(theta)), float(centre[1] + rho * math.sin(theta)), piece.length, weight

    # ------------------------------------------------------------------ batches

    def _crossing_batch(self, nodes: list[int]) -> bool:
        """Whether the rings (circles, in the ideal model) of ``nodes``, crossed at one instant,
        have a common point: one of the pairwise intersections of their boundary circles."""
        if len(nodes) < 2:
            return True
        nodes = np.asarray(nodes)
        pos, r_out, r_in = self.net.positions[nodes], self.net.ranges[nodes], self.ranges_in[nodes]
        ideal = r_in >= r_out
        c = np.concatenate([pos, pos[~ideal]])
        r = np.concatenate([r_out, r_in[~ideal]])
        a, b = np.triu_indices(len(c), k=1)
        points = circle_pair_points(c[a], r[a], c[b], r[b])
        dist = np.hypot(points[:, None, 0] - pos[None, :, 0], points[:, None, 1] - pos[None, :, 1])
        slack = _ON_CIRCLE_REL * r_out
        in_rings = (dist >= r_in - slack) & (dist <= r_out + slack)
        return bool(in_rings.all(axis=1).any())

    def _estimates(self, transitions: list[Transition]) -> list[LocalEstimate]:
        nodes = [self.net.index[tr.sensor] for tr in transitions]
        if not self._crossing_batch(nodes):
            return []
        out = []
        for tr, i in zip(transitions, nodes):
            x, y, arc, weight = self.estimate(i)
            self.last_t[i] = tr.t
            self.last_xy[i] = (x, y)
            velocity = self._share(i, tr.t, x, y, arc)
            vx, vy = velocity if velocity is not None else (None, None)
            out.append(LocalEstimate(t=tr.t, node=tr.sensor, tracker=self.name, x=x, y=y, vx=vx, vy=vy,
                                     arc=arc, weight=weight))
        return out

    def _share(self, i: int, t: float, x: float, y: float, arc: float) -> tuple[float, float] | None:
        """Node i's estimate reaches i and its neighbours, each timing it on its own clock
        (§3.2.3); returns i's velocity estimate (units/s) with it included."""
        radius = self.net.ranges[i]
        for j in self.net.neighbours[i]:
            self.velocity[j].hear(self.clocks[j].local(t), x, y, arc, radius)
        return self.velocity[i].observe(self.clocks[i].local(t), x, y, arc, radius)
