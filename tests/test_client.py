"""The async client against a real Zenoh router on loopback: decoding, bad payloads, bounds,
the ``tracks`` queryable, liveliness, and a clean close."""

from __future__ import annotations

import asyncio

import msgpack
import pytest
import zenoh

from bintrack.live.session_options import client_config
from bintrack.client import BintrackClient
from bintrack.keys import Keys
from bintrack.bus_payloads import LocalEstimate, Track, TrackSet, Transition
from bintrack.message_codec import encode
from support import HUNG, free_port

NET = "test-client"
KEYS = Keys(NET)


@pytest.fixture
def bus(zenoh_router):
    """A second, independent client session on the test router: the other side of the bus."""
    session = zenoh.open(client_config([zenoh_router]))
    try:
        yield session
    finally:
        session.close()


def client_for(endpoint: str, **kwargs) -> BintrackClient:
    return BintrackClient(net=NET, connect=[endpoint], wait=5.0, **kwargs)


async def until(condition, what: str) -> None:
    """Wait (on the loop) for ``condition()``; HUNG only fails a hung run."""
    deadline = asyncio.get_running_loop().time() + HUNG
    while not condition():
        assert asyncio.get_running_loop().time() < deadline, f"timed out waiting for {what}"
        await asyncio.sleep(0.01)


async def matched(publisher: zenoh.Publisher) -> zenoh.Publisher:
    """Wait until the router knows a subscriber for ``publisher``: puts from now on arrive."""
    await until(lambda: publisher.matching_status.matching, f"a subscriber matching {publisher.key_expr}")
    return publisher


async def next_of(subscription, timeout: float = HUNG):
    return await asyncio.wait_for(anext(subscription), timeout)


def scan(t: float, *positions: tuple[float, float]) -> TrackSet:
    return TrackSet(t=t, tracker="mcmcda",
                    tracks=[Track(track=i, x=x, y=y, vx=1.0, vy=None) for i, (x, y) in enumerate(positions)])


async def test_iterators_decode_each_kind_and_skip_bad_payloads(zenoh_router, bus):
    async with client_for(zenoh_router) as client:
        tracks, estimates, transitions = client.tracks(), client.estimates(), client.transitions()
        tracks_pub = await matched(bus.declare_publisher(KEYS.tracks()))
        estimate_pub = await matched(bus.declare_publisher(KEYS.estimate("n7")))
        transition_pub = await matched(bus.declare_publisher(KEYS.transition("n7")))

        first, second = scan(1.5, (10.0, 20.0), (30.0, 40.0)), scan(2.5)
        tracks_pub.put(encode(first))
        tracks_pub.put(b"\xc1 not msgpack")                                    # undecodable
        tracks_pub.put(msgpack.packb({"version": 1, "t": 2.0, "tracker": "x"}))  # no 'tracks' field
        tracks_pub.put(msgpack.packb([1, 2, 3]))                                # not a map
        tracks_pub.put(encode(second))
        estimate = LocalEstimate(t=3.0, node="n7", tracker="arc", x=1.0, y=2.0, vx=0.5, vy=-0.5, arc=0.3)
        estimate_pub.put(encode(scan(3.0)))                                      # a TrackSet is no estimate
        estimate_pub.put(encode(estimate))
        transition = Transition(t=4.0, sensor="n7", value=1, previous=0, seq=1)
        transition_pub.put(encode(transition.model_copy(update={"seq": 0})))     # seq must be ≥ 1
        transition_pub.put(encode(transition))

        assert await next_of(tracks) == first
        assert await next_of(tracks) == second
        assert await next_of(estimates) == estimate
        assert await next_of(transitions) == transition
        assert (tracks.bad, estimates.bad, transitions.bad) == (3, 1, 1)
        assert (tracks.received, estimates.received, transitions.received) == (2, 1, 1)
        assert client.bad.total == 5 and client.dropped == 0
        assert client.bad.counts["not msgpack"] == 1


