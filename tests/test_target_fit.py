"""The fitted fusion (bintrack.trackers.multi.target_fit): targets fitted to a scan by eq. (4), helped by tracks."""

from __future__ import annotations

import math
import pickle
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from bintrack.errors import TrackerConfigError
from bintrack.formats import open_dataset
from bintrack.pipeline import run_tracker
from bintrack.trackers import make_tracker
from bintrack.trackers.multi import target_fit
from bintrack.trackers.multi.fit_scan import FitScan, _Target
from bintrack.trackers.multi.fusion import GridFusion
from bintrack.trackers.multi.fusion_config import FusionConfig
from bintrack.trackers.multi.mcmcda import OnlineMCMCDA
from bintrack.trackers.multi.mcmcda_config import MCMCDAConfig
from bintrack.bus_payloads import PositionReport, PositionReports, TrackSet
from bintrack.deployment_model import Deployment, DiskSensor, Region
from support import DATASETS
from bintrack.trackers.multi.track_expectation import Expectation

from test_mcmcda import detecting_near, grid_deployment


def near(report: PositionReport, x: float, y: float, within: float) -> bool:
    return math.hypot(report.x - x, report.y - y) <= within


def test_two_people_a_little_more_than_a_range_apart_are_two_reports_not_one_cluster():
    deployment = grid_deployment()
    people = [(17.0, 22.0), (27.0, 23.0)]  # 10 m apart, 8 m disks: one blob of detections
    detecting = detecting_near(GridFusion(deployment), deployment, people)
    fitted = GridFusion(deployment).reports(detecting)
    assert len(fitted) == 2
    for x, y in people:
        assert any(near(r, x, y, 3.0) for r in fitted)
    clustered = GridFusion(deployment, FusionConfig(clustering="explain")).reports(detecting)
    assert not (len(clustered) == 2 and all(any(near(r, x, y, 3.0) for r in clustered) for x, y in people))


def test_a_track_expecting_its_target_lowers_the_bar_for_weak_evidence():
    deployment = grid_deployment()
    fusion = GridFusion(deployment)
    detecting = np.zeros(len(fusion.ids), dtype=bool)
    for sensor in ("n0404", "n0405", "n0505"):  # three of the ~8 sensors covering (22.5, 23.5)
        detecting[fusion.index[sensor]] = True
    assert fusion.reports(detecting) == []  # 3 hits and 5 misses: 2.2 nats, below min_gain
    expected = [Expectation(x=22.5, y=23.5, sigma=1.5, vx=1.0, vy=0.0, reports=10, unreported=1)]
    (report,) = fusion.reports(detecting, expected)
    assert near(report, 22.5, 23.5, 2.0) and not report.shared
    # the same two detections far from where the track expects its target support nothing
    away = [Expectation(x=5.0, y=40.0, sigma=1.5, vx=1.0, vy=0.0, reports=10, unreported=1)]
    assert fusion.reports(detecting, away) == []


def test_cleaner_sensors_raise_the_bar_for_a_new_target_in_proportion_to_their_evidence():
    clean = grid_deployment(pd=0.95, pfa=0.01)  # 4.18 nats per covering sensor against 1.7
    fusion = GridFusion(clean)
    assert fusion.bar_scale == pytest.approx(4.178 / 1.7, rel=1e-3)
    assert fusion.config.min_gain == pytest.approx(4.0 * fusion.bar_scale)
    assert fusion.config.expected_split_gain == pytest.approx(FusionConfig().expected_split_gain * fusion.bar_scale)
    fixed = GridFusion(clean, FusionConfig(evidence_reference=None))
    detecting = np.zeros(len(fusion.ids), dtype=bool)
    for sensor in ("n0404", "n0405", "n0505", "n0504"):  # four of the ~8 covering (22.5, 22.5)
        detecting[fusion.index[sensor]] = True
    (report,) = fixed.reports(detecting)  # 6.3 nats: over 4, under 9.8
    assert 4.0 < report.weight < fusion.config.min_gain
    assert fusion.reports(detecting) == []
    # paper 004's sensors (1.5 nats), and sensors that state no pd or pfa, keep the bars in nats
    assert GridFusion(grid_deployment()).bar_scale == 1.0
    assert GridFusion(grid_deployment(pd=None, pfa=None)).bar_scale == 1.0
    with pytest.raises(TrackerConfigError, match="evidence_reference"):
        GridFusion(clean, FusionConfig(evidence_reference=0.0))


