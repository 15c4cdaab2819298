"""The simulator: exact transitions, sampling, faults, scenarios, the command, shipped datasets."""

from __future__ import annotations

import math
import shlex
from pathlib import Path

import numpy as np
import pytest

from bintrack.cli.main import main
from bintrack.formats import Event, open_dataset
from bintrack.deployment_model import DiskSensor, LineSensor, MotionSensor, Region, SectorSensor
from bintrack.sensing import model_for
from bintrack.sim import ScenarioError, build_scenario, simulate, simulate_scenario, truth_rows
from bintrack.sim.faults import packet_faults, wrong_reports
from bintrack.sim.sampling import periodic_events, presence_samples, sample_times
from bintrack.sim.trajectories import circle, polyline, random_walk
from bintrack.sim.transitions import beam_crossings, exact_transitions, inside_intervals
from support import REPO

EXACT = 1e-9


def _times(events):
    return [e.t for e in events]


def _values(events):
    return [e.value for e in events]


# --------------------------------------------------------------------------- exact transitions


def test_disk_transitions_of_a_line_through_the_disk():
    sensor = DiskSensor(id="d", x=50, y=6, range=10)
    path = polyline("0", 0.0, [(0, 0), (100, 0)], 2.0)  # half chord 8: x = 42 and 58
    events = exact_transitions(sensor, [path])
    assert _values(events) == [1, 0]
    assert _times(events) == pytest.approx([21.0, 29.0], abs=EXACT)


def test_disk_holding_the_target_at_entry_and_exit():
    sensor = DiskSensor(id="d", x=0, y=0, range=10)
    events = exact_transitions(sensor, [polyline("0", 5.0, [(1, 0), (4, 0)], 1.0)])
    assert events == [Event(5.0, "d", 1), Event(8.0, "d", 0)]


def test_sector_boundary_crossing():
    # 4 sectors with offset π/2: the boundary ray of sector 0 points up (+y) from (50, 0)
    sensor = SectorSensor(id="s", x=50, y=0, range=10, sectors=4, offset=math.pi / 2)
    events = exact_transitions(sensor, [polyline("0", 0.0, [(0, 3), (100, 3)], 2.0)])
    half = math.sqrt(100 - 9)
    assert _values(events) == [3, 0, -1]
    assert _times(events) == pytest.approx([(50 - half) / 2, 25.0, (50 + half) / 2], abs=EXACT)


def test_beam_crossing():
    sensor = LineSensor(id="L1", a=0.1, b=0.05)  # x/10 + y/20 = 1
    events = beam_crossings(sensor, [polyline("0", 1.0, [(0, 0), (20, 20)], math.sqrt(2))])
    assert _values(events) == [1]
    assert _times(events) == pytest.approx([1.0 + 20 / 3], abs=EXACT)


def test_circular_path_crossing_a_disk():
    # circle of radius 10 about the origin at 1 rad/s from φ = 0; disk of radius 10 at (0, 10):
    # inside for φ in (π/6, 5π/6)
    path = circle("0", 0.0, (0, 0), 10.0, 0.0, 10.0, 2 * math.pi)
    events = exact_transitions(DiskSensor(id="d", x=0, y=10, range=10), [path])
    assert _values(events) == [1, 0]
    assert _times(events) == pytest.approx([math.pi / 6, 5 * math.pi / 6], abs=EXACT)
    # a disk at the start point holds the target at entry and again at the end
    events = exact_transitions(DiskSensor(id="e", x=10, y=0, range=10), [path])
    assert _values(events) == [1, 0, 1, 0]
    assert _times(events) == pytest.approx([0, math.pi / 3, 5 * math.pi / 3, 2 * math.pi], abs=EXACT)


