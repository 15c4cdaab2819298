"""The sector tracker of paper 000 (§III) on hand-built configurations and simulated data."""

import math

import numpy as np
import pytest

from bintrack.trackers.arc.arcs import ArcSet
from bintrack.evaluation.eval_report import evaluate
from bintrack.formats import open_dataset, write_dataset, write_tracks
from bintrack.geometry import TWO_PI
from bintrack.bus_payloads import Transition
from bintrack.deployment_model import Deployment
from bintrack.pipeline import output_rows, run_tracker
from bintrack.sensing import SectorModel, model_for
from bintrack.sim import trajectories
from bintrack.sim.scenarios import simulate
from bintrack.sim.transitions import exact_transitions
from bintrack.trackers import TRACKER_NAMES, make_tracker
from bintrack.trackers.arc.sector_tracker import (
    SectorTracker,
    crossed_boundary,
    match_angles,
    neighbour_sector_match,
    radius_match,
    sector_arc,
    status_bits,
)
from bintrack.transition_detector import TransitionDetector

SECTOR_COUNTS = (1, 2, 3, 4, 6, 12)


def sector_sensor(sid, x, y, r, s, offset):
    return dict(id=sid, kind="sector", x=x, y=y, range=r, sectors=s, offset=offset)


def hand_deployment(sensors) -> Deployment:
    return Deployment(name="hand", units="unit", region=dict(xmin=-5, ymin=-5, xmax=5, ymax=5), sensors=sensors)


def feed(tracker, steps):
    out, seq, last = [], {}, {}
    for t, sensor, value in steps:
        seq[sensor] = seq.get(sensor, 0) + 1
        out += tracker.update(Transition(t=t, sensor=sensor, value=value, previous=last.get(sensor, -1),
                                         seq=seq[sensor]))
        last[sensor] = value
    return out + tracker.flush(math.inf)


def test_registered_and_status_bits():
    assert "sector" in TRACKER_NAMES
    assert isinstance(make_tracker("sector", hand_deployment([sector_sensor("a", 0, 0, 1, 4, 0)])), SectorTracker)
    # b = ⌈log2(s + 1)⌉
    assert [status_bits(s) for s in (1, 2, 3, 4, 7, 8, 12)] == [1, 2, 2, 3, 3, 4, 4]
    for s in range(1, 40):
        assert status_bits(s) == math.ceil(math.log2(s + 1))


def test_sector_arc_is_the_border_of_the_sector():
    model = SectorModel(0, 0, 1.0, 1.0, None, 4, 0.3)
    theta = np.linspace(0, TWO_PI, 4001)[:-1] + 1e-4
    points = np.c_[np.cos(theta), np.sin(theta)]
    for k in range(4):
        arc = sector_arc(model, k)
        assert arc.length == pytest.approx(TWO_PI / 4)
        assert np.array_equal(arc.contains(theta, tol=0.0), model.sector_of(points) == k)
    assert sector_arc(SectorModel(0, 0, 1.0, 1.0, None, 1, 2.0), 0).is_full


def random_model(rng, s=None) -> SectorModel:
    s = int(rng.choice(SECTOR_COUNTS)) if s is None else s
    return SectorModel(float(rng.uniform(-1, 1)), float(rng.uniform(-1, 1)), float(rng.uniform(0.6, 1.4)), 0.0, None,
                       s, float(rng.uniform(0, TWO_PI)))


def test_neighbour_sector_match_equals_dense_sampling():
    """§III.B.1: every point of the node's circle lies in exactly the piece (own sector j,
    neighbour status k) that brute force finds, for differing s, offsets and ranges."""
    rng = np.random.default_rng(3)
    n = 50_000
    theta = (np.arange(n) + 0.5) * TWO_PI / n
    checked = 0
    for _ in range(60):
        node, nbr = random_model(rng), random_model(rng)
        if math.dist(node.centre, nbr.centre) >= node.range + nbr.range:
            continue
        match = neighbour_sector_match(node, nbr)
        points = np.asarray(node.centre) + node.range * np.c_[np.cos(theta), np.sin(theta)]
        own, theirs = node.sector_of(points), nbr.status(points)
        cuts = match_angles(node, nbr)
        gap = np.abs((theta[:, None] - cuts[None, :] + math.pi) % TWO_PI - math.pi).min(axis=1, initial=math.pi)
        clear = gap > 1e-7
        covered = np.zeros(n, dtype=int)
        for (j, k), arcs in match.items():
            inside = arcs.contains(theta, tol=0.0)
            covered += inside
            assert np.array_equal(inside[clear], ((own == j) & (theirs == k))[clear]), (j, k)
        assert np.array_equal(covered[clear], (theirs != -1)[clear].astype(int))
        assert sum(arcs.length for arcs in match.values()) == pytest.approx(TWO_PI * (theirs != -1).mean(), abs=1e-3)
        checked += 1
    assert checked > 30


