"""One scan's search of the target fit (:mod:`.target_fit`, steps 1–6 of its docstring): the
targets placed so far, how many cover each sensor, the gain of every cell given them, and the
moves that place, settle, split and prune targets and report them."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from bintrack.bus_payloads import PositionReport
from bintrack.trackers.multi.track_expectation import Expectation

if TYPE_CHECKING:
    from bintrack.trackers.multi.target_fit import TargetFit

# A report's least variance per axis, in cells²: a uniform position in a cell of side h has h²/12.
_MIN_VARIANCE_CELLS = 1.0 / 12.0
_MAX_SWEEPS = 10
# Rounds of the coordinate ascent that places the two targets of a split.
_SPLIT_ROUNDS = 4
# real PIR (soft footprints): a report's cells lie within this many sensing ranges of its target
_SOFT_REACH = 1.5


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


class FitScan:
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
        self.multiple = self.config.multiplicity
        if self.multiple:
            self._log_m = fit.log_miss_each  # log(1 − pd)
            self._sensors = np.arange(len(self.hits))
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
        sensors_of = self.fit.sensors_of
        touched = np.concatenate([sensors_of[c] for c in (remove, add) if c is not None])
        before = self.count[touched] == 0
        if remove is not None:
            self.count[sensors_of[remove]] -= 1
        if add is not None:
            self.count[sensors_of[add]] += 1
        changed = touched if self.multiple else touched[(self.count[touched] == 0) != before]
        rows = self.fit.cells_covering(changed)
        self.base[rows] = self.fit.sums(rows, self._free_weight())
        self._best.clear()

    def _append(self, target: _Target) -> None:
        self.targets.append(target)
        self._recount(None, target.cell)

    def _remove(self, k: int) -> None:
        self._recount(self.targets[k].cell, None)
        del self.targets[k]

    def remove_last(self) -> None:
        """Take back the target placed last, and settle the others."""
        self._remove(len(self.targets) - 1)
        self.settle()

    def _move(self, target: _Target, cell: int) -> None:
        old, target.cell = target.cell, cell
        self._recount(old, cell)

    def _free(self, k: int | None = None, extra=()) -> np.ndarray:
        """Per sensor: True where no target but target ``k`` (and none at the cells ``extra``) covers it."""
        free = self.count == 0
        if k is not None:
            own = self.fit.sensors_of[self.targets[k].cell]
            free[own] = self.count[own] == 1
        for c in extra:
            free[self.fit.sensors_of[c]] = False
        return free

    def _counts(self, k: int | None = None, extra=()) -> np.ndarray:
        """Per sensor: the targets covering it but target ``k``, and with targets at ``extra``."""
        count = self.count.copy()
        if k is not None:
            count[self.fit.sensors_of[self.targets[k].cell]] -= 1
        for c in extra:
            count[self.fit.sensors_of[c]] += 1
        return count

    def _marginal(self, count: np.ndarray) -> np.ndarray:
        """Per sensor (and the padding's 0): what one more target covering it adds to ℓ (nats)
        given ``count`` targets cover it already: eq. (4)'s weight where none does; with
        ``multiplicity``, log(P_{n+1}/P_n) for a detection and log(1 − pd) for a miss where n do."""
        if not self.multiple:
            return self.weight * (count == 0)
        n = count[:-1]
        k = np.maximum(n, 1)
        table = self.fit.more_hits
        if int(k.max()) < len(table):
            gained = table[k, self._sensors]
        else:  # more targets on one sensor than the table holds
            gained = self.fit.log_fires(k + 1) - self.fit.log_fires(k)
        more = np.where(self.hits, gained, self._log_m)
        return np.append(np.where(n == 0, self.weight[:-1], more), 0.0)

    def _free_weight(self, k: int | None = None, extra=()) -> np.ndarray:
        """Per sensor: what a target there adds (nats) given every target but ``k`` and targets
        at ``extra``: its weight where no other covers it, else 0 (with ``multiplicity``, the
        marginal of one more covering target)."""
        if self.multiple:
            return self._marginal(self._counts(k, extra))
        return self.weight * self._free(k, extra)

    def _gains_on(self, rows: np.ndarray, k: int | None = None, extra=()) -> np.ndarray:
        """Gains (nats) of a target at the cells ``rows`` given every target but ``k`` (and
        targets at ``extra``)."""
        return self.fit.sums(rows, self._free_weight(k, extra))

    def _differing(self, k: int, extra=()) -> tuple[np.ndarray, np.ndarray]:
        """The cells where a target's gain given every target but ``k`` and targets at ``extra``
        differs from ``base`` (those target ``k`` or ``extra`` reach), and those gains (nats)."""
        if self.multiple:
            count = self._counts(k, extra)
            rows = self.fit.cells_covering(np.flatnonzero(count != self.count))
            return rows, self.fit.sums(rows, self._marginal(count))
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

    def _expected_target(self, e: int, expectation: Expectation) -> _Target | None:
        """An unplaced target for expectation ``e``: its gate (cells within expected_sigmas σ of
        the prediction) and log prior over it; None if the gate holds no cell."""
        radius = self.config.expected_sigmas * expectation.sigma
        gate = np.asarray(self.grid.cell_tree.query_ball_point((expectation.x, expectation.y), r=radius), dtype=int)
        if gate.size == 0:
            return None
        d2 = ((self.grid.cells[gate] - (expectation.x, expectation.y)) ** 2).sum(axis=1)
        # normalised per cell of the whole Gaussian, not over the gate's covered cells: prior
        # mass beyond the sensors' reach (a target leaving) supports nothing
        log_prior = -0.5 * d2 / expectation.sigma ** 2 - math.log(2 * math.pi * expectation.sigma ** 2 / self.grid.cell ** 2)
        return _Target(cell=-1, expectation=e, gate=gate, log_prior=log_prior)

    def place_expected(self, e: int, expectation: Expectation) -> None:
        target = self._expected_target(e, expectation)
        if target is None:
            return
        gate = target.gate
        if self._support(target, self.gains_alone[gate]) >= self.config.expected_gain:
            target.cell = int(gate[np.argmax(self._gains_on(gate))])
            self._append(target)

    def place_new(self, threshold: int | None = None) -> bool:
        """Place a new target at the cell of largest gain among those that newly explain
        ``threshold`` detections (default n_d), if that gain reaches min_gain; whether one was placed."""
        new_hits = self.grid.cover @ (self.hits & (self.count[:-1] == 0)).astype(float)
        gain = np.where(new_hits >= (self.config.threshold if threshold is None else threshold), self.base, -np.inf)
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

    def _total(self, k: int | None = None, extra=()) -> float:
        """ℓ (nats) of every target but ``k`` and targets at ``extra``."""
        if not self.multiple:
            return float((self.weight[:-1] - self._free_weight(k, extra)[:-1]).sum())
        count = self._counts(k, extra)[:-1]
        n = np.maximum(count, 1)
        table = self.fit.fires
        fired = table[n, self._sensors] if int(n.max()) < len(table) else self.fit.log_fires(n)
        # n targets on a sensor: a detection log(P_n/pfa) = log(pd/pfa) + log(P_n/P_1), a miss
        # log((1 − P_n)/(1 − pfa)) = log((1 − pd)/(1 − pfa)) + (n − 1)·log(1 − pd)
        more = np.where(self.hits, fired - table[1], (n - 1) * self._log_m)
        return float((self.weight[:-1] + more)[count > 0].sum())

    def split_one(self) -> bool:
        """Replace one target by the two that explain the scan best, if that gains min_gain (a
        track's target: expected_split_gain)."""
        for k, target in enumerate(self.targets):
            expected = target.expectation is not None
            bar = self.config.expected_split_gain if expected else self.config.min_gain
            if bar == math.inf:
                continue
            best_pair, best_total = None, self._total() + bar
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
                total = self._total(k, extra=pair)
                if total > best_total:
                    best_pair, best_total = pair, total
            if best_pair is not None:
                self._move(target, best_pair[0])
                self._append(_Target(cell=best_pair[1]))
                return True
        return False

    def prune(self) -> None:
        """Drop, one at a time, the target furthest below its threshold given the others; then,
        with ``soft_count``, the same under the soft footprints (:meth:`_prune_soft`)."""
        while self.targets:
            margins = []
            for k, target in enumerate(self.targets):
                if target.expectation is not None:
                    margins.append(self._support(target, self._gains_on(target.gate, k)) - self.config.expected_gain)
                else:
                    margins.append(float(self._gains_on(np.array([target.cell]), k)[0]) - self.config.min_gain)
            worst = int(np.argmin(margins))
            if margins[worst] >= 0:
                break
            self._remove(worst)
            self.settle()
        self._prune_soft()

    def _prune_soft(self) -> None:
        """Real PIR (``soft_count``): drop, one at a time, the target whose evidence given the
        others under the soft footprints falls furthest below its bar (min_gain for a new target,
        expected_gain for a track's): one walker's far firings need no second target."""
        counting = self.grid.counting
        while counting is not None and self.targets:
            points = self.grid.cells[[t.cell for t in self.targets]].reshape(-1, 2)
            bars = np.array([self.config.expected_gain if t.expectation is not None else self.config.min_gain
                             for t in self.targets])
            margins = counting.gains(points, self.hits) - bars
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
        soft = self.grid.soft
        if soft is None:
            free = self._standing(near)
            return weighted_report(self.grid.cells[near[free]], np.exp(gain[free] - here), self.grid.cell,
                                   weight=max(here, 0.0))
        reach = _SOFT_REACH * float(self.grid.cell_range[target.cell])
        cells = np.asarray(self.grid.cell_tree.query_ball_point(self.grid.cells[target.cell], r=reach), dtype=int)
        cells = cells[self._standing(cells)]
        others = self.grid.cells[[t.cell for j, t in enumerate(self.targets) if j != k]].reshape(-1, 2)
        log_l = soft.log_likelihood(self.grid.cells[cells], self.hits, others, reach)
        return weighted_report(self.grid.cells[cells], np.exp(log_l - log_l.max()), self.grid.cell, weight=max(here, 0.0))

    def _standing(self, cells: np.ndarray) -> np.ndarray | slice:
        """Which of ``cells`` a report may be placed on: those outside the floor plan's obstacles,
        or all of them where none is free (a target wholly inside an obstacle stays reported)."""
        free = self.grid.free
        if free is None or not free[cells].any():
            return slice(None)
        return free[cells]

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
            if c.shared_chain is not None and (hidden.unreported_own is None or hidden.unreported_own > c.shared_chain):
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
            if c.shared_support is not None:
                target = self._expected_target(e, hidden)
                if target is None or self._support(target, self._gains_on(target.gate)) < c.shared_support:
                    continue
            copied.add(k)
            r = reports[k]
            loose = gaps[k] ** 2 + (0.5 * reach) ** 2
            copies.append(PositionReport(x=r.x, y=r.y, cov=((r.cov[0][0] + loose, r.cov[0][1]),
                                                             (r.cov[1][0], r.cov[1][1] + loose)),
                                         weight=0.0, shared=True))
        return copies