def test_a_tracked_person_and_an_untracked_one_beside_them_are_two_reports():
    # 7 m apart, 8 m disks: the tracked person's target, free to move within its gate, would
    # settle between the two and explain both; splitting it gives each person a report
    deployment = grid_deployment(pd=0.8)
    people = [(17.0, 21.0), (24.0, 21.0)]
    tracked = [Expectation(x=17.0, y=21.0, sigma=1.0, vx=1.0, vy=0.0, reports=20, unreported=1)]
    fusion = GridFusion(deployment)
    detecting = detecting_near(fusion, deployment, people)
    reports = fusion.reports(detecting, tracked)
    assert len(reports) == 2 and not any(r.shared for r in reports)
    for x, y in people:
        assert any(near(r, x, y, 1.5) for r in reports)
    (between,) = GridFusion(deployment, FusionConfig(expected_split_gain=math.inf)).reports(detecting, tracked)
    assert near(between, 20.5, 21.0, 1.0)
    # one person alone where the track expects them stays one report
    alone = detecting_near(fusion, deployment, people[:1])
    assert len(fusion.reports(alone, tracked)) == 1


def test_no_report_for_a_track_whose_target_has_left_the_sensors():
    deployment = grid_deployment()
    fusion = GridFusion(deployment)
    silent = np.zeros(len(fusion.ids), dtype=bool)
    leaving = [Expectation(x=49.0, y=20.0, sigma=2.0, vx=1.2, vy=0.0, reports=30, unreported=1)]
    assert fusion.reports(silent, leaving) == []


# The blob of two people 2 m apart hides one of them from a fit over the union of the disks whose
# tracks' targets need a nat of support (each person detected on their own, the default, finds
# both): the case shared copies are for.
HIDING = FusionConfig(multiplicity=False, expected_gain=1.0)


def crossing(vx_hidden: float, reports: int = 20, x: float = 22.5) -> list[Expectation]:
    """Track 0 owns the blob at (x, 22.5); track 1 expects its target 2 m away, hidden in it."""
    return [Expectation(x=x, y=22.5, sigma=1.0, vx=1.2, vy=0.0, reports=reports, unreported=1),
            Expectation(x=x + 1.0, y=24.2, sigma=1.0, vx=vx_hidden, vy=-1.2, reports=reports, unreported=1)]


def test_a_track_hidden_in_another_tracks_blob_gets_a_loose_shared_copy():
    deployment = grid_deployment()
    fusion = GridFusion(deployment, HIDING)
    detecting = detecting_near(fusion, deployment, [(22.5, 22.5), (23.5, 24.2)])
    reports = fusion.reports(detecting, crossing(vx_hidden=-1.2))
    own = [r for r in reports if not r.shared]
    copies = [r for r in reports if r.shared]
    assert len(own) == 1 and len(copies) == 1
    assert (copies[0].x, copies[0].y) == (own[0].x, own[0].y)
    assert copies[0].cov[0][0] >= own[0].cov[0][0] + 16.0  # (R/2)² looser: no pull onto the other
    # two people side by side move alike and get copies too, unless shared_speed asks for
    # tracks that move differently; no copies for tracks too young to trust
    alike = crossing(vx_hidden=1.2)[:1] + [
        Expectation(x=23.5, y=24.2, sigma=1.0, vx=1.2, vy=0.0, reports=20, unreported=1)]
    assert any(r.shared for r in fusion.reports(detecting, alike))
    assert not any(r.shared for r in GridFusion(deployment, replace(HIDING, shared_speed=0.5)).reports(detecting, alike))
    assert not any(r.shared for r in fusion.reports(detecting, crossing(vx_hidden=-1.2, reports=2)))
    # a track unreported in the previous scan still gets copies; one unreported longer does not
    late = [crossing(vx_hidden=-1.2)[0], replace(crossing(vx_hidden=-1.2)[1], unreported=2)]
    assert any(r.shared for r in fusion.reports(detecting, late))
    later = [late[0], replace(late[1], unreported=3)]
    assert not any(r.shared for r in fusion.reports(detecting, later))
    assert not any(r.shared for r in GridFusion(deployment, replace(HIDING, shared=False)).reports(
        detecting, crossing(vx_hidden=-1.2)))
    # with shared_chain, only a track with a report of its own in the last scans gets copies:
    # copies may not keep a track alive on their own (a duplicate of one person)
    chained = GridFusion(deployment, replace(HIDING, shared_chain=2))
    own_lately, own_long_ago, own_none = ([crossing(vx_hidden=-1.2)[0], replace(crossing(vx_hidden=-1.2)[1], unreported_own=k)]
                                          for k in (2, 3, None))
    assert any(r.shared for r in chained.reports(detecting, own_lately))
    assert not any(r.shared for r in chained.reports(detecting, own_long_ago))
    assert not any(r.shared for r in chained.reports(detecting, own_none))


