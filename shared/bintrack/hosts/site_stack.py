"""The stack of ``up --regions N --hosts`` run process by process, without ``up``'s supervision:
for tests and benchmarks that need to give a site's processes an environment of their own
(a clock that is off), keep replay from holding event time, or read the sites' links before the
network is removed.

The commands are ``up``'s (:func:`bintrack.live.stack.region_stack_commands` on a
:class:`~bintrack.hosts.site_network.SiteNetwork`, the mesh's lease); the hub router is a
``bintrack.services.router`` on this machine, listening on loopback and on the sites' LAN.
Each process logs to a file of its own in ``log_dir``.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path

from bintrack.hosts.mesh_links import hub_endpoint, router_options, site_endpoints
from bintrack.hosts.site_network import SiteNetwork
from bintrack.live.stack import region_stack_commands

STOP_TIMEOUT = 30.0  # s a process has to end after SIGTERM before it is killed


class Process:
    """A process of a :class:`SiteStack`, its output in ``log_dir/<name>.log``."""

    def __init__(self, name: str, argv: list[str], log_dir: Path):
        self.name = name
        self.log_path = log_dir / f"{name}.log"
        self._log = open(self.log_path, "w")
        self.proc = subprocess.Popen(argv, stdout=self._log, stderr=subprocess.STDOUT)

    @property
    def log(self) -> str:
        """Its output so far."""
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text()

    def wait_logged(self, text: str, timeout: float) -> None:
        """Wait until ``text`` is in its output; TimeoutError after ``timeout`` s or if it ended first."""
        deadline = time.monotonic() + timeout
        while text not in self.log:
            if self.proc.poll() is not None or time.monotonic() > deadline:
                raise TimeoutError(f"{self.name}: no {text!r} in its output:\n{self.log[-2000:]}")
            time.sleep(0.05)


class SiteStack:
    """The region stack of ``regions`` on hosts of their own, replaying ``source`` into network
    ``net`` at ``speed`` (0: as fast as flow control allows), recorded into ``record`` if given.
    ``site_env``: region → environment variables for that site's processes; ``hold``: whether
    replay holds event time while a site's services are out of reach (``--no-hold`` if not);
    ``port``: the routers' (default: one free now). Started on construction; :meth:`stop` ends
    every process and removes the network (also if starting failed)."""

    def __init__(self, regions: list[str], source: str, net: str, log_dir: Path, *, speed: float = 0.0,
                 record: Path | None = None, site_env: dict[str, dict[str, str]] | None = None, hold: bool = True,
                 port: int | None = None):
        self.network = SiteNetwork(list(regions)).create()
        self.procs: dict[str, Process] = {}
        try:
            self.listen = listen = f"tcp/127.0.0.1:{port or _free_port()}"
            lan = hub_endpoint(self.network, listen)
            self.hub = self.start("router-hub", [sys.executable, "-m", "bintrack.services.router", "-l", listen, "-l",
                                                 lan, "--name", "hub", *router_options()], log_dir)
            self.hub.wait_logged("listening on", 60.0)
            state = log_dir / "state"
            state.mkdir(exist_ok=True)
            for command in region_stack_commands(regions=list(regions), endpoint=listen, net=net, source=source,
                                                 speed=speed, record=None if record is None else str(record),
                                                 routers=site_endpoints(self.network, listen), hub=lan,
                                                 router_args=router_options()):
                argv = command.argv(sys.executable)
                if command.name != "router":
                    argv += ["--id", command.key, "--state-dir", str(state)]
                if command.name == "replay" and not hold:
                    argv.append("--no-hold")
                if command.site:
                    env = [f"{k}={v}" for k, v in (site_env or {}).get(command.site, {}).items()]
                    argv = self.network.argv(command.site, ["env", *env, *argv] if env else argv)
                self.start(command.key, argv, log_dir)
        except BaseException:
            self.stop()
            raise

    def start(self, name: str, argv: list[str], log_dir: Path) -> Process:
        self.procs[name] = Process(name, argv, log_dir)
        return self.procs[name]

    def stop(self) -> None:
        """Stop every process (SIGTERM, then SIGKILL if it hangs) and remove the network."""
        for proc in self.procs.values():
            if proc.proc.poll() is None:
                proc.proc.terminate()
        for proc in self.procs.values():
            try:
                proc.proc.wait(timeout=STOP_TIMEOUT)
            except subprocess.TimeoutExpired:
                proc.proc.kill()
                proc.proc.wait()
        self.network.remove()


def _free_port() -> int:
    """A TCP port free on 127.0.0.1 and on the sites' LAN now."""
    with socket.socket() as sock:
        sock.bind(("0.0.0.0", 0))
        return sock.getsockname()[1]
