"""The laser tracker's per-pass bounds (pass_bound), its real-world re-solve (realworld_solve) and
the revised estimates it publishes (revisions): against Monte Carlo, the truth and themselves."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bintrack.cli import main as cli
from bintrack.evaluation.metrics import entry_exit_errors, truth_paths
from bintrack.formats import open_dataset, write_objects
from bintrack.message_codec import decode, encode
from bintrack.pipeline import output_objects, run_tracker
from bintrack.sim.scenarios import build_scenario
from bintrack.bus_payloads import LineObjectEstimate
from bintrack.trackers.laser.pass_bound import known_beams_bound, timing_variance, unknown_beams_bounds
from bintrack.trackers.laser.realworld_solve import fit_passes
from bintrack.trackers.laser.revisions import SETTLE_UNITS
from bintrack.trackers.laser.tracker import AdaptiveBasisTracker
from bintrack.transition_detector import TransitionDetector

BOX = (0.0, 0.0, 16.0, 8.0)
JITTER = 0.02


def _truth(seed: int, passes: int):
    scenario = build_scenario("laser-testbed", seed, passes=passes, jitter=JITTER, lean=63.0, offset=0.2)
    lines = np.array([(s.a, s.b) for s in scenario.sensors])
    segs = [t.segments[0] for t in scenario.trajectories]
    return scenario, lines, np.array([[s.vx, s.x0, s.vy, s.y0] for s in segs]), np.array([s.t0 for s in segs])


def _simulate(tmp_path_factory, seed: int, passes: int):
    folder = tmp_path_factory.mktemp("laser") / "dataset"
    assert cli.main(["simulate", "laser-testbed", "--seed", str(seed), "--passes", str(passes), "--jitter", str(JITTER),
                     "--lean", "63", "--offset", "0.2", "--out", str(folder)]) == 0
    return folder


@pytest.fixture(scope="module")
def testbed(tmp_path_factory):
    return _simulate(tmp_path_factory, 105, 24)


def test_known_beams_bound_is_what_least_squares_attains():
    """Gauss–Markov: the time-residual fit of a pass with the beams known has covariance equal to
    the bound for any noise of variance J²/3 (here uniform); 3000 draws, RMS within 6 %."""
    _, lines, w, refs = _truth(3, 6)
    rng = np.random.default_rng(7)
    for l in (2, 4):
        bound = known_beams_bound(lines, w[l], refs[l], BOX, JITTER)
        tau = (1.0 - lines @ w[l, [1, 3]]) / (lines @ w[l, [0, 2]])
        draws = 3000
        noisy = tau[:, None] + rng.uniform(-JITTER, JITTER, (len(lines), draws))
        fitted = fit_passes(lines, noisy, np.ones_like(noisy, dtype=bool), np.tile(w[l], (draws, 1)),
                            np.ones(draws, dtype=bool))
        x0, v = fitted[:, [1, 3]], fitted[:, [0, 2]]
        # the entry is on x = 0 for every draw (the pass enters through the left edge)
        entry_y = x0[:, 1] + v[:, 1] * (0.0 - x0[:, 0]) / v[:, 0]
        true_y = w[l, 3] + w[l, 2] * (0.0 - w[l, 1]) / w[l, 0]
        rms = math.sqrt(np.mean((entry_y - true_y) ** 2))
        assert rms == pytest.approx(bound[0], rel=0.06)


def test_unknown_beams_bound_is_above_the_known_one_and_falls_with_passes():
    scenario, lines, w, refs = _truth(5, 24)
    positions = {k: (s.x, s.y) for k, s in enumerate(scenario.sensors)}
    known = np.array([known_beams_bound(lines, w[l], refs[l], BOX, JITTER) for l in range(24)])
    final = unknown_beams_bounds(lines, w, refs, BOX, JITTER, known=(0, 1), positions=positions)
    early = unknown_beams_bounds(lines, w[:8], refs[:8], BOX, JITTER, known=(0, 1), positions=positions)
    free = unknown_beams_bounds(lines, w, refs, BOX, JITTER, known=(0, 1))
    assert np.all(np.isnan(final[:2]))
    assert np.all(final[2:] > known[2:])
    assert np.all(early[2:8] > final[2:8])
    assert np.all(free[2:] > final[2:])  # known positions add information
    assert timing_variance(0.03) == pytest.approx(0.0003)


def _stream(folder, **kw):
    dataset = open_dataset(folder)
    tracker = AdaptiveBasisTracker(dataset.deployment, **kw)
    return dataset, tracker, list(run_tracker(dataset, tracker))


@pytest.fixture(scope="module")
def streamed(testbed):
    return _stream(testbed)


def test_revisions_are_numbered_move_by_more_than_their_sd_and_end_at_the_final_solve(streamed):
    dataset, tracker, out = streamed
    last: dict[int, LineObjectEstimate] = {}
    for o in out:
        if o.revision is None:
            assert o.object not in last
        else:
            before = last[o.object]
            assert o.revision == (before.revision or 0) + 1
            entry = math.dist((o.entry_x, o.entry_y), (before.entry_x, before.entry_y))
            exit_ = math.dist((o.exit_x, o.exit_y), (before.exit_x, before.exit_y))
            # moved by more than its sd, or (the last revision, at the end) by more than SETTLE_UNITS
            assert entry > before.entry_sd or exit_ > before.exit_sd or max(entry, exit_) > SETTLE_UNITS
        last[o.object] = o
    assert sum(1 for o in out if o.revision) >= 10
    # the latest revision of every pass is within SETTLE_UNITS of the final re-solve
    sol = tracker.revisions.solution
    for obj, message in last.items():
        got = tracker.revisions.estimate(obj - 1, float(tracker.basis.t_refs[obj - 1]), message)
        if got is not None:
            assert math.dist((message.entry_x, message.entry_y), (got[0].entry_x, got[0].entry_y)) <= SETTLE_UNITS
    assert sol is not None and tracker.revisions.settled


def test_online_and_final_estimates_recover_from_a_hard_start(tmp_path_factory):
    """Seed 108's phase 1 start is degenerate (phases 1–3 alone err by feet, passes standing still
    in the adaptive frame); the re-solve, started also from the calibration passes, is near the
    bound when each pass closes (the online estimate) and at the end (the final one)."""
    folder = _simulate(tmp_path_factory, 108, 36)
    dataset, _, out = _stream(folder)
    _, _, plain = _stream(folder, revise=False)
    paths = truth_paths(dataset.truth())
    old, online, final = ([e.entry for e in entry_exit_errors(rows, paths) if e.object >= 5] for rows in
                          (output_objects(plain), output_objects(out, online=True), output_objects(out)))
    assert np.mean(old) > 1.0
    assert np.mean(online) < 0.1 and max(online) < 0.3
    assert np.mean(final) < 0.1 and max(final) < 0.3


def test_online_output_is_the_estimate_known_when_each_pass_closed(testbed, streamed, tmp_path):
    """The first estimate of a pass is the re-solve over the passes so far, this one included
    (phases 1–3's where the re-solve has none); it is never revised in the output that publishes it;
    ``--online`` writes the first estimates, ``track`` the latest."""
    dataset, _, out = streamed
    tracker = AdaptiveBasisTracker(dataset.deployment)
    detector = TransitionDetector(dataset.deployment)
    first, resolved = [], 0
    transitions = [tr for tr in map(detector.update, dataset.events()) if tr is not None]
    for tr in transitions + [None]:
        step = tracker.update(tr) if tr is not None else tracker.flush(math.inf)
        new = [o for o in step if o.revision is None]
        assert not {o.object for o in step if o.revision} & {o.object for o in new}
        for o in new:
            got = tracker.revisions.estimate(o.object - 1, float(tracker.basis.t_refs[o.object - 1]), o)
            if got is not None and got[0] == o:
                resolved += 1
            else:  # phases 1–3's estimate, where the re-solve had none
                assert o == tracker._estimate(o.object - 1)
        first += new
    assert resolved == len(first) == 24
    assert first == [o for o in out if o.revision is None]
    # better than phases 1–3 alone (the first estimates before revisions existed), passes 5 on
    _, _, plain = _stream(testbed, revise=False)
    paths = truth_paths(dataset.truth())
    ours, old = ([e.entry for e in entry_exit_errors(output_objects(rows), paths) if e.object >= 5]
                 for rows in (first, plain))
    assert np.mean(ours) < np.mean(old)
    online, final = tmp_path / "online.csv", tmp_path / "final.csv"
    assert cli.main(["track", str(testbed), "--tracker", "adaptive-basis", "--online", "--out", str(online)]) == 0
    assert cli.main(["track", str(testbed), "--tracker", "adaptive-basis", "--out", str(final)]) == 0
    expected_online, expected_final = tmp_path / "first.csv", tmp_path / "latest.csv"
    write_objects(expected_online, output_objects(first))
    write_objects(expected_final, output_objects(out))
    assert online.read_bytes() == expected_online.read_bytes()
    assert final.read_bytes() == expected_final.read_bytes() != online.read_bytes()


def test_flushing_after_every_transition_gives_the_same_revisions(testbed, streamed):
    dataset = open_dataset(testbed)
    tracker = AdaptiveBasisTracker(dataset.deployment)
    detector = TransitionDetector(dataset.deployment)
    out = []
    for event in dataset.events():
        tr = detector.update(event)
        if tr is not None:
            out += tracker.update(tr) + tracker.flush(tr.t)
    out += tracker.flush(math.inf) + tracker.flush(math.inf)
    assert out == streamed[2]


def test_online_flag_is_refused_for_other_trackers(testbed, capsys):
    assert cli.main(["track", str(testbed), "--tracker", "equal-weight", "--online", "--out", "-"]) != 0
    assert "--online" in capsys.readouterr().err


def test_an_old_message_without_a_revision_still_decodes():
    import msgpack

    new = LineObjectEstimate(object=3, t_first=0, t_last=1, entry_x=0, entry_y=3, exit_x=16, exit_y=4, vx=1, vy=.1,
                             revision=2)
    fields = msgpack.unpackb(encode(new))
    if isinstance(fields, dict):
        fields.pop("revision")
    else:
        pytest.skip("payloads are not maps")
    old = decode(LineObjectEstimate, msgpack.packb(fields))
    assert old.revision is None and old.model_copy(update={"revision": 2}) == new


def test_the_map_keeps_the_latest_revision_of_each_object():
    from bintrack.view.map_messages import message_item
    from bintrack.view.map_state import MapState

    state = MapState()
    first = LineObjectEstimate(object=4, t_first=0, t_last=1, entry_x=0, entry_y=3, exit_x=16, exit_y=4, vx=1, vy=.1)
    other = first.model_copy(update={"object": 5})
    revised = first.model_copy(update={"entry_y": 3.5, "revision": 1})
    for message in (first, other, revised, first):  # a stale first estimate after the revision is ignored
        assert state.apply(message_item(message))
    objects = state.snapshot()["objects"]
    assert [(o["n"], o["rev"], o["entry"][1]) for o in objects] == [(4, 1, 3.5), (5, 0, 3.0)]


def test_eval_prints_final_and_online_figures_side_by_side(testbed, tmp_path, capsys):
    import json

    online, final = tmp_path / "online.csv", tmp_path / "final.csv"
    assert cli.main(["track", str(testbed), "--tracker", "adaptive-basis", "--online", "--out", str(online)]) == 0
    assert cli.main(["track", str(testbed), "--tracker", "adaptive-basis", "--out", str(final)]) == 0
    capsys.readouterr()
    assert cli.main(["eval", str(testbed), str(final), "--online", str(online), "--json"]) == 0
    both = json.loads(capsys.readouterr().out)
    assert both["final"]["entry_error_mean"] < both["online"]["entry_error_mean"]
    assert cli.main(["eval", str(testbed), str(final), "--online", str(online)]) == 0
    text = capsys.readouterr().out
    row = next(line for line in text.splitlines() if line.startswith("entry point error, mean"))
    shown = [float(v) for v in row.split()[-3:-1]]
    assert shown == pytest.approx([both["final"]["entry_error_mean"], both["online"]["entry_error_mean"]], rel=1e-3)


def test_ill_conditioned_calibration_passes_are_flagged(testbed):
    deployment = open_dataset(testbed).deployment
    assert AdaptiveBasisTracker(deployment).warnings == []
    first, second = deployment.calibration.passes
    flat = second.model_copy(update={"exit": (16.0, 1.0)})  # 3.6° from pass 1
    bad = deployment.model_copy(update={"calibration": deployment.calibration.model_copy(update={"passes": [first, flat]})})
    warnings = AdaptiveBasisTracker(bad).warnings
    assert len(warnings) == 2 and "within 3.58° of parallel" in warnings[0] and "near one line" in warnings[1]
