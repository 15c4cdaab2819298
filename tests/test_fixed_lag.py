"""The fixed-lag smoother of mcmcda's tracks (``bintrack track --lag``): late by exactly the lag,
gaps filled, a new identity shown a scan early, positions averaged, nothing invented."""

from __future__ import annotations

import math
import pickle

import pytest

from bintrack.bus_payloads import PositionReport, PositionReports, Track, TrackSet, Transition
from bintrack.cli import main as cli
from bintrack.errors import TrackerConfigError
from bintrack.formats import read_tracks
from bintrack.trackers.multi.fixed_lag import FixedLagSmoother

from support import DATASETS

DARPA3 = DATASETS / "darpa-grid-3"


class Scripted:
    """A tracker that gives, per transition, the next of a list of scans (identity → x; y = 0)."""

    name = "scripted"

    def __init__(self, scans: list[dict[int, float]]):
        self.scans = list(scans)
        self.late_estimates = 7

    def update(self, message):
        t = message.t
        shown = self.scans.pop(0)
        tracks = [Track(track=k, x=x, y=0.0, vx=1.0, vy=0.0) for k, x in sorted(shown.items())]
        return [PositionReports(t=t, reports=[PositionReport(x=0.0, y=0.0, cov=((1.0, 0.0), (0.0, 1.0)))]),
                TrackSet(t=t, tracker=self.name, tracks=tracks)]

    def flush(self, t):
        return []


def scan(n: int) -> Transition:
    return Transition(t=0.5 * n, sensor="s", value=1, previous=0, seq=n + 1)


def run(scans: list[dict[int, float]], lag: int, stop: int | None = None):
    smoother = FixedLagSmoother(Scripted(scans), lag)
    out = [smoother.update(scan(n)) for n in range(len(scans) if stop is None else stop)]
    return smoother, out


def shown(track_set: TrackSet) -> dict[int, float]:
    return {track.track: round(track.x, 9) for track in track_set.tracks}


def test_each_scan_comes_lag_scans_late_and_all_at_the_end():
    scans = [{1: float(n)} for n in range(6)]
    smoother, out = run(scans, lag=2)
    # the reports pass at once; the first track set once two later scans are known
    assert [[type(m).__name__ for m in step] for step in out] == [
        ["PositionReports"], ["PositionReports"], ["PositionReports", "TrackSet"],
        ["PositionReports", "TrackSet"], ["PositionReports", "TrackSet"], ["PositionReports", "TrackSet"]]
    given = [m for step in out for m in step if isinstance(m, TrackSet)]
    assert [m.t for m in given] == [0.0, 0.5, 1.0, 1.5]
    assert smoother.flush(10.0) == []  # more scans may come
    rest = smoother.flush(math.inf)
    assert [m.t for m in rest] == [2.0, 2.5]
    assert all(m.tracker == "scripted" for m in given + rest)
    # a straight walk is its own moving average, but at the ends, where the average is one-sided
    assert [shown(m)[1] for m in given[1:]] == [1.0, 2.0, 3.0]


def test_a_gap_the_lag_closes_is_filled_and_a_longer_one_is_not():
    # identity 1 hidden for 2 scans, identity 2 for 4: with a lag of 3, only the first is filled
    scans = [{1: 0.0, 2: 10.0}, {}, {}, {1: 3.0}, {}, {}, {}, {}, {2: 18.0}, {}, {}]
    smoother, out = run(scans, lag=3)
    given = [m for step in out for m in step if isinstance(m, TrackSet)] + smoother.flush(math.inf)
    ones = [n for n, m in enumerate(given) if 1 in shown(m)]
    twos = [n for n, m in enumerate(given) if 2 in shown(m)]
    assert ones == [0, 1, 2, 3]
    assert twos == [0, 8]
    # linear in time between the two showings, then averaged over a scan on each side, where
    # known within the lag (at scan 0 scan 1 is not yet filled: its gap closes at scan 2)
    smoother, out = run([{1: 0.0}, {}, {1: 4.0}, {}], lag=1)
    given = [m for step in out for m in step if isinstance(m, TrackSet)] + smoother.flush(math.inf)
    assert [shown(m) for m in given] == [{1: 0.0}, {1: 2.0}, {1: 3.0}, {}]


def test_a_new_identity_is_shown_one_scan_early_and_a_returning_one_is_not():
    scans = [{}, {}, {}, {5: 3.0}, {5: 3.0}, {5: 3.0}, {}, {}, {}, {}, {}, {}, {5: 9.0}, {}]
    smoother, out = run(scans, lag=2)
    given = [m for step in out for m in step if isinstance(m, TrackSet)] + smoother.flush(math.inf)
    assert [n for n, m in enumerate(given) if 5 in shown(m)] == [2, 3, 4, 5, 12]
    assert shown(given[2]) == {5: 3.0}
    # an identity smaller than one already shown is an old one coming back, not shown early
    scans = [{4: 0.0}, {}, {}, {}, {}, {}, {9: 1.0}, {}, {}, {}, {}, {4: 5.0}, {}]
    smoother, out = run(scans, lag=2)
    given = [m for step in out for m in step if isinstance(m, TrackSet)] + smoother.flush(math.inf)
    assert [n for n, m in enumerate(given) if 4 in shown(m)] == [0, 11]
    assert [n for n, m in enumerate(given) if 9 in shown(m)] == [5, 6]


def test_it_shows_no_identity_the_tracker_did_not_and_pickles_mid_stream():
    scans = [{1: float(n), 2: 5.0 - n} if n % 3 else {1: float(n)} for n in range(12)]
    whole, out = run(scans, lag=4)
    expected = [m for step in out for m in step if isinstance(m, TrackSet)] + whole.flush(math.inf)
    assert {k for m in expected for k in shown(m)} == {1, 2}
    assert whole.late_estimates == 7  # the tracker's own attributes show through
    half, out = run(scans, lag=4, stop=5)
    again = pickle.loads(pickle.dumps(half))  # a base station's checkpoint
    given = [m for step in out for m in step if isinstance(m, TrackSet)]
    for n in range(5, 12):
        given += [m for m in again.update(scan(n)) if isinstance(m, TrackSet)]
    given += again.flush(math.inf)
    assert given == expected


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
