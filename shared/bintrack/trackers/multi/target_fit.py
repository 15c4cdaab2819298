"""Position reports by fitting targets to one scan's detections (our fusion for paper 004 §III).

The paper clusters the grid cells whose eq. (4) likelihood was computed. Two people a little more
than a sensing range apart then make one cluster, and one person makes satellites. Here we fit
targets to the scan instead. A set X of target positions (grid cells) covers the sensors within
range of any of them. Eq. (4), taken over every sensor, gives X a log-likelihood ratio against
"no target anywhere":

    ℓ(X) = Σ_{i covered by X} w_i,   w_i = log(p_i / q_i) if i detects, else log((1 − p_i)/(1 − q_i)),

with p_i the sensor's pd and q_i its pfa. ℓ depends on X only through the union of the disks, so
a target adds the weights of the sensors it covers that no other target covers (its *gain*).

1. **Expected targets.** A track that expects its target near (x, y), with standard deviation
   σ, places one if the scan supports it: the gain averaged over the track's Gaussian prior on
   the cell, log Σ_c π(c) e^{gain(c)}, must reach ``expected_gain``. That average is the
   likelihood ratio of "the target is where the track says" against "it is not there".
   π is normalised over the whole plane, so prior mass outside the sensors' reach (a target
   leaving) supports nothing. The placed target may move within 3σ of the prediction.
   Each track's support is judged on the scan alone, not given the targets of the tracks placed
   before it: two tracks whose people walk within a range of each other share detections, and
   whichever was placed first would take them all. Their targets settle together (coordinate
   ascent, as in step 2), and step 4 drops one whose support, given the others, has fallen
   below the bar.
2. **New targets**, greedily. Each is placed at the cell of largest gain, if that gain is at
   least ``min_gain`` and the cell newly explains at least n_d detections (the paper's
   threshold). After each placement, every target moves in turn to its best cell given the
   others (coordinate ascent on ℓ).
3. **Splits.** A new target is replaced by two if that raises ℓ by ``min_gain``. This finds two
   people whose disks overlap, which the greedy step sees as one. A track's target is split in
   the same way, one of the two staying within its gate, if that raises ℓ by
   ``expected_split_gain``. Free to move within 3σ, it would otherwise settle between its
   person and an untracked one beside them (6–7 m apart, 8 m disks) and explain both.
4. **Pruning.** A target whose gain has fallen below its threshold, once the others have moved,
   is dropped.
5. **Reports.** A target's report is the mean and covariance of its cell under its own gain,
   given the other targets, over the cells within one range of it. That is the posterior of
   its position under a flat prior.
6. **Shared reports.** A track whose target found no support of its own is given a copy of a
   nearby report, marked ``shared``, when all of these hold:
   - its prediction lies within one sensing range of that report;
   - the report was placed for another track;
   - the two tracks have moved differently by at least ``shared_speed``, m/s (0 by default:
     two people walking side by side move alike);
   - both are established (at least ``shared_age`` reports);
   - it was reported, or given a copy, within the last ``shared_unreported`` scans (2: a
     scan in which its copy was not made does not end its copies);
   - its prediction is at least ``shared_edge`` sensing ranges inside the sensor field (the
     sensors' convex hull). Nearer the edge, a person with no support of their own has as
     likely left, and a copy would keep a departed person's track alive on someone else's
     detections.

   Two people passing each other, or walking side by side, make one blob of detections, and
   binary sensors cannot resolve it. The copy keeps the hidden person's track, and its count,
   alive. The copy has a loose covariance (the gap plus (R/2)² per axis), so it does not pull
   the track onto the other person. A new track cannot begin with a copy (``mcmcda``).

The likelihood is eq. (4) itself, and each sensor's term stays local. Everything runs on the
grid of ``GridFusion``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree

from bintrack.bus_payloads import PositionReport
from bintrack.trackers.multi.fusion_config import FusionConfig

# A report's least variance per axis, in cells²: a uniform position in a cell of side h has h²/12.
_MIN_VARIANCE_CELLS = 1.0 / 12.0
# Starting offsets of a split, as angles of the line through the two new targets.
_SPLIT_ANGLES = np.arange(4) * np.pi / 4
_MAX_SWEEPS = 10
# Rounds of the coordinate ascent that places the two targets of a split.
_SPLIT_ROUNDS = 4


@dataclass(frozen=True)
class Expectation:
    """Where a live track expects its target in the scan being fused."""

    x: float
    """predicted position, deployment units"""
    y: float
    sigma: float
    """standard deviation of the predicted position (larger axis), units"""
    vx: float
    """velocity, units/s"""
    vy: float
    reports: int
    """reports the track has taken so far"""
    unreported: int
    """scans since its last report, counting this one (1: it was reported in the previous scan)"""


@dataclass
class _Target:
    cell: int
    expectation: int | None = None  # index into the scan's expectations; None for a new target
    gate: np.ndarray | None = None  # cells it may occupy (an expected target)
    log_prior: np.ndarray | None = None  # log π over ``gate``


def weighted_report(cells: np.ndarray, w: np.ndarray, cell: float, weight: float) -> PositionReport:
    """A position report from grid cells (n × 2, units) weighted by ``w``: their weighted mean
    and covariance plus the quantization of a cell of side ``cell`` (h²/12 per axis), units²."""
    w_sum = float(w.sum())
    centre = (w[:, None] * cells).sum(axis=0) / w_sum
    spread = cells - centre
    cov = (w[:, None, None] * np.einsum("ni,nj->nij", spread, spread)).sum(axis=0) / w_sum
    cov += np.eye(2) * _MIN_VARIANCE_CELLS * cell ** 2
    return PositionReport(x=float(centre[0]), y=float(centre[1]),
                          cov=((float(cov[0, 0]), float(cov[0, 1])), (float(cov[1, 0]), float(cov[1, 1]))),
                          weight=weight)


class FitGrid(Protocol):
    """What the fit reads of the grid (:class:`bintrack.trackers.multi.fusion.GridFusion`):
    cells of side ``cell`` (units) at ``cells`` (n × 2), the sparse cells × sensors ``cover``, each
    cell's sensing range ``cell_range``, the per-sensor log likelihood ratios of eq. (4)."""

    config: FusionConfig
    ids: list[str]
    cell: float
    cells: np.ndarray
    cell_tree: cKDTree
    cell_range: np.ndarray
    cover: csr_matrix
    log_hit_ratio: np.ndarray
    log_miss_ratio: np.ndarray
    shared_speed: float

    def depth(self, x: float, y: float) -> float: ...


