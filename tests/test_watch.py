"""Programs that print live tracks: ``bintrack watch`` and ``examples/subscribe_tracks.py``
(zenoh + msgpack only), each as a subprocess against a real router while the test publishes."""

from __future__ import annotations

import queue
import signal
import subprocess
import sys
import threading

import pytest
import zenoh

from bintrack.live.session_options import client_config
from bintrack.keys import Keys
from bintrack.bus_payloads import LocalEstimate, Track, TrackSet, Transition
from bintrack.message_codec import encode
from support import HUNG, REPO, bintrack, free_port, wait_until

NET = "test-watch"
KEYS = Keys(NET)


class Printer:
    """A subprocess whose stdout lines are collected by a thread (so reads can time out)."""

    def __init__(self, argv: list[str]):
        self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
        self.lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._pump, daemon=True).start()

    def _pump(self) -> None:
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))

    def line(self, timeout: float = HUNG) -> str:
        return self.lines.get(timeout=timeout)

    def interrupt(self, sig: int = signal.SIGINT) -> tuple[int, str]:
        """Send ``sig``; the exit status and stderr (a hang fails the test)."""
        self.proc.send_signal(sig)
        try:
            _, err = self.proc.communicate(timeout=HUNG)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            raise
        return self.proc.returncode, err


@pytest.fixture
def bus(zenoh_router):
    session = zenoh.open(client_config([zenoh_router]))
    yield session
    session.close()


def publish_when_matched(session: zenoh.Session, key: str, payload: bytes, printer: Printer) -> None:
    publisher = session.declare_publisher(key)

    def subscribed() -> bool:
        assert printer.proc.poll() is None, printer.proc.communicate()[1]
        return publisher.matching_status.matching

    wait_until(subscribed, "the printer to subscribe")
    publisher.put(payload)
    publisher.undeclare()


SCAN = TrackSet(t=12.5, tracker="mcmcda", tracks=[Track(track=0, x=10.0, y=20.0, vx=0.5, vy=-0.1),
                                                  Track(track=3, x=-1.25, y=7.0)])


def test_example_prints_one_line_per_track(zenoh_router, bus):
    printer = Printer([sys.executable, str(REPO / "examples" / "subscribe_tracks.py"), "-e", zenoh_router,
                       "--net", NET])
    publish_when_matched(bus, KEYS.tracks(), b"junk", printer)
    publish_when_matched(bus, KEYS.tracks(), encode(SCAN), printer)
    assert printer.line() == "t=12.500 track=0 x=10.00 y=20.00 vx=0.50 vy=-0.10"
    assert printer.line() == "t=12.500 track=3 x=-1.25 y=7.00 vx=- vy=-"
    status, err = printer.interrupt(signal.SIGINT)
    assert status == 0, err
    assert "skipped a payload" in err and "Traceback" not in err


def test_example_uses_no_bintrack_code():
    source = (REPO / "examples" / "subscribe_tracks.py").read_text()
    imports = {line.split()[1].split(".")[0] for line in source.splitlines()
               if line.startswith(("import ", "from "))}
    assert "bintrack" not in imports and {"zenoh", "msgpack"} <= imports


@pytest.mark.parametrize("what, key, message, expected", [
    ("tracks", KEYS.tracks(), SCAN,
     "t=12.500 tracker=mcmcda tracks=2 | #0 (10.00, 20.00) v=(0.50, -0.10) | #3 (-1.25, 7.00) v=(-, -)"),
    ("estimates", KEYS.estimate("n4"), LocalEstimate(t=3.25, node="n4", tracker="arc", x=1.0, y=2.0),
     "t=3.250 node=n4 tracker=arc x=1.00 y=2.00 v=(-, -)"),
    ("transitions", KEYS.transition("n4"), Transition(t=3.25, sensor="n4", value=1, previous=0, seq=4),
     "t=3.250 sensor=n4 0->1 seq=4"),
])
def test_watch_prints_each_message_on_a_line(zenoh_router, bus, what, key, message, expected):
    printer = Printer([sys.executable, "-m", "bintrack.cli", "watch", "--what", what, "-e", zenoh_router,
                       "--net", NET])
    publish_when_matched(bus, key, b"\x00\x01", printer)
    publish_when_matched(bus, key, encode(message), printer)
    assert printer.line() == expected
    status, err = printer.interrupt(signal.SIGTERM if what == "transitions" else signal.SIGINT)
    assert status == 0, err
    assert "1 bad payloads" in err and "Traceback" not in err


def test_watch_without_router_fails_with_one_line():
    result = bintrack("watch", "-e", f"tcp/127.0.0.1:{free_port()}", "--wait", "0.2")
    assert result.returncode == 1
    last = result.stderr.splitlines()[-1]
    assert last.startswith("bintrack watch: no Zenoh router reachable at tcp/127.0.0.1:") and "bintrack up" in last


@pytest.mark.parametrize("program", ["watch", "example"])
def test_without_net_the_one_network_alive_is_taken(zenoh_router, bus, program):
    token = bus.liveliness().declare_token(KEYS.alive("basestation", "b1"))
    try:
        argv = ([sys.executable, "-m", "bintrack.cli", "watch", "-e", zenoh_router] if program == "watch" else
                [sys.executable, str(REPO / "examples" / "subscribe_tracks.py"), "-e", zenoh_router])
        printer = Printer(argv)
        publish_when_matched(bus, KEYS.tracks(), encode(SCAN), printer)
        assert printer.line().startswith("t=12.500")
        status, err = printer.interrupt(signal.SIGINT)
        assert status == 0, err
    finally:
        token.undeclare()


@pytest.mark.parametrize("program", ["watch", "example"])
def test_without_net_several_networks_alive_are_listed(zenoh_router, bus, program):
    tokens = [bus.liveliness().declare_token(Keys(net).alive("sensor_agent", "a1")) for net in ("north", "south")]
    try:
        argv = ([sys.executable, "-m", "bintrack.cli", "watch", "-e", zenoh_router] if program == "watch" else
                [sys.executable, str(REPO / "examples" / "subscribe_tracks.py"), "-e", zenoh_router])
        result = subprocess.run(argv, capture_output=True, text=True, timeout=HUNG, cwd=REPO)
    finally:
        for token in tokens:
            token.undeclare()
    assert result.returncode != 0
    last = result.stderr.strip().splitlines()[-1]
    assert "north, south" in last and "--net" in last, result.stderr


def test_watch_without_net_and_no_network_alive_says_so(zenoh_router):
    result = bintrack("watch", "-e", zenoh_router)
    assert result.returncode == 1
    assert "no bintrack network is alive on the bus" in result.stderr.strip().splitlines()[-1], result.stderr