def test_several_targets_disk_any_and_sector_lowest_numbered():
    first = polyline("1", 0.0, [(-20, 1), (20, 1)], 1.0)    # inside for t ∈ (20 − √99, 20 + √99)
    second = polyline("2", 10.0, [(3, -20), (3, 20)], 1.0)  # inside for t ∈ (30 − √91, 30 + √91)
    r1, r2 = math.sqrt(99), math.sqrt(91)
    disk = DiskSensor(id="d", x=0, y=0, range=10)
    events = exact_transitions(disk, [first, second])
    assert _values(events) == [1, 0]
    assert _times(events) == pytest.approx([20 - r1, 30 + r2], abs=EXACT)
    # 2 sectors, offset 0: sector 0 is the lower half (−π, 0], sector 1 the upper half (0, π].
    # Target 1 (upper half) owns the report while inside; then target 2 shows, still below the
    # x axis, and moves up through the boundary ray along +x at t = 30.
    sector = SectorSensor(id="s", x=0, y=0, range=10, sectors=2, offset=0.0)
    events = exact_transitions(sector, [first, second])
    assert _values(events) == [1, 0, 1, -1]
    assert _times(events) == pytest.approx([20 - r1, 20 + r1, 30.0, 30 + r2], abs=EXACT)


def test_inside_intervals_merge_across_segments():
    path = polyline("0", 0.0, [(-20, 0), (0, 0), (0, 20)], 1.0)
    intervals = inside_intervals(path, (0, 0), 5.0)
    assert intervals == [pytest.approx((15.0, 25.0))]


def test_exact_transitions_match_dense_sampling():
    scenario = build_scenario("sector-300", 3, nodes=120, sectors=6, trajectory="random")
    result = simulate_scenario(scenario, 3)
    path = scenario.trajectories[0]
    t = np.arange(path.t_entry, path.t_exit, 0.01)
    positions = path.position(t)
    by_sensor = {}
    for e in result.events:
        by_sensor.setdefault(e.sensor, []).append(e)
    for sensor in scenario.sensors:
        status = np.concatenate([[-1], model_for(sensor).status(positions), [-1]])
        assert int(np.sum(status[1:] != status[:-1])) == len(by_sensor.get(sensor.id, []))


def test_imperfect_event_driven_disk_reports_at_one_radius_per_visit():
    rng = np.random.default_rng(2)
    sensors = [DiskSensor(id=f"d{k}", x=50, y=y, range=40, range_in=36, detection_law="linear")
               for k, y in enumerate(np.linspace(30, 39.9, 200))]
    path = polyline("0", 0.0, [(-100, 0), (200, 0)], 5.0)
    detected = []
    for sensor in sensors:
        events = exact_transitions(sensor, [path], rng)
        detected.append(bool(events))
        if events:
            assert _values(events) == [1, 0]
            d = [float(np.hypot(*(path.position(e.t) - (50, sensor.y)))) for e in events]
            assert 36 - 1e-9 <= d[0] <= 40 + 1e-9 and d[0] == pytest.approx(d[1], abs=1e-9)
    # within R_in always detected; the detected share in the ring follows eq. 25 (on average ~0.5)
    ring = np.array([s.y for s in sensors]) > 36
    assert all(np.array(detected)[~ring])
    assert 0.3 < np.mean(np.array(detected)[ring]) < 0.7
    with pytest.raises(ValueError, match="random generator"):
        exact_transitions(sensors[0], [path])


# --------------------------------------------------------------------------- sampling


def test_sample_times():
    assert sample_times(0.2, 0.5, 0.0, 2.0).tolist() == pytest.approx([0.2, 0.7, 1.2, 1.7])
    assert sample_times(0.0, 1.0, 1.0, 3.0).tolist() == [1.0, 2.0, 3.0]


def test_periodic_disk_without_noise_reports_changes_at_samples():
    sensor = DiskSensor(id="d", x=50, y=0, range=10, period=0.5)
    path = polyline("0", 0.0, [(0, 0), (100, 0)], 2.0)  # inside t ∈ (20, 30)
    events = periodic_events(sensor, [path], (0.0, 50.0), 0.1, np.random.default_rng(0))
    assert events == [Event(pytest.approx(20.1), "d", 1), Event(pytest.approx(30.1), "d", 0)]


def test_periodic_detection_and_false_alarm_rates():
    rng = np.random.default_rng(4)
    times = sample_times(0.0, 0.5, 0.0, 5000.0)
    far = polyline("0", 0.0, [(1000, 0), (1000, 1)], 1e-4)
    near = polyline("0", 0.0, [(0, 0), (0, 1)], 1e-4)
    sensor = DiskSensor(id="d", x=0, y=0, range=8, period=0.5, pd=0.7, pfa=0.05)
    assert presence_samples(sensor, [far], times, rng).mean() == pytest.approx(0.05, abs=0.01)
    # 1 − (1 − 0.7)(1 − 0.05) = 0.715
    assert presence_samples(sensor, [near], times, rng).mean() == pytest.approx(0.715, abs=0.015)
    sector = SectorSensor(id="s", x=0, y=0, range=8, sectors=4, period=0.5, pfa=0.5)
    values = presence_samples(sector, [far], times, rng)
    assert set(values.tolist()) == {-1, 0, 1, 2, 3}


