"""Metrics of bintrack.evaluation.metrics on hand-computed cases."""

import math

import numpy as np
import pytest

from bintrack.formats import ObjectRow, TrackRow, TruthRow
from bintrack.deployment_model import Deployment
from bintrack.evaluation.metrics import (
    ErrorStats,
    area_between,
    entry_exit_errors,
    gospa,
    location_errors,
    match_objects,
    multi_target_scores,
    sensing_range,
    trajectory_error,
    truth_paths,
    velocity_errors,
)


def straight(target="a", t0=0.0, t1=10.0, start=(0.0, 0.0), end=(10.0, 0.0), steps=1):
    """Truth rows of a straight constant-speed pass, ``steps`` segments."""
    return [TruthRow(t0 + (t1 - t0) * k / steps, target, start[0] + (end[0] - start[0]) * k / steps,
                     start[1] + (end[1] - start[1]) * k / steps) for k in range(steps + 1)]


# --------------------------------------------------------------------------- truth


def test_truth_interpolates_linearly_and_exists_only_between_first_and_last_row():
    path = truth_paths([TruthRow(4, "a", 4, 4), TruthRow(0, "a", 0, 0), TruthRow(2, "a", 2, 0)])["a"]
    assert np.allclose(path.position(1.0), (1, 0))
    assert np.allclose(path.position(3.0), (3, 2))
    assert np.isnan(path.position(-0.5)).all() and np.isnan(path.position(4.5)).all()
    assert path.exists([0, 4, 4.0000005]).all() and not path.exists(4.01)
    assert np.allclose(path.velocity([0.5, 2.0, 4.0]), [(1, 0), (1, 2), (1, 2)])
    assert path.length == pytest.approx(2 + math.sqrt(20))
    assert np.allclose(path.between(1, 3), [(1, 0), (2, 0), (3, 2)])


def test_truth_keeps_the_first_row_of_a_repeated_time_and_a_single_row_is_still():
    paths = truth_paths([TruthRow(0, "b", 5, 5), TruthRow(0, "b", 9, 9), TruthRow(1, "c", 1, 1)])
    assert np.allclose(paths["b"].xy, [(5, 5)])
    assert np.allclose(paths["c"].velocity(1.0), (0, 0))
    assert sorted(paths) == ["b", "c"]


def test_sensing_range_is_the_median_range_of_disk_and_sector_sensors():
    dep = Deployment.model_validate({
        "name": "r", "units": "m", "region": {"xmin": 0, "ymin": 0, "xmax": 1, "ymax": 1},
        "sensors": [{"id": "a", "kind": "disk", "x": 0, "y": 0, "range": 2},
                    {"id": "b", "kind": "sector", "x": 0, "y": 0, "range": 5, "sectors": 4},
                    {"id": "c", "kind": "disk", "x": 0, "y": 0, "range": 9},
                    {"id": "m", "kind": "motion", "x": 0, "y": 0, "period": 1}]})
    assert sensing_range(dep) == 5
    only_motion = dep.model_copy(update={"sensors": dep.sensors[3:]})
    assert sensing_range(only_motion) is None


# --------------------------------------------------------------------------- single target


def test_location_error_is_to_the_nearest_existing_target():
    paths = truth_paths(straight("a") + straight("b", start=(0, 10), end=(10, 10)) + straight("c", 20, 30))
    rows = [TrackRow(5, 0, 5, 3), TrackRow(5, 0, 5, 8), TrackRow(25, 0, 0, 0), TrackRow(15, 0, 0, 0)]
    errors = location_errors(rows, paths)
    assert errors[:2] == pytest.approx([3, 2])
    assert errors[2] == pytest.approx(math.hypot(5, 0))  # only c exists at t = 25, at (5, 0)
    assert np.isnan(errors[3])  # nobody exists at t = 15
    stats = ErrorStats.of(errors)
    assert stats.n == 3 and stats.max == pytest.approx(5) and stats.median == pytest.approx(3)


def test_constant_offset_from_a_straight_truth_gives_trajectory_error_d():
    path = truth_paths(straight(steps=4))["a"]
    d = 0.7
    rows = [TrackRow(t, 0, t, d) for t in np.linspace(0, 10, 21)]
    assert trajectory_error(rows, path) == pytest.approx(d)
    # only the real path over the estimates' span counts: [2, 6] here
    rows = [TrackRow(t, 0, t, -d) for t in (2.0, 4.0, 6.0)]
    assert trajectory_error(rows, path) == pytest.approx(d)


