"""The tests' one harness (conftest.py holds the fixtures built on it).

* paths: the repository, its datasets, the real recordings beside it;
* ``HUNG``, the one timeout: every wait is on an event (a message, a log line, a liveliness
  change, an exit), and its timeout only fails a hung run; a loaded CPU is not one (pytest-timeout,
  set in pyproject.toml, ends a test hung anywhere else, with every thread's stack);
* ``bintrack(*args)`` and ``python_module``: a command in a subprocess, output captured;
* ``ServiceProcess``: a service started as ``python -m bintrack.services.<name>``, logging to a file;
* ``wait_until`` and ``wait_logged``: wait on a condition or a log line;
* ``free_port``: a loopback port no other test process is handed, under pytest-xdist too;
* ``rss_kb``: a process's resident memory;
* ``FakeBus``: the test's own Zenoh session on a network, playing replay's part.
"""

from __future__ import annotations

import fcntl
import itertools
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import zenoh

from bintrack.keys import Keys, parse_key
from bintrack.live.session_options import client_config
from bintrack.live.control_guard import control_attachment
from bintrack.live.recording import KIND_TYPES
from bintrack.bus_payloads import Clock
from bintrack.message_codec import decode, encode

REPO = Path(__file__).resolve().parents[1]
DATASETS = REPO / "datasets"
REALDATA = REPO.parent / "shared" / "realdata"  # real recordings, beside a checkout; tests skip without
HUNG = 600.0  # s: only a hung run takes this long


# --------------------------------------------------------------------------- subprocesses


def python_module(module: str, *args: str, cwd: Path = REPO, **options) -> subprocess.CompletedProcess:
    """``python -m module args`` in a subprocess, stdout and stderr captured as text."""
    return subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True, cwd=cwd,
                          timeout=HUNG, **options)


def bintrack(*args: str, cwd: Path = REPO, **options) -> subprocess.CompletedProcess:
    """The ``bintrack`` command in a subprocess (``check=True`` to fail on a non-zero exit)."""
    return python_module("bintrack.cli", *args, cwd=cwd, **options)


_logs = itertools.count()


class ServiceProcess:
    """A service started as ``python -m bintrack.services.<name>``; output goes to a log file."""

    def __init__(self, name: str, args: list[str], endpoint: str, log_dir: Path):
        self.name = name
        self.log_path = log_dir / f"{name}-{os.getpid()}-{next(_logs)}.log"
        self._log = open(self.log_path, "w")
        self.proc = subprocess.Popen([sys.executable, "-m", f"bintrack.services.{name}", *args, "-e", endpoint],
                                     stdout=self._log, stderr=subprocess.STDOUT, cwd=REPO)

    @property
    def log(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text()

    def wait(self, timeout: float = HUNG) -> int:
        code = self.proc.wait(timeout=timeout)
        self._log.close()
        return code

    def stop(self, timeout: float = HUNG) -> int:
        """SIGTERM, then the exit status (a hang fails the test)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        return self.wait(timeout)


# --------------------------------------------------------------------------- waiting on events


def wait_until(condition, what: str, timeout: float = HUNG, logs=(), interval: float = 0.02) -> None:
    """Wait for ``condition()`` (polled every ``interval`` s); fail naming ``what``, with the
    tails of the ``logs`` (processes with a ``log``), if it does not hold within ``timeout``."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}\n" + "\n".join(p.log[-3000:] for p in logs))
        time.sleep(interval)


def wait_logged(proc, text, what: str | None = None, count: int = 1, timeout: float = HUNG) -> None:
    """Wait until ``text`` shows ``count`` times in ``proc``'s log (or, ``text`` a function,
    until ``text(log)`` holds); fails at once if the process ended without it."""
    holds = text if callable(text) else (lambda log: log.count(text) >= count)
    what = what or repr(text)
    deadline = time.monotonic() + timeout
    while not holds(proc.log):
        assert proc.proc.poll() is None or holds(proc.log), f"{proc.name} ended before {what}:\n{proc.log[-3000:]}"
        assert time.monotonic() < deadline, f"{proc.name}: no {what}:\n{proc.log[-3000:]}"
        time.sleep(0.02)


# --------------------------------------------------------------------------- ports and memory

# Ports below Linux's ephemeral range (32768–60999 by default), which the kernel never gives to
# an outgoing connection; each is claimed by an exclusive lock file held until the process that
# claimed it exits, so two pytest workers (or two runs) are never handed the same one.
_PORTS = range(20000, 32000)
_PORT_LOCKS = Path(tempfile.gettempdir()) / f"bintrack-test-ports-{os.getuid()}"
_held: list = []  # the open lock files of this process's ports
_port_lock = threading.Lock()
_next_port = [None]


def _bindable(port: int) -> bool:
    with socket.socket() as sock:
        try:
            sock.bind(("0.0.0.0", port))
        except OSError:
            return False
    return True