def test_fig3_kinds_of_points():
    """Fig. 3: two 4-sector nodes; the cut points are the two circle–circle points (type 1), the
    neighbour's boundaries on the node's circle (type 2) and the node's own boundaries (type 3)."""
    node = SectorModel(0, 0, 1.0, 1.0, None, 4, math.pi / 4)
    nbr = SectorModel(1.2, 0, 1.0, 1.0, None, 4, 0.0)
    cuts = match_angles(node, nbr)
    half = math.acos(0.6)  # circle–circle points at ±acos(d/2R)
    expected = {half, TWO_PI - half}  # type 1
    expected |= {math.pi / 4, 3 * math.pi / 4, 5 * math.pi / 4, 7 * math.pi / 4}  # type 3 (own boundaries)
    # type 2: the neighbour's boundaries at π/2, π and 3π/2 meet the node's circle
    for boundary in (math.pi / 2, math.pi, 3 * math.pi / 2):
        u = np.array([math.cos(boundary), math.sin(boundary)])
        # |(1.2, 0) + t·u| = 1, t in [0, 1]
        b, c = 2 * 1.2 * u[0], 1.2**2 - 1
        for t in ((-b + s * math.sqrt(b * b - 4 * c)) / 2 for s in (-1, 1) if b * b - 4 * c >= 0):
            if 0 <= t <= 1:
                p = np.array([1.2, 0]) + t * u
                expected.add(math.atan2(p[1], p[0]) % TWO_PI)
    assert np.allclose(np.sort(cuts), np.sort(list(expected)), atol=1e-12)


def test_transitions_include_sector_changes():
    """A sector sensor publishes on entering, on every change of sector and on leaving: the
    simulator emits every change and the sensor agent's TransitionDetector turns each into a message."""
    sensor = sector_sensor("a", 0.0, 0.0, 1.0, 4, 0.0)
    dep = hand_deployment([sensor])
    path = trajectories.polyline("0", 0.0, [(-2.0, 0.3), (2.0, 0.3)], 1.0)
    events = exact_transitions(dep.sensors[0], [path])
    # clockwise from offset 0: sector 2 is (π/2, π], sector 3 is (0, π/2]; the path crosses the boundary at π/2
    assert [e.value for e in events] == [2, 3, -1]
    assert events[1].t == pytest.approx(2.0)
    detector = TransitionDetector(dep)
    transitions = [tr for e in events if (tr := detector.update(e)) is not None]
    assert [(tr.previous, tr.value, tr.seq) for tr in transitions] == [(-1, 2, 1), (2, 3, 2), (3, -1, 3)]


def test_a_sector_change_updates_the_lists_but_makes_no_estimate():
    dep = hand_deployment([sector_sensor("x", 0, 0, 1, 4, 0), sector_sensor("y", 0.8, 0.5, 1, 4, 1.0)])
    tracker = SectorTracker(dep)
    estimates = feed(tracker, [(1.0, "x", 3), (2.0, "x", 2), (3.0, "y", 1), (4.0, "x", -1)])
    assert [e.node for e in estimates] == ["x", "y", "x"]
    assert tracker.status.tolist() == [-1, 1]