def test_square_detour_area_over_length():
    path = truth_paths(straight())["a"]
    detour = [(0, 0, 0), (3, 3, 0), (4, 3, 2), (6, 7, 2), (7, 7, 0), (10, 10, 0)]
    rows = [TrackRow(t, 0, x, y) for t, x, y in detour]
    assert trajectory_error(rows, path) == pytest.approx(4 * 2 / 10)


def test_crossing_paths_count_each_enclosed_region_once():
    # a bow tie: the signed area of the ring would cancel to 0
    assert area_between(np.array([(0, 1), (10, -1)]), np.array([(0, 0), (10, 0)])) == pytest.approx(5)
    path = truth_paths(straight())["a"]
    rows = [TrackRow(0, 0, 0, 1), TrackRow(10, 0, 10, -1)]
    assert trajectory_error(rows, path) == pytest.approx(0.5)


def test_trajectory_error_needs_two_estimates_in_the_targets_life():
    path = truth_paths(straight())["a"]
    assert trajectory_error([TrackRow(5, 0, 5, 1), TrackRow(20, 0, 5, 1)], path) is None


def test_velocity_error_uses_the_slope_of_the_truth_and_skips_rows_without_velocity():
    path = truth_paths([TruthRow(0, "a", 0, 0), TruthRow(10, "a", 10, 0), TruthRow(20, "a", 10, 20)])["a"]
    rows = [TrackRow(5, 0, 5, 0, 1.0, 0.0), TrackRow(15, 0, 10, 10, 3.0, 2.0), TrackRow(16, 0, 10, 12),
            TrackRow(30, 0, 10, 20, 0.0, 2.0)]
    assert velocity_errors(rows, path) == pytest.approx([0, 3])


# --------------------------------------------------------------------------- GOSPA


def test_gospa_of_known_sets():
    c = 10.0
    assert gospa([], [], c).distance == 0
    one_missed = gospa([], [(1, 1)], c)
    assert one_missed.distance == pytest.approx(math.sqrt(c**2 / 2))
    assert (one_missed.n_missed, one_missed.n_false, one_missed.missed) == (1, 0, pytest.approx(50))
    one_false = gospa([(1, 1)], [], c)
    assert one_false.distance == pytest.approx(c / math.sqrt(2)) and one_false.n_false == 1
    near = gospa([(3, 4)], [(0, 0)], c)
    assert near.distance == pytest.approx(5) and near.pairs == ((0, 0),) and near.localisation == pytest.approx(25)
    far = gospa([(30, 40)], [(0, 0)], c)
    assert far.distance == pytest.approx(c) and far.pairs == () and (far.n_missed, far.n_false) == (1, 1)


def test_gospa_assigns_optimally_and_its_parts_add_up():
    # estimates 1 off each of two targets, a third estimate far from both, and a missed target
    truths = [(0, 0), (10, 0), (100, 100)]
    estimates = [(10, 1), (0, 1), (50, 50)]
    g = gospa(estimates, truths, c=5)
    assert sorted(g.pairs) == [(0, 1), (1, 0)]
    assert g.localisation == pytest.approx(2)
    assert (g.n_missed, g.n_false) == (1, 1)
    assert g.distance**2 == pytest.approx(g.localisation + g.missed + g.false)
    assert g.distance == pytest.approx(math.sqrt(2 + 25 / 2 + 25 / 2))


def test_gospa_rejects_a_bad_cut_off():
    with pytest.raises(ValueError):
        gospa([(0, 0)], [(0, 0)], c=0)


def test_identity_switches_and_target_counts():
    # two targets on parallel lines y = 0 and y = 10, t = 0..4
    paths = truth_paths(straight("a", 0, 4, (0, 0), (4, 0), 4) + straight("b", 0, 4, (0, 10), (4, 10), 4))
    rows = []
    for t in range(5):
        # track 1 follows a, track 2 follows b, except: t = 2 a is followed by track 3 (switch),
        # t = 3 a is only followed from afar (no assignment), t = 4 track 3 again (no switch)
        on_a = {0: 1, 1: 1, 2: 3, 3: None, 4: 3}[t]
        rows.append(TrackRow(t, 2, t, 10.5))
        if on_a is not None:
            rows.append(TrackRow(t, on_a, t, 0.5))
        else:
            rows.append(TrackRow(t, 7, t, -50))
    scores = multi_target_scores(rows, paths, c=5)
    assert scores.identity_switches == 1
    assert len(scores.scans) == 5
    assert [s.gospa.n_missed for s in scores.scans] == [0, 0, 0, 1, 0]
    assert scores.count_error_mean == 0 and scores.count_correct == 1
    assert scores.missed_targets_mean == pytest.approx(0.2) and scores.false_tracks_mean == pytest.approx(0.2)
    expected = [math.sqrt(0.5)] * 3 + [math.sqrt(0.25 + 25)] + [math.sqrt(0.5)]
    assert scores.gospa_mean == pytest.approx(np.mean(expected))


