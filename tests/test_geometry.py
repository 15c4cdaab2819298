"""Geometry helpers: property tests (hypothesis) and a few hand-computed cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from bintrack import geometry
from bintrack.geometry import TWO_PI

TOL = 1e-9

coord = st.floats(-100.0, 100.0, allow_nan=False)
point = st.tuples(coord, coord)
radius = st.floats(0.1, 100.0)
velocity = st.tuples(st.floats(-10.0, 10.0), st.floats(-10.0, 10.0)).filter(lambda v: math.hypot(*v) > 1e-3)
duration = st.floats(0.01, 50.0)
angle = st.floats(-20.0, 20.0)
omega = st.floats(-2.0, 2.0).filter(lambda w: abs(w) > 1e-3)

settings.register_profile("bintrack", deadline=None, max_examples=150)
settings.load_profile("bintrack")


def _on_segment(p0, v, tau):
    return np.array(p0) + np.outer(tau, v)


def _on_arc(centre, rho, phi0, w, tau):
    phi = phi0 + w * np.asarray(tau)
    return np.stack([centre[0] + rho * np.cos(phi), centre[1] + rho * np.sin(phi)], axis=-1)


@given(st.floats(-1e6, 1e6))
def test_normalized_angle_in_range_and_congruent(theta):
    wrapped = geometry.normalize_angle(theta)
    assert 0.0 <= wrapped < TWO_PI
    turns = (theta - wrapped) / TWO_PI
    assert abs(turns - round(turns)) < 1e-6


def test_normalize_angle_arrays_and_tiny_negative():
    out = geometry.normalize_angle(np.array([-1e-18, 0.0, TWO_PI, -math.pi / 2]))
    assert out.tolist() == pytest.approx([0.0, 0.0, 0.0, 1.5 * math.pi])


@given(point, radius, point, radius)
def test_circle_circle_points_lie_on_both_circles(c1, r1, c2, r2):
    points = geometry.circle_circle_intersections(c1, r1, c2, r2)
    assert points.shape[1] == 2 and len(points) <= 2
    for x, y in points:
        assert abs(math.hypot(x - c1[0], y - c1[1]) - r1) < TOL * 10
        assert abs(math.hypot(x - c2[0], y - c2[1]) - r2) < TOL * 10
    d = math.hypot(c2[0] - c1[0], c2[1] - c1[1])
    if abs(r1 - r2) + 1e-6 < d < r1 + r2 - 1e-6:
        assert len(points) == 2


def test_circle_circle_by_hand():
    points = geometry.circle_circle_intersections((0, 0), 5, (8, 0), 5)
    np.testing.assert_allclose(points, [[4, -3], [4, 3]])
    assert geometry.circle_circle_angles((0, 0), 5, (8, 0), 5).tolist() == pytest.approx(
        [geometry.normalize_angle(-math.atan2(3, 4)), math.atan2(3, 4)])
    assert len(geometry.circle_circle_intersections((0, 0), 1, (5, 0), 1)) == 0
    assert len(geometry.circle_circle_intersections((0, 0), 5, (1, 0), 1)) == 0
    np.testing.assert_allclose(geometry.circle_circle_intersections((0, 0), 1, (2, 0), 1), [[1, 0]])


@given(point, velocity, duration, point, radius)
def test_segment_circle_times_lie_on_circle(p0, v, T, c, r):
    tau = geometry.segment_circle_times(p0, v, T, c, r)
    assert np.all((tau >= 0) & (tau <= T)) and np.all(np.diff(tau) >= 0)
    for x, y in _on_segment(p0, v, tau):
        assert abs(math.hypot(x - c[0], y - c[1]) - r) < TOL
    # a path from inside to outside (or back) crosses the circle at least once
    d0 = math.hypot(p0[0] - c[0], p0[1] - c[1])
    d1 = math.hypot(p0[0] + v[0] * T - c[0], p0[1] + v[1] * T - c[1])
    if (d0 - r) * (d1 - r) < 0:
        assert len(tau) >= 1


def test_segment_circle_by_hand():
    # along y = 6 at 2 units/s past a circle of radius 10 at (50, 0): x = 42 and 58
    assert geometry.segment_circle_times((0, 6), (2, 0), 100, (50, 0), 10).tolist() == pytest.approx([21, 29], abs=1e-12)
    assert geometry.segment_circle_times((0, 10), (1, 0), 100, (50, 0), 10).tolist() == pytest.approx([50])
    assert len(geometry.segment_circle_times((0, 11), (1, 0), 100, (50, 0), 10)) == 0
    assert len(geometry.segment_circle_times((0, 0), (0, 0), 100, (0, 0), 10)) == 0


@given(point, velocity, duration, st.floats(-1.0, 1.0), st.floats(-1.0, 1.0))
def test_segment_line_times_lie_on_line(p0, v, T, a, b):
    assume(abs(a) + abs(b) > 1e-3)
    for x, y in _on_segment(p0, v, geometry.segment_line_times(p0, v, T, a, b)):
        assert abs(a * x + b * y - 1.0) < TOL


@given(point, velocity, duration, point, angle, radius)
def test_segment_ray_times_lie_on_ray_within_length(p0, v, T, origin, theta, length):
    tau = geometry.segment_ray_times(p0, v, T, origin, theta, length)
    u = (math.cos(theta), math.sin(theta))
    for x, y in _on_segment(p0, v, tau):
        rx, ry = x - origin[0], y - origin[1]
        assert abs(rx * u[1] - ry * u[0]) < TOL
        assert -TOL <= rx * u[0] + ry * u[1] <= length + TOL


def test_segment_ray_by_hand():
    # the ray from (50, 0) straight up, crossed by y = 3 at x = 50; y = 12 is beyond the length 10
    assert geometry.segment_ray_times((0, 3), (2, 0), 100, (50, 0), math.pi / 2, 10).tolist() == pytest.approx([25])
    assert len(geometry.segment_ray_times((0, 12), (2, 0), 100, (50, 0), math.pi / 2, 10)) == 0
    assert len(geometry.segment_ray_times((0, -3), (2, 0), 100, (50, 0), math.pi / 2, 10)) == 0
    # moving along the ray itself (+x from (50, 0)) never crosses it
    assert len(geometry.segment_ray_times((40, 0), (1, 0), 100, (50, 0), 0.0, 10)) == 0


@given(st.floats(-10, 10), st.floats(-10, 10), st.floats(-15, 15))
def test_harmonic_angles_solve_the_equation(A, B, C):
    for phi in geometry.harmonic_angles(A, B, C):
        assert 0 <= phi < TWO_PI
        assert abs(A * math.cos(phi) + B * math.sin(phi) - C) < 1e-9
    if math.hypot(A, B) > abs(C) + 1e-9:
        assert len(geometry.harmonic_angles(A, B, C)) == 2


@given(point, radius, angle, omega, duration, point, radius)
def test_arc_circle_times_lie_on_circle(centre, rho, phi0, w, T, c, r):
    tau = geometry.arc_circle_times(centre, rho, phi0, w, T, c, r)
    assert np.all((tau >= 0) & (tau <= T)) and np.all(np.diff(tau) >= 0)
    for x, y in _on_arc(centre, rho, phi0, w, tau):
        assert abs(math.hypot(x - c[0], y - c[1]) - r) < TOL * 10


@given(point, radius, angle, omega, duration, st.floats(-1.0, 1.0), st.floats(-1.0, 1.0))
def test_arc_line_times_lie_on_line(centre, rho, phi0, w, T, a, b):
    assume(abs(a) + abs(b) > 1e-3)
    for x, y in _on_arc(centre, rho, phi0, w, geometry.arc_line_times(centre, rho, phi0, w, T, a, b)):
        assert abs(a * x + b * y - 1.0) < TOL


@given(point, radius, angle, omega, duration, point, angle, radius)
def test_arc_ray_times_lie_on_ray(centre, rho, phi0, w, T, origin, theta, length):
    u = (math.cos(theta), math.sin(theta))
    for x, y in _on_arc(centre, rho, phi0, w, geometry.arc_ray_times(centre, rho, phi0, w, T, origin, theta, length)):
        rx, ry = x - origin[0], y - origin[1]
        assert abs(rx * u[1] - ry * u[0]) < TOL * 10
        assert -TOL <= rx * u[0] + ry * u[1] <= length + TOL


def test_arc_times_by_hand_over_several_turns():
    # unit-speed circle of radius 10 about the origin from φ = 0, ω = 1 rad/s: it meets the
    # circle of radius 10 about (0, 10) at φ = π/6 and 5π/6, every 2π seconds
    tau = geometry.arc_circle_times((0, 0), 10, 0.0, 1.0, 2 * TWO_PI, (0, 10), 10)
    expected = [math.pi / 6, 5 * math.pi / 6, math.pi / 6 + TWO_PI, 5 * math.pi / 6 + TWO_PI]
    assert tau.tolist() == pytest.approx(expected, abs=1e-12)
    # clockwise: φ = −ωt reaches 5π/6 ≡ −7π/6 first
    tau = geometry.arc_circle_times((0, 0), 10, 0.0, -1.0, TWO_PI, (0, 10), 10)
    assert tau.tolist() == pytest.approx([7 * math.pi / 6, 11 * math.pi / 6], abs=1e-12)
    # the line x = 5 (a = 0.2, b = 0) at φ = ±π/3
    assert geometry.arc_line_times((0, 0), 10, 0.0, 1.0, TWO_PI, 0.2, 0.0).tolist() == pytest.approx(
        [math.pi / 3, 5 * math.pi / 3], abs=1e-12)
    # the ray from the origin along +y, length 20: crossed once per turn at φ = π/2
    assert geometry.arc_ray_times((0, 0), 10, 0.0, 1.0, TWO_PI, (0, 0), math.pi / 2, 20).tolist() == pytest.approx(
        [math.pi / 2], abs=1e-12)


def test_box_exit_distance():
    assert geometry.box_exit_distance((1, 1), (1, 0), 0, 0, 10, 5) == pytest.approx(9)
    assert geometry.box_exit_distance((1, 1), (0, -1), 0, 0, 10, 5) == pytest.approx(1)
    s = math.sqrt(0.5)
    assert geometry.box_exit_distance((5, 2.5), (s, s), 0, 0, 10, 5) == pytest.approx(2.5 / s)
