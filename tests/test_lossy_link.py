"""A lossy link between sensor agent and peer agent: the receiver recovers every lost edge.

The real chain replay → sensor_agent ``--lose 3`` → peer_agent → basestation → recorder runs
on a real Zenoh router at ``--speed 0``. The recording shows that the sensor agent really
published only two transitions in three, and that the peer agent's estimates are nevertheless
exactly the offline ones: every lost transition was fetched from the sensors' ``state``
queryable (seq gaps, and progress reports that count what was sent) in time.
Also unit tests of the receiver's bookkeeping, :class:`SequenceCheck` and :class:`SourceCheck`.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bintrack.cli.export_command import track_rows
from bintrack.formats import open_dataset
from bintrack.bus_payloads import Transition
from bintrack.message_codec import decode
from bintrack.pipeline import output_rows, run_tracker
from bintrack.live.recording import open_recording
from bintrack.trackers import make_tracker
from bintrack.live.sequence_checks import SequenceCheck, SourceCheck
from bintrack.live.watermark import UpstreamWatermark
from bintrack.transition_detector import TransitionDetector

from conftest import write_foreign_dataset
from support import DATASETS, HUNG

TRACKER = "equal-weight"
CHAIN = ("sensor_agent", "peer_agent", "basestation", "recorder")


# --------------------------------------------------------------------------- unit


def tr(sensor: str, seq: int, source: str | None = None, source_seq: int | None = None) -> Transition:
    return Transition(t=float(seq), sensor=sensor, value=seq % 2, previous=(seq + 1) % 2, seq=seq,
                      source=source, source_seq=source_seq)


def test_sequence_check_new_duplicate_gap_per_sensor():
    check = SequenceCheck()
    assert check.classify(tr("a", 1)) == "new"
    assert check.classify(tr("a", 2)) == "gap"  # nothing accepted yet: 1 is missing
    check.accept(tr("a", 1))
    assert check.classify(tr("a", 1)) == "duplicate"
    assert check.classify(tr("a", 2)) == "new"
    assert check.classify(tr("a", 4)) == "gap"
    assert check.classify(tr("b", 1)) == "new"  # sensors are independent
    check.accept(tr("a", 4))  # taken after the gap was repaired
    assert check.last == {"a": 4}
    assert check.classify(tr("a", 2)) == "duplicate"  # an older seq arriving late is a duplicate
    assert check.classify(tr("a", 3)) == "duplicate"
    check.accept(tr("a", 2))  # accepting an older one never moves the last seq back
    assert check.last["a"] == 4
    assert check.classify(tr("a", 5)) == "new"


def test_source_check_contiguous_out_of_order_and_first_missing():
    check = SourceCheck()
    assert check.first_missing("s1", 0) is None
    assert check.first_missing("s1", 2) == 1
    for n in (1, 2, 4, 5):  # 3 was lost
        check.accept(tr("a", n, "s1", n))
    assert check.seen(tr("x", 9, "s1", 2)) and check.seen(tr("x", 9, "s1", 5))
    assert not check.seen(tr("x", 9, "s1", 3)) and not check.seen(tr("x", 9, "s1", 6))
    assert check.first_missing("s1", 2) is None  # everything up to 2 arrived
    assert check.first_missing("s1", 5) == 3
    assert check.first_missing("s1", 7) == 3
    assert check.first_missing("s2", 1) == 1  # instances are independent
    check.accept(tr("a", 3, "s1", 3))  # the fetched one closes the gap
    assert check.first_missing("s1", 5) is None
    assert check.first_missing("s1", 6) == 6
    # a transition without its source (a hand-made one) is never "seen" and changes nothing
    check.accept(tr("a", 7))
    assert not check.seen(tr("a", 7))
    assert check.first_missing("s1", 6) == 6
    # an instance restarted under the same id counts from 1 again: forget, and start over
    check.accept(tr("b", 1, "s2", 1))
    check.forget("s1")
    assert not check.seen(tr("a", 1, "s1", 1)) and check.first_missing("s1", 1) == 1
    assert check.seen(tr("b", 1, "s2", 1))  # other instances are kept


def test_a_departed_upstream_holds_the_watermark_for_the_hold_after_it_went_not_after_its_floor():
    mark = UpstreamWatermark({"peer_agent"}, hold=2.0, grace=0.0)
    # before any peer agent was seen nothing is released: its token may come after the clock
    assert mark.bound(0.0) == float("-inf")
    mark.on_liveliness("peer_agent", "p1", True)
    mark.on_liveliness("peer_agent", "p2", True)
    assert mark.bound(0.5) == float("-inf")  # p1 and p2 have not reported yet
    mark.reported("peer_agent", "p1", 8.0)
    mark.reported("peer_agent", "p2", 16.0)
    assert mark.bound(16.0) == 8.0
    # p1 dies with the clock already 8 s past its report (the replay's lead at a 0.5 s period):
    # it still holds, for 2 s counted from the first tick after it went
    mark.on_liveliness("peer_agent", "p1", False)
    assert mark.bound(16.0) == 8.0
    assert mark.bound(17.5) == 8.0
    mark.on_liveliness("peer_agent", "p1", True)  # back (a restart under the same id)
    mark.reported("peer_agent", "p1", 9.0)
    assert mark.bound(17.5) == 9.0
    mark.on_liveliness("peer_agent", "p1", False)
    assert mark.bound(18.0) == 9.0
    assert mark.bound(20.0) == 16.0  # gone for good: p2 alone bounds
    mark.on_liveliness("peer_agent", "other", False)  # never seen: ignored
    mark.on_liveliness("sensor_agent", "s1", True)  # not an upstream service of this one
    assert mark.bound(20.5) == 16.0
    mark.on_liveliness("peer_agent", "p2", False)  # p2 goes before it reported again
    assert mark.bound(21.0) == 16.0
    assert mark.bound(23.0) == float("inf")  # every instance gone for good: the clock alone bounds


def test_ticks_already_in_flight_when_an_upstream_went_do_not_use_up_its_hold():
    mark = UpstreamWatermark({"sensor_agent"}, hold=2.0, grace=0.0)
    mark.on_liveliness("sensor_agent", "s1", True)
    mark.reported("sensor_agent", "s1", 8.0)
    mark.on_liveliness("sensor_agent", "s1", False)
    # the departure is seen at the tick 8.5; the replay had sent 16 ticks of 0.5 s ahead of
    # what s1 acknowledged, and they still arrive: s1's floor holds through all of them
    lead = 16 * 0.5
    assert mark.bound(8.5, lead) == 8.0
    assert mark.bound(16.0, lead) == 8.0
    assert mark.bound(18.0, lead) == 8.0
    mark.on_liveliness("sensor_agent", "s1", True)  # restarted: what it resends from 8 s is not late
    assert mark.bound(18.0, lead) == 8.0
    mark.on_liveliness("sensor_agent", "s1", False)
    assert mark.bound(18.5, lead) == 8.0
    assert mark.bound(28.5, lead) == float("inf")  # gone for good after the hold and the lead


def test_a_departed_upstream_holds_for_the_grace_in_wall_time_however_fast_the_clock_runs():
    # at --speed 0 the replay, which saw the tokens come back, runs the hold's event time out in
    # a fraction of a second, while this consumer's view of the token waits for a link of the mesh
    wall = [100.0]
    mark = UpstreamWatermark({"sensor_agent"}, hold=2.0, grace=3.0, now=lambda: wall[0])
    mark.on_liveliness("sensor_agent", "s1", True)
    mark.on_liveliness("sensor_agent", "s2", True)
    mark.reported("sensor_agent", "s1", 16.5)
    mark.reported("sensor_agent", "s2", 30.0)
    mark.on_liveliness("sensor_agent", "s1", False)
    assert mark.bound(16.5) == 16.5
    wall[0] += 0.4
    assert mark.bound(20.1, 1.6) == 16.5  # the event-time hold is over, the grace is not
    mark.on_liveliness("sensor_agent", "s1", True)  # its token back over the healed link
    assert mark.bound(21.0, 1.6) == 16.5  # what it sends from 16.5 s is not late
    mark.on_liveliness("sensor_agent", "s1", False)
    wall[0] += 2.9
    assert mark.bound(25.0) == 16.5
    wall[0] += 0.2
    assert mark.bound(27.0) == 30.0  # gone for good: 2 s of event time and 3 s of wall time


def test_an_upstream_that_went_while_this_consumer_was_cut_off_is_judged_from_its_reconnection():
    # the consumer's own router was killed: every token went at once, and the restart took 3 s;
    # the replay saw the agent back and runs on, while this consumer's view of its token still
    # waits for the mesh. Its grace starts again when the consumer's link is back
    wall = [100.0]
    mark = UpstreamWatermark({"sensor_agent"}, hold=2.0, grace=3.0, now=lambda: wall[0])
    mark.on_liveliness("sensor_agent", "s1", True)
    mark.reported("sensor_agent", "s1", 15.5)
    mark.on_liveliness("sensor_agent", "s1", False)
    assert mark.bound(15.5) == 15.5
    wall[0] += 3.0
    mark.reconnected()
    assert mark.bound(19.0, 1.0) == 15.5  # without the reconnection: gone for good here
    wall[0] += 2.9
    assert mark.bound(22.0, 1.0) == 15.5
    mark.on_liveliness("sensor_agent", "s1", True)  # its token back over the mesh
    mark.reported("sensor_agent", "s1", 22.0)
    assert mark.bound(22.5, 1.0) == 22.0
    mark.on_liveliness("sensor_agent", "s1", False)  # and gone for good this time
    wall[0] += 3.0
    assert mark.bound(22.5, 1.0) == 22.0  # the next tick starts its hold
    assert mark.bound(25.6, 1.0) == float("inf")


def test_an_upstream_silent_behind_a_stale_token_is_taken_for_gone_until_it_reports_again():
    # a router of the mesh kept s1's token after the link to s1's site was cut (the others
    # dropped it): its reports stop while the clock goes on. Under flow control a connected
    # instance never falls more than the hold and the lead behind; s1 stays that far behind for
    # 10 s of wall time and is then taken for gone, until a report comes from it again
    wall = [0.0]
    mark = UpstreamWatermark({"sensor_agent"}, hold=2.0, grace=3.0, now=lambda: wall[0], silent_after=10.0)
    mark.on_liveliness("sensor_agent", "s1", True)
    mark.on_liveliness("sensor_agent", "s2", True)
    mark.reported("sensor_agent", "s1", 16.0)
    mark.reported("sensor_agent", "s2", 16.0)
    lead = 1.0
    assert mark.bound(19.0, lead) == 16.0  # 3 s behind: not more than the hold and the lead
    mark.reported("sensor_agent", "s2", 19.5)
    assert mark.bound(19.5, lead) == 16.0  # now behind: its 10 s start
    wall[0] += 9.9
    mark.reported("sensor_agent", "s2", 29.0)
    assert mark.bound(29.0, lead) == 16.0
    wall[0] += 0.1
    assert mark.bound(29.0, lead) == 29.0  # s1 taken for gone: s2 alone bounds
    mark.reported("sensor_agent", "s2", 31.0)
    assert mark.bound(31.0, lead) == 31.0
    mark.reported("sensor_agent", "s1", 30.5)  # the link healed: s1 reports again and bounds again
    assert mark.bound(31.0, lead) == 30.5
    # a lag that ends before the 10 s does not count, and an instance that never reported is
    # not taken for gone (its first report may come after the first ticks)
    mark.reported("sensor_agent", "s1", 31.0)
    mark.on_liveliness("sensor_agent", "s3", True)
    wall[0] += 5.0
    assert mark.bound(40.0, lead) == float("-inf")
    mark.reported("sensor_agent", "s3", 40.0)
    wall[0] += 6.0
    assert mark.bound(40.0, lead) == 31.0  # s1 and s2 behind for 6 s only
    mark.reported("sensor_agent", "s1", 40.0)
    mark.reported("sensor_agent", "s2", 40.0)
    wall[0] += 20.0
    assert mark.bound(40.0, lead) == 40.0
    mark.on_liveliness("sensor_agent", "s1", False)  # a token withdrawn at last, after all that
    assert mark.bound(40.0, lead) == 40.0


def test_the_watermark_waits_for_an_instance_of_each_upstream_service():
    mark = UpstreamWatermark({"sensor_agent", "peer_agent"}, hold=2.0, grace=0.0)
    mark.on_liveliness("sensor_agent", "s1", True)
    mark.reported("sensor_agent", "s1", 5.0)
    assert mark.bound(5.0) == float("-inf")  # no peer agent seen yet
    mark.on_liveliness("peer_agent", "p1", True)
    mark.on_liveliness("peer_agent", "p1", False)  # one that went before reporting holds at −inf
    assert mark.bound(5.5) == float("-inf")
    assert mark.bound(7.5) == 5.0


# --------------------------------------------------------------------------- live


@pytest.fixture(scope="module")
def foreign(tmp_path_factory) -> Path:
    return write_foreign_dataset(tmp_path_factory.mktemp("lossy") / "foreign", nodes=400, speed=4.0)


SOURCES = {"foreign": None, "darpa-grid-1": DATASETS / "darpa-grid-1"}


def run_chain(dataset: Path, out: Path, endpoint: str, services, lose: int) -> dict:
    """replay → sensor_agent [--lose N] → peer_agent → basestation → recorder --out ``out``."""
    net = ("--net", open_dataset(dataset).deployment.name)
    lossy = ("--lose", str(lose)) if lose else ()
    procs = {
        "sensor_agent": services("sensor_agent", *lossy, *net, endpoint=endpoint),
        "peer_agent": services("peer_agent", "--tracker", TRACKER, *net, endpoint=endpoint),
        "basestation": services("basestation", "--tracker", TRACKER, *net, endpoint=endpoint),
        "recorder": services("recorder", "--out", str(out), *net, endpoint=endpoint),
    }
    replay = services("replay", str(dataset), "--speed", "0", "--wait-for", ",".join(CHAIN), endpoint=endpoint)
    assert replay.wait(HUNG) == 0, replay.log
    assert procs["recorder"].wait(HUNG) == 0, procs["recorder"].log
    for name in ("sensor_agent", "peer_agent", "basestation"):
        assert procs[name].stop() == 0, procs[name].log
    return {name: proc.log for name, proc in procs.items()}


@pytest.mark.parametrize("lose", [3, 0], ids=["lose-3", "lossless"])
@pytest.mark.parametrize("name", SOURCES)
def test_receiver_recovers_every_lost_transition(name, lose, foreign, tmp_path, zenoh_router, services):
    dataset = SOURCES[name] or foreign
    ds = open_dataset(dataset)
    detector = TransitionDetector(ds.deployment)
    offline = [t for e in ds.events() if (t := detector.update(e)) is not None]
    n = len(offline)
    assert n > 100

    out = tmp_path / "chain.mcap"
    logs = run_chain(dataset, out, zenoh_router, services, lose)
    recording = open_recording(out)

    # (a) what the sensor agent published: every transition but each lose-th it sent
    published = [decode(Transition, r.payload) for r in recording.records() if r.kind == "transition"]
    lost = n // lose if lose else 0
    assert len(published) == n - lost
    assert sorted(t.source_seq for t in published) == [k for k in range(1, n + 1) if not lose or k % lose]
    strip = {"source": None, "source_seq": None}
    expected = {(t.sensor, t.seq): t for t in offline}
    assert all(expected[(t.sensor, t.seq)] == t.model_copy(update=strip) for t in published)
    assert len({(t.sensor, t.seq) for t in published}) == len(published)

    # (b) the peer agent's estimates are nevertheless exactly the offline ones, and so are the tracks
    rows = sorted(output_rows(run_tracker(ds, make_tracker(TRACKER, ds.deployment))))
    assert len(rows) > 50
    assert sorted(track_rows(recording, "estimates")) == rows
    assert sorted(track_rows(recording, "tracks")) == rows
    peer_log = logs["peer_agent"]
    if lose:
        assert f"peer_agent: {lost} transitions that never arrived were fetched from the sensors' state" in peer_log
    else:
        assert "fetched" not in peer_log
    for name_, log in logs.items():
        assert "bad payload" not in log and "could not be" not in log and "Traceback" not in log, (name_, log)
