"""The adaptive basis algorithm (paper 003): phase 1 closed form, phase 2 Newton, phase 3 frames,
and the streaming tracker on the shipped laser testbed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bintrack.evaluation.parameter_error import parameter_error
from bintrack.sim.passage_scene import passage_scene
from bintrack.trackers.laser.adaptive_basis import AdaptiveBasis
from bintrack.trackers.laser.line_model import DegenerateError, border_times
from bintrack.trackers.laser.phase1_closed_form import closed_form
from bintrack.trackers.laser.phase3_frame import Frame, collinear, frame_from_points, frame_from_sensors
from bintrack.errors import TrackerConfigError
from bintrack.formats import ObjectRow, open_dataset
from bintrack.bus_payloads import LineObjectEstimate
from bintrack.deployment_model import Calibration, Deployment, DiskSensor, LineSensor, Region
from bintrack.evaluation.metrics import entry_exit_errors, truth_paths
from bintrack.pipeline import TrackerDriver, output_objects, run_tracker
from bintrack.sim.scenarios import build_scenario
from bintrack.trackers.laser.tracker import AdaptiveBasisTracker
from bintrack.transition_detector import TransitionDetector

from support import DATASETS

TESTBED = DATASETS / "laser-testbed"


def _basis(times: np.ndarray, **kw) -> AdaptiveBasis:
    basis = AdaptiveBasis(times.shape[0], **kw)
    for col in times.T:
        basis.add_object(col)
        basis.try_initialise()
    return basis


def _real(basis: AdaptiveBasis, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """Beams and (vx, x0, vy, y0) of every object in real-world coordinates."""
    return frame.lines(basis.lines), frame.objects(basis.object_parameters())


def _jp(basis: AdaptiveBasis, scene) -> float:
    lines, objects = _real(basis, frame_from_points(scene.calibration_pairs(basis)))
    n = basis.objects
    return parameter_error(lines, objects, scene.lines, scene.objects[:n])


# --------------------------------------------------------------------------- phase 1


@pytest.mark.parametrize("seed", range(5))
def test_phase1_recovers_the_truth_exactly_on_noiseless_data(seed):
    scene = passage_scene(np.random.default_rng(seed), objects=4, noise=0.0)
    sol = closed_form(scene.times)
    # in the adaptive frame: o1 moves along x at speed 1, o2 along y at speed 1
    assert np.allclose(sol.velocities[:2], [[1, 0], [0, 1]])
    # every detection time is reproduced (eq. 3)
    for j in range(4):
        pred = (1 - sol.lines @ sol.centres[j]) / (sol.lines @ sol.velocities[j]) + sol.t_refs[j]
        assert np.allclose(pred, scene.times[:, j], atol=1e-9)
    # up to the frame: the affine map fixed by the two known passes gives back every true parameter
    basis = AdaptiveBasis(6, iterations=0)
    for col in scene.times.T:
        basis.add_object(col)
    basis.initialise((0, 1, 2, 3))
    lines, objects = _real(basis, frame_from_points(scene.calibration_pairs(basis)))
    assert np.allclose(lines, scene.lines, rtol=1e-8, atol=1e-8)
    assert np.allclose(objects, scene.objects, rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize("seed", range(5))
def test_phase1_sign_is_chosen_by_the_fourth_object(seed):
    scene = passage_scene(np.random.default_rng(seed), objects=4, noise=0.0)
    sol = closed_form(scene.times)
    assert len(sol.roots) == 2
    kept, other = sol.residuals[sol.chosen], sol.residuals[1 - sol.chosen]
    assert kept < 1e-9 and other > 1e-3  # seconds: only one root explains o4's detection times
    # the root kept is the true position of o2 in the adaptive frame: the true o2 mapped there
    frame_true = frame_from_points([(sol.centres[0] + sol.velocities[0] * (t - sol.t_refs[0]), p)
                                    for t, p in ((0.0, scene.entries[0]), (scene.durations[0], scene.exits[0]))]
                                   + [(sol.centres[1] + sol.velocities[1] * (t - sol.t_refs[1]), p)
                                      for t, p in ((0.0, scene.entries[1]), (scene.durations[1], scene.exits[1]))])
    true_o2 = frame_true.A @ (scene.entries[1] + scene.objects[1, [0, 2]] * sol.t_refs[1]) + frame_true.d
    assert np.allclose(sol.roots[sol.chosen], true_o2, atol=1e-7)


def _times(lines, entries, velocities):
    return (1 - lines @ entries.T) / (lines @ velocities.T)


def test_parallel_beams_are_a_clear_error():
    scene = passage_scene(np.random.default_rng(0), objects=4, noise=0.0)
    lines = np.linspace(0.6, 1.6, 6)[:, None] * scene.lines[0]
    times = _times(lines, scene.entries, scene.objects[:, [0, 2]])
    with pytest.raises(DegenerateError, match="beams are parallel"):
        closed_form(times)


def test_parallel_first_objects_are_a_clear_error():
    scene = passage_scene(np.random.default_rng(0), objects=4, noise=0.0)
    entries, velocities = scene.entries.copy(), scene.objects[:, [0, 2]].copy()
    entries[1], velocities[1] = (0.0, 0.5), (0.05, 0.0)  # o2 parallel to o1
    with pytest.raises(DegenerateError, match="objects 1 and 2 are parallel"):
        closed_form(_times(scene.lines, entries, velocities))
    # the streaming estimator skips that quadruple and starts from the next one that solves
    extra = passage_scene(np.random.default_rng(1), objects=6, noise=0.0)
    entries = np.vstack([entries, extra.entries[2:]])
    velocities = np.vstack([velocities, extra.objects[2:, [0, 2]]])
    basis = _basis(_times(scene.lines, entries, velocities))
    assert basis.initialised and basis.phase1_objects == (0, 2, 3, 4)
    assert basis.object_known().all()  # o2 estimated afterwards from the beams


def test_phase1_input_checks():
    scene = passage_scene(np.random.default_rng(0), sensors=6, objects=4, noise=0.0)
    with pytest.raises(DegenerateError, match="needs 6 sensors"):
        closed_form(scene.times[:5])
    times = scene.times.copy()
    times[:2, 3] = np.nan
    with pytest.raises(DegenerateError, match="object 4 needs 5 detections"):
        closed_form(times)
    times = scene.times.copy()
    times[0, 1] = np.nan
    with pytest.raises(DegenerateError, match="every sensor must detect objects 1–3"):
        closed_form(times)
    with pytest.raises(ValueError, match="m × 4"):
        closed_form(scene.times[:, :3])


# --------------------------------------------------------------------------- phase 2


def test_missed_detections_wait_for_enough_data():
    scene = passage_scene(np.random.default_rng(4), sensors=8, objects=12, noise=0.0)
    times = scene.times.copy()
    times[6:, :3] = np.nan  # sensors 7–8 asleep for the first three passes
    times[0, 1] = np.nan  # sensor 1 misses pass 2: phase 1 uses sensors 2–6 … not enough, waits
    times[[1, 2, 3, 4, 5], 6] = np.nan  # pass 7 seen by three sensors only: cannot be estimated
    basis = AdaptiveBasis(8)
    for j, col in enumerate(times.T):
        basis.add_object(col)
        basis.try_initialise()
        if j < 4:
            assert not basis.initialised  # five sensors saw passes 1–3, six saw 1, 3, 4
    assert basis.phase1_objects == (0, 2, 3, 4)
    assert basis.omega.sum() == np.isfinite(times).sum()
    known = basis.object_known()
    assert not known[6] and known.sum() == 11
    assert basis.line_known().all()  # sensors 7–8 fixed from later passes
    frame = frame_from_points(scene.calibration_pairs(basis))
    lines, objects = _real(basis, frame)
    assert np.allclose(lines, scene.lines, rtol=1e-7)
    assert np.allclose(objects[known], scene.objects[known], rtol=1e-7, atol=1e-9)


def test_newton_never_increases_the_cost_and_lowers_jp():
    before, after = [], []
    for seed in range(6):
        scene = passage_scene(np.random.default_rng(seed), objects=40, noise=0.01)
        basis = _basis(scene.times[:, :4], iterations=0, phase2="paper")
        before.append(_jp(basis, scene))
        for col in scene.times[:, 4:].T:
            basis.add_object(col)
            costs = [basis.cost()] + basis.iterate(5)
            assert np.all(np.diff(costs) <= 1e-12 * costs[0])
        after.append(_jp(basis, scene))
    # Fig. 6: the parameter error falls as objects accumulate (Jp is averaged over them all)
    assert np.mean(after) < 0.5 * np.mean(before)


def test_time_residuals_and_object_parameters():
    scene = passage_scene(np.random.default_rng(2), objects=6, noise=0.0)
    basis = _basis(scene.times)
    assert np.nanmax(np.abs(basis.time_residuals())) < 1e-8
    assert basis.object_parameters().shape == (6, 4)
    assert np.allclose(basis.position(0, basis.t_refs[0] + 1) - basis.position(0, basis.t_refs[0]), [1, 0])


# --------------------------------------------------------------------------- phase 3


def test_frame_from_six_sensor_positions():
    scene = passage_scene(np.random.default_rng(5), objects=6, noise=0.0)
    basis = _basis(scene.times)
    rng = np.random.default_rng(9)
    # a point of each true beam at a random height: positions not on one line
    ys = rng.uniform(0, 1, 6)
    xs = (1 - scene.lines[:, 1] * ys) / scene.lines[:, 0]
    positions = dict(enumerate(zip(xs, ys)))
    frame = frame_from_sensors(basis.lines, positions)
    assert frame.source == "sensors"
    lines, objects = _real(basis, frame)
    assert np.allclose(lines, scene.lines, rtol=1e-7)
    assert np.allclose(objects, scene.objects, rtol=1e-7, atol=1e-9)
    # collinear positions cannot fix the frame (eq. 29 singular)
    on_bottom = {k: ((1.0 / a), 0.0) for k, (a, _) in enumerate(scene.lines)}
    assert collinear(list(on_bottom.values()))
    with pytest.raises(DegenerateError, match="do not fix the frame"):
        frame_from_sensors(basis.lines, on_bottom)
    # three known beams do
    frame = frame_from_sensors(basis.lines, beams={k: scene.lines[k] for k in (0, 2, 4)})
    assert np.allclose(_real(basis, frame)[0], scene.lines, rtol=1e-7)


def test_frame_from_two_known_passes():
    scene = passage_scene(np.random.default_rng(6), objects=5, noise=0.0)
    basis = _basis(scene.times)
    lines, objects = _real(basis, frame_from_points(scene.calibration_pairs(basis)))
    assert np.allclose(objects, scene.objects, rtol=1e-8, atol=1e-10)
    with pytest.raises(DegenerateError, match="cannot fix the 6 unknowns"):
        frame_from_points(scene.calibration_pairs(basis, objects=(0,)))


def test_border_times():
    box = (0.0, 0.0, 16.0, 8.0)
    assert border_times((8.0, 4.0), (2.0, 0.0), 10.0, box) == pytest.approx((6.0, 14.0))
    assert border_times((8.0, 20.0), (1.0, 0.0), 0.0, box) is None


# --------------------------------------------------------------------------- the tracker


def _transitions(deployment, events):
    detector = TransitionDetector(deployment)
    return [detector.update(e) for e in events]


def _run(deployment, events, flush_every=False, **kw) -> tuple[AdaptiveBasisTracker, list[LineObjectEstimate]]:
    tracker = AdaptiveBasisTracker(deployment, **kw)
    out = []
    for tr in _transitions(deployment, events):
        out += tracker.update(tr)
        if flush_every:
            out += tracker.flush(tr.t)
    return tracker, out + tracker.flush(math.inf)


def _errors(out, truth, first=4):
    errors = [e for e in entry_exit_errors(output_objects(out), truth) if e.object >= first]
    return np.array([e.entry for e in errors]), np.array([e.exit for e in errors])


@pytest.fixture(scope="module")
def testbed():
    dataset = open_dataset(TESTBED)
    return dataset, list(dataset.events()), truth_paths(dataset.truth())


def test_tracker_on_the_laser_testbed(testbed):
    dataset, events, truth = testbed
    tracker = AdaptiveBasisTracker(dataset.deployment)
    out = list(run_tracker(dataset, tracker))
    # each pass once as first estimated, in order (revisions, test_laser_revisions.py, come after)
    assert [o.object for o in out if o.revision is None] == list(range(1, 33))
    # the light sensors all stand on y = 0: the calibration passes fix the frame
    assert tracker.frame_source == "calibration" and "lie on one line" in tracker.frame_reason
    assert tracker.gap == pytest.approx(0.5 * (12.374946679937437 - 1.0))
    entry, exit_ = _errors(out, truth)
    assert len(entry) == 29
    # measured: entry mean 0.030 ft, max 0.091; exit mean 0.052, max 0.199 (ft, track 16 × 8 ft)
    assert entry.mean() < 0.1 and exit_.mean() < 0.15
    assert entry.max() < 0.3 and exit_.max() < 0.5
    # stable as passes accumulate (§7.2): the last third no worse than the first
    both = entry + exit_
    assert both[-10:].mean() < 2.0 * both[:10].mean() + 0.05
    # velocity: ≈ 1.41 ft/s ± 5 %, and equal to (exit − entry) over the border-crossing time
    speeds = np.array([math.hypot(o.vx, o.vy) for o in out])
    assert np.all(np.abs(speeds / 1.41 - 1) < 0.08)
    # the estimated beams are the simulated ones (the dataset is seed 1 of the scenario)
    true = {s.id: (s.a, s.b) for s in build_scenario("laser-testbed", 1).sensors}
    for sid, (a, b) in tracker.beams().items():
        assert np.hypot(a - true[sid][0], b - true[sid][1]) < 0.05 * np.hypot(*true[sid])


def test_tracker_output_does_not_depend_on_when_flush_is_called(testbed):
    dataset, events, _ = testbed
    _, once = _run(dataset.deployment, events)
    _, often = _run(dataset.deployment, events, flush_every=True)
    assert once == often
    # the offline driver with a watermark as the live base station uses it
    driver = TrackerDriver(AdaptiveBasisTracker(dataset.deployment))
    live = []
    for tr in _transitions(dataset.deployment, events):
        live += driver.advance(tr.t - 0.5)
        driver.push(tr)
    live += driver.finish()
    assert live == once


def test_tracker_emits_the_first_four_passes_together_then_one_per_pass(testbed):
    dataset, events, _ = testbed
    tracker = AdaptiveBasisTracker(dataset.deployment)
    emitted = []
    for tr in _transitions(dataset.deployment, events[:36]):
        emitted.append([o.object for o in tracker.update(tr) if o.revision is None])
    got = [e for e in emitted if e]
    assert got == [[1, 2, 3, 4], [5], [6]]  # each pass complete when all six beams have fired
    # the end of the stream closes no pass; it may only revise the passes given
    assert all(o.revision and o.object <= 6 for o in tracker.flush(math.inf))


def test_tracker_closes_a_pass_with_a_missed_sensor_after_the_gap(testbed):
    dataset, events, truth = testbed
    # L6 misses pass 5, L3 misses pass 9 and L1 pass 20
    passes = {"L6": truth["5"], "L3": truth["9"], "L1": truth["20"]}
    kept = [e for e in events if not (e.sensor in passes and passes[e.sensor].start <= e.t <= passes[e.sensor].end)]
    tracker = AdaptiveBasisTracker(dataset.deployment)
    out = []
    transitions = _transitions(dataset.deployment, kept)
    for tr in transitions:
        out += tracker.update(tr)
        if 5 in [o.object for o in out]:
            break
    # pass 5 lacks L6: it ends only when the next pass begins with L1 (rule 2)
    assert [o for o in out if o.revision is None][-1].object == 5 and tr.sensor == "L1" and tr.t > truth["6"].start
    # … or, at the end of the stream, once the gap has elapsed
    tracker = AdaptiveBasisTracker(dataset.deployment)
    last = [tr for tr in transitions if tr.t <= truth["5"].end]
    for tr in last:
        tracker.update(tr)
    assert tracker.flush(last[-1].t + 0.99 * tracker.gap) == []
    assert [o.object for o in tracker.flush(last[-1].t + tracker.gap)] == [5]
    _, out = _run(dataset.deployment, kept)
    entry, exit_ = _errors(out, truth)
    assert len(entry) == 29 and entry.mean() < 0.1 and exit_.mean() < 0.15


def _deployment(sensors, calibration=None, name="lines") -> Deployment:
    return Deployment(name=name, units="ft", region=Region(xmin=0, ymin=0, xmax=16, ymax=8), sensors=sensors,
                      calibration=calibration)


def test_tracker_uses_known_positions_off_one_line(testbed):
    dataset, events, truth = testbed
    sensors = []
    for k, s in enumerate(build_scenario("laser-testbed", 1).sensors):
        if k % 2:  # the laser's end of the beam, on y = 8
            sensors.append(LineSensor(id=s.id, x=(1 - 8 * s.b) / s.a, y=8.0))
        else:
            sensors.append(LineSensor(id=s.id, x=s.x, y=s.y))
    tracker, out = _run(_deployment(sensors), events)
    assert tracker.frame_source == "sensors" and tracker.gap_source == "learnt"
    entry, exit_ = _errors(out, truth)
    # measured: mean 0.15 / 0.12 ft, max 0.44 / 0.35 ft (six positions fix the 6 unknowns exactly)
    assert len(entry) == 29 and entry.mean() < 0.4 and exit_.mean() < 0.4
    # known beams are used too (two equations each)
    tracker, out = _run(_deployment(list(build_scenario("laser-testbed", 1).sensors)), events)
    assert tracker.frame_source == "sensors"
    entry, exit_ = _errors(out, truth)
    assert entry.mean() < 0.2 and exit_.mean() < 0.25


def test_tracker_constructor_errors():
    region = Region(xmin=0, ymin=0, xmax=16, ymax=8)
    with pytest.raises(TrackerConfigError, match="needs line sensors"):
        AdaptiveBasisTracker(Deployment(name="d", units="m", region=region,
                                        sensors=[DiskSensor(id="n1", x=1, y=1, range=2)]))
    with pytest.raises(TrackerConfigError, match="at least 6 line sensors"):
        AdaptiveBasisTracker(_deployment([LineSensor(id=f"L{k}") for k in range(5)]))
    with pytest.raises(TrackerConfigError, match="lie on one line"):
        AdaptiveBasisTracker(_deployment([LineSensor(id=f"L{k}", x=k, y=0) for k in range(6)]))
    with pytest.raises(TrackerConfigError, match="real-world coordinates"):
        AdaptiveBasisTracker(_deployment([LineSensor(id=f"L{k}") for k in range(6)], Calibration(passes=[])))
    with pytest.raises(TrackerConfigError, match="gap"):
        AdaptiveBasisTracker(open_dataset(TESTBED).deployment, gap=0)


def test_object_rows_are_the_estimates_field_by_field():
    est = [LineObjectEstimate(object=2, t_first=1, t_last=2, entry_x=0, entry_y=1, exit_x=16, exit_y=2, vx=1, vy=0),
           LineObjectEstimate(object=1, t_first=0, t_last=1, entry_x=0, entry_y=3, exit_x=16, exit_y=4, vx=1, vy=.1)]
    assert output_objects(est) == [ObjectRow(1, 0, 1, 0, 3, 16, 4, 1, .1), ObjectRow(2, 1, 2, 0, 1, 16, 2, 1, 0)]


def test_non_line_and_repeated_transitions_are_ignored(testbed):
    dataset, events, _ = testbed
    tracker = AdaptiveBasisTracker(dataset.deployment)
    first = _transitions(dataset.deployment, events[:1])[0]
    assert tracker.update(first) == []
    assert tracker.update(first) == []  # the same crossing delivered twice
    assert tracker.update(first.model_copy(update={"sensor": "unknown"})) == []
    assert tracker.update(first.model_copy(update={"value": 0})) == []
    assert len(tracker._current) == 1


# --------------------------------------------------------------------------- phase 2 to the optimum (issue 19)


def _simulated(tmp_path, seed: int, **options):
    from bintrack.formats import write_dataset
    from bintrack.sim.scenarios import simulate

    sim = simulate("laser-testbed", seed, **options)
    return open_dataset(write_dataset(tmp_path / f"laser-{seed}", sim.deployment, sim.events, sim.truth))


def test_least_squares_phase2_recovers_the_truth_on_noiseless_data():
    for seed in range(3):
        scene = passage_scene(np.random.default_rng(seed), objects=12, noise=0.0)
        basis = _basis(scene.times)
        assert basis.phase2 == "lsq" and basis.last_solve is not None
        lines, objects = _real(basis, frame_from_points(scene.calibration_pairs(basis)))
        assert np.abs(lines - scene.lines).max() < 1e-9
        assert np.abs(objects - scene.objects).max() < 1e-9


def test_tracker_recovers_beams_and_points_to_1e6_ft_without_timing_noise(tmp_path):
    dataset = _simulated(tmp_path, 2, passes=12, jitter=0.0)
    tracker = AdaptiveBasisTracker(dataset.deployment)
    out = list(run_tracker(dataset, tracker))
    # pass 1 runs along the border y = 0 and pass 2 into the corner: their border crossings are ill-posed
    entry, exit_ = _errors(out, truth_paths(dataset.truth()), first=3)
    assert len(entry) == 10 and entry.max() < 1e-6 and exit_.max() < 1e-6
    true = {s.id: (s.a, s.b) for s in build_scenario("laser-testbed", 2).sensors}
    for sid, ab in tracker.beams().items():
        # a beam's error as a distance: where it crosses y = 0 and y = 8 (ft)
        for y in (0.0, 8.0):
            assert abs((1 - ab[1] * y) / ab[0] - (1 - true[sid][1] * y) / true[sid][0]) < 1e-6
    assert tracker.frame_residual < 1e-6 and tracker.warnings == []


def test_least_squares_phase2_converges_on_noisy_data():
    scene = passage_scene(np.random.default_rng(4), objects=30, noise=0.01)
    basis = AdaptiveBasis(6)
    for col in scene.times.T:
        basis.add_object(col)
        if basis.try_initialise() and basis.objects > 4:
            report = basis.last_solve
            # the gradient of eq. 5 vanishes at the returned solution (relative to its scale)
            problem = basis._layout()
            x = problem.pack(basis.lines)
            jac, r = problem.jacobian(x), problem.residuals(x)
            scale = float(np.sqrt(np.sum(jac.multiply(jac))) * np.linalg.norm(r))
            assert report.gradient == pytest.approx(basis.gradient_norm())
            assert report.gradient < 1e-6 * scale
            assert report.cost <= report.cost_before
    # and it is the optimum the joint solve (beams and objects together) reaches from there
    cost = basis.cost()
    joint = basis.solve(joint=True)
    assert joint.cost == pytest.approx(cost, rel=1e-9)
    # the paper's five Newton iterations per pass stop well short of it
    paper = _basis(scene.times, phase2="paper")
    assert paper.cost() > 1.01 * cost and paper.gradient_norm() > 100 * basis.gradient_norm()


def test_object_covariance_is_the_inverse_normal_matrix_block():
    scene = passage_scene(np.random.default_rng(3), objects=20, noise=0.01)
    basis = _basis(scene.times)
    objs = [1, 5, 19]
    cov = basis.object_covariance(objs)
    problem = basis._layout()
    x = problem.pack(basis.lines)
    jac, r = problem.jacobian(x).toarray(), problem.residuals(x)
    full = float(r @ r) / (len(r) - len(x)) * np.linalg.inv(jac.T @ jac)
    for c, obj in zip(cov, objs):
        free = problem.free[obj]
        cols = problem.obj_col[obj][free]
        assert np.allclose(c[np.ix_(free, free)], full[np.ix_(cols, cols)], rtol=1e-6, atol=0)
        assert np.all(c[~free] == 0)  # o2's velocity is fixed by the adaptive frame


def test_phase2_option_errors():
    with pytest.raises(ValueError, match="phase2"):
        AdaptiveBasis(6, phase2="newton")
    with pytest.raises(TrackerConfigError, match="phase 2"):
        AdaptiveBasisTracker(open_dataset(TESTBED).deployment, phase2="newton")


def test_a_wrong_calibration_point_gives_one_warning_naming_the_passes(tmp_path):
    dataset = _simulated(tmp_path, 3, passes=20)
    tracker = AdaptiveBasisTracker(dataset.deployment)
    list(run_tracker(dataset, tracker))
    assert tracker.warnings == [] and tracker.frame_residual < 0.1
    assert tracker.info()["frame_residual"] == tracker.frame_residual
    # pass 2's entry written 1.5 ft off: (0, 1.5) instead of (0, 0). (Its exit could not be checked:
    # the two passes share their entry point, and three distinct points fit an affine map exactly.)
    cal = dataset.deployment.calibration
    wrong = cal.passes[1].model_copy(update={"entry": (0.0, 1.5)})
    deployment = dataset.deployment.model_copy(update={"calibration": cal.model_copy(update={"passes": [cal.passes[0], wrong]})})
    tracker = AdaptiveBasisTracker(deployment)
    list(run_tracker(dataset, tracker))
    assert tracker.frame_residual > 0.25
    assert len(tracker.warnings) == 1
    assert "calibration passes 1, 2" in tracker.warnings[0] and "ft" in tracker.warnings[0]
    assert tracker.info()["warnings"] == tracker.warnings


def test_known_positions_beat_the_calibration_passes(testbed):
    dataset, events, truth = testbed
    sensors = []
    for k, s in enumerate(build_scenario("laser-testbed", 1).sensors):
        y = 8.0 if k % 2 else 0.0  # odd sensors: the laser's end of the beam
        sensors.append(LineSensor(id=s.id, x=(1 - y * s.b) / s.a, y=y))
    tracker, out = _run(_deployment(sensors, dataset.deployment.calibration), events)
    assert tracker.frame_source == "sensors" and "(fallback)" in tracker.frame_reason
    assert tracker.frame_residual < 0.25 and "known positions/beams of sensors" in tracker.info()["frame_points"]
    entry, exit_ = _errors(out, truth)
    assert entry.mean() < 0.4 and exit_.mean() < 0.4


def test_estimates_carry_entry_and_exit_standard_deviations(testbed):
    dataset, events, truth = testbed
    _, out = _run(dataset.deployment, events)
    sds = np.array([(o.entry_sd, o.exit_sd) for o in out if o.object >= 5], dtype=float)
    assert np.all(np.isfinite(sds)) and np.all(sds > 0) and np.all(sds < 2.0)
    # an old recording's message, without them, still decodes
    from bintrack.message_codec import decode, encode
    old = LineObjectEstimate(object=1, t_first=0, t_last=1, entry_x=0, entry_y=3, exit_x=16, exit_y=4, vx=1, vy=.1)
    payload = msgpack_without(encode(old), ("entry_sd", "exit_sd"))
    assert decode(LineObjectEstimate, payload) == old and old.entry_sd is None


def msgpack_without(payload: bytes, fields) -> bytes:
    import msgpack

    data = msgpack.unpackb(payload)
    for f in fields:
        data.pop(f)
    return msgpack.packb(data)


def test_track_writes_the_beams_and_reports_the_frame(tmp_path, capsys):
    import csv

    from bintrack.cli import main as cli

    def bintrack(*args):
        code = cli.main(list(args))
        return code, capsys.readouterr().err

    beams, objects = tmp_path / "beams.csv", tmp_path / "objects.csv"
    code, err = bintrack("track", str(TESTBED), "--tracker", "adaptive-basis", "--out", str(objects), "--beams", str(beams))
    assert code == 0, err
    assert "real-world frame from calibration; residual" in err and "warning" not in err
    rows = list(csv.DictReader(beams.open()))
    assert [r["sensor"] for r in rows] == [f"L{k}" for k in range(1, 7)]
    true = {s.id: (s.a, s.b) for s in build_scenario("laser-testbed", 1).sensors}
    for r in rows:
        a, b = float(r["a"]), float(r["b"])
        assert np.hypot(a - true[r["sensor"]][0], b - true[r["sensor"]][1]) < 0.05 * np.hypot(*true[r["sensor"]])
    code, err = bintrack("track", str(TESTBED), "--tracker", "adaptive-basis", "--phase2", "paper", "--out",
                         str(tmp_path / "paper.csv"), "--beams", str(tmp_path / "paper-beams.csv"))
    assert code == 0 and "phase 2: paper" in err
    # the beams are phase 2's (the objects are the re-solve's, which phase 2 only starts)
    assert (tmp_path / "paper-beams.csv").read_text() != beams.read_text()
    code, err = bintrack("track", str(TESTBED), "--tracker", "line-fit", "--out", str(tmp_path / "t.csv"), "--beams",
                         str(tmp_path / "b.csv"))
    assert code != 0 and "--beams" in err and not (tmp_path / "b.csv").exists()
    code, err = bintrack("track", str(TESTBED), "--tracker", "arc", "--phase2", "paper")
    assert code != 0 and "--phase2 applies to the adaptive-basis tracker only" in err
