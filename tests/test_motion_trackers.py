"""Closer/farther estimators and trackers of paper 002 (velocity plane, SVM, PPR, random walk)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bintrack.trackers.motion.closer_farther import counters
from bintrack.trackers.motion.ppr_estimator import ppr_direction, ppr_fit
from bintrack.trackers.motion.svm_estimator import svm_fit, svm_velocity
from bintrack.trackers.motion.velocity_plane import velocity_plane
from bintrack.errors import TrackerConfigError
from bintrack.bus_payloads import Transition, VelocityEstimate
from bintrack.deployment_model import Deployment, MotionSensor, Region
from bintrack.pipeline import TrackerDriver
from bintrack.time_span import MAX_SILENCE
from bintrack.sim.scenarios import build_scenario, simulate
from bintrack.trackers.motion.tracker import (
    MOTION_TRACKERS,
    MotionRandomWalkTracker,
    PprTracker,
    SvmTracker,
    VelocityPlaneTracker,
)
from bintrack.transition_detector import TransitionDetector
from svm_reference import svm_fit_qp


def _angle_error(a: float, b: float) -> float:
    return abs((a - b + math.pi) % (2 * math.pi) - math.pi)


def _run(tracker, result, flush_every: bool = True) -> list[VelocityEstimate]:
    """The offline runner's loop (pipeline.run_tracker) on simulated events; with
    ``flush_every=False`` the tracker is flushed only at the end (a different watermark cadence)."""
    detector = TransitionDetector(result.deployment)
    driver = TrackerDriver(tracker)
    out: list[VelocityEstimate] = []
    for event in result.events:
        transition = detector.update(event)
        if transition is not None:
            if flush_every:
                out.extend(driver.advance(transition.t))
            driver.push(transition)
    out.extend(driver.finish())
    return out


@pytest.fixture(scope="module")
def constant_run():
    """100 sensors, a constant-velocity target at 2 m/s for 60 s, noiseless signs."""
    options = dict(nodes=100, trajectory="constant", speed=2.0, duration=60.0)
    result = simulate("motion", 11, **options)
    path = build_scenario("motion", 11, **options).trajectories[0]
    return result, path


def _labels(seed: int, nodes: int, duration: float = 60.0, trajectory: str = "constant"):
    scenario = build_scenario("motion", seed, nodes=nodes, trajectory=trajectory, duration=duration)
    positions = np.array([(s.x, s.y) for s in scenario.sensors])
    path = scenario.trajectories[0]
    times = np.arange(0.0, duration + 1e-9, 1.0)
    x, v = path.position(times), path.velocity(times)
    labels = np.where(((positions[None] - x[:, None]) * v[:, None]).sum(-1) > 0, 1, -1)
    return positions, labels, times, path


# --------------------------------------------------------------------------- estimators on a run


@pytest.mark.parametrize("name", ["velocity-plane", "svm", "ppr"])
def test_estimators_recover_constant_velocity(constant_run, name):
    result, path = constant_run
    out = _run(MOTION_TRACKERS[name](result.deployment), result)
    assert out and all(e.method == name and e.x is None and e.y is None for e in out)
    times = [e.t for e in out]
    assert times == sorted(set(times)) and all(float(t).is_integer() for t in times)  # one per period
    last = out[-1]
    v = path.velocity(np.array([last.t]))[0]
    assert math.degrees(_angle_error(math.atan2(last.vy, last.vx), math.atan2(v[1], v[0]))) < 1.0
    assert abs(math.hypot(last.vx, last.vy) / math.hypot(*v) - 1.0) < 0.02


def test_live_cadence_equals_offline(constant_run):
    """Flushing at every transition (live watermarks) or only at the end gives the same rows."""
    result, _ = constant_run
    for cls in (VelocityPlaneTracker, MotionRandomWalkTracker):
        assert _run(cls(result.deployment), result, True) == _run(cls(result.deployment), result, False)


def test_random_walk_tracker_is_deterministic_and_bounded(constant_run):
    result, path = constant_run
    first = _run(MotionRandomWalkTracker(result.deployment, seed=3), result)
    assert first == _run(MotionRandomWalkTracker(result.deployment, seed=3), result)
    assert all(e.method == "motion-rw" and e.x is not None for e in first)
    region = result.deployment.region
    assert all(region.xmin <= e.x <= region.xmax and region.ymin <= e.y <= region.ymax for e in first)
    # along the heading the position is observable: the band keeps it within a few metres
    v = path.velocity(np.array([0.0]))[0]
    u = v / np.hypot(*v)
    along = [abs((np.array([e.x, e.y]) - path.position(np.array([e.t]))[0]) @ u) for e in first[5:]]
    assert np.median(along) < 5.0
    speeds = [math.hypot(e.vx, e.vy) for e in first[20:]]
    assert abs(np.median(speeds) - 2.0) < 0.5


def test_random_walk_band_contains_the_truth(constant_run):
    """At each period the true position's projection on the true heading lies between the
    largest projection of the −1 sensors and the smallest of the +1 sensors (paper 002 §IV.C),
    and the uniform initialisation lands in the first period's band."""
    result, path = constant_run
    tracker = MotionRandomWalkTracker(result.deployment)
    seen = []
    estimate = tracker._estimate

    def spy(k, rows, times):
        seen.append((times[-1], rows[-1].copy(), tracker._x is None))
        out = estimate(k, rows, times)
        if seen[-1][2]:
            seen[-1] = seen[-1] + (tracker._x.copy(), tracker._u.copy())
        return out

    tracker._estimate = spy
    _run(tracker, result)
    assert len(seen) > 50
    for t, status, *_ in seen:
        v = path.velocity(np.array([t]))[0]
        u = v / np.hypot(*v)
        a, b = tracker._band(status, u)
        p = float(path.position(np.array([t]))[0] @ u)
        assert a <= p <= b
    _, status, first, x0, u0 = seen[0]
    assert first
    a, b = tracker._band(status, u0)
    assert a <= float(x0 @ u0) <= b