def test_fig4_present_and_absent_neighbour_sectors():
    """Fig. 4(a)/(c): "&" with a present neighbour's sector, "−" with an absent neighbour's disk."""
    node = dict(id="x", kind="sector", x=0, y=0, range=1.0, sectors=1, offset=0.0)
    y = sector_sensor("y", 1.0, 0.0, 1.0, 2, 0.0)  # sector 0: lower half-plane below y's centre, 1: upper
    z = dict(id="z", kind="disk", x=0.9, y=1.1, range=0.6)
    tracker = SectorTracker(hand_deployment([node, y, z]))
    feed(tracker, [(1.0, "y", 1)])
    tracker._apply(0, 0)
    tracker.crossed[0] = 0
    fa, present = tracker.final_arcs(0)
    # x's circle inside y's disk: |θ| ≤ π/3; in y's upper sector: y > 0, so 0 < θ ≤ π/3; minus z's disk
    theta = (np.arange(20000) + 0.5) * TWO_PI / 20000
    p = np.c_[np.cos(theta), np.sin(theta)]
    expected = (np.hypot(p[:, 0] - 1, p[:, 1]) < 1) & (p[:, 1] > 0) & (np.hypot(p[:, 0] - 0.9, p[:, 1] - 1.1) >= 0.6)
    assert np.array_equal(fa.contains(theta, tol=0.0), expected)
    assert present.tolist() == [1]


def test_split_result_is_resolved_by_the_last_estimate():
    """Fig. 4(d): the crossed border minus an absent neighbour's disk is two arcs; with no estimate
    yet the longer is taken, after a neighbour's estimate on the left the left one."""
    x = sector_sensor("x", 0, 0, 1.0, 2, 0.0)  # sector 1 borders the upper half of the circle
    y = dict(id="y", kind="disk", x=-0.3, y=1.0, range=0.5)  # cuts the top: right piece longer
    w = dict(id="w", kind="disk", x=-1.3, y=0.4, range=0.5)  # on the left
    dep = hand_deployment([x, y, w])
    alone = SectorTracker(dep)
    (first,) = feed(alone, [(2.0, "x", 1)])
    fa, _ = alone.final_arcs(0)
    assert len(fa) == 2
    assert first.x > 0 and first.arc == pytest.approx(max(a.length for a in fa))
    guided = SectorTracker(dep)
    out = feed(guided, [(1.0, "w", 1), (1.5, "w", 0), (2.0, "x", 1)])
    assert [e.node for e in out] == ["w", "w", "x"]
    assert out[0].x < 0 and out[-1].x < 0
    assert out[-1].arc == pytest.approx(min(a.length for a in fa))


def mixed_deployment(rng, nodes=70, side=300.0):
    """Sector sensors of differing s, offset and range, and a few disk sensors."""
    sensors = []
    for k in range(nodes):
        x, y = rng.uniform(0, side, 2)
        r = float(rng.uniform(35, 65))
        if k % 7 == 0:
            sensors.append(dict(id=f"d{k}", kind="disk", x=float(x), y=float(y), range=r))
        else:
            sensors.append(sector_sensor(f"s{k}", float(x), float(y), r, int(rng.choice(SECTOR_COUNTS)),
                                         float(rng.uniform(0, TWO_PI))))
    return Deployment(name="mixed", units="unit", region=dict(xmin=0, ymin=0, xmax=side, ymax=side), sensors=sensors)


class RecordingSectorTracker(SectorTracker):
    """Keeps (node, border, FA) of every estimate, in the order of the estimates; the border is
    ("circle", crossed sector) or ("radius", boundary index)."""

    def __init__(self, deployment, radial):
        super().__init__(deployment, radial=radial)
        self.seen = []

    def estimate(self, i):
        m = int(self.boundary[i])
        if m >= 0:
            self.seen.append((i, ("radius", m), self.radius_arcs(i, m)))
        else:
            self.seen.append((i, ("circle", int(self.crossed[i])), self.final_arcs(i)[0]))
        return super().estimate(i)


def cross(a, b) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def wrapped_gap(values, ends, period=TWO_PI):
    if len(ends) == 0:
        return np.full(len(values), np.inf)
    return np.abs((values[:, None] - np.asarray(ends)[None, :] + period / 2) % period - period / 2).min(axis=1)