def test_motion_sensor_reports_every_sample():
    sensor = MotionSensor(id="m", x=50, y=10, period=1.0)
    path = polyline("0", 0.0, [(0, 0), (100, 0)], 5.0)  # passes x = 50 at t = 10
    events = periodic_events(sensor, [path], (0.0, 20.0), 0.0, np.random.default_rng(0))
    assert _times(events) == [float(k) for k in range(21)]
    assert _values(events) == [1] * 10 + [-1] * 11


# --------------------------------------------------------------------------- faults


class _Draws:
    """A stand-in generator whose ``random()`` returns fixed draws."""

    def __init__(self, draws):
        self.draws = list(draws)

    def random(self):
        return self.draws.pop(0)


def _visits(sensor="A"):
    return [Event(1.0, sensor, 1), Event(2.0, sensor, 0), Event(3.0, sensor, 1), Event(4.0, sensor, 0)]


def test_wrong_report_of_an_arrival_keeps_the_status():
    out = wrong_reports(_visits(), _Draws([0.04, 0.5, 0.5, 0.5]))
    assert out == [Event(3.0, "A", 1), Event(4.0, "A", 0)]


def test_wrong_report_of_a_departure_keeps_the_status():
    out = wrong_reports(_visits(), _Draws([0.5, 0.009, 0.5, 0.5]))
    assert out == [Event(1.0, "A", 1), Event(4.0, "A", 0)]
    # 0.03 misses an arrival (< 5 %) but not a departure (≥ 1 %)
    assert wrong_reports(_visits(), _Draws([0.5, 0.03, 0.5, 0.5])) == _visits()


def test_wrong_report_rates():
    events = [Event(float(k), "A", 1 - k % 2) for k in range(40000)]
    out = wrong_reports(events, np.random.default_rng(1))
    assert len(out) < len(events)
    arrivals = sum(e.value == 1 for e in out)
    assert arrivals / 20000 == pytest.approx(0.95, abs=0.01)


def test_packet_collisions_and_abandoned_transmissions():
    positions = {"A": (0, 0), "B": (50, 0), "C": (500, 0)}
    events = [
        Event(1.0, "A", 1), Event(1.00001, "C", 1), Event(1.00005, "B", 1),  # A, B collide; C far
        Event(2.0, "A", 0), Event(2.005, "B", 0),                            # B hears A: abandons
        Event(3.0, "A", 1), Event(3.02, "B", 1),                             # apart: both sent
        Event(4.0, "A", 0), Event(4.0, "A", 1),                              # one node: no collision
    ]
    out = packet_faults(events, positions, comm_range=80.0)
    assert out == [Event(1.00001, "C", 1), Event(2.0, "A", 0), Event(3.0, "A", 1), Event(3.02, "B", 1),
                   Event(4.0, "A", 0), Event(4.0, "A", 1)]


def test_abandoned_report_does_not_block_others():
    positions = {"A": (0, 0), "B": (50, 0), "D": (100, 0)}  # A–B and B–D neighbours, A–D not
    events = [Event(1.0, "A", 1), Event(1.005, "B", 1), Event(1.00505, "D", 1)]
    # B abandons (hears A); D does not hear the abandoned B, so D's report goes through
    assert packet_faults(events, positions, comm_range=80.0) == [Event(1.0, "A", 1), Event(1.00505, "D", 1)]


def test_collisions_spare_the_initial_state_but_drop_some_crossings():
    clean = simulate("uniform-800", 1, nodes=400, sensing_range=150)
    faulty = simulate("uniform-800", 1, nodes=400, sensing_range=150, faults="collision")
    start = clean.events[0].t
    assert [e for e in clean.events if e.t == start] == [e for e in faulty.events if e.t == start]
    assert len([e for e in clean.events if e.t == start]) > 10
    assert set(faulty.events) < set(clean.events)


# --------------------------------------------------------------------------- scenarios


