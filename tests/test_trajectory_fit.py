import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bintrack.metrics import area_between
from bintrack.trajectory_fit import fit_line, fit_trajectory, segment_groups


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