# --------------------------------------------------------------------------- SVM


def test_svm_single_period_known_geometry():
    # +1 on x ≥ 1, −1 on x ≤ −1: the maximum-margin line is x = 0 with w = (1, 0), margin 1
    positions = np.array([[1.0, 0.0], [1.0, 3.0], [4.0, -2.0], [-1.0, 1.0], [-1.0, -4.0], [-3.0, 2.0]])
    labels = np.array([[1, 1, 1, -1, -1, -1]])
    for fit in (svm_fit(positions, labels), svm_fit_qp(positions, labels)):
        assert fit.separable
        np.testing.assert_allclose(fit.w, [1.0, 0.0], atol=1e-6)
        np.testing.assert_allclose(fit.b, [0.0], atol=1e-6)
        assert fit.margin == pytest.approx(1.0, abs=1e-6)
    # a tilted pair decides: +1 at (2, 2), −1 at (0, 0) and far points → normal along (1, 1)
    positions = np.array([[2.0, 2.0], [5.0, 1.0], [1.0, 6.0], [0.0, 0.0], [-3.0, 1.0], [1.0, -5.0]])
    fit = svm_fit(positions, np.array([[1, 1, 1, -1, -1, -1]]))
    assert math.degrees(_angle_error(fit.heading, math.pi / 4)) < 1e-4
    assert fit.margin == pytest.approx(math.sqrt(2.0), rel=1e-6)


def test_svm_two_periods_speed_from_distance_between_lines():
    # both periods separate along x; the line moves from x = 0 to x = 3 in 1.5 s: 2 units/s
    xs = np.repeat([-2.0, -1.0, 1.0, 2.0, 4.0, 5.0], 2)
    positions = np.column_stack([xs, np.tile([0.0, 3.0], 6)])
    labels = np.array([np.where(xs > 0, 1, -1), np.where(xs > 3, 1, -1)])
    fit = svm_velocity(positions, labels, np.array([0.0, 1.5]))
    assert fit.heading == pytest.approx(0.0, abs=1e-6)
    assert fit.speed == pytest.approx(2.0, rel=1e-6)


def test_svm_multi_period_solvers_agree():
    positions, labels, _, _ = _labels(4, 40, duration=8.0)
    auto, qp = svm_fit(positions, labels), svm_fit_qp(positions, labels)
    assert auto.separable and qp.separable
    assert math.degrees(_angle_error(auto.heading, qp.heading)) < 1e-3
    assert auto.margin == pytest.approx(qp.margin, rel=1e-4)


def test_svm_soft_margin_non_separable_stays_sensible():
    rng = np.random.default_rng(1)
    positions = rng.uniform(0, 300, (60, 2))
    u = np.array([math.cos(0.7), math.sin(0.7)])
    labels = np.where(positions @ u > 200 + 4.0 * np.arange(4)[:, None], 1, -1)
    near = np.argsort(np.abs(positions @ u - 200))[:3]
    labels[0, near] *= -1  # three wrong reports near the line: not separable any more
    auto = svm_fit(positions, labels, c=10.0)
    qp = svm_fit_qp(positions, labels, c=10.0)
    assert not auto.separable and not qp.separable
    assert math.degrees(_angle_error(auto.heading, 0.7)) < 10.0
    assert math.degrees(_angle_error(auto.heading, qp.heading)) < 1e-3
    fit = svm_velocity(positions, labels, np.arange(4.0))
    assert fit is not None and math.isfinite(fit.speed) and 1.0 < fit.speed < 8.0


def test_svm_needs_both_classes():
    positions = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 0.0]])
    assert svm_fit(positions, np.array([[1, 1, 1]])) is None
    assert svm_velocity(positions, np.array([[1, -1, 1]]), np.array([0.0])) is None  # one period: no speed


# --------------------------------------------------------------------------- PPR and the plane


