import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bintrack.evaluation.metrics import area_between, polyline_length
from bintrack.trackers.arc.trajectory_fit import TrajectoryFitter, fit_line, fit_trajectory, segment_groups, trajectory_from_estimates


def test_weighted_line_ignores_a_down_weighted_outlier():
    xy = np.array([[0, 0], [1, 0], [2, 0], [3, 0], [1.5, 5.0]])
    line = fit_line(xy, np.array([10, 10, 10, 10, 0.001]))
    assert abs(line.direction[1]) < 1e-3 and line.direction[0] > 0
    heavy = fit_line(xy, np.ones(5))
    assert abs(heavy.centre[1] - 1.0) < 1e-9  # equal weights: the outlier pulls the centre


@given(st.floats(-np.pi, np.pi), st.floats(-100, 100), st.floats(-100, 100))
@settings(max_examples=50, deadline=None)
def test_a_line_of_any_direction_is_recovered_and_oriented_by_time(angle, x0, y0):
    u = np.array([np.cos(angle), np.sin(angle)])
    xy = np.array([x0, y0]) + np.outer(np.linspace(0, 50, 12), u)
    line = fit_line(xy, np.ones(12))
    assert np.allclose(line.direction, u, atol=1e-9)


def test_a_straight_noisy_path_is_one_segment_close_to_the_truth():
    rng = np.random.default_rng(3)
    t = np.linspace(0, 100, 30)
    truth = np.column_stack([t, 0.5 * t + 10])
    estimates = truth + rng.normal(0, 1.0, truth.shape)
    assert len(segment_groups(estimates, np.ones(30))) == 1
    path = fit_trajectory(estimates, np.ones(30))
    assert len(path) == 2
    error = area_between(path, truth) / np.linalg.norm(truth[-1] - truth[0])
    assert error < 0.5  # noise σ = 1: the fitted line is far closer than any single estimate


def test_a_right_angle_turn_gives_two_segments_meeting_at_the_corner():
    leg1 = np.column_stack([np.linspace(0, 60, 15), np.zeros(15)])
    leg2 = np.column_stack([np.full(15, 60.0), np.linspace(4, 60, 15)])
    xy = np.vstack([leg1, leg2])
    runs = segment_groups(xy, np.ones(30), group=5, eps=0.2)
    assert len(runs) == 2
    path = fit_trajectory(xy, np.ones(30), group=5, eps=0.2)
    assert len(path) == 3
    assert np.linalg.norm(path[1] - [60, 0]) < 1e-6


def test_eps_decides_what_counts_as_a_turn():
    angles = np.linspace(0, 0.6, 30)  # a gentle arc: 0.6 rad over 30 points
    xy = np.column_stack([np.cumsum(np.cos(angles)), np.cumsum(np.sin(angles))])
    assert len(segment_groups(xy, np.ones(30), group=6, eps=1.0)) == 1
    assert len(segment_groups(xy, np.ones(30), group=6, eps=0.05)) > 1


def test_only_the_last_cache_estimates_are_used():
    xy = np.column_stack([np.arange(100.0), np.zeros(100)])
    path = fit_trajectory(xy, np.ones(100), cache=30)
    assert path[0][0] == pytest.approx(70.0) and path[-1][0] == pytest.approx(99.0)


def test_bad_input_is_refused():
    with pytest.raises(ValueError):
        fit_line(np.array([[0.0, 0.0]]), np.array([1.0]))
    with pytest.raises(ValueError):
        fit_line(np.array([[0.0, 0.0], [1.0, 1.0]]), np.zeros(2))
    with pytest.raises(ValueError):
        segment_groups(np.zeros((5, 2)), np.ones(5), group=1)


# --------------------------------------------------------------------------- arc-tracker-like noise

R = 40.0  # sensing range, units


