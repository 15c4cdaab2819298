"""Order by counts (DESIGN §11), on the pure parts: a region's base station moves past a sensor
agent's report only once it holds what the report counts for its region, in any arrival order;
a region's sensor agent acknowledges a tick only once its region's raw samples before it are in."""

from __future__ import annotations

from bintrack.bus_payloads import Clock
from bintrack.live.count_order import CountOrder
from bintrack.live.recent_catchup import CatchUp
from bintrack.live.tick_order import TickOrder


def test_a_report_that_overtook_its_transitions_waits_for_them():
    order = CountOrder("r0")
    order.held("a", 1)
    order.report("a", 1.0, sent=4, sent_to={"r0": 3, "r1": 2})  # 1, 3, 4 are r0's; 2 went to r1 only
    assert order.ready("a") == [] and order.short("a") is None  # short, but no later report yet
    order.held("a", 4)
    assert order.ready("a") == []
    order.held("a", 3)
    assert order.ready("a") == [(1.0, 4, 0)]
    assert order.waiting() == []
    # the next report counts on from there; a transition ahead of its report is kept for it
    order.held("a", 6)
    order.report("a", 2.0, sent=5, sent_to={"r0": 3})
    assert order.ready("a") == [(2.0, 5, 0)]
    order.report("a", 3.0, sent=6, sent_to={"r0": 4})
    assert order.ready("a") == [(3.0, 6, 0)]


def test_a_count_still_short_at_the_next_report_is_a_gap_and_a_forced_one_names_the_missing():
    order = CountOrder("r0")
    order.report("a", 1.0, sent=2, sent_to={"r0": 2})
    order.held("a", 1)
    order.report("a", 2.0, sent=3, sent_to={"r0": 3})
    order.held("a", 3)
    short = order.short("a")
    assert short is not None and (short.t, short.sent, short.need) == (1.0, 2, 2)
    assert order.ready("a") == []
    # fetched from the sensors' state and still missing: lost, the watermark goes on
    assert order.ready("a", force=True) == [(1.0, 2, 1), (2.0, 3, 0)]
    # at the end of the stream no later report comes: a short one is a gap at once
    order.report("a", 4.0, sent=4, sent_to={"r0": 4})
    assert order.short("a") is None and order.short("a", final=True) is not None


def test_agents_are_counted_apart_and_a_restart_counts_from_one_again():
    order = CountOrder("r0")
    order.report("a", 1.0, sent=1, sent_to={"r1": 1})  # none of r0's
    assert order.ready("a") == [(1.0, 1, 0)]
    order.held("b", 1)
    order.report("b", 1.0, sent=1, sent_to={"r0": 1})
    assert order.ready("b") == [(1.0, 1, 0)]
    order.report("b", 2.0, sent=5, sent_to={"r0": 5})
    assert order.ready("b") == []
    assert order.waiting() == ["b"]
    order.forget("b")  # it counts from 1 again (seen by a transition's counts)
    assert order.waiting() == []
    order.report("c", 1.0, sent=9, sent_to={"r0": 0})
    assert order.ready("c") == [(1.0, 9, 0)]
    order.report("c", 2.0, sent=1, sent_to={"r0": 1})  # fewer than before: counting from 1 again
    order.held("c", 1)
    assert order.ready("c") == [(2.0, 1, 0)]


def test_a_tick_waits_for_its_regions_raw_samples_before_it():
    order = TickOrder("r0")
    order.tick(Clock(t=0.5, sent=3, sent_to={"r0": 2, "r1": 1}))
    assert order.arrived("a", 0.1)
    assert order.arrived("a", 0.6)  # after the tick: it does not count for it
    assert order.ready() == []
    order.tick(Clock(t=1.0, sent=4, sent_to={"r0": 3, "r1": 1}))
    assert order.short()  # the next tick came and the first still lacks one
    assert order.arrived("b", 0.2)
    assert [tick.t for tick in order.ready()] == [0.5, 1.0]
    order.tick(Clock(t=1.5, sent=9, sent_to={"r0": 5, "r1": 4}))
    order.tick(Clock(t=2.0, sent=9, sent_to={"r0": 5, "r1": 4}))
    assert order.short()
    # replay's recent answer taken (two samples of it had not come): all it published is in ...
    order.caught_up(CatchUp(taken=2, published=9, published_to={"r0": 5, "r1": 4}, complete=True,
                            taken_samples=[("a", 1.2), ("b", 1.4)]))
    assert [tick.t for tick in order.ready()] == [1.5, 2.0]
    # ... and those two, coming late, are not counted (nor handled) again
    assert not order.arrived("a", 1.2) and not order.arrived("b", 1.4)
    assert order.arrived("a", 2.1)
    order.tick(Clock(t=2.5, sent=10, sent_to={"r0": 6, "r1": 4}))
    assert [tick.t for tick in order.ready()] == [2.5]
    order.tick(Clock(t=3.0, sent=11, sent_to={"r0": 7, "r1": 4}))
    assert order.ready() == []
