"""The router mesh: ``python -m bintrack.services.router`` processes in a chain on 127.0.0.1/2/3
route a publisher's samples on the first to a subscriber on the last, and log routers
connecting and leaving."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import zenoh

from bintrack.live.session_options import client_config
from support import HUNG, REPO, free_port, python_module, wait_logged, wait_until


class RouterProcess:
    """A router of the mesh in a process of its own; its log in a file."""

    def __init__(self, name: str, listen: str, connect: list[str], log_dir: Path, config: str | None = None,
                 argv: list[str] | None = None, env: dict[str, str] | None = None):
        """``argv``: the router's whole command line (e.g. as ``bintrack up`` builds it) instead
        of one made of ``listen``, ``connect`` and ``config``."""
        self.name, self.listen = name, listen
        self.log_path = log_dir / f"router-{name}.log"
        self._log = open(self.log_path, "w")
        if argv is None:
            argv = [sys.executable, "-m", "bintrack.services.router", "-l", listen, "--name", name]
            if config is not None:
                argv += ["-c", config]
            for peer in connect:
                argv += ["-e", peer]
        self.proc = subprocess.Popen(argv, stdout=self._log, stderr=subprocess.STDOUT, cwd=REPO,
                                     env=None if env is None else {**os.environ, **env})
        self.wait_logged("listening on", "start")

    @property
    def log(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text()

    def wait_logged(self, text: str, what: str, count: int = 1) -> None:
        """Wait until ``text`` appears ``count`` times in the log."""
        wait_logged(self, text, what, count)

    def stop(self, sig: int = signal.SIGTERM) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        code = self.proc.wait(timeout=HUNG)
        self._log.close()
        return code


def start_chain(tmp_path: Path, count: int = 3) -> list[RouterProcess]:
    """``count`` routers on 127.0.0.1, .2, .3 …, each connected to the one before."""
    routers: list[RouterProcess] = []
    port = free_port()
    for i in range(count):
        endpoint = f"tcp/127.0.0.{i + 1}:{port}"
        routers.append(RouterProcess(f"r{i + 1}", endpoint, [routers[-1].listen] if routers else [], tmp_path))
    for i, router in enumerate(routers):  # each sees its neighbours in the chain
        router.wait_logged(": router ", "its neighbours", count=2 if 0 < i < count - 1 else 1)
    return routers


def stop_chain(routers: list[RouterProcess]) -> None:
    """Kill the routers of :func:`start_chain` still running."""
    for router in routers:
        if router.proc.poll() is None:
            router.proc.kill()
            router.proc.wait()


@pytest.fixture
def chain(tmp_path):
    routers = start_chain(tmp_path)
    yield routers
    stop_chain(routers)


def test_a_sample_crosses_a_chain_of_three_routers(chain):
    first, _, last = chain
    received: list[bytes] = []
    arrived = threading.Event()

    def on_sample(sample: zenoh.Sample) -> None:
        received.append(sample.payload.to_bytes())
        if len(received) == 20:
            arrived.set()

    subscriber_session = zenoh.open(client_config([last.listen]))
    publisher_session = zenoh.open(client_config([first.listen]))
    subscriber = subscriber_session.declare_subscriber("mesh/test/**", on_sample)
    try:
        publisher = publisher_session.declare_publisher("mesh/test/a")
        # the subscription spreads through the mesh: publish until the first sample is through
        def through() -> bool:
            if received:
                return True
            publisher.put(b"probe")
            return False

        wait_until(through, "a probe through the mesh", interval=0.05)
        # the probes still on their way arrive before this one (one publisher: in order)
        publisher.put(b"last probe")
        wait_until(lambda: received[-1] == b"last probe", "the last probe")
        received.clear()
        for i in range(20):
            publisher.put(str(i).encode())
        assert arrived.wait(HUNG), received
        assert received == [str(i).encode() for i in range(20)]  # all, in order
    finally:
        subscriber.undeclare()
        subscriber_session.close()
        publisher_session.close()


def test_killing_the_middle_router_is_logged_by_the_others(chain):
    first, middle, last = chain
    middle.proc.kill()
    middle.proc.wait()
    for router in (first, last):
        router.wait_logged(" left", "the middle router leaving")
    assert all(f"router {middle_zid(middle)} left" in r.log for r in (first, last))


def middle_zid(router: RouterProcess) -> str:
    """The router's Zenoh id, from its "listening" line (a neighbour's "connected" line can come
    before it)."""
    return re.search(rf"router {router.name} \((\w+)\): listening", router.log).group(1)


def test_sigterm_ends_a_router_cleanly_and_its_neighbour_logs_it(chain):
    first, middle, _ = chain
    assert middle.stop(signal.SIGTERM) == 0
    assert "stopped" in middle.log
    first.wait_logged(" left", "the middle router leaving")


def test_sigusr1_writes_every_threads_stack_and_the_router_goes_on(tmp_path):
    # every service and router takes this from configure_logging: a hung one says where it is
    router = RouterProcess("solo", f"tcp/127.0.0.1:{free_port()}", [], tmp_path)
    try:
        router.proc.send_signal(signal.SIGUSR1)
        main_stack = r"Current thread 0x\w+ \(most recent call first\):\n(  File .*\n)*  File .*services/router\.py"
        wait_until(lambda: re.search(main_stack, router.log), "the main thread's stack", logs=[router])
        assert router.proc.poll() is None
        assert router.stop(signal.SIGTERM) == 0 and "stopped" in router.log
    finally:
        stop_chain([router])


def test_a_router_without_listen_endpoint_is_refused(tmp_path):
    result = python_module("bintrack.services.router")
    assert result.returncode == 2
    assert "give at least one -l/--listen endpoint" in result.stderr


ACL = {"enabled": True, "default_permission": "deny",
       "rules": [{"id": "demo", "messages": ["put", "declare_subscriber"], "flows": ["ingress", "egress"],
                  "permission": "allow", "key_exprs": ["demo/**"]}],
       "subjects": [{"id": "loopback", "interfaces": ["lo"]}],
       "policies": [{"rules": ["demo"], "subjects": ["loopback"]}]}


def test_with_rust_log_the_router_names_each_put_its_access_control_denies(tmp_path):
    """Zenoh 1.x reports a denial only in its own log, at trace level: the router passes
    RUST_LOG on, so an operator can see what the access control drops (docs/secure.md)."""
    listen = f"tcp/127.0.0.1:{free_port()}"
    router = RouterProcess("acl", listen, [], tmp_path, argv=[
        sys.executable, "-m", "bintrack.services.router", "-l", listen, "--name", "acl",
        "--cfg", f"access_control:{json.dumps(ACL)}"],
        env={"RUST_LOG": "error,zenoh::net::routing::interceptor::access_control=trace"})
    client = zenoh.open(client_config([listen]))
    try:
        client.put("demo/allowed", b"1")
        client.put("other/denied", b"2")
        router.wait_logged("unauthorized to Put (ingress) on other/denied", "the denied put in the router's log")
    finally:
        client.close()
        router.stop()
    assert "unauthorized to Put (ingress) on demo/allowed" not in router.log