def test_ppr_direction_from_a_staircase():
    rng = np.random.default_rng(2)
    positions = rng.uniform(0, 300, (100, 2))
    heading = math.radians(-123.0)
    u = np.array([math.cos(heading), math.sin(heading)])
    p = positions @ u
    count = np.clip(np.ceil((p - p.min() - 40.0) / 2.0), 0, 60)  # step 2 units, 60 periods
    assert math.degrees(_angle_error(ppr_direction(positions, count), heading)) < 0.5
    assert ppr_direction(positions, np.full(100, 7.0)) is None


def test_ppr_and_plane_batch_accuracy_and_speed():
    positions, labels, _, path = _labels(5, 100)
    v = path.velocity(np.array([0.0]))[0]
    for fit in (ppr_fit(positions, labels, 1.0), velocity_plane(positions, labels, 1.0)):
        assert math.degrees(_angle_error(fit.heading, math.atan2(v[1], v[0]))) < 1.0
        assert fit.speed == pytest.approx(math.hypot(*v), rel=0.02)
    assert counters(labels).max() <= labels.shape[0]


def test_velocity_plane_needs_a_sign_change():
    positions = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0]])
    labels = np.array([[1, 1, -1, -1], [1, 1, -1, -1]])  # nobody changed: no staircase
    assert velocity_plane(positions, labels, 1.0) is None


# --------------------------------------------------------------------------- periods


def _deployment(n: int = 4, period: float = 1.0) -> Deployment:
    sensors = [MotionSensor(id=f"m{i}", x=float(10 * i), y=float(5 * (i % 2)), period=period) for i in range(n)]
    return Deployment(name="t", units="m", region=Region(xmin=0, ymin=0, xmax=40, ymax=10), sensors=sensors)


class _Recorder(VelocityPlaneTracker):
    """Records each completed period's (k, status row) instead of estimating."""

    def __init__(self, deployment):
        super().__init__(deployment)
        self.rows = []

    def _estimate(self, k, rows, times):
        self.rows.append((k, times[-1], rows[-1].tolist()))
        return VelocityEstimate(t=times[-1], method=self.name, vx=0.0, vy=0.0)


def _tr(t, sensor, value, previous, seq):
    return Transition(t=t, sensor=sensor, value=value, previous=previous, seq=seq)


def test_periods_with_silent_sensors():
    tracker = _Recorder(_deployment())
    # period 0: m0 turns +1 (sampled 0.4 s late: still period 0); m1..m3 report −1, silently
    assert tracker.update(_tr(0.4, "m0", 1, -1, 1)) == []
    assert tracker.flush(0.49) == []  # period 0 ends at 0.5 s
    assert [e.t for e in tracker.flush(0.5)] == [0.0]
    assert tracker.flush(5.0) == []  # nothing reported after period 0: no evidence of a target
    # period 3: m1 turns +1; periods 1 and 2 (everyone silent) are emitted with held statuses
    out = tracker.update(_tr(3.0, "m1", 1, -1, 1))
    assert [e.t for e in out] == [1.0, 2.0]
    assert tracker.flush(3.2) == []
    assert tracker.update(_tr(3.45, "m0", -1, 1, 2)) == []  # same period (window [2.5, 3.5))
    assert [e.t for e in tracker.flush(math.inf)] == [3.0]
    assert tracker.rows == [(0, 0.0, [1, -1, -1, -1]), (1, 1.0, [1, -1, -1, -1]), (2, 2.0, [1, -1, -1, -1]),
                            (3, 3.0, [-1, 1, -1, -1])]
    assert tracker.flush(math.inf) == []


def test_transitions_of_other_sensors_are_ignored_and_options_checked():
    deployment = _deployment()
    tracker = _Recorder(deployment)
    assert tracker.update(_tr(0.0, "not-a-motion-sensor", 1, 0, 1)) == []
    assert tracker.flush(math.inf) == []
    with pytest.raises(TrackerConfigError):
        VelocityPlaneTracker(deployment, window=0)
    with pytest.raises(TrackerConfigError):
        SvmTracker(deployment, period=-1.0)
    assert PprTracker(deployment, period=0.5).period == 0.5
    assert VelocityPlaneTracker(deployment).period == 1.0


@pytest.mark.parametrize("name", ["velocity-plane", "svm", "ppr", "motion-rw"])
def test_non_motion_deployment_raises(name):
    disks = simulate("uniform-800", 1, nodes=20).deployment
    with pytest.raises(TrackerConfigError, match="motion") as info:
        MOTION_TRACKERS[name](disks)
    assert "\n" not in str(info.value)
    assert MOTION_TRACKERS[name].name == name


def test_a_silence_longer_than_max_silence_is_passed_over():
    tracker = _Recorder(_deployment())
    tracker.update(_tr(0.0, "m0", 1, -1, 1))
    # a transition 1e9 s later: the periods up to MAX_SILENCE after the last transition are
    # completed (held statuses), the rest of the gap is empty time, not 1e9 periods
    out = tracker.update(_tr(1e9, "m1", 1, -1, 1))
    assert [e.t for e in out] == [float(k) for k in range(int(MAX_SILENCE) + 1)]
    assert [e.t for e in tracker.flush(math.inf)] == [1e9]
    assert tracker.rows[-1] == (10 ** 9, 1e9, [1, 1, -1, -1])