def test_no_shared_copy_near_the_edge_of_the_sensor_field_where_people_leave():
    deployment = grid_deployment()  # sensors on 0..45 m in x and y
    fusion = GridFusion(deployment, HIDING)
    assert fusion.depth(22.5, 22.5) == 22.5 and fusion.depth(0.0, 30.0) == 0.0 and fusion.depth(-3.0, 30.0) == -3.0
    at_edge = crossing(vx_hidden=-1.2, x=2.0)  # the hidden track's prediction is 3 m inside
    detecting = detecting_near(fusion, deployment, [(2.0, 22.5), (3.0, 24.2)])
    assert [r.shared for r in fusion.reports(detecting, at_edge)] == [False]  # under half the 8 m range
    nearer = GridFusion(deployment, replace(HIDING, shared_edge=0.25))  # 2 m of the 8 m range
    assert [r.shared for r in nearer.reports(detecting, at_edge)] == [False, True]
    line = Deployment(name="line", units="m", region=Region(xmin=-5, ymin=-5, xmax=50, ymax=5),
                      sensors=[DiskSensor(id=f"s{i}", x=5.0 * i, y=0.0, range=8.0, pd=0.7, pfa=0.05, period=0.5)
                               for i in range(10)])
    assert GridFusion(line).depth(20.0, 0.0) == math.inf  # a line of sensors encloses no area


def test_a_new_track_cannot_begin_with_a_shared_copy():
    copy = PositionReport(x=10.0, y=10.0, cov=((20.0, 0.0), (0.0, 20.0)), weight=0.0, shared=True)
    tracker = OnlineMCMCDA(MCMCDAConfig(seed=0, n_mc=300, window=10))  # all 8 scans stay in the window
    for k in range(8):  # a shared copy, then a real report moving on at 1 m/s, every scan
        real = PositionReport(x=10.0 + 0.5 * k, y=12.0, cov=((1.0, 0.0), (0.0, 1.0)))
        tracker.step(PositionReports(t=0.5 * k, reports=[copy, real]))
    starts = [tracker._reports[t.reports[0]] for t in tracker._tracks if t.anchor is None and t.reports]
    assert starts and not any(rep.shared for rep in starts)


def test_two_tracks_whose_people_share_detections_each_keep_a_target():
    # Two people 7 m apart, 8 m disks: most detections are in both disks. This scan's pattern
    # (9 of the 12 sensors covering either person detect) is one where a target placed for the
    # first track takes the shared detections, leaving the second too little support *given*
    # it; judged on the scan alone, as step 1 of the fit does, each track keeps its target.
    deployment = grid_deployment()
    fusion = GridFusion(deployment)
    detecting = np.zeros(len(fusion.ids), dtype=bool)
    for sensor in ("n0204", "n0304", "n0305", "n0403", "n0404", "n0405", "n0503", "n0505", "n0605"):
        detecting[fusion.index[sensor]] = True
    people = [(17.0, 21.0), (24.0, 21.0)]
    expected = [Expectation(x=x, y=y, sigma=1.0, vx=vx, vy=0.0, reports=20, unreported=1)
                for (x, y), vx in zip(people, (1.0, -1.0))]
    reports = fusion.reports(detecting, expected)
    assert len(reports) == 2 and not any(r.shared for r in reports)
    for x, y in people:
        assert any(near(r, x, y, 2.5) for r in reports)