def free_port() -> int:
    """A TCP port free on every loopback address, that no other process using this harness is
    handed while this one runs (a lock file per port, not a bind-and-close race)."""
    with _port_lock:
        _PORT_LOCKS.mkdir(exist_ok=True)
        if _next_port[0] is None:  # processes start at different places, to find a free one at once
            _next_port[0] = (os.getpid() * 101) % len(_PORTS)
        for _ in range(len(_PORTS)):
            port = _PORTS[_next_port[0]]
            _next_port[0] = (_next_port[0] + 1) % len(_PORTS)
            handle = open(_PORT_LOCKS / str(port), "a")
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                handle.close()
                continue
            if _bindable(port):
                _held.append(handle)
                return port
            handle.close()
        raise RuntimeError(f"no free port in {_PORTS.start}–{_PORTS.stop - 1}")


def rss_kb(pid: int) -> int:
    """Resident memory of process ``pid``, kB (``VmRSS`` of /proc/<pid>/status)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError(f"no VmRSS for {pid}")


# --------------------------------------------------------------------------- the fake bus


def kind_of(key: str) -> str | None:
    """The key kind of ``key`` (``parse_key``), None if it is not a bintrack key."""
    try:
        return parse_key(key).kind
    except ValueError:
        return None


class FakeBus:
    """The test's own Zenoh session on a network: it plays replay's part (serves the deployment,
    holds a replay's liveliness token, so its clock and end of stream are taken), publishes by
    hand on keys built with ``self.keys``, and keeps every message of the network in arrival
    order (one subscriber, so the order each publisher sent them in is kept)."""

    def __init__(self, endpoint: str, deployment, serve_deployment: bool = True):
        self.keys = Keys(deployment.name)
        self.session = zenoh.open(client_config([endpoint]))
        self.lock = threading.Lock()
        self.seen: list[tuple[str, bytes]] = []
        self.entities = [self.session.declare_subscriber(self.keys.all(), self._on_sample),
                         self.session.liveliness().declare_token(self.keys.alive("replay", "test"))]
        self.control = control_attachment("replay", "test")
        self.played: list[str] = []
        if serve_deployment:
            payload = encode(deployment)
            self.entities.append(self.session.declare_queryable(
                self.keys.deployment(), lambda query: query.reply(self.keys.deployment(), payload)))

    def _on_sample(self, sample) -> None:
        with self.lock:
            self.seen.append((str(sample.key_expr), sample.payload.to_bytes()))

    def put(self, key: str, payload, attachment: bytes | None = None) -> None:
        """Publish ``payload`` (bytes, or a message to encode) on ``key``, as replay would (with
        ``attachment``, as that sender would): blocking where a queue is full (Zenoh's default
        drops the put there)."""
        self.session.put(key, payload if isinstance(payload, bytes) else encode(payload),
                         attachment=self.control if attachment is None else attachment,
                         congestion_control=zenoh.CongestionControl.BLOCK)

    def messages(self, kind: str, start: int = 0) -> list[tuple[str, object]]:
        """(key, decoded message) of every message of key kind ``kind`` seen, from index ``start``."""
        with self.lock:
            seen = self.seen[start:]
        return [(key, decode(KIND_TYPES[kind], payload)) for key, payload in seen if kind_of(key) == kind]

    def mark(self) -> int:
        with self.lock:
            return len(self.seen)

    def alive(self, service: str) -> list[str]:
        """The liveliness tokens of ``service`` now (the query ends when the router answered)."""
        replies = self.session.liveliness().get(self.keys.alive(service), timeout=HUNG)
        return [str(r.ok.key_expr) for r in replies if r.ok is not None]

    def play(self, service: str) -> None:
        """Play an upstream instance of ``service`` too (a liveliness token, and a progress
        report at each tick): the services downstream wait for an upstream of each kind."""
        self.entities.append(self.session.liveliness().declare_token(self.keys.alive(service, "test")))
        self.played.append(service)

    def wait_for(self, service: str, proc=None) -> None:
        """Wait until ``service`` holds its liveliness token."""
        wait_until(lambda: self.alive(service), f"{service} to come up", logs=[proc] if proc else [], interval=0.1)

    def tick(self, t: float, service: str, proc=None, sent: int | None = None) -> None:
        """Publish a clock tick and wait until ``service`` reports progress to it (so it has
        handled everything published before the tick). A played upstream reports having
        handled everything up to ``t`` first (a played sensor agent: having sent ``sent``).
        ``proc``, the service's process: it must not end meanwhile."""
        for upstream in self.played:
            self.put(self.keys.progress(upstream, "test"), Clock(t=t, sent=sent), control_attachment(upstream, "test"))
        self.put(self.keys.clock(), Clock(t=t))

        def reported() -> bool:
            assert proc is None or proc.proc.poll() is None, f"{proc.name} ended:\n{proc.log[-3000:]}"
            return any(parse_key(key).service == service and message.t >= t for key, message in self.messages("progress"))

        wait_until(reported, f"progress {t} from {service}", logs=[proc] if proc else [])

    def close(self) -> None:
        for entity in self.entities:
            entity.undeclare()
        self.session.close()