def _arc_estimates(truth: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Estimates like the arc tracker's at R = 40 (uniform-800, ideal model): eq. 2 weights
    log-normal about 33 (10th–90th percentiles ≈ 13–85, clipped to 6–800, as on simulated
    runs), so final arcs 2π/w; each estimate in a random direction within R·arc/2 of the truth
    (it lies on the final arc)."""
    weights = np.clip(np.exp(rng.normal(np.log(33.0), 0.75, len(truth))), 6.0, 800.0)
    arc = 2 * np.pi / weights
    angle = rng.uniform(0, 2 * np.pi, len(truth))
    error = (rng.uniform(0, 1, len(truth)) * R * arc / 2)[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
    return truth + error, weights


def _straight(rng, length=650.0, spacing=5.0):
    heading = rng.uniform(0, 2 * np.pi)
    s = np.sort(rng.uniform(0, length, int(length / spacing)))
    return np.column_stack([np.cos(heading) * s, np.sin(heading) * s]) + 400


@pytest.mark.parametrize("seed", range(20))
def test_a_straight_path_with_heavy_tailed_weights_is_one_segment(seed):
    rng = np.random.default_rng(seed)
    truth = _straight(rng)
    xy, weights = _arc_estimates(truth, rng)
    assert weights.max() / weights.min() > 20  # the weights are heavy-tailed, as on real runs
    runs = segment_groups(xy, weights)
    assert len(runs) == 1
    path = trajectory_from_estimates(xy, weights)
    assert len(path) == 2
    assert area_between(path, truth) / polyline_length(truth) < 0.5


def test_the_literal_one_group_test_is_what_fails_on_such_a_path():
    # the reason for the departures in the module docstring: one group's line against the
    # segment, without persistence or significance, splits a straight path many times
    rng = np.random.default_rng(1)
    truth = _straight(rng)
    xy, weights = _arc_estimates(truth, rng)
    false_turns = 0
    line = fit_line(xy[:6], weights[:6])
    start = 0
    for lo in range(6, len(xy) - 1, 6):
        hi = min(lo + 6, len(xy))
        candidate = fit_line(xy[lo:hi], weights[lo:hi])
        if abs(np.angle(np.exp(1j * (candidate.angle - line.angle)))) < 0.2:
            line = fit_line(xy[start:hi], weights[start:hi])
        else:
            false_turns += 1
            start, line = lo, candidate
    assert false_turns >= 3
    assert len(segment_groups(xy, weights)) == 1


def _turning(rng, turn, corner_at=300.0, length=650.0, spacing=5.0):
    heading = rng.uniform(0, 2 * np.pi)
    s = np.sort(rng.uniform(0, length, int(length / spacing)))
    u0 = np.array([np.cos(heading), np.sin(heading)])
    u1 = np.array([np.cos(heading + turn), np.sin(heading + turn)])
    corner = np.array([400.0, 400.0])
    before = s < corner_at
    truth = np.where(before[:, None], corner + np.outer(s - corner_at, u0), corner + np.outer(s - corner_at, u1))
    return truth, corner


def _heading(a, b):
    return float(np.arctan2(b[1] - a[1], b[0] - a[0]))


@pytest.mark.parametrize("turn", [np.radians(30), np.radians(-45), np.radians(90)])
@pytest.mark.parametrize("seed", range(8))
def test_a_real_turn_is_found_close_to_where_it_happens(turn, seed):
    rng = np.random.default_rng(100 + seed)
    truth, corner = _turning(rng, turn)
    xy, weights = _arc_estimates(truth, rng)
    path = trajectory_from_estimates(xy, weights)
    inner = path[1:-1]
    assert 1 <= len(inner) <= 2  # the turn is found (a sharp one may be cut by one short piece)
    # every vertex lies within R of the real corner: no false turn elsewhere
    assert np.all(np.linalg.norm(inner - corner, axis=1) < R)
    # the legs before and after have the right headings
    heading_in = _heading(truth[0], corner)
    assert abs(np.angle(np.exp(1j * (_heading(path[0], path[1]) - heading_in)))) < 0.05
    assert abs(np.angle(np.exp(1j * (_heading(path[-2], path[-1]) - heading_in - turn)))) < 0.05


def test_the_stream_fitter_matches_the_batch_function_and_reading_does_not_disturb_it():
    rng = np.random.default_rng(7)
    truth, _ = _turning(rng, np.radians(60))
    xy, weights = _arc_estimates(truth, rng)
    fitter = TrajectoryFitter()
    for i, ((x, y), w) in enumerate(zip(xy, weights)):
        fitter.add(x, y, w)
        if i % 7 == 0:
            fitter.polyline()  # a node may read its trajectory at any time
    assert np.allclose(fitter.polyline(), trajectory_from_estimates(xy, weights))
    runs = fitter.runs()
    assert runs[0].start == 0 and runs[-1].stop == len(xy)
    assert all(a.stop == b.start for a, b in zip(runs, runs[1:]))


def test_a_long_segment_is_fitted_to_all_its_estimates_not_only_the_cache():
    # the cache (k = 30) bounds memory; the segment's line comes from running moments of all
    # its estimates, so a long straight run is as good as one line through everything
    rng = np.random.default_rng(11)
    truth = _straight(rng)
    xy, weights = _arc_estimates(truth, rng)
    path = trajectory_from_estimates(xy, weights, k=30)
    one_line = fit_line(xy, weights)
    assert np.allclose(path[1] - path[0], np.ptp(one_line.project(xy)) * one_line.direction, atol=1e-6)


def test_without_noise_the_significance_check_changes_nothing():
    leg1 = np.column_stack([np.linspace(0, 60, 15), np.zeros(15)])
    leg2 = np.column_stack([np.full(15, 60.0), np.linspace(4, 60, 15)])
    xy = np.vstack([leg1, leg2])
    for z in (0.0, 3.0, 100.0):
        assert len(segment_groups(xy, np.ones(30), group=5, eps=0.2, z=z)) == 2


def test_weights_must_be_positive():
    with pytest.raises(ValueError):
        TrajectoryFitter().add(0.0, 0.0, 0.0)
    with pytest.raises(ValueError):
        TrajectoryFitter(cache=10, group=6)