def _log_likelihood_ratio(deployment, fusion, detecting, cells) -> float:
    """ℓ of targets at ``cells`` against no target, straight from the model: a sensor that n ≥ 1
    of them cover detects with 1 − (1 − pd)^n (each detected on its own), else with pfa."""
    total = 0.0
    for s in deployment.sensors:
        n = sum(math.hypot(s.x - x, s.y - y) <= s.range for x, y in fusion.cells[cells])
        if n:
            p = 1 - (1 - s.pd) ** n
            total += math.log(p / s.pfa) if detecting[fusion.index[s.id]] else math.log((1 - p) / (1 - s.pfa))
    return total


def test_with_multiplicity_a_targets_gain_is_the_model_s_likelihood_ratio_of_adding_it():
    deployment = grid_deployment()
    fusion = GridFusion(deployment, FusionConfig(multiplicity=True))
    detecting = np.random.default_rng(3).random(len(fusion.ids)) < 0.4
    scan = FitScan(fusion._fit, detecting)
    rng = np.random.default_rng(5)
    for cell in rng.choice(len(fusion.cells), size=4, replace=False):
        scan._append(_Target(cell=int(cell)))
    cells = [t.cell for t in scan.targets]
    assert scan._total() == pytest.approx(_log_likelihood_ratio(deployment, fusion, detecting, cells), abs=1e-6)
    scan._move(scan.targets[1], int(rng.integers(len(fusion.cells))))  # gains kept per cell follow a move
    cells = [t.cell for t in scan.targets]
    for c in rng.choice(len(fusion.cells), size=25, replace=False):
        with_c = _log_likelihood_ratio(deployment, fusion, detecting, [*cells, c])
        assert scan.base[c] == pytest.approx(with_c - scan._total(), abs=1e-6)
        # without target 2, and with one more at c: as a split's ascent scores a pair
        rest = [cell for i, cell in enumerate(cells) if i != 2]
        assert scan._total(2, extra=[c]) == pytest.approx(
            _log_likelihood_ratio(deployment, fusion, detecting, [*rest, c]), abs=1e-6)


def test_with_multiplicity_two_tracked_people_in_one_blob_keep_two_reports_more_often():
    # 3 m apart under 8 m disks; each person detected on their own, as the simulator draws them
    deployment = grid_deployment()
    people = [(20.0, 22.0), (23.0, 22.0)]
    tracked = [Expectation(x=x, y=y, sigma=1.0, vx=1.0, vy=0.0, reports=20, unreported=1) for x, y in people]
    positions = np.array([(s.x, s.y) for s in deployment.sensors])

    def share(multiplicity: bool, walkers) -> tuple[float, float]:
        fusion = GridFusion(deployment, FusionConfig(multiplicity=multiplicity, shared=False))
        n = sum(np.hypot(positions[:, 0] - x, positions[:, 1] - y) <= 8.0 for x, y in walkers)
        rng = np.random.default_rng(7)
        both = two = 0
        for _ in range(200):
            fired = rng.random(len(n)) < np.where(n > 0, 1 - 0.3 ** n, 0.05)
            detecting = np.zeros(len(fusion.ids), dtype=bool)
            detecting[[fusion.index[s.id] for s in deployment.sensors]] = fired
            reports = fusion.reports(detecting, tracked)
            both += all(any(near(r, x, y, 2.0) for r in reports) for x, y in people)
            two += len(reports) >= 2
        return both / 200, two / 200

    (union_both, _), (mult_both, _) = share(False, people), share(True, people)
    assert mult_both >= union_both + 0.08  # 0.24 against 0.105 with these draws
    # one person where both tracks expect theirs: no more second reports than over the union
    (_, union_two), (_, mult_two) = share(False, people[:1]), share(True, people[:1])
    assert mult_two <= union_two