def test_swapped_tracks_at_a_crossing_count_two_switches_and_extra_tracks_count():
    paths = truth_paths(straight("a", 0, 2, (0, 0), (2, 0), 2) + straight("b", 0, 2, (0, 10), (2, 10), 2))
    rows = [TrackRow(0, 1, 0, 0), TrackRow(0, 2, 0, 10),
            TrackRow(1, 2, 1, 0), TrackRow(1, 1, 1, 10),
            TrackRow(2, 2, 2, 0), TrackRow(2, 1, 2, 10), TrackRow(2, 9, 50, 50)]
    scores = multi_target_scores(rows, paths, c=5)
    assert scores.identity_switches == 2
    assert scores.count_error_mean == pytest.approx(1 / 3)
    assert scores.count_correct == pytest.approx(2 / 3)
    # a target that does not exist yet is not missed
    late = truth_paths(straight("c", 5, 6))
    assert multi_target_scores([TrackRow(0, 1, 0, 0)], late, c=5).scans[0].n_targets == 0


def test_tracks_that_keep_their_people_through_a_close_pass_count_no_switch():
    # a walks (0,0) → (10,10), b walks (0,10) → (10,0); they meet at (5,5) at t = 5
    paths = truth_paths(straight("a", 0, 10, (0, 0), (10, 10), 10) + straight("b", 0, 10, (0, 10), (10, 0), 10))
    rows = []
    for t in range(11):
        a, b = paths["a"].position(t), paths["b"].position(t)
        if t == 4:
            # each track is 1.1 m from its own person and 0.9 m from the other: the optimal
            # assignment of this scan alone swaps them
            rows += [TrackRow(t, 1, 4.0, 5.1), TrackRow(t, 2, 4.0, 4.9)]
        else:
            rows += [TrackRow(t, 1, a[0], a[1]), TrackRow(t, 2, b[0], b[1])]
    scores = multi_target_scores(rows, paths, c=5)
    assert scores.scans[4].gospa.pairs == ((0, 1), (1, 0))
    assert scores.identity_switches == 0
    # the same tracks traded between the people for good are two switches, once a kept pair
    # is no longer within c
    traded = [TrackRow(r.t, 3 - r.track if r.t >= 6 else r.track, r.x, r.y) for r in rows]
    assert multi_target_scores(traded, paths, c=5).identity_switches == 2


# --------------------------------------------------------------------------- line-sensor objects


def test_entry_exit_errors_of_objects_matched_by_time_overlap():
    paths = truth_paths(straight("p1", 0, 10, (0, 0), (16, 8)) + straight("p2", 20, 30, (0, 8), (16, 0)))
    objects = [
        ObjectRow(2, 21, 29, 0, 5, 16, 0, 1.6, -0.8),   # p2: entry 3 off, exit exact
        ObjectRow(1, 1, 9, 3, 4, 16, 8, 1.6, 0.8),      # p1: entry 5 off, exit exact
        ObjectRow(3, 40, 45, 0, 0, 1, 1, 1, 1),         # nothing then
    ]
    assert {o.object: target for o, target in match_objects(objects, paths)} == {1: "p1", 2: "p2"}
    errors = entry_exit_errors(objects, paths)
    assert [(e.object, e.target) for e in errors] == [(1, "p1"), (2, "p2")]
    assert [e.entry for e in errors] == pytest.approx([5, 3])
    assert [e.exit for e in errors] == pytest.approx([0, 0])


def test_one_target_is_matched_to_one_object_only():
    paths = truth_paths(straight("p1", 0, 10))
    objects = [ObjectRow(1, 0, 2, 0, 0, 10, 0, 1, 0), ObjectRow(2, 1, 9, 0, 1, 10, 0, 1, 0)]
    assert [(o.object, t) for o, t in match_objects(objects, paths)] == [(2, "p1")]


def test_mean_ci_is_the_student_t_interval():
    from bintrack.evaluation.metrics import mean_ci

    mean, half = mean_ci([1.0, 2.0, 3.0, 4.0])
    assert mean == 2.5
    assert half == pytest.approx(3.182446 * 1.290994 / 2.0, rel=1e-5)  # t(0.975, 3) · s / √n
    assert np.isnan(mean_ci([5.0])[1])
