"""A region's base station fetches what an agent's progress report counts and did not arrive
(GapRepair with CountOrder): an answer its router cut short is asked again, not taken for
the agent's whole memory, so the transitions missing from it are never named lost."""

from __future__ import annotations

from bintrack.bus_payloads import SensorState, Transition
from bintrack.keys import Keys
from bintrack.live.count_order import CountOrder
from bintrack.live.gap_repair import GapRepair
from bintrack.message_codec import encode

KEYS = Keys("net")
SENSORS = ("a", "b", "c")


def sent(sensor: str, seq: int, t: float, source_seq: int) -> Transition:
    return Transition(t=t, sensor=sensor, value=seq % 2, previous=1 - seq % 2, seq=seq, source="ag",
                      source_seq=source_seq)


class Agent:
    """The state queryable of agent ``ag`` hosting a, b and c: each query by source gets one reply
    per sensor, each saying how many; ``cut`` replies are dropped from the end (its router went)."""

    def __init__(self, transitions: list[Transition]):
        self.transitions = transitions
        self.cut = 0

    def query(self, selector: str, timeout: float) -> list[bytes]:
        after = int(selector.rsplit("after=", 1)[1])
        replies = [encode(SensorState(t=3.0, sensor=s, value=1, seq=9, answers=len(SENSORS),
                                      missed=[tr for tr in self.transitions if tr.sensor == s and tr.source_seq > after]))
                   for s in SENSORS]
        return replies[:len(replies) - self.cut]


def region_intake(agent: Agent) -> tuple[GapRepair, list[Transition], list[str]]:
    taken: list[Transition] = []
    bad: list[str] = []
    intake = GapRepair("basestation", KEYS, set(SENSORS), taken.append, agent.query,
                       lambda key, reason: bad.append(reason))
    intake.state.order = CountOrder("r0")
    return intake, taken, bad


def test_an_answer_cut_short_is_asked_again_and_nothing_is_named_lost(caplog):
    transitions = [sent("a", 1, 1.0, 1), sent("b", 1, 1.5, 2), sent("c", 1, 2.0, 3), sent("c", 2, 2.5, 4)]
    agent = Agent(transitions)
    intake, taken, bad = region_intake(agent)
    for transition in transitions[:2]:
        intake.receive(transition, KEYS.transition(transition.sensor))
    order = intake.state.order
    order.report("ag", 3.0, 4, {"r0": 4})
    assert intake.settle("ag") == []  # short, but no later report yet: it waits
    order.report("ag", 3.5, 4, {"r0": 4})
    agent.cut = 1  # c's reply, with both of c's transitions, never comes
    assert intake.settle("ag") is None  # held: asked again at the next report
    assert "answered for 2 of its 3 sensors (cut short)" in caplog.text
    assert "lost" not in caplog.text
    agent.cut = 0
    assert intake.settle("ag") == [3.0, 3.5]
    assert sorted(tr.source_seq for tr in taken) == [1, 2, 3, 4]
    assert "lost" not in caplog.text and not bad
    # c's transitions arriving now after all are duplicates of the fetched ones, not a restart
    for transition in transitions[2:]:
        intake.receive(transition, KEYS.transition(transition.sensor))
    assert len(taken) == 4 and not bad and "counts its transitions from 1 again" not in caplog.text


def test_a_whole_answer_without_them_names_them_lost(caplog):
    """The agent answered for every sensor and no longer has them: lost, named, and the
    watermark moves on."""
    transitions = [sent("a", 1, 1.0, 1), sent("b", 1, 1.5, 2)]
    agent = Agent(transitions[:1])  # b's is past its memory
    intake, taken, _ = region_intake(agent)
    order = intake.state.order
    order.report("ag", 3.0, 2, {"r0": 2})
    order.report("ag", 3.5, 2, {"r0": 2})
    assert intake.settle("ag") == [3.0, 3.5]
    assert [tr.source_seq for tr in taken] == [1]
    assert "1 transitions ag sent up to its count 2 were lost" in caplog.text