@pytest.mark.parametrize("kind", ["estimates", "transitions"])
async def test_filters_by_node_and_sensor(zenoh_router, bus, kind):
    """The filtered subscription gets n2's messages only, although n1's reached the client: an
    unfiltered one on the same client got them all."""
    if kind == "estimates":
        key = KEYS.estimate
        message = lambda node, t: LocalEstimate(t=t, node=node, tracker="arc", x=t, y=0.0)  # noqa: E731
        source = lambda m: m.node  # noqa: E731
    else:
        key = KEYS.transition
        message = lambda node, t: Transition(t=t, sensor=node, value=1, previous=0, seq=1)  # noqa: E731
        source = lambda m: m.sensor  # noqa: E731
    async with client_for(zenoh_router) as client:
        every, only_n2 = getattr(client, kind)(), getattr(client, kind)("n2")
        # both publishers matched: each put from now on reaches the client
        publisher_n1 = await matched(bus.declare_publisher(key("n1")))
        publisher_n2 = await matched(bus.declare_publisher(key("n2")))
        for t in (1.0, 2.0):
            publisher_n1.put(encode(message("n1", t)))
            publisher_n2.put(encode(message("n2", t + 0.5)))
        got = [await next_of(every) for _ in range(4)]
        assert sorted((source(m), m.t) for m in got) == [("n1", 1.0), ("n1", 2.0), ("n2", 1.5), ("n2", 2.5)]
        assert [(source(m), m.t) for m in [await next_of(only_n2), await next_of(only_n2)]] == [("n2", 1.5), ("n2", 2.5)]
        assert only_n2.received == 2 and every.received == 4


async def test_slow_reader_keeps_the_newest_and_counts_the_dropped(zenoh_router, bus):
    async with client_for(zenoh_router, capacity=3) as client:
        tracks = client.tracks()
        publisher = await matched(bus.declare_publisher(KEYS.tracks()))
        for k in range(10):
            publisher.put(encode(scan(float(k))))
        await until(lambda: tracks.received == 10, "the ten scans")   # nobody reads meanwhile
        assert [(await next_of(tracks)).t for _ in range(3)] == [7.0, 8.0, 9.0]
        assert tracks.dropped == 7 and client.dropped == 7
        # nothing else was kept: the next one read is one published after
        publisher.put(encode(scan(10.0)))
        assert (await next_of(tracks)).t == 10.0
        assert tracks.dropped == 7 and tracks.received == 11


async def test_close_ends_iteration_and_undeclares(zenoh_router, bus):
    client = await client_for(zenoh_router).open()
    tracks = client.tracks()
    publisher = await matched(bus.declare_publisher(KEYS.tracks()))
    seen = []

    async def read():
        async for message in tracks:
            seen.append(message.t)

    reader = asyncio.create_task(read())
    publisher.put(encode(scan(1.0)))
    await until(lambda: seen, "the first scan read")
    await client.close()
    await asyncio.wait_for(reader, HUNG)   # the loop ended by itself
    assert seen == [1.0] and tracks.closed
    await until(lambda: not publisher.matching_status.matching, "the router to forget the subscriber")
    await client.close()   # twice is harmless


async def test_latest_tracks_reads_the_queryable(zenoh_router, bus):
    latest = scan(42.0, (1.0, 2.0))
    queryable = bus.declare_queryable(KEYS.tracks())   # a channel: answered below, not in a callback

    async def answer_one(payload: bytes) -> None:
        query = await asyncio.to_thread(queryable.handler.recv)
        with query:
            query.reply(KEYS.tracks(), payload)

    async with client_for(zenoh_router) as client:
        server = asyncio.create_task(answer_one(encode(latest)))
        assert await client.latest_tracks(timeout=HUNG) == latest
        await server

        server = asyncio.create_task(answer_one(b"garbage"))
        assert await client.latest_tracks(timeout=HUNG) is None
        await server
        assert client.bad.total == 1

        queryable.undeclare()
        assert await client.latest_tracks(timeout=0.5) is None


async def test_alive_lists_liveliness_tokens(zenoh_router, bus):
    token = bus.liveliness().declare_token(KEYS.alive("recorder", "host-1"))
    other = bus.liveliness().declare_token(Keys("elsewhere").alive("recorder", "host-2"))
    try:
        async with client_for(zenoh_router) as client:
            assert await client.alive("recorder") == [("recorder", "host-1")]
            assert await client.alive("basestation") == []
            assert await client.alive() == [("recorder", "host-1")]
    finally:
        token.undeclare()
        other.undeclare()


async def test_no_router_is_a_connection_error():
    with pytest.raises(ConnectionError, match="no Zenoh router reachable"):
        await BintrackClient(net=NET, connect=[f"tcp/127.0.0.1:{free_port()}"], wait=0.2).open()


async def test_bad_configuration_is_a_value_error():
    with pytest.raises(ValueError, match="KEY:VALUE"):
        await BintrackClient(net=NET, cfg=["no-colon"]).open()
    with pytest.raises(ValueError, match="network name"):
        BintrackClient(net="a/b")


async def test_subscribing_needs_an_open_client():
    with pytest.raises(RuntimeError, match="not open"):
        BintrackClient(net=NET).tracks()