def test_same_seed_same_output_other_seed_other_output():
    a = simulate("uniform-800", 3, nodes=150, trajectory="circular", model="imperfect", law="exponential",
                 faults="both")
    b = simulate("uniform-800", 3, nodes=150, trajectory="circular", model="imperfect", law="exponential",
                 faults="both")
    c = simulate("uniform-800", 4, nodes=150, trajectory="circular", model="imperfect", law="exponential",
                 faults="both")
    assert a.events == b.events and a.truth == b.truth and a.deployment == b.deployment
    assert a.events != c.events and a.truth != c.truth
    assert a.events == sorted(a.events, key=lambda e: (e.t, e.sensor))


def test_layout_does_not_depend_on_range_or_trajectory():
    a = build_scenario("uniform-800", 9, nodes=50, sensing_range=40, trajectory="linear")
    b = build_scenario("uniform-800", 9, nodes=50, sensing_range=150, trajectory="random")
    assert [(s.x, s.y) for s in a.sensors] == [(s.x, s.y) for s in b.sensors]


def test_speed_is_r_over_15_and_paths_stay_in_the_central_square():
    for kind in ("linear", "circular", "random", "speed-changes"):
        scenario = build_scenario("uniform-800", 1, nodes=10, sensing_range=60, trajectory=kind)
        path = scenario.trajectories[0]
        t = np.linspace(path.t_entry, path.t_exit, 2000)
        xy = path.position(t)
        assert xy.min() >= 75 - 1e-9 and xy.max() <= 725 + 1e-9
        speeds = np.hypot(*path.velocity(t).T)
        if kind == "speed-changes":
            assert set(np.round(speeds / 4.0, 9)) <= {1.0, 2.0, 3.0} and len(set(np.round(speeds, 9))) > 1
        else:
            assert speeds == pytest.approx(4.0)


def test_truth_interpolates_the_path_to_a_millimetre():
    path = circle("0", 0.0, (0, 0), 300.0, 0.3, 10.0, 100.0)
    rows = truth_rows([path])
    t = np.array([r.t for r in rows])
    assert t[0] == 0.0 and t[-1] == 100.0 and np.all(np.diff(t) > 0)
    dense = np.linspace(0, 100, 20001)
    xy = np.array([(r.x, r.y) for r in rows])
    interpolated = np.stack([np.interp(dense, t, xy[:, 0]), np.interp(dense, t, xy[:, 1])], axis=1)
    assert np.max(np.hypot(*(interpolated - path.position(dense)).T)) < 1.1e-3
    walk = random_walk(np.random.default_rng(0), Region(xmin=0, ymin=0, xmax=300, ymax=300), 2.0, 0.1, 1.0, 10.0)
    assert [r.t for r in truth_rows([walk], step=None)] == [float(k) for k in range(11)]


def test_clocks_go_into_the_deployment_and_leave_event_times_alone():
    plain = simulate("uniform-800", 2, nodes=100)
    clocked = simulate("uniform-800", 2, nodes=100, clock_offset=0.5, clock_skew=1e-4)
    assert plain.events == clocked.events
    offsets = [s.clock_offset for s in clocked.deployment.sensors]
    skews = [s.clock_skew for s in clocked.deployment.sensors]
    assert max(map(abs, offsets)) <= 0.5 and max(map(abs, skews)) <= 1e-4 and len(set(offsets)) > 1
    assert all(s.clock_offset == 0 for s in plain.deployment.sensors)


def test_darpa_grid_layout_dead_nodes_and_crossing_people():
    scenario = build_scenario("darpa-grid", 3, people=3)
    result = simulate_scenario(scenario, 3)
    assert len(scenario.deployment.sensors) == 144 and len(scenario.dead) == 6
    assert not {e.sensor for e in result.events} & scenario.dead
    assert all(s.range == 8 and s.pd == 0.7 and s.pfa == 0.05 and s.period == 0.5 for s in scenario.sensors)
    entries = [p.t_entry for p in scenario.trajectories]
    assert [p.target for p in scenario.trajectories] == ["1", "2", "3"]
    assert np.diff(entries) == pytest.approx([10, 10], abs=2)
    # people 2 and 3 meet mid-field at the same instant
    t = np.linspace(0, scenario.window[1], 20001)
    gap = np.hypot(*(scenario.trajectories[1].position(t) - scenario.trajectories[2].position(t)).T)
    k = np.nanargmin(gap)
    assert gap[k] < 0.05
    assert np.all(np.abs(scenario.trajectories[1].position(t[k]) - 27.5) < 6)
    speeds = [np.hypot(*p.velocity(p.t_entry)) for p in scenario.trajectories]
    assert all(1.0 <= s <= 1.5 for s in speeds)
    # false alarms before anyone enters
    assert any(e.value == 1 and e.t < min(entries) for e in result.events)
    assert scenario.window[1] >= 90