def test_fa_is_the_true_feasible_set_with_differing_nodes():
    """At every estimate FA equals, point for point, the part of the crossed border (the crossed
    sector's arc, or with ``radial`` the crossed boundary radius) where every other sensor would
    report what it reports at the target's true position (brute force over all sensors); the
    true point is on FA and the estimate on the border, for nodes of differing s, offset, range."""
    rng = np.random.default_rng(0)
    dep = mixed_deployment(rng)
    path = trajectories.polyline("0", 0.0, [(-80, 120), (150, 210), (380, 90)], 5.0)
    events = sorted((e for s in dep.sensors for e in exact_transitions(s, [path])), key=lambda e: (e.t, e.sensor))
    tracker = RecordingSectorTracker(dep, radial=True)
    detector = TransitionDetector(dep)
    estimates = []
    for e in events:
        if (tr := detector.update(e)) is not None:
            estimates += tracker.update(tr)
    estimates += tracker.flush(math.inf)
    assert len(estimates) == len(tracker.seen) > 20
    kinds = [kind for _, (kind, _), _ in tracker.seen]
    assert kinds.count("radius") > 10 and kinds.count("circle") > 10
    models = [model_for(s) for s in dep.sensors]
    n = 10_000
    grid = (np.arange(n) + 0.5) / n
    chosen = 0
    for est, (i, (kind, index), fa) in zip(estimates, tracker.seen):
        node = models[i]
        centre = np.asarray(node.centre)
        truth = path.position(np.array([est.t]))[0]
        if kind == "circle":
            param = grid * TWO_PI
            q = centre + node.range * np.c_[np.cos(param), np.sin(param)]
            own = node.sector_of(q) if isinstance(node, SectorModel) else np.zeros(n, dtype=int)
            feasible = own == index
            assert math.dist(truth, centre) == pytest.approx(node.range, rel=1e-9)
            truth_param = math.atan2(truth[1] - centre[1], truth[0] - centre[0]) % TWO_PI
            est_param = math.atan2(est.y - centre[1], est.x - centre[0]) % TWO_PI
            assert math.dist((est.x, est.y), centre) == pytest.approx(node.range)
        else:
            angle = node.boundary_angles()[index]
            u = np.array([math.cos(angle), math.sin(angle)])
            param = grid * math.pi
            q = centre + np.outer(grid * node.range, u)
            feasible = np.ones(n, dtype=bool)
            assert abs(cross(u, truth - centre)) < 1e-6 * node.range  # the target is on the radius
            truth_param = float((truth - centre) @ u) / node.range * math.pi
            est_param = float((np.array([est.x, est.y]) - centre) @ u) / node.range * math.pi
            assert abs(cross(u, np.array([est.x, est.y]) - centre)) < 1e-6 * node.range
        for m, model in enumerate(models):
            if m != i:
                feasible &= model.status(q) == model.status(truth[None, :])[0]
        ends = [a for arc in fa for a in (arc.start, arc.start + arc.length)]
        clear = wrapped_gap(param, ends) > 1e-6
        assert np.array_equal(fa.contains(param, tol=0.0)[clear], feasible[clear]), (kind, i)
        assert fa.contains(truth_param, tol=1e-9)
        assert fa.contains(est_param, tol=1e-9)
        chosen += ArcSet([fa.nearest(truth_param)]).contains(est_param, tol=1e-9)
    assert chosen > 0.9 * len(estimates)


def test_radius_match_equals_dense_sampling():
    rng = np.random.default_rng(8)
    n = 20_000
    grid = (np.arange(n) + 0.5) / n
    checked = 0
    for _ in range(60):
        node, nbr = random_model(rng, s=int(rng.choice((3, 4, 6, 12)))), random_model(rng)
        m = int(rng.integers(node.sectors))
        angle = float(node.boundary_angles()[m])
        u = np.array([math.cos(angle), math.sin(angle)])
        match = radius_match(node, m, nbr)
        theirs = nbr.status(np.asarray(node.centre) + np.outer(grid * node.range, u))
        param = grid * math.pi
        ends = [a for arcs in match.values() for arc in arcs for a in (arc.start, arc.start + arc.length)]
        clear = wrapped_gap(param, ends) > 1e-7
        covered = np.zeros(n, dtype=bool)
        for k in set(theirs.tolist()) | set(match):
            if k == -1:
                continue
            inside = match[k].contains(param, tol=0.0) if k in match else np.zeros(n, dtype=bool)
            assert np.array_equal(inside[clear], (theirs == k)[clear]), k
            covered |= inside
        assert np.array_equal(covered[clear], (theirs != -1)[clear])
        checked += bool(match)
    assert checked > 20


