"""The fixed-lag smoother of mcmcda's tracks (``bintrack track --lag``): late by exactly the lag,
made from the tracker's later association of each scan's reports, gaps bridged, positions
smoothed, nothing invented."""

from __future__ import annotations

import math
import pickle
from collections import deque

import numpy as np
import pytest

from bintrack.bus_payloads import PositionReport, PositionReports, Track, TrackSet, Transition
from bintrack.cli import main as cli
from bintrack.errors import TrackerConfigError
from bintrack.formats import read_tracks
from bintrack.trackers.multi.fixed_lag import FixedLagSmoother
from bintrack.trackers.multi.kalman_model import kf_smoothed

from support import DATASETS

DARPA3 = DATASETS / "darpa-grid-3"


class Scripted:
    """A tracker that gives, per transition, the next scan's ``TrackSet`` (empty: what it
    publishes does not matter to the smoother) and, as its revision, its association of the last
    ``window`` scans: ``scans[n]`` (identity → x; y = 0) as known after scan n, each replaced by
    ``revised[(m, n)]`` where given (scan n's association as known after scan m)."""

    name = "scripted"
    motion = (0.1, 2.25, 0.25)
    """q, a new track's speed variance, the least report variance (MCMCDATracker.motion)"""

    def __init__(self, scans: list[dict[int, float]], window: int = 3,
                 revised: dict[tuple[int, int], dict[int, float]] | None = None):
        self.scans = list(scans)
        self.window = window
        self.revised = revised or {}
        self.step = 0
        self.late_estimates = 7
        self.revisions = None

    def keep_revisions(self):
        self.revisions = []

    def update(self, message):
        m, t = self.step, message.t
        self.step += 1
        known = [(0.5 * n, {k: _report(x) for k, x in self.revised.get((m, n), self.scans[n]).items()})
                 for n in range(max(0, m - self.window + 1), m + 1)]
        self.revisions.append(known)
        return [PositionReports(t=t, reports=[PositionReport(x=0.0, y=0.0, cov=((1.0, 0.0), (0.0, 1.0)))]),
                TrackSet(t=t, tracker=self.name, tracks=[])]

    def flush(self, t):
        return []


def _report(x: float | tuple[float, float]) -> tuple[float, float, float, float]:
    """A report at (x, 0), of variance 0.25 on each axis unless given as (x, variance)."""
    x, var = x if isinstance(x, tuple) else (x, 0.25)
    return x, 0.0, var, var


def scan(n: int) -> Transition:
    return Transition(t=0.5 * n, sensor="s", value=1, previous=0, seq=n + 1)


def run(scans: list[dict[int, float]], lag: int, stop: int | None = None, **script):
    smoother = FixedLagSmoother(Scripted(scans, **script), lag)
    out = [smoother.update(scan(n)) for n in range(len(scans) if stop is None else stop)]
    return smoother, out


def shown(track_set: TrackSet) -> dict[int, float]:
    return {track.track: round(track.x, 9) for track in track_set.tracks}


def given(smoother: FixedLagSmoother, out) -> list[TrackSet]:
    return [m for step in out for m in step if isinstance(m, TrackSet)] + smoother.flush(math.inf)


def test_each_scan_comes_lag_scans_late_and_all_at_the_end():
    scans = [{1: float(n)} for n in range(6)]
    smoother, out = run(scans, lag=2)
    # the reports pass at once; the first track set once two later scans are known
    assert [[type(m).__name__ for m in step] for step in out] == [
        ["PositionReports"], ["PositionReports"], ["PositionReports", "TrackSet"],
        ["PositionReports", "TrackSet"], ["PositionReports", "TrackSet"], ["PositionReports", "TrackSet"]]
    early = [m for step in out for m in step if isinstance(m, TrackSet)]
    assert [m.t for m in early] == [0.0, 0.5, 1.0, 1.5]
    assert smoother.flush(10.0) == []  # more scans may come
    rest = smoother.flush(math.inf)
    assert [m.t for m in rest] == [2.0, 2.5]
    assert all(m.tracker == "scripted" for m in early + rest)
    # a straight walk is followed, at 1 unit per 0.5 s once the start's still prior is behind
    assert [shown(m)[1] for m in early + rest] == pytest.approx([0.0, 1.0, 2.0, 3.0, 4.0, 5.0], abs=0.2)
    assert [track.vx for m in early[2:] + rest for track in m.tracks] == pytest.approx([2.0] * 4, abs=0.1)
    assert [track.vy for m in early + rest for track in m.tracks] == pytest.approx([0.0] * 6)