def test_darpa_grid_variations_curving_walks_pairs_stops_and_layout():
    plain = build_scenario("darpa-grid", 4, people=7)
    varied = build_scenario("darpa-grid", 4, people=7, walk="curving", crossings=2, pairs=1, stops=2,
                            dead=12, node_jitter=0.0, grid=14, entry_gap=6.0)
    assert len(varied.sensors) == 14 * 14 and len(varied.dead) == 12
    xs = sorted({s.x for s in varied.sensors})
    assert xs[:3] == [0.0, 5.0, 10.0]  # no jitter: the grid itself
    field = 13 * 5.0
    walks = {w.target: w for w in varied.trajectories}
    assert np.diff([w.t_entry for w in varied.trajectories[:5]]) == pytest.approx([6] * 4, abs=1.2)
    # crossings: persons 2-3 and 4-5 meet mid-field at the same instant
    t = np.linspace(0, varied.window[1], 40001)
    for a, b in (("2", "3"), ("4", "5")):
        gap = np.hypot(*(walks[a].position(t) - walks[b].position(t)).T)
        assert np.nanmin(gap) < 0.05
    # person 1 curves: its heading wanders around its course, at a constant walking speed
    headings = [math.atan2(s.vy, s.vx) for s in walks["1"].segments if s.vx or s.vy]
    assert len(headings) > 10 and np.ptp(np.unwrap(headings)) > 0.2
    assert all(1.0 <= math.hypot(s.vx, s.vy) <= 1.5 for s in walks["1"].segments if s.vx or s.vy)
    end = walks["1"].position(walks["1"].t_exit)
    assert min(end[0], end[1], field - end[0], field - end[1]) == pytest.approx(0, abs=1e-9)
    # person 7 walks 2-5 m beside person 6, up to 1 s behind
    lead, side = walks["6"].segments[0], walks["7"].segments[0]
    assert len(walks["7"].segments) >= len(walks["6"].segments) > 10
    assert 0 <= side.t0 - lead.t0 <= 1 and (side.vx, side.vy) == (lead.vx, lead.vy)
    offset = math.hypot(side.x0 - lead.x0, side.y0 - lead.y0)
    assert 2 <= offset <= 5 and abs((side.x0 - lead.x0) * lead.vx + (side.y0 - lead.y0) * lead.vy) < 1e-9
    # two people stop for 5-15 s
    stops = [s.t1 - s.t0 for w in varied.trajectories for s in w.segments if s.vx == 0 and s.vy == 0]
    assert len(stops) == 2 and all(5 <= d <= 15 for d in stops)
    # the default options give the default scenario (the shipped datasets stay as they are)
    assert build_scenario("darpa-grid", 4, people=7, grid=12, node_jitter=0.5, dead=6, entry_gap=10.0, walk="straight",
                          crossings=1, pairs=0, stops=0) == plain
    assert not any(s.vx == 0 and s.vy == 0 for w in plain.trajectories for s in w.segments)


@pytest.mark.parametrize("grid, spacing", [(16, 3.5), (9, 7.0)])
def test_darpa_grid_denser_or_sparser_over_the_same_field(grid, spacing):
    scenario = build_scenario("darpa-grid", 2, people=4, grid=grid, spacing=spacing, node_jitter=0.0, dead=0)
    xs = sorted({s.x for s in scenario.sensors})
    assert len(scenario.sensors) == grid * grid and xs == pytest.approx([spacing * k for k in range(grid)])
    side = (grid - 1) * spacing
    region = scenario.deployment.region
    assert (region.xmin, region.xmax) == pytest.approx((-spacing, side + spacing))
    for walk in scenario.trajectories:  # people cross the whole field, edge to edge
        t = np.linspace(walk.t_entry, walk.t_exit, 200)
        xy = walk.position(t)
        assert np.all((xy > -1e-9) & (xy < side + 1e-9))
        ends = [walk.position(walk.t_entry), walk.position(walk.t_exit)]
        assert all(min(p[0], p[1], side - p[0], side - p[1]) == pytest.approx(0, abs=1e-9) for p in ends)
    result = simulate_scenario(scenario, 2)
    assert {e.sensor for e in result.events} <= {s.id for s in scenario.sensors}
    # the default spacing is the scenario's 5 m (the shipped datasets stay as they are)
    assert build_scenario("darpa-grid", 2, people=4, spacing=5.0) == build_scenario("darpa-grid", 2, people=4)