def test_copies_need_evidence_that_the_hidden_track_s_target_may_be_there():
    # track 0 on a person; track 1 expects its target 3 m away. Alone there, track 1 is a
    # duplicate of the person; with a second person there, it is their hidden partner
    deployment = grid_deployment()
    people = [(20.0, 22.0), (23.0, 22.0)]
    tracked = [Expectation(x=x, y=y, sigma=sigma, vx=1.0, vy=0.0, reports=20, unreported=1)
               for (x, y), sigma in zip(people, (1.0, 2.5))]
    positions = np.array([(s.x, s.y) for s in deployment.sensors])

    def copied(bar: float | None, walkers) -> float:
        fusion = GridFusion(deployment, FusionConfig(shared_support=bar))
        n = sum(np.hypot(positions[:, 0] - x, positions[:, 1] - y) <= 8.0 for x, y in walkers)
        rng = np.random.default_rng(7)
        copies = 0
        for _ in range(300):
            fired = rng.random(len(n)) < np.where(n > 0, 1 - 0.3 ** n, 0.05)
            detecting = np.zeros(len(fusion.ids), dtype=bool)
            detecting[[fusion.index[s.id] for s in deployment.sensors]] = fired
            copies += any(r.shared for r in fusion.reports(detecting, tracked))
        return copies / 300

    assert copied(-4.0, people[:1]) <= copied(None, people[:1]) - 0.1  # 0.73 against 0.90
    assert copied(-4.0, people) >= copied(None, people) - 0.01  # 0.27 against 0.27
    assert copied(-1e9, people[:1]) == copied(None, people[:1])


class _WholeGrid(FitScan):
    """The fit with every gain recomputed over the whole grid from the targets' cells by
    scipy's ``cover @ weights`` (how it was computed before gains were kept per cell and
    updated only where a sensor changes)."""

    def _whole(self, k, extra) -> np.ndarray:
        count = np.zeros(len(self.weight), dtype=np.int32)  # the last entry pads TargetFit.sums
        for i, target in enumerate(self.targets):
            if i != k:
                count[self.fit.sensors_of[target.cell]] += 1
        for c in extra:
            count[self.fit.sensors_of[c]] += 1
        return self.grid.cover @ self._marginal(count)[:-1]

    def _recount(self, remove, add) -> None:
        super()._recount(remove, add)
        self.base = self._whole(None, ())

    def _gains_all(self, k, extra=()) -> np.ndarray:
        return self._whole(k, extra)

    def _gains_on(self, rows, k=None, extra=()) -> np.ndarray:
        return self._whole(k, extra)[rows]

    def _best_all(self, k, extra=()) -> int:
        return int(np.argmax(self._whole(k, extra)))


def _tracks(folder: Path) -> list[tuple]:
    dataset = open_dataset(folder)
    return [(ts.t, tr.track, tr.x, tr.y, tr.vx, tr.vy) for ts in run_tracker(dataset, make_tracker("mcmcda", dataset.deployment))
            if isinstance(ts, TrackSet) for tr in ts.tracks]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["darpa-grid-1", "darpa-grid-2", "darpa-grid-3"])
def test_local_gain_updates_give_the_whole_grid_fit_exactly(name, monkeypatch):
    folder = DATASETS / name
    local = _tracks(folder)
    monkeypatch.setattr(target_fit, "FitScan", _WholeGrid)
    whole = _tracks(folder)
    assert len(local) > 50 and local == whole  # bit for bit: the same sums over the same sensors


def test_the_cells_covering_some_sensors_are_the_union_of_their_cells_in_index_order():
    fit = target_fit.TargetFit(GridFusion(grid_deployment()))
    rng = np.random.default_rng(4)
    n = len(fit._cells_of)
    for size in (0, 1, 2, 5, 12, n):
        sensors = rng.choice(n, size=size, replace=False)
        union = np.unique(np.concatenate([fit._cells_of[s] for s in sensors] + [np.zeros(0, dtype=np.intp)]))
        assert np.array_equal(fit.cells_covering(sensors), union)


def test_a_checkpointed_fit_leaves_out_its_split_starts_and_makes_them_again():
    fit = target_fit.TargetFit(GridFusion(grid_deployment()))
    starts = fit.split_starts(10)
    assert len(starts) == len(target_fit._SPLIT_ANGLES) and fit.split_starts(10) is starts  # kept per cell
    restored = pickle.loads(pickle.dumps(fit))
    assert restored._split_starts == {} and restored.split_starts(10) == starts
    older = target_fit.TargetFit.__new__(target_fit.TargetFit)  # a checkpoint from before the table
    older.__setstate__({k: v for k, v in fit.__dict__.items() if k != "_split_starts"})
    assert older.split_starts(10) == starts