def test_a_gap_the_lag_closes_is_filled_and_a_longer_one_is_not():
    # identity 1 unreported for 2 scans, identity 2 for 4: with a lag of 3, only the first is filled
    scans = [{1: 0.0, 2: 10.0}, {}, {}, {1: 3.0}, {}, {}, {}, {}, {2: 18.0}, {}, {}]
    smoother, out = run(scans, lag=3)
    result = given(smoother, out)
    assert [n for n, m in enumerate(result) if 1 in shown(m)] == [0, 1, 2, 3]
    assert [n for n, m in enumerate(result) if 2 in shown(m)] == [0, 8]
    # the gap is bridged along the model's path, halfway between the two reports
    smoother, out = run([{1: 0.0}, {}, {1: 4.0}, {}], lag=1)
    result = [shown(m) for m in given(smoother, out)]
    assert [sorted(m) for m in result] == [[1], [1], [1], []]
    assert result[1][1] == pytest.approx(2.0, abs=0.05)


def rts_by_matrices(observations, t, q, v0):
    """The textbook Rauch–Tung–Striebel smoother of a constant-velocity model, in 2 × 2 matrices,
    started at the first observation: (position, velocity) at ``t``."""
    times = sorted({u for u, _, _ in observations} | {t})
    z = {u: (p, r) for u, p, r in observations}
    m, P = np.array([z[times[0]][0], 0.0]), np.diag([z[times[0]][1], v0])
    filtered, predicted, steps = [(m, P)], [(m, P)], [None]
    for prev, now in zip(times, times[1:]):
        dt = now - prev
        F = np.array([[1.0, dt], [0.0, 1.0]])
        m, P = F @ m, F @ P @ F.T + q * np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]])
        predicted.append((m, P))
        steps.append(F)
        if now in z:
            gain = P[:, 0] / (P[0, 0] + z[now][1])
            m, P = m + gain * (z[now][0] - m[0]), P - np.outer(gain, P[0, :])
        filtered.append((m, P))
    smoothed = filtered[-1][0]
    for k in range(len(times) - 2, times.index(t) - 1, -1):
        C = filtered[k][1] @ steps[k + 1].T @ np.linalg.inv(predicted[k + 1][1])
        smoothed = filtered[k][0] + C @ (smoothed - predicted[k + 1][0])
    return tuple(smoothed)


def test_the_smoother_is_rauch_tung_striebel():
    rng = np.random.default_rng(3)
    for _ in range(100):
        times = np.sort(rng.choice(np.arange(20) * 0.5, rng.integers(1, 10), replace=False))
        observations = [(float(u), float(rng.normal(0, 3)), float(rng.uniform(0.05, 2))) for u in times]
        t = float(rng.choice(np.arange(times[0], 10, 0.5)))
        assert kf_smoothed(observations, t, 0.1, 2.25) == pytest.approx(rts_by_matrices(observations, t, 0.1, 2.25), abs=1e-9)