def test_darpa_grid_spreads_the_arrivals_over_a_long_duration():
    scenario = build_scenario("darpa-grid", 11, people=10, duration=3600.0)
    entries = [p.t_entry for p in scenario.trajectories]
    exits = [p.t_exit for p in scenario.trajectories]
    assert np.diff(entries) == pytest.approx([(3600 - 90) / 10] * 9, abs=2)  # evenly, ≈ 351 s apart
    assert max(exits) <= 3600 - 5
    assert min(entries) < 400 and max(entries) > 3400  # people in every part of the hour
    # a short --duration keeps the usual spacing (and the shipped datasets their bytes)
    assert [p.t_entry for p in build_scenario("darpa-grid", 3, people=3, duration=90.0).trajectories] == \
        [p.t_entry for p in build_scenario("darpa-grid", 3, people=3).trajectories]


def test_laser_testbed():
    scenario = build_scenario("laser-testbed", 1, passes=5)
    result = simulate_scenario(scenario, 1)
    published = scenario.deployment.sensors
    assert [s.id for s in published] == ["L1", "L2", "L3", "L4", "L5", "L6"]
    assert all(s.a is None and s.x is not None for s in published)
    assert scenario.deployment.units == "ft"
    passes = scenario.deployment.calibration.passes
    assert [(p.pass_, p.entry, p.exit) for p in passes] == [(1, (0, 0), (16, 0)), (2, (0, 0), (16, 8))]
    assert passes[0].t_exit - passes[0].t_entry == pytest.approx(16 / 1.41, rel=0.06)
    # every pass crosses every beam once, within the detection noise of the exact time
    assert len(result.events) == 6 * 5
    for run in scenario.trajectories:
        assert run.position(run.t_entry)[0] == 0 and run.position(run.t_exit)[0] == pytest.approx(16)
        for sensor in scenario.sensors:
            exact = beam_crossings(sensor, [run])
            assert len(exact) == 1
            near = [e for e in result.events if e.sensor == sensor.id and abs(e.t - exact[0].t) <= 0.01 + 1e-12]
            assert len(near) == 1
    angles = sorted(math.degrees(math.atan2(abs(s.a), abs(s.b))) % 180 for s in scenario.sensors)
    assert all(55 <= a <= 70 for a in angles) and min(np.diff(angles)) > 0.5


def test_motion_scenarios():
    for kind in ("constant", "random-walk"):
        result = simulate("motion", 1, nodes=20, trajectory=kind, duration=30)
        assert len(result.events) == 20 * 31
        assert {e.value for e in result.events} == {-1, 1}


