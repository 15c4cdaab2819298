"""Position reports by fitting targets to one scan's detections (our fusion for paper 004 §III).

The paper clusters the grid cells whose eq. (4) likelihood was computed. Two people a little more
than a sensing range apart then make one cluster, and one person makes satellites. Here we fit
targets to the scan instead. A set X of target positions (grid cells) covers the sensors within
range of any of them. Eq. (4), taken over every sensor, gives X a log-likelihood ratio against
"no target anywhere":

    ℓ(X) = Σ_{i covered by X} w_i,   w_i = log(p_i / q_i) if i detects, else log((1 − p_i)/(1 − q_i)),

with p_i the sensor's pd and q_i its pfa. So read, ℓ depends on X only through the union of the
disks, and a target adds the weights of the sensors it covers that no other target covers (its
*gain*). With ``multiplicity`` (the default) each target is detected on its own, as the
simulator draws them: a sensor that n ≥ 1 targets cover detects with P_n = 1 − (1 − p_i)^n, so
a target also adds log(P_{n+1}/P_n) for each detection and log(1 − p_i) for each miss of a
sensor that n others cover already. Two people in one blob fire its shared sensors more often
than one does, and a second target there gains from that, or loses on their misses.

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
   is dropped. With ``soft_count`` (real PIR, off by default) so is one whose evidence given the
   others falls below it under Gaussian footprints (:meth:`.SoftFootprint.gains`).
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
     detections;
   - the scan does not rule its target out: its support given the targets placed, log Σ π e^gain
     over its gate, is at least ``shared_support`` nats (−4; with ``multiplicity`` a duplicate
     of one person pays log(1 − pd) for each sensor of the blob that missed).

   Two people passing each other, or walking side by side, make one blob of detections, and
   binary sensors cannot resolve it. The copy keeps the hidden person's track, and its count,
   alive. The copy has a loose covariance (the gap plus (R/2)² per axis), so it does not pull
   the track onto the other person. A new track cannot begin with a copy (``mcmcda``).
7. **The count's people** (real PIR, ``count_switch``; off by default). A count of the people
   from how many sensors fire (:mod:`.firing_count`) may hold more people than steps 1–6
   reported (targets and copies). Then as many more targets are sought, greedily as in step 2
   but from ``count_threshold`` detections (1: a person only one sensor saw). Each is kept only if
   Gaussian footprints (σ = ``count_soft`` × range, :meth:`.SoftFootprint.gains`) find it
   ``min_gain`` of evidence given the others: a real walker fires sensors beyond the disk, and
   those firings need no second person.

The likelihood is eq. (4) itself, and each sensor's term stays local. Everything runs on the
grid of ``GridFusion``.
"""

from __future__ import annotations

import math
from typing import Callable, Protocol

import numpy as np
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree

from bintrack.bus_payloads import PositionReport
from bintrack.trackers.multi.fit_scan import FitScan
from bintrack.trackers.multi.soft_footprint import SoftFootprint
from bintrack.trackers.multi.fusion_config import FusionConfig
from bintrack.trackers.multi.track_expectation import Expectation

# ``multiplicity``: targets covering one sensor up to which its gains are kept in a table
_COUNTS = 32
# Starting offsets of a split, as angles of the line through the two new targets.
_SPLIT_ANGLES = np.arange(4) * np.pi / 4