def test_a_report_counts_by_its_variance_and_the_model_by_its_q():
    # a straight walk, x = n, with one report 3 units off at scan 5: the smoother is pulled
    # toward it as a report of variance 0.25, far less as a loose one (a shared copy's)
    at_five = {}
    for var in (0.25, 25.0):
        scans = [{1: (n + 3.0, var) if n == 5 else float(n)} for n in range(11)]
        smoother, out = run(scans, lag=3)
        at_five[var] = shown(given(smoother, out)[5])[1]
    assert at_five[0.25] > 5.4 and abs(at_five[25.0] - 5.0) < 0.05
    # a person who walks out and back (x = 0, 1, …, 7, 6, …, 0, the turn at scan 7): with the
    # tracker's q larger the smoother follows the turn closer
    xs = [float(min(n, 14 - n)) for n in range(15)]
    at_turn = {}
    for q in (0.1, 10.0):
        smoother = FixedLagSmoother(Scripted([{1: x} for x in xs]), 3)
        smoother.inner.motion = (q, 2.25, 0.25)
        out = [smoother.update(scan(n)) for n in range(len(xs))]
        at_turn[q] = shown(given(smoother, out)[7])[1]
    assert 7.0 - at_turn[10.0] < 0.5 < 7.0 - at_turn[0.1]


def test_the_trackers_later_association_of_a_scan_is_what_is_shown():
    # online, identity 5's first two reports were false alarms and identity 3 a track of one
    # report; two scans later the sampler gave those reports to 5 and dropped 3
    scans = [{}, {}, {3: 1.0}, {5: 3.0}, {5: 3.0}, {5: 3.0}, {}, {}, {}]
    revised = {(m, n): {5: 3.0} for m in (3, 4) for n in (1, 2) if m - n < 3}
    smoother, out = run(scans, lag=2, revised=revised)
    result = given(smoother, out)
    assert [n for n, m in enumerate(result) if 5 in shown(m)] == [1, 2, 3, 4, 5]
    assert not any(3 in shown(m) for m in result)
    # a revision the lag does not wait for is not shown: scan 1's, made at scan 4, is 3 scans late
    smoother, out = run(scans, lag=2, revised={(4, 2): {5: 3.0}, (4, 1): {5: 3.0}}, window=4)
    result = given(smoother, out)
    assert [n for n, m in enumerate(result) if 5 in shown(m)] == [2, 3, 4, 5]
    assert [n for n, m in enumerate(result) if 3 in shown(m)] == []


def test_it_shows_no_identity_the_tracker_did_not_and_pickles_mid_stream():
    scans = [{1: float(n), 2: 5.0 - n} if n % 3 else {1: float(n)} for n in range(12)]
    whole, out = run(scans, lag=4)
    expected = given(whole, out)
    assert {k for m in expected for k in shown(m)} == {1, 2}
    assert whole.late_estimates == 7  # the tracker's own attributes show through
    half, out = run(scans, lag=4, stop=5)
    again = pickle.loads(pickle.dumps(half))  # a base station's checkpoint
    result = [m for step in out for m in step if isinstance(m, TrackSet)]
    for n in range(5, 12):
        result += [m for m in again.update(scan(n)) if isinstance(m, TrackSet)]
    result += again.flush(math.inf)
    assert result == expected


def test_a_checkpoint_of_the_smoother_before_revisions_goes_on():
    """A smoother pickled by the release before (it held the published tracks and the largest
    identity shown; its tracker kept no revisions) goes on from the positions it held."""
    tracker = Scripted([{1: float(n)} for n in range(8)])
    tracker.step = 3
    old = FixedLagSmoother.__new__(FixedLagSmoother)
    old.__setstate__({"inner": tracker, "lag": 2, "half_width": 1, "_first": 0, "_next": 1, "_top": 1,
                      "_scans": deque((0.5 * n, "scripted", {1: Track(track=1, x=float(n), y=0.0)}, 1)
                                      for n in range(3))})
    assert tracker.revisions == []
    result = []
    for n in range(3, 8):
        result += [m for m in old.update(scan(n)) if isinstance(m, TrackSet)]
    result += old.flush(math.inf)
    assert [m.t for m in result] == [0.5 * n for n in range(1, 8)]
    assert [shown(m)[1] for m in result] == pytest.approx([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0], abs=0.1)


