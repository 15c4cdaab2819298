"""The merge counts each region's scans (DESIGN §11): a real merge service on a real router,
with this test as the two regions' base stations. A scan that never reached the merge, though
the region's later progress report did (a put dropped while routes were declared again after a
router came back), is fetched from the base station's ``tracks`` queryable before the report is
taken; one the base station no longer has is named in the log, never merged away silently."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest
import zenoh

from bintrack.bus_payloads import Clock, Track, TrackSet
from bintrack.formats import read_deployment
from bintrack.keys import Keys
from bintrack.live.session_options import client_config
from bintrack.message_codec import decode, encode
from bintrack.live.region_scan_counts import KEEP, SHORT_FOR, RegionScanCounts, ReportCheck
from bintrack.regions import RegionMap
from support import HUNG, bintrack, wait_logged, wait_until

NET = "counts"
TIMES = [0.5 * k for k in range(1, 13)]  # the scans, s


@pytest.fixture(scope="module")
def deployment(tmp_path_factory) -> tuple[bytes, float, float]:
    """A two-region deployment (encoded) and a point inside region r0c1 (units)."""
    folder = tmp_path_factory.mktemp("field")
    bintrack("simulate", "darpa-grid", "--out", "field", "--regions", "2", "--seed", "3", cwd=folder, check=True)
    deployment = read_deployment(Path(folder, "field", "deployment.json"))
    inside = RegionMap(deployment).shapes["r0c1"].representative_point()
    return encode(deployment), inside.x, inside.y


def x_at(t: float, x0: float) -> float:
    """Where r0c1's one track is at ``t`` (s): it walks along x."""
    return x0 + 0.01 * t


class BaseStations:
    """Regions r0c0 (no track) and r0c1 (one track, :func:`x_at`) on a client session: each
    scan is kept for the ``region/<r>/tracks?after=T`` queryable, some are never put."""

    def __init__(self, endpoint: str, deployment: tuple[bytes, float, float]):
        deployment, self.x0, self.y0 = deployment
        self.keys = Keys(NET)
        self.session = zenoh.open(client_config([endpoint]))
        self.kept: dict[str, list[TrackSet]] = {"r0c0": [], "r0c1": []}
        self.sent = {"r0c0": 0, "r0c1": 0}
        self.merged: dict[float, TrackSet] = {}
        self.changed = threading.Condition()
        self.entities = [
            self.session.declare_queryable(self.keys.deployment(),
                                           lambda q: q.reply(self.keys.deployment(), deployment)),
            *(self.session.declare_queryable(self.keys.region_tracks(r), self.answer(r)) for r in self.kept),
            *(self.session.liveliness().declare_token(self.keys.region_alive(r)) for r in self.kept),
            self.session.declare_subscriber(self.keys.tracks(), self.on_merged),
        ]

    def wait_for(self, merge) -> None:
        """Until the router routes the regions' scans and reports to ``merge``'s subscribers: a
        put before that is dropped, and a lost first report would hold the merge back."""
        keys = [k(r) for r in self.kept for k in (self.keys.region_tracks, self.keys.region_progress)]
        publishers = [self.session.declare_publisher(k) for k in keys]
        try:
            wait_until(lambda: all(p.matching_status.matching for p in publishers), "the merge's subscribers",
                       logs=[merge])
        finally:
            for publisher in publishers:
                publisher.undeclare()

    def answer(self, region: str):
        def reply(query: zenoh.Query) -> None:
            after = float(query.parameters.get("after"))
            for scan in self.kept[region]:
                if scan.t > after:
                    query.reply(self.keys.region_tracks(region), encode(scan))
        return reply

    def on_merged(self, sample: zenoh.Sample) -> None:
        scan = decode(TrackSet, sample.payload.to_bytes())
        with self.changed:
            self.merged[scan.t] = scan
            self.changed.notify_all()

    def scan(self, t: float, put: bool = True, keep: bool = True) -> None:
        """Both regions' scans at ``t`` (r0c1's put only with ``put``, kept only with ``keep``),
        then both progress reports."""
        for region in self.kept:
            tracks = [Track(track=0, x=x_at(t, self.x0), y=self.y0)] if region == "r0c1" else []
            scan = TrackSet(t=t, tracker="mcmcda", tracks=tracks)
            self.sent[region] += 1
            if keep or region == "r0c0":
                self.kept[region].append(scan)
            if put or region == "r0c0":
                self.session.put(self.keys.region_tracks(region), encode(scan))
        self.report(t)

    def report(self, t: float) -> None:
        for region in self.kept:
            self.session.put(self.keys.region_progress(region), encode(Clock(t=t, sent=self.sent[region])))

    def merged_at(self, t: float) -> TrackSet:
        with self.changed:
            assert self.changed.wait_for(lambda: t in self.merged, HUNG), f"no merged scan at t={t} s"
            return self.merged[t]

    def close(self) -> None:
        for entity in self.entities:
            entity.undeclare()
        self.session.close()