class TargetFit:
    """Fits targets to one scan's detections on ``grid`` (see the module docstring)."""

    def __init__(self, grid: FitGrid):
        self.grid = grid
        self.config = grid.config
        cover = grid.cover
        self._sensors_of = [cover.indices[cover.indptr[c]:cover.indptr[c + 1]] for c in range(cover.shape[0])]
        by_sensor = cover.tocsc()
        self._cells_of = [by_sensor.indices[by_sensor.indptr[s]:by_sensor.indptr[s + 1]] for s in range(cover.shape[1])]
        # column c: cell c's sensors in ``cover``'s order, padded with index n, a sensor that
        # weighs 0 (the last entry of a scan's per-sensor weights)
        lengths = np.diff(cover.indptr)
        self._padded = np.full((max(int(lengths.max(initial=0)), 1), cover.shape[0]), cover.shape[1], dtype=np.intp)
        self._padded[np.arange(cover.nnz) - np.repeat(cover.indptr[:-1], lengths),
                     np.repeat(np.arange(cover.shape[0]), lengths)] = cover.indices
        self._split_starts: dict[int, list[tuple[int, int]]] = {}

    def sums(self, rows: np.ndarray, per_sensor: np.ndarray) -> np.ndarray:
        """Per cell of ``rows``: the sum of ``per_sensor`` (n + 1 entries, the last 0) over the
        sensors covering it, added one sensor after another in ``cover``'s order from 0, as
        ``cover @ per_sensor[:n]`` does, so the two agree bit for bit."""
        values = per_sensor[self._padded[:, rows]]
        total = np.zeros(values.shape[1])
        for layer in values:
            total += layer
        return total

    def __getstate__(self) -> dict:
        """For a checkpoint: the fit without its table of split starts, which is made again."""
        return {k: v for k, v in self.__dict__.items() if k != "_split_starts"}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._split_starts = {}

    def split_starts(self, cell: int) -> list[tuple[int, int]]:
        """The pairs of cells a split of a target at ``cell`` starts its ascents from: half a
        sensing range either side of it, along each of the ``_SPLIT_ANGLES`` (kept per cell)."""
        pairs = self._split_starts.get(cell)
        if pairs is None:
            centre = self.grid.cells[cell]
            offset = 0.5 * float(self.grid.cell_range[cell])
            pairs = []
            for angle in _SPLIT_ANGLES:
                u = offset * np.array((math.cos(angle), math.sin(angle)))
                pairs.append((int(self.grid.cell_tree.query(centre + u)[1]), int(self.grid.cell_tree.query(centre - u)[1])))
            self._split_starts[cell] = pairs
        return pairs

    def cells_covering(self, sensors: np.ndarray) -> np.ndarray:
        """The cells covered by any of ``sensors``, in index order."""
        covered = np.zeros(len(self._sensors_of), dtype=bool)
        for s in sensors:
            covered[self._cells_of[s]] = True
        return np.flatnonzero(covered)

    def reports(self, detecting: np.ndarray, expected: list[Expectation] | tuple = ()) -> list[PositionReport]:
        """The position reports of one scan: ``detecting`` is every sensor's status in
        ``grid.ids`` order; ``expected`` the tracks' expectations, strongest first. Covariances
        are in units²; ``weight`` is the target's gain in nats."""
        scan = _Scan(self, detecting)
        for e, expectation in enumerate(expected):
            scan.place_expected(e, expectation)
        if scan.targets:
            scan.settle()
        # each new target newly explains n_d detections when placed: a bound that ends the loop
        # even where settling hands detections back and forth
        limit = len(scan.targets) + int(scan.hits.sum()) // self.config.threshold
        while len(scan.targets) < limit and scan.place_new():
            scan.settle()
        if self.config.split:
            for _ in range(len(scan.targets) + 1):
                if not scan.split_one():
                    break
            scan.settle()
        scan.prune()
        reports = [scan.report(k) for k in range(len(scan.targets))]
        if self.config.shared:
            reports += scan.shared_copies(reports, expected)
        return reports