class FitGrid(Protocol):
    """What the fit reads of the grid (:class:`bintrack.trackers.multi.fusion.GridFusion`):
    cells of side ``cell`` (units) at ``cells`` (n × 2), the sparse cells × sensors ``cover``, each
    cell's sensing range ``cell_range``, the per-sensor log likelihood ratios of eq. (4), and for
    real PIR the soft footprints that place a report (``soft``) and confirm the targets (``counting``);
    with a floor plan, which cells are outside its obstacles (``free``)."""

    config: FusionConfig
    ids: list[str]
    cell: float
    cells: np.ndarray
    cell_tree: cKDTree
    cell_range: np.ndarray
    cover: csr_matrix
    log_hit_ratio: np.ndarray
    log_miss_ratio: np.ndarray
    pd_c: np.ndarray
    shared_speed: float
    soft: SoftFootprint | None
    counting: SoftFootprint | None
    count_check: SoftFootprint | None
    free: np.ndarray | None

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

    @property
    def log_miss_each(self) -> np.ndarray:
        """``multiplicity``: per sensor, log(1 − pd), nats, the chance that one target it covers
        goes undetected. Made on first use (also for a fit restored from a checkpoint made before it)."""
        log_m = self.__dict__.get("_log_miss_each")
        if log_m is None:
            log_m = self._log_miss_each = np.log1p(-self.grid.pd_c)
        return log_m

    def log_fires(self, n) -> np.ndarray:
        """``multiplicity``: per sensor, log P_n, P_n = 1 − (1 − pd)^n the chance that a sensor
        which ``n`` ≥ 1 targets cover detects when each is detected on its own (P_1 = pd and
        P_0 = pfa, as in eq. (4)); ``n`` a number or one per sensor."""
        return np.log(-np.expm1(n * self.log_miss_each))

    @property
    def fires(self) -> np.ndarray:
        """``multiplicity``: row n (1 ≤ n ≤ ``_COUNTS``), per sensor, ``log_fires(n)``, nats; row 0
        unused. Made on first use."""
        table = self.__dict__.get("_fires")
        if table is None:
            table = self._fires = np.array([np.zeros_like(self.log_miss_each)] + [self.log_fires(n) for n in range(1, _COUNTS + 1)])
        return table

    @property
    def more_hits(self) -> np.ndarray:
        """``multiplicity``: row n (1 ≤ n < ``_COUNTS``), per sensor, log(P_{n+1}/P_n), nats, what
        a detection adds for one more target where n cover it; row 0 unused. Made on first use."""
        table = self.__dict__.get("_more_hits")
        if table is None:
            fires = self.fires
            table = self._more_hits = np.concatenate([np.zeros_like(fires[:1]), fires[2:] - fires[1:-1]])
        return table

    @property
    def sensors_of(self) -> list[np.ndarray]:
        """Per cell: the sensors covering it, in ``cover``'s order."""
        return self._sensors_of

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
        """For a checkpoint: the fit without its tables of split starts and gains, which are made again."""
        return {k: v for k, v in self.__dict__.items() if k not in ("_split_starts", "_fires", "_more_hits", "_log_miss_each")}

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

    def reports(self, detecting: np.ndarray, expected: list[Expectation] | tuple = (),
                beyond: Callable[[int], int] | None = None) -> list[PositionReport]:
        """The position reports of one scan: ``detecting`` is every sensor's status in
        ``grid.ids`` order; ``expected`` the tracks' expectations, strongest first. Covariances
        are in units²; ``weight`` is the target's gain in nats. ``beyond``, given how many reports
        the fit made (targets and shared copies), says how many more people the scan holds
        (:meth:`.FiringCount.beyond`); so many more targets are sought (step 7)."""
        scan = FitScan(self, detecting)
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
        reports = self._reported(scan, expected)
        if beyond is not None and self._seek(scan, beyond(len(reports))):
            reports = self._reported(scan, expected)
        return reports

    def _reported(self, scan: FitScan, expected) -> list[PositionReport]:
        reports = [scan.report(k) for k in range(len(scan.targets))]
        if self.config.shared:
            reports += scan.shared_copies(reports, expected)
        return reports

    def _seek(self, scan: FitScan, more: int) -> bool:
        """Up to ``more`` new targets beyond those fitted (step 7 of the module docstring), each
        from ``count_threshold`` detections and kept only if the soft footprints (``count_soft``)
        find it at least min_gain nats of evidence given the others; whether any was kept."""
        before = len(scan.targets)
        check = self.grid.count_check
        for _ in range(more):
            if not scan.place_new(self.config.count_threshold):
                break
            scan.settle()
            if check is not None:
                points = self.grid.cells[[t.cell for t in scan.targets]]
                if check.gains(points[-1:], scan.hits, fixed=points[:-1])[0] < self.config.min_gain:
                    scan.remove_last()
                    break
        if len(scan.targets) == before:
            return False
        scan.prune()
        return True