@pytest.fixture
def stations(zenoh_router, deployment):
    stations = BaseStations(zenoh_router, deployment)
    yield stations
    stations.close()


def test_a_scan_that_never_came_is_fetched_before_its_region_s_report_is_taken(stations, services,
                                                                              zenoh_router):
    merge = services("merge", "--net", NET, endpoint=zenoh_router)
    wait_logged(merge, "merging regions r0c0, r0c1")
    stations.wait_for(merge)
    for t in TIMES:
        stations.scan(t, put=t != 2.0)
    for t in TIMES:
        assert [tr.x for tr in stations.merged_at(t).tracks] == [x_at(t, stations.x0)], t
    assert "region r0c1's scans up to t=2 s had not all arrived; fetched from its base station" in merge.log
    assert "never arrived" not in merge.log


def test_a_scan_its_base_station_no_longer_has_is_named_lost_and_the_merge_goes_on(stations, services,
                                                                                  zenoh_router):
    merge = services("merge", "--net", NET, endpoint=zenoh_router)
    wait_logged(merge, "merging regions r0c0, r0c1")
    stations.wait_for(merge)
    for t in TIMES[:4]:
        stations.scan(t, put=t != 1.5, keep=t != 1.5)
    assert [tr.x for tr in stations.merged_at(1.0).tracks] == [x_at(1.0, stations.x0)]
    # the report is set aside a while, then the loss is named and the merge goes on
    while "never arrived" not in merge.log:
        stations.report(TIMES[3])
        assert merge.proc.poll() is None, merge.log[-3000:]
        with stations.changed:
            stations.changed.wait(0.2)
    assert "1 scans region r0c1's base station published up to t=2 s never arrived and it no longer gives them" \
        in merge.log
    assert stations.merged_at(1.5).tracks == []
    for t in TIMES[4:]:
        stations.scan(t)
    assert [tr.x for tr in stations.merged_at(TIMES[-1]).tracks] == [x_at(TIMES[-1], stations.x0)]


def test_the_count_takes_a_second_copy_once_and_keeps_counting_what_it_forgot():
    counts = RegionScanCounts()
    for t in (0.5, 1.0, 1.0, 2.0):  # a scan fetched that had come after all
        counts.heard("r0c1", t)
    assert counts.missing("r0c1", 1.5, 3) == 1  # three up to 1.5 s: one never came
    assert counts.missing("r0c1", 2.0, 3) == 0
    assert counts.missing("r0c1", 2.0, 1) == 0  # a base station restarted without its checkpoint
    counts.forget_before(KEEP + 1.5)  # 0.5 and 1.0 counted, no longer kept one by one
    assert counts.times["r0c1"] == {2.0} and counts.older["r0c1"] == 2
    assert counts.missing("r0c1", KEEP + 1.5, 4) == 1
    assert counts.missing("r0c0", 1.0, 2) == 2


def test_a_report_short_of_scans_is_set_aside_for_a_while_then_taken_with_the_loss_named(caplog):
    clock = [0.0]
    counts = RegionScanCounts()
    fetched: list[str] = []
    check = ReportCheck("merge", counts, fetched.append, now=lambda: clock[0])
    counts.heard("r0c0", 0.5)
    assert check.complete("r0c0", 0.5, 1)
    assert not check.complete("r0c0", 1.0, 2) and fetched == ["r0c0"]  # fetched, still short: set aside
    clock[0] = SHORT_FOR / 2
    assert check.retry({"r0c0"}) == [] and fetched == ["r0c0"] * 2
    counts.heard("r0c0", 1.0)  # it came after all
    assert check.retry({"r0c0"}) == [("r0c0", 1.0)]
    assert not check.complete("r0c0", 1.5, 3)
    clock[0] += SHORT_FOR
    with caplog.at_level("WARNING", logger="bintrack"):
        assert check.retry({"r0c0"}) == [("r0c0", 1.5)]
    assert "1 scans region r0c0's base station published up to t=1.5 s never arrived" in caplog.text
    assert check.complete("r0c0", 1.5, 3)  # named once, then counted as heard
