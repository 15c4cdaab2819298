"""Multi-sensor fusion of binary detections into position reports (paper 004 §III).

The surveillance region is quantized into square cells. For a cell c covered by the sensing
disks of the sensors S(c), the *detection-likelihood* of one scan's detections y is the
detection part of eq. (4),

    L(c) = ∏_{i ∈ S(c)} p_i^{y_i} (1 − p_i)^{1 − y_i},

computed only where at least ``n_d`` sensors of S(c) detect (the threshold test that replaces
the false-detection part, which would need every sensor's report). In the distributed form each
cell is assigned to one sensor that covers it (here the nearest), which computes it from its
own and its neighbours' reports; the paper has a sensor do so only when it itself reports a
detection (``FusionConfig.owner_detects``). The paper clusters the cells whose likelihood was
computed: take a seed cell, gather the remaining cells within the sensing radius of it, remove
them, repeat; each cluster's likelihood-weighted centre of mass is one position report. The
paper picks seeds at random; we take the most likely remaining cell, which is deterministic and
puts the seed on the strongest evidence.

By default we do not cluster but fit targets to the scan by eq. (4) over all sensors, helped by
where the tracks expect targets (:mod:`bintrack.trackers.multi.target_fit`): clusters merge two people a little
more than a sensing range apart and make satellites around one person.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np
from scipy.sparse import csr_matrix
from scipy.spatial import ConvexHull, QhullError, cKDTree

from bintrack.errors import TrackerConfigError
from bintrack.bus_payloads import PositionReport, PositionReports, Transition
from bintrack.deployment_model import Deployment, DiskSensor, SectorSensor
from bintrack.sensing import reports_presence
from bintrack.time_span import MAX_SILENCE
from bintrack.trackers.multi.firing_count import FiringCount
from bintrack.trackers.multi.fusion_config import FusionConfig
from bintrack.trackers.multi.fit_scan import weighted_report
from bintrack.trackers.multi.target_fit import TargetFit
from bintrack.trackers.multi.soft_footprint import SoftFootprint
from bintrack.trackers.multi.track_expectation import Expectation

DEFAULT_SCAN = 0.5  # s, when the sensors are event-driven (no sampling period)


def bar_scale(pd: np.ndarray, log_hit_ratio: np.ndarray, log_miss_ratio: np.ndarray, reference: float | None) -> float:
    """How much the fit's bars grow for these sensors (``FusionConfig.evidence_reference``; pass
    those that state both pd and pfa): the median of the evidence a covering sensor gives of a
    person, pd·log(pd/pfa) + (1 − pd)·log((1 − pd)/(1 − pfa)) in nats from eq. (4)'s per-sensor
    weights (their mean under a target), over ``reference``; 1 where that is lower, for no
    sensors, or without a reference."""
    if reference is None or pd.size == 0:
        return 1.0
    evidence = pd * log_hit_ratio + (1 - pd) * log_miss_ratio
    return max(float(np.median(evidence)) / reference, 1.0)


class GridFusion:
    """The quantized detection-likelihood of a deployment's disk (or sector) sensors.

    pd and pfa come from each sensor (pd 1 and pfa 0 where the deployment gives none, the ideal
    model). Sector sensors count as present whenever they report a sector.
    """

    soft: SoftFootprint | None = None
    """real PIR: the Gaussian footprints that place a "fit" target's report
    (``FusionConfig.soft_spread``); a class default, so that a grid pickled before it existed loads"""
    counting: SoftFootprint | None = None
    """real PIR: the Gaussian footprints that confirm a "fit" scan's targets
    (``FusionConfig.soft_count``); a class default, as ``soft``"""
    count_check: SoftFootprint | None = None
    """real PIR: the Gaussian footprints that judge a target the count asks for (``FusionConfig.count_soft``)"""
    firings: np.ndarray | None = None
    """real PIR (``FusionConfig.count_switch``): per cell, the firing sensors a person there is
    expected to give, Σ pd over the disks covering it (:mod:`.firing_count`'s a)"""
    false_alarms = 0.0
    """real PIR (``count_switch``): Σ pfa, the firings per scan of an empty room (the count's b)"""
    free: np.ndarray | None = None
    """per cell: whether someone can stand there (outside the floor plan's obstacles); None
    without a floor plan. Targets are counted on every cell, but a report is placed on free
    cells only (:meth:`~.fit_scan.FitScan.report`)"""

    def __init__(self, deployment: Deployment, config: FusionConfig = FusionConfig()):
        sensors = [s for s in deployment.sensors if isinstance(s, (DiskSensor, SectorSensor))]
        if not sensors:
            raise TrackerConfigError("fusion needs disk or sector sensors; this deployment has none")
        if config.cell is not None and not config.cell > 0:
            raise TrackerConfigError(f"fusion cell size must be positive, got {config.cell}")
        if not config.min_gain >= 0:
            raise TrackerConfigError(f"fusion min_gain must be at least 0 nats, got {config.min_gain}")
        if not config.expected_split_gain >= 0:
            raise TrackerConfigError(f"fusion expected_split_gain must be at least 0 nats, got {config.expected_split_gain}")
        if config.evidence_reference is not None and not config.evidence_reference > 0:
            raise TrackerConfigError(f"fusion evidence_reference must be positive nats, got {config.evidence_reference}")
        if not config.shared_edge >= 0:
            raise TrackerConfigError(f"fusion shared_edge must be at least 0 sensing ranges, got {config.shared_edge}")
        if config.soft_spread is not None and not config.soft_spread > 0:
            raise TrackerConfigError(f"fusion soft_spread must be positive, got {config.soft_spread}")
        if config.soft_count is not None and not config.soft_count > 0:
            raise TrackerConfigError(f"fusion soft_count must be positive, got {config.soft_count}")
        if config.count_switch is not None and not 0.0 < config.count_switch < 1.0:
            raise TrackerConfigError(f"fusion count_switch must lie between 0 and 1, got {config.count_switch}")
        if config.count_threshold < 1:
            raise TrackerConfigError(f"fusion count_threshold must be at least 1, got {config.count_threshold}")
        if config.count_soft is not None and not config.count_soft > 0:
            raise TrackerConfigError(f"fusion count_soft must be positive, got {config.count_soft}")
        if config.threshold < 1:
            raise TrackerConfigError(f"fusion threshold n_d must be at least 1, got {config.threshold}")
        self.config = config
        self._made_from = (deployment, config)
        self.shared_speed = config.shared_speed / deployment.metres_per_unit
        """``config.shared_speed`` in the deployment's units per second"""
        self.ids = [s.id for s in sensors]
        self.index = {sid: i for i, sid in enumerate(self.ids)}
        positions = np.array([(s.x, s.y) for s in sensors])
        ranges = np.array([s.range for s in sensors])
        pd = np.array([1.0 if s.pd is None else s.pd for s in sensors])
        pfa = np.array([0.0 if s.pfa is None else s.pfa for s in sensors])
        with np.errstate(divide="ignore"):
            self._log_hit = np.log(pd)
            self._log_miss = np.log1p(-pd)
            # eq. (4) over all sensors = ∏_{i∉S(c)} q_i^y(1−q_i)^(1−y) · ∏_{i∈S(c)} p_i^y(1−p_i)^(1−y),
            # i.e. a constant (no target anywhere) times ∏_{i∈S(c)} (p_i/q_i)^y ((1−p_i)/(1−q_i))^(1−y)
            # (clamped, so that ideal sensors, pd = 1 and pfa = 0, give large finite ratios)
            pd_c, pfa_c = np.clip(pd, 1e-9, 1 - 1e-9), np.clip(pfa, 1e-9, 1 - 1e-9)
            self.log_hit_ratio = np.log(pd_c) - np.log(pfa_c)
            """per sensor: log(pd/pfa), nats, the weight of a detection in eq. (4)"""
            self.log_miss_ratio = np.log1p(-pd_c) - np.log1p(-pfa_c)
            """per sensor: log((1 − pd)/(1 − pfa)), nats, the weight of a miss"""
        self.pd_c = pd_c
        """per sensor: pd clamped into (0, 1), as eq. (4)'s weights take it"""
        stated = np.array([s.pd is not None and s.pfa is not None for s in sensors])
        self.bar_scale = bar_scale(pd_c[stated], self.log_hit_ratio[stated], self.log_miss_ratio[stated],
                                   config.evidence_reference)
        """what ``min_gain`` and ``expected_split_gain`` are multiplied by here (``evidence_reference``)"""
        if self.bar_scale != 1.0:
            self.config = config = replace(config, min_gain=config.min_gain * self.bar_scale,
                                           expected_split_gain=config.expected_split_gain * self.bar_scale)
        region = deployment.region
        h = config.cell if config.cell is not None else float(min(s.range for s in sensors)) / 8.0
        self.cell = h
        """side of a grid cell, deployment units"""
        xs = np.arange(region.xmin + h / 2, region.xmax, h)
        ys = np.arange(region.ymin + h / 2, region.ymax, h)
        grid = np.array(np.meshgrid(xs, ys, indexing="xy")).reshape(2, -1).T
        tree = cKDTree(positions)
        covering = tree.query_ball_point(grid, r=float(ranges.max()))
        rows, cols = [], []
        owner = np.full(len(grid), -1)
        for c, candidates in enumerate(covering):
            if not candidates:
                continue
            candidates = np.asarray(candidates)
            gaps = np.linalg.norm(positions[candidates] - grid[c], axis=1)
            inside = candidates[gaps <= ranges[candidates]]
            if inside.size == 0:
                continue
            rows.extend([c] * inside.size)
            cols.extend(inside.tolist())
            owner[c] = candidates[np.argmin(np.where(gaps <= ranges[candidates], gaps, np.inf))]
        covered = owner >= 0
        keep = np.flatnonzero(covered)
        renumber = np.full(len(grid), -1)
        renumber[keep] = np.arange(keep.size)
        self.cells = grid[keep]
        """cell centres (m × 2), deployment units"""
        self.owner = owner[keep]
        """index of the sensor each cell is assigned to (the nearest that covers it)"""
        data = np.ones(len(rows))
        self.cover = csr_matrix((data, (renumber[np.array(rows, dtype=int)], np.array(cols, dtype=int))),
                                shape=(keep.size, len(sensors)))
        """cells × sensors, 1 where the sensor's disk covers the cell"""
        if deployment.floor_plan is not None:
            from bintrack.floor_plan import FloorShape  # shapely: only for a deployment with a plan

            try:
                self.free = FloorShape(deployment.floor_plan).free(self.cells)
            except ValueError as exc:
                raise TrackerConfigError(str(exc)) from None
        self._radius = ranges
        self._positions = positions
        self._sensor_tree = tree
        self.cell_tree = cKDTree(self.cells)
        try:
            self._hull = ConvexHull(positions).equations
        except QhullError:  # fewer than three sensors, or all on one line: no area to be inside
            self._hull = None
        self.cell_range = ranges[self.owner]
        """per cell: the sensing range of the sensor it is assigned to, units"""
        self.max_range = float(ranges.max())
        """the longest sensing range, units"""
        if config.soft_spread is not None:
            self.soft = SoftFootprint(positions, ranges * config.soft_spread, pd, pfa)
        if config.soft_count is not None:
            self.counting = SoftFootprint(positions, ranges * config.soft_count, pd, pfa)
        if config.count_soft is not None:
            self.count_check = SoftFootprint(positions, ranges * config.count_soft, pd, pfa)
        if config.count_switch is not None:
            self.firings = self.cover @ pd_c
            self.false_alarms = float(pfa.sum())
        self._fit = TargetFit(self)

    def __reduce__(self):
        """Pickled (a live service's checkpoint) as what it is made from: its tables follow from
        the deployment and the config, and pickling them took a megabyte and a tenth of a second."""
        return GridFusion, self._made_from

    def depth(self, x: float, y: float) -> float:
        """How far (units) the point (x, y) lies inside the sensor field, the convex hull of the
        sensors: the distance to its edge, negative outside; infinite when the sensors enclose
        no area."""
        if self._hull is None:
            return math.inf
        return -float(np.max(self._hull[:, :2] @ (x, y) + self._hull[:, 2]))

    def detection_likelihood(self, detecting: np.ndarray, full: bool = False,
                             active: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Cells whose likelihood is computed for the 0/1 vector ``detecting`` (one entry per
        sensor, in ``ids`` order), and their log-likelihoods.

        A cell counts when at least n_d covering sensors detect (and, with ``owner_detects``, the
        sensor it is assigned to, which computes it, §III distributed form). The value is the
        detection part of eq. (4); with ``full``, eq. (4) itself up to a factor common to all
        cells (the covering sensors' likelihood ratios against a false detection), which is just
        as local. Sensors outside ``active`` (default: all) take no part: neither their
        detections nor their misses count.
        """
        y = detecting.astype(float)
        if active is not None:
            y = y * active
        counts = self.cover @ y
        computed = counts >= self.config.threshold
        if self.config.owner_detects:
            computed &= y[self.owner] > 0
        cells = np.flatnonzero(computed)
        if cells.size == 0:
            return cells, np.zeros(0)
        if full:
            per_sensor = np.where(y > 0, self.log_hit_ratio, self.log_miss_ratio)
        else:
            per_sensor = np.where(y > 0, self._log_hit, self._log_miss)
        per_sensor = np.where(np.isfinite(per_sensor), per_sensor, -1e300)
        if active is not None:
            per_sensor = per_sensor * active
        return cells, self.cover[cells] @ per_sensor

    def likelihood_map(self, detecting: np.ndarray, full: bool = False) -> np.ndarray:
        """Likelihood of every cell (0 where it is not computed), scaled to a maximum of 1, for plots."""
        out = np.zeros(len(self.cells))
        cells, values = self.detection_likelihood(detecting, full)
        if cells.size:
            out[cells] = np.exp(values - values.max())
        return out

    def reports(self, detecting: np.ndarray, expected: list[Expectation] | tuple = (),
                beyond: Callable[[int], int] | None = None) -> list[PositionReport]:
        """Position reports of one scan; covariances in units². ``beyond``: see
        :meth:`.TargetFit.reports` ("fit" only).

        ``clustering="fit"`` (default): targets fitted to the detections by eq. (4) over every
        sensor, using ``expected`` (the tracks' predictions, strongest first), see
        :mod:`bintrack.trackers.multi.target_fit`. ``"paper"`` (§III): seeds in order of likelihood, each
        gathering the remaining computed cells within its sensing radius; a report is the
        likelihood-weighted centre and spread of its cells plus the cell quantization (h²/12).
        ``"explain"``: as "paper", but after each cluster the detections of the sensors covering
        its centre are explained by it and the likelihood is computed again without them, so
        that one target's detections make one report rather than a report and satellites.
        """
        if self.config.clustering == "paper":
            cells, log_l = self.detection_likelihood(detecting, self.config.full)
            return self._clusters(cells, log_l, limit=None)
        if self.config.clustering == "fit":
            return self._fit.reports(detecting, expected, beyond)
        active = np.ones(len(self.ids))
        reports: list[PositionReport] = []
        while True:
            cells, log_l = self.detection_likelihood(detecting, self.config.full, active)
            found = self._clusters(cells, log_l, limit=1)
            if not found:
                return reports
            report = found[0]
            reports.append(report)
            covering = self._sensor_tree.query_ball_point((report.x, report.y), r=float(self._radius.max()))
            explained = [i for i in covering if active[i] and detecting[i] and math.hypot(
                self._positions[i, 0] - report.x, self._positions[i, 1] - report.y) <= self.config.explained * self._radius[i]]
            if not explained:  # nothing left for it to explain: it cannot change the next pass
                return reports
            active[explained] = 0.0

    def _clusters(self, cells: np.ndarray, log_l: np.ndarray, limit: int | None) -> list[PositionReport]:
        if cells.size == 0:
            return []
        likelihood = np.exp(log_l - log_l.max())
        order = np.argsort(-likelihood, kind="stable")
        free = np.zeros(len(self.cells), dtype=bool)
        free[cells] = True
        weight = np.zeros(len(self.cells))
        weight[cells] = likelihood
        reports = []
        for seed in cells[order]:
            if not free[seed]:
                continue
            members = np.asarray(self.cell_tree.query_ball_point(self.cells[seed], r=float(self.cell_range[seed])))
            members = members[free[members]]
            free[members] = False
            w = weight[members]
            reports.append(weighted_report(self.cells[members], w, self.cell, weight=float(w.sum())))
            if limit is not None and len(reports) >= limit:
                break
        return reports


def scan_period(deployment: Deployment, config: FusionConfig) -> float:
    """The scan period, s: ``config.scan``, else the sensors' longest sampling period, else 0.5 s."""
    if config.scan is not None:
        if not config.scan > 0:
            raise TrackerConfigError(f"scan period must be positive, got {config.scan}")
        return config.scan
    periods = [s.period for s in deployment.sensors if getattr(s, "period", None)]
    return max(periods) if periods else DEFAULT_SCAN


@dataclass(frozen=True)
class Scan:
    """Every sensor's status (``GridFusion.ids`` order, True = detecting) at event time ``t`` (s)."""

    t: float
    detecting: np.ndarray
    skipped: int = 0
    """scans passed over just before this one (a silence longer than ``MAX_SILENCE``)"""


class ScanFusion:
    """Transitions in event-time order → one ``PositionReports`` per scan.

    Scan k is at event time k·P (P the scan period) and sees every sensor's status as of that
    time (the last sample at or before it). It is emitted once no transition at or before k·P
    can come (``flush``). Scans run from the first one at or after the first transition to the
    first one at or after the last transition. After ``MAX_SILENCE`` s without a transition no
    scan is emitted; the next transition's scan follows, counting those passed over.
    """

    _skipped = 0  # scans passed over before the next one (a class default: checkpoints made before it)
    count: FiringCount | None = None
    """the count of the people from the firings (``FusionConfig.count_switch``), else None"""

    def __init__(self, deployment: Deployment, config: FusionConfig = FusionConfig()):
        self.grid = GridFusion(deployment, config)
        self.period = scan_period(deployment, config)
        if config.count_switch is not None and config.clustering == "fit":
            grid = self.grid
            inside = np.array([grid.depth(x, y) >= 0 for x, y in grid.cells])
            floor = grid.firings[inside] if inside.any() else grid.firings
            # k ≤ the sensors, so with a ≥ ½ firing per person no larger count is told apart
            self.count = FiringCount(config.count_switch, float(floor.mean()), grid.false_alarms,
                                     most=2 * len(grid.ids))
        self._detecting = np.zeros(len(self.grid.ids), dtype=bool)
        self._sensors = deployment.by_id()
        self._next: int | None = None  # index of the next scan to emit
        self._last_t: float | None = None

    @property
    def sensors(self) -> dict:
        """The deployment's sensors by id."""
        return self._sensors

    def fuse(self, scan: Scan, expected: list[Expectation] | tuple = ()) -> PositionReports:
        """The position reports of ``scan`` (``GridFusion.reports``), given where the tracks
        expect targets (used by the "fit" fusion); with ``count_switch``, the count of the people
        from the firings (:mod:`.firing_count`) asks for more targets."""
        count = self.count
        if count is None:
            return PositionReports(t=scan.t, reports=self.grid.reports(scan.detecting, expected))
        count.update(int(scan.detecting.sum()))
        reports = self.grid.reports(scan.detecting, expected, count.beyond)
        own = [(r.x, r.y) for r in reports if not r.shared]
        if own:
            count.placed(self.grid.firings[self.grid.cell_tree.query(own)[1]])
        return PositionReports(t=scan.t, reports=reports)

    def update(self, transition: Transition) -> list[Scan]:
        """Apply ``transition`` after emitting the scans strictly before its time."""
        out = self.flush(math.nextafter(transition.t, -math.inf))
        if self._next is not None and transition.t - self._last_t > MAX_SILENCE and self.scan_of(transition.t) > self._next:
            self._skipped = self.scan_of(transition.t) - self._next
            self._next += self._skipped
        i = self.grid.index.get(transition.sensor)
        if i is not None:
            self._detecting[i] = reports_presence(self._sensors[transition.sensor], transition.value)
        if self._next is None:
            self._next = self.scan_of(transition.t)
        self._last_t = transition.t
        return out

    def flush(self, t: float) -> list[Scan]:
        """Emit every scan at event time ≤ ``t`` (s); with t = ∞, up to the last transition's."""
        if self._next is None:
            return []
        if math.isinf(t):
            t = self.scan_of(self._last_t) * self.period
        t = min(t, self._last_t + MAX_SILENCE)
        out = []
        while (scan_t := round(self._next * self.period, 9)) <= t:
            out.append(Scan(t=scan_t, detecting=self._detecting.copy(), skipped=self._skipped))
            self._skipped = 0
            self._next += 1
        return out

    def scan_of(self, t: float) -> int:
        """Index of the first scan at or after event time ``t`` (s)."""
        return math.ceil(round(t / self.period, 9))

    def next_scan(self) -> int:
        """Index of the next scan to be emitted (scans before it are final)."""
        return -math.inf if self._next is None else self._next

    def detecting(self) -> np.ndarray:
        """The current 0/1 status of every sensor (``grid.ids`` order)."""
        return self._detecting.copy()