class _Scan:
    """The targets placed so far in one scan, how many of them cover each sensor, and the gain
    of every cell given all of them.

    A target's gain at a cell depends only on the sensors covering that cell. So placing,
    moving or removing a target changes the gains only of the cells covering a sensor it frees or
    newly covers, and the gains given every target but one differ from those given all only at
    the cells covering a sensor that target alone covers. Only those cells are recomputed (an
    expected target's, only over its gate); the rest of the grid is read, so a step's cost no
    longer grows with targets × cells. Every gain is the same sum over the same sensors, in the
    same order, as a whole-grid ``cover @ weights`` gives, bit for bit.
    """

    def __init__(self, fit: TargetFit, detecting: np.ndarray):
        self.fit = fit
        self.grid = fit.grid
        self.config = fit.config
        self.hits = detecting > 0
        # per sensor, nats, and a last entry 0 for the padding of ``TargetFit.sums``
        self.weight = np.append(np.where(self.hits, self.grid.log_hit_ratio, self.grid.log_miss_ratio), 0.0)
        self.targets: list[_Target] = []
        self.count = np.zeros(len(self.weight), dtype=np.int32)
        """per sensor: the targets whose cell it covers (the padding's entry stays 0)"""
        self.base = self.grid.cover @ self.weight[:-1]
        """per cell: the gain (nats) of a target there given all the targets placed, kept up to
        date where a sensor becomes free or covered"""
        self.gains_alone = self.base.copy()
        """per cell: the gain (nats) of a target there with no other target, the same for every
        track's expected target in the scan"""
        self._best: dict[tuple, int] = {}
        """``_best_all`` for the present targets, by (cell of the target left out, extra cells)"""

    def _recount(self, remove: int | None, add: int | None) -> None:
        """Take a target off the cell ``remove`` and put one on ``add`` (either may be None),
        and recompute ``base`` at the cells covering a sensor that became free or covered."""
        sensors_of = self.fit._sensors_of
        touched = np.concatenate([sensors_of[c] for c in (remove, add) if c is not None])
        before = self.count[touched] == 0
        if remove is not None:
            self.count[sensors_of[remove]] -= 1
        if add is not None:
            self.count[sensors_of[add]] += 1
        rows = self.fit.cells_covering(touched[(self.count[touched] == 0) != before])
        self.base[rows] = self.fit.sums(rows, self._free_weight())
        self._best.clear()

    def _append(self, target: _Target) -> None:
        self.targets.append(target)
        self._recount(None, target.cell)

    def _remove(self, k: int) -> None:
        self._recount(self.targets[k].cell, None)
        del self.targets[k]

    def _move(self, target: _Target, cell: int) -> None:
        old, target.cell = target.cell, cell
        self._recount(old, cell)

    def _free(self, k: int | None = None, extra=()) -> np.ndarray:
        """Per sensor: True where no target but target ``k`` (and none at the cells ``extra``) covers it."""
        free = self.count == 0
        if k is not None:
            own = self.fit._sensors_of[self.targets[k].cell]
            free[own] = self.count[own] == 1
        for c in extra:
            free[self.fit._sensors_of[c]] = False
        return free

    def _free_weight(self, k: int | None = None, extra=()) -> np.ndarray:
        """Per sensor: its weight (nats) where ``_free``, else 0."""
        return self.weight * self._free(k, extra)

    def _gains_on(self, rows: np.ndarray, k: int | None = None, extra=()) -> np.ndarray:
        """Gains (nats) of a target at the cells ``rows`` given every target but ``k`` (and
        targets at ``extra``)."""
        return self.fit.sums(rows, self._free_weight(k, extra))

    def _differing(self, k: int, extra=()) -> tuple[np.ndarray, np.ndarray]:
        """The cells where a target's gain given every target but ``k`` and targets at ``extra``
        differs from ``base`` (those target ``k`` or ``extra`` reach), and those gains (nats)."""
        free = self._free(k, extra)
        rows = self.fit.cells_covering(np.flatnonzero((self.count == 0) != free))
        return rows, self.fit.sums(rows, self.weight * free)

    def _gains_all(self, k: int, extra=()) -> np.ndarray:
        """Per cell: the gain (nats) of a target there given every target but ``k`` and targets
        at ``extra``: ``base``, recomputed where target ``k`` or ``extra`` reach."""
        rows, gains = self._differing(k, extra)
        gain = self.base.copy()
        gain[rows] = gains
        return gain

    def _best_all(self, k: int, extra=()) -> int:
        """``np.argmax(self._gains_all(k, extra))``, without copying the grid's gains (once
        per placement of the targets: a split's ascents often ask again)."""
        key = (self.targets[k].cell, *extra)
        best = self._best.get(key)
        if best is None:
            rows, gains = self._differing(k, extra)
            kept = self.base[rows]
            self.base[rows] = gains
            best = self._best[key] = int(np.argmax(self.base))
            self.base[rows] = kept
        return best

    def _support(self, target: _Target, gain: np.ndarray) -> float:
        """log Σ π e^gain over an expected target's gate (``gain`` per gate cell): its evidence, nats."""
        x = target.log_prior + gain
        top = float(x.max())
        return top + math.log(float(np.exp(x - top).sum()))

    def place_expected(self, e: int, expectation: Expectation) -> None:
        radius = self.config.expected_sigmas * expectation.sigma
        gate = np.asarray(self.grid.cell_tree.query_ball_point((expectation.x, expectation.y), r=radius), dtype=int)
        if gate.size == 0:
            return
        d2 = ((self.grid.cells[gate] - (expectation.x, expectation.y)) ** 2).sum(axis=1)
        # normalised per cell of the whole Gaussian, not over the gate's covered cells: prior
        # mass beyond the sensors' reach (a target leaving) supports nothing
        log_prior = -0.5 * d2 / expectation.sigma ** 2 - math.log(2 * math.pi * expectation.sigma ** 2 / self.grid.cell ** 2)
        target = _Target(cell=-1, expectation=e, gate=gate, log_prior=log_prior)
        if self._support(target, self.gains_alone[gate]) >= self.config.expected_gain:
            target.cell = int(gate[np.argmax(self._gains_on(gate))])
            self._append(target)

    def place_new(self) -> bool:
        new_hits = self.grid.cover @ (self.hits & (self.count[:-1] == 0)).astype(float)
        gain = np.where(new_hits >= self.config.threshold, self.base, -np.inf)
        best = int(np.argmax(gain))
        if not gain[best] >= self.config.min_gain:
            return False
        self._append(_Target(cell=best))
        return True

    def settle(self) -> None:
        """Coordinate ascent: each target moves to its best cell (within its gate) given the others."""
        for _ in range(_MAX_SWEEPS):
            moved = False
            for k, target in enumerate(self.targets):
                if target.gate is not None:
                    cells = target.gate
                    gain = self._gains_on(cells, k)
                    i = int(np.argmax(gain))
                    best, better = int(cells[i]), gain[i] > gain[np.flatnonzero(cells == target.cell)[0]] + 1e-9
                else:
                    gain = self._gains_all(k)
                    best = int(np.argmax(gain))
                    better = gain[best] > gain[target.cell] + 1e-9
                if better:
                    self._move(target, best)
                    moved = True
            if not moved:
                return

    def _total(self, free_weight: np.ndarray) -> float:
        """ℓ of the targets that leave the sensors of ``free_weight`` (from ``_free_weight``) free, nats."""
        return float((self.weight[:-1] - free_weight[:-1]).sum())

    def split_one(self) -> bool:
        """Replace one target by the two that explain the scan best, if that gains min_gain (a
        track's target: expected_split_gain)."""
        for k, target in enumerate(self.targets):
            expected = target.expectation is not None
            bar = self.config.expected_split_gain if expected else self.config.min_gain
            if bar == math.inf:
                continue
            best_pair, best_total = None, self._total(self._free_weight()) + bar
            # each round of the ascent depends only on the pair it starts from: the pair that
            # (pair, rounds left) ends at, and the pairs already scored (a repeat cannot win)
            ends: dict[tuple[int, int, int], tuple[int, int]] = {}
            scored: set[tuple[int, int]] = set()
            for pair in self.fit.split_starts(target.cell):
                pair = list(pair)
                if expected:
                    pair[0] = target.cell
                path = []
                for left in range(_SPLIT_ROUNDS, 0, -1):
                    start = (pair[0], pair[1])
                    if (*start, left) in ends:
                        pair = list(ends[(*start, left)])
                        break
                    path.append((*start, left))
                    for i in (0, 1):
                        if expected and i == 0:
                            gain = self._gains_on(target.gate, k, extra=[pair[1]])
                            pair[0] = int(target.gate[int(np.argmax(gain))])
                        else:
                            pair[i] = self._best_all(k, extra=[pair[1 - i]])
                    if (pair[0], pair[1]) == start:  # a fixed point: the rounds left change nothing
                        break
                end = (pair[0], pair[1])
                ends.update(dict.fromkeys(path, end))
                if end in scored:
                    continue
                scored.add(end)
                total = self._total(self._free_weight(k, extra=pair))
                if total > best_total:
                    best_pair, best_total = pair, total
            if best_pair is not None:
                self._move(target, best_pair[0])
                self._append(_Target(cell=best_pair[1]))
                return True
        return False

    def prune(self) -> None:
        """Drop, one at a time, the target furthest below its threshold given the others."""
        while self.targets:
            margins = []
            for k, target in enumerate(self.targets):
                if target.expectation is not None:
                    margins.append(self._support(target, self._gains_on(target.gate, k)) - self.config.expected_gain)
                else:
                    margins.append(float(self._gains_on(np.array([target.cell]), k)[0]) - self.config.min_gain)
            worst = int(np.argmin(margins))
            if margins[worst] >= 0:
                return
            self._remove(worst)
            self.settle()

    def report(self, k: int) -> PositionReport:
        target = self.targets[k]
        near = np.asarray(self.grid.cell_tree.query_ball_point(self.grid.cells[target.cell],
                                                               r=float(self.grid.cell_range[target.cell])), dtype=int)
        gain = self._gains_on(near, k)
        here = float(gain[np.flatnonzero(near == target.cell)[0]])
        return weighted_report(self.grid.cells[near], np.exp(gain - here), self.grid.cell, weight=max(here, 0.0))

    def shared_copies(self, reports: list[PositionReport], expected) -> list[PositionReport]:
        """Copies of reports for established tracks hidden in another track's blob (module docstring, 6)."""
        if not reports:
            return []
        c = self.config
        placed_for = {t.expectation: k for k, t in enumerate(self.targets) if t.expectation is not None}
        owner_of = {k: e for e, k in placed_for.items()}
        centres = np.array([(r.x, r.y) for r in reports])
        copies, copied = [], set()
        for e, hidden in enumerate(expected):
            if e in placed_for or hidden.reports < c.shared_age or hidden.unreported > c.shared_unreported:
                continue
            gaps = np.hypot(centres[:, 0] - hidden.x, centres[:, 1] - hidden.y)
            k = int(np.argmin(gaps))
            if k not in owner_of or k in copied:
                continue
            reach = float(self.grid.cell_range[self.targets[k].cell])
            other = expected[owner_of[k]]
            if (gaps[k] > c.shared_gap * reach or other.reports < c.shared_age
                    or math.hypot(hidden.vx - other.vx, hidden.vy - other.vy) < self.grid.shared_speed
                    or self.grid.depth(hidden.x, hidden.y) < c.shared_edge * reach):
                continue
            copied.add(k)
            r = reports[k]
            loose = gaps[k] ** 2 + (0.5 * reach) ** 2
            copies.append(PositionReport(x=r.x, y=r.y, cov=((r.cov[0][0] + loose, r.cov[0][1]),
                                                             (r.cov[1][0], r.cov[1][1] + loose)),
                                         weight=0.0, shared=True))
        return copies