def test_a_checkpoint_that_held_positions_without_variances_goes_on():
    """The release before the smoother held each report's (x, y) only: they get the least
    variance a report has (0.25 here, which every report of this script has), so the stream goes
    on as if nothing had been restarted."""
    scans = [{1: float(n), 2: 5.0 - n} if n % 3 else {1: float(n)} for n in range(12)]
    whole, out = run(scans, lag=4)
    expected = given(whole, out)
    half, out = run(scans, lag=4, stop=5)
    state = pickle.loads(pickle.dumps(half)).__dict__
    state["_scans"] = deque((t, name, {k: p[:2] for k, p in a.items()}) for t, name, a in state["_scans"])
    old = FixedLagSmoother.__new__(FixedLagSmoother)
    old.__setstate__(state)
    result = [m for step in out for m in step if isinstance(m, TrackSet)]
    for n in range(5, 12):
        result += [m for m in old.update(scan(n)) if isinstance(m, TrackSet)]
    result += old.flush(math.inf)
    assert result == expected


def test_a_lag_below_one_scan_is_refused_by_the_smoother():
    with pytest.raises(TrackerConfigError, match="at least 1 scan"):
        FixedLagSmoother(Scripted([]), 0)


def test_a_lag_below_one_is_refused_by_the_command_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        cli.main(["track", str(DARPA3), "--tracker", "mcmcda", "--lag", "0", "--out", str(tmp_path / "t.csv")])
    assert stop.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1].endswith("argument --lag: must be at least 1, got '0'")
    assert not (tmp_path / "t.csv").exists()


@pytest.mark.parametrize("argv, words", [
    (["--tracker", "line-fit", "--lag", "3"], "--lag smooths the mcmcda tracker's tracks only"),
    (["--tracker", "mcmcda", "--lag", "3", "--regions"], "--lag smooths one base station's tracks"),
])
def test_bad_lag_options_get_one_line(tmp_path, capsys, argv, words):
    assert cli.main(["track", str(DARPA3), *argv, "--out", str(tmp_path / "t.csv")]) != 0
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "t.csv").exists()


def test_up_refuses_a_lag_with_regions_before_it_starts(capsys):
    assert cli.main(["up", str(DARPA3), "--tracker", "mcmcda", "--regions", "2", "--lag", "3", "--no-map"]) != 0
    err = capsys.readouterr().err.strip()
    assert "--lag smooths one base station's tracks" in err and len(err.splitlines()) == 1, err


def test_track_with_a_lag_keeps_the_online_identities_and_fills_their_gaps(tmp_path):
    online, lagged = tmp_path / "online.csv", tmp_path / "lagged.csv"
    assert cli.main(["track", str(DARPA3), "--tracker", "mcmcda", "--out", str(online), "--no-progress"]) == 0
    assert cli.main(["track", str(DARPA3), "--tracker", "mcmcda", "--lag", "4", "--out", str(lagged),
                     "--no-progress"]) == 0
    a, b = read_tracks(online), read_tracks(lagged)
    assert {r.track for r in b} == {r.track for r in a}
    assert len(b) >= len(a)
    assert {r.t for r in b} <= {r.t for r in a} | {r.t - 0.5 for r in a} | {r.t + 0.5 * k for r in a for k in range(5)}


def test_the_trackers_revisions_cover_its_window_and_its_reported_tracks():
    """What the smoother reads: after each scan, mcmcda's association of the reports of its
    window, one revision per ``TrackSet``; an identity holding a report of the newest scan is
    one the tracker publishes at that scan."""
    from bintrack.formats import open_dataset
    from bintrack.pipeline import run_tracker
    from bintrack.trackers import TrackerOptions, make_tracker

    dataset = open_dataset(DARPA3)
    tracker = make_tracker("mcmcda", dataset.deployment, TrackerOptions())
    tracker.keep_revisions()
    sets = [m for m in run_tracker(dataset, tracker) if isinstance(m, TrackSet)]
    assert len(tracker.revisions) == len(sets) > 100
    held = 0
    for track_set, revision in zip(sets, tracker.revisions):
        times = [t for t, _ in revision]
        assert times == sorted(times) and times[-1] == track_set.t and len(times) <= tracker.mcmcda.config.window
        newest = revision[-1][1]
        assert set(newest) <= {track.track for track in track_set.tracks}
        held += len(newest)
    assert held > 100