@pytest.mark.parametrize("options, message", [
    (dict(name="uniform-800", sectors=4), "--sectors does not apply"),
    (dict(name="uniform-800", law="linear"), "--law applies to --model imperfect"),
    (dict(name="uniform-800", pd=0.5), "need --period"),
    (dict(name="uniform-800", faults="both", period=1.0), "cannot go with --period"),
    (dict(name="uniform-800", faults="sometimes"), "--faults must be one of"),
    (dict(name="uniform-800", sensing_range=-1.0), "--range must be within"),
    (dict(name="uniform-800", duration=1e6), "lower --duration"),
    (dict(name="uniform-800", trajectory="speed-changes", duration=10.0), "--duration does not apply"),
    (dict(name="sector-300", sectors=0), "--sectors must be at least 1"),
    (dict(name="sector-300", faults="wrong"), "--faults does not apply"),
    (dict(name="darpa-grid", people=0), "--people must be at least 1"),
    (dict(name="darpa-grid", duration=30.0), "ends before the last person leaves"),
    (dict(name="darpa-grid", walk="zigzag"), "--walk must be one of"),
    (dict(name="darpa-grid", people=3, crossings=2), "--crossings must be within 0..1"),
    (dict(name="darpa-grid", people=4, pairs=1), "would include crossing ones"),
    (dict(name="darpa-grid", people=2, stops=3), "--stops must be within 0..2"),
    (dict(name="darpa-grid", grid=1), "--grid must be within"),
    (dict(name="darpa-grid", node_jitter=3.0), "--node-jitter must be within"),
    (dict(name="darpa-grid", spacing=4.0, node_jitter=2.0), r"--node-jitter must be within \[0, 2\) m"),
    (dict(name="darpa-grid", spacing=0.0), "--spacing must be positive"),
    (dict(name="laser-testbed", passes=1), "--passes must be at least 2"),
    (dict(name="motion", trajectory="circular"), "--trajectory must be one of constant, random-walk"),
    (dict(name="nowhere"), "unknown scenario"),
])
def test_impossible_options_are_rejected(options, message):
    name = options.pop("name")
    with pytest.raises(ScenarioError, match=message):
        build_scenario(name, 0, **options)


# --------------------------------------------------------------------------- the command


@pytest.mark.parametrize("argv", [
    ["uniform-800", "--nodes", "80", "--model", "imperfect", "--law", "exponential", "--faults", "both"],
    ["uniform-800", "--nodes", "80", "--trajectory", "random", "--period", "0.5", "--pd", "0.9", "--pfa", "0.01"],
    ["sector-300", "--nodes", "60", "--sectors", "6", "--trajectory", "circular", "--clock-offset", "0.1"],
    ["darpa-grid", "--people", "2"],
    ["darpa-grid", "--people", "2", "--grid", "9", "--spacing", "7"],
    ["laser-testbed", "--passes", "4"],
    ["motion", "--nodes", "15", "--trajectory", "random-walk", "--duration", "20"],
])
def test_every_scenario_writes_a_readable_dataset(tmp_path, capsys, argv):
    out = tmp_path / "ds"
    assert main(["simulate", *argv, "--seed", "5", "--out", str(out)]) == 0
    summary = capsys.readouterr().out.strip().splitlines()
    assert len(summary) == 1 and "events from" in summary[0]
    dataset = open_dataset(out)
    events = list(dataset.events())
    assert events and dataset.has_truth and dataset.truth()


def test_command_errors_are_one_line_with_status_2(tmp_path, capsys):
    assert main(["simulate", "uniform-800", "--sectors", "4", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--sectors does not apply to scenario uniform-800" in err[0]
    assert main(["simulate", "uniform-800", "--range", "nan", "--out", str(tmp_path / "x")]) == 2
    assert "finite" in capsys.readouterr().err
    (tmp_path / "file").write_text("")
    assert main(["simulate", "motion", "--out", str(tmp_path / "file")]) == 2
    assert "not a folder" in capsys.readouterr().err
    assert main(["simulate", "motion", "--seed", "-1", "--out", str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()


def _dataset_commands():
    """The ``$(BINTRACK) simulate …`` lines of the Makefile's ``datasets`` recipe."""
    text = (REPO / "Makefile").read_text()
    recipe = text.split("\ndatasets:", 1)[1].split("\n\n", 1)[0]
    return [shlex.split(line.replace("$(BINTRACK)", "")) for line in recipe.splitlines() if "simulate" in line]


def test_shipped_datasets_are_remade_byte_for_byte(tmp_path, capsys):
    commands = _dataset_commands()
    assert {Path(argv[argv.index("--out") + 1]).name for argv in commands} == {
        "darpa-grid-1", "darpa-grid-2", "darpa-grid-3", "darpa-grid-3-sites", "laser-testbed"}
    for argv in commands:
        shipped = REPO / argv[argv.index("--out") + 1]
        out = tmp_path / shipped.name
        argv[argv.index("--out") + 1] = str(out)
        assert main(argv) == 0
        files = sorted(p.name for p in shipped.iterdir())
        assert files == sorted(p.name for p in out.iterdir()) == ["deployment.json", "events.csv", "truth.csv"]
        for name in files:
            assert (out / name).read_bytes() == (shipped / name).read_bytes(), f"{shipped.name}/{name} differs"
        assert sum((shipped / name).stat().st_size for name in files) < 1_000_000