def test_crossed_boundary():
    model = SectorModel(0, 0, 1.0, 1.0, None, 4, 0.0)
    assert crossed_boundary(model, 0, 1) == 1  # clockwise: sector 0 ends at offset − 2π/4
    assert crossed_boundary(model, 1, 0) == 1
    assert crossed_boundary(model, 3, 0) == 0 and crossed_boundary(model, 0, 3) == 0
    assert crossed_boundary(model, 0, 2) is None  # not adjacent
    assert crossed_boundary(SectorModel(0, 0, 1.0, 1.0, None, 2, 0.0), 0, 1) is None  # either of two radii
    theta = np.array([-math.pi / 2 + 1e-6, -math.pi / 2 - 1e-6])  # either side of boundary 1 at −π/2
    assert model.sector_of(np.c_[np.cos(theta), np.sin(theta)]).tolist() == [0, 1]


def test_one_sector_is_the_arc_tracker(tmp_path):
    """With s = 1 (omni-directional sensors) FA starts at 2π, as in paper 001: same estimates."""
    result = simulate("sector-300", seed=4, sensing_range=70.0, sectors=1, nodes=200, trajectory="random")
    dataset = open_dataset(write_dataset(tmp_path / "s1", *result))
    arc = list(run_tracker(dataset, make_tracker("arc", dataset.deployment)))
    sector = list(run_tracker(dataset, make_tracker("sector", dataset.deployment)))
    assert len(arc) == len(sector) > 20
    for a, s in zip(arc, sector):
        assert (a.t, a.node) == (s.t, s.node)
        assert (s.x, s.y, s.arc) == pytest.approx((a.x, a.y, a.arc), abs=1e-9)


def test_more_sectors_more_accurate_than_omni(tmp_path):
    """Paper 000 §V.C on two runs at R = 100: 4 sectors beat omni (the arc tracker on the same
    nodes, which ignores the sector), 12 sectors beat 4, and 12 sectors are well under omni."""
    errors = {"arc": [], 4: [], 12: []}
    for seed in range(2):
        for s in (4, 12):
            result = simulate("sector-300", seed=seed, sensing_range=100.0, sectors=s, trajectory="linear")
            dataset = open_dataset(write_dataset(tmp_path / f"d{seed}-{s}", *result))
            for name in ("arc", "sector") if s == 4 else ("sector",):
                tracks = dataset.path / f"{name}.csv"
                write_tracks(tracks, output_rows(run_tracker(dataset, make_tracker(name, dataset.deployment))))
                errors["arc" if name == "arc" else s].append(
                    evaluate(dataset, tracks).value("location_error_over_R_mean"))
    mean = {k: float(np.mean(v)) for k, v in errors.items()}
    assert mean[4] < mean["arc"]
    assert mean[12] < mean[4]
    assert mean[12] < 0.7 * mean["arc"]


def test_radial_crossing_estimate_is_on_the_boundary_radius():
    """With ``radial``, a change from sector 0 to 1 puts the target on the radius between them
    (here at −π/2); an absent neighbour splits that radius, and the piece nearest the node's
    last estimate (at r ≈ 0.71 along it) is taken although the other is longer. The paper's
    tracker makes no estimate at the change of sector."""
    x = sector_sensor("x", 0, 0, 1.0, 4, 0.0)
    y = dict(id="y", kind="disk", x=0.1, y=-0.6, range=0.2)  # cuts the radius at r = 0.6 ∓ √0.03
    dep = hand_deployment([x, y])
    steps = [(1.0, "x", 0), (2.0, "x", 1)]
    assert len(feed(SectorTracker(dep), steps)) == 1
    entered, changed = feed(SectorTracker(dep, radial=True), steps)
    assert (entered.x, entered.y) == pytest.approx((math.sqrt(0.5), -math.sqrt(0.5)))
    cut = math.sqrt(0.03)
    assert (changed.x, changed.y) == pytest.approx((0.0, -(0.6 + cut + 1.0) / 2))
    assert changed.arc == pytest.approx(1.0 - 0.6 - cut)
