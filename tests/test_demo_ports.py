"""The map never takes the stack down.

``make demo`` succeeds while another program holds port 8080 and while a second ``up`` runs
(whose map took 8080 first, or fell back too): the demo's map serves on a free port, and says
so once. And when the map cannot be served at all, ``up`` says so in one line and the stack
runs to its end without it.
"""

from __future__ import annotations

import errno
import shutil
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from support import HUNG, REPO, bintrack, free_port

DARPA1 = REPO / "datasets" / "darpa-grid-1"


class Background:
    """A bintrack command in the background; ``wait_for(text)`` until a stderr line holds it."""

    def __init__(self, *args: str):
        self.proc = subprocess.Popen([sys.executable, "-m", "bintrack.cli", *args], cwd=REPO, text=True,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        self.lines: list[str] = []
        self.changed = threading.Condition()
        self.reader = threading.Thread(target=self._drain, daemon=True)
        self.reader.start()

    def _drain(self) -> None:
        for line in self.proc.stderr:
            with self.changed:
                self.lines.append(line.rstrip())
                self.changed.notify_all()
        with self.changed:
            self.changed.notify_all()

    def wait_for(self, text: str) -> str:
        with self.changed:
            self.changed.wait_for(lambda: any(text in line for line in self.lines) or not self.reader.is_alive(), HUNG)
            found = [line for line in self.lines if text in line]
        assert found, "\n".join(self.lines[-30:])
        return found[0]

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        return self.proc.wait(timeout=HUNG)


def hold_8080() -> socket.socket | None:
    """A socket listening on 127.0.0.1:8080, or None if another program already holds it."""
    sock = socket.socket()
    try:
        sock.bind(("127.0.0.1", 8080))
    except OSError as exc:
        sock.close()
        if exc.errno == errno.EADDRINUSE:
            return None
        raise
    sock.listen()
    return sock


def demo_command(out) -> list[str]:
    """``make demo`` when the Makefile's virtual environment is there (as after `make test`), else
    the command it runs."""
    venv_python = REPO / ".venv" / "bin" / "python"
    if shutil.which("make") and (REPO / ".venv" / ".installed").exists() and venv_python.resolve() == Path(sys.executable).resolve():
        return ["make", "-s", "demo", f"DEMO_ARGS=--out {out}"]
    return [sys.executable, "-m", "bintrack.cli", "demo", "--out", str(out)]


@pytest.mark.slow
def test_make_demo_succeeds_while_8080_is_held_and_another_up_runs(tmp_path):
    held = hold_8080()
    other = Background("up", str(DARPA1), "--speed", "1", "--loop", "--listen", f"tcp/127.0.0.1:{free_port()}")
    try:
        other.wait_for("view: map on")   # its map has a port too (8080 is held: another one)
        result = subprocess.run(demo_command(tmp_path / "demo"), cwd=REPO, capture_output=True, text=True,
                                timeout=HUNG)
    finally:
        assert other.stop() in (0, 128 + signal.SIGINT), "\n".join(other.lines[-30:])
        if held is not None:
            held.close()
    assert result.returncode == 0, result.stderr[-3000:]
    assert "final track table" in result.stdout and "GOSPA" in result.stdout
    assert (tmp_path / "demo" / "demo.png").stat().st_size > 0
    served = [line for line in result.stderr.splitlines() if "map on http" in line]
    assert len(served) == 1, result.stderr[-3000:]
    if held is not None:   # (held by another program, 8080 may have come free again meanwhile)
        assert "(port 8080 was taken)" in served[0] and "127.0.0.1:8080/" not in served[0], served
    assert "Traceback" not in result.stderr


def test_up_goes_on_without_the_map_when_it_cannot_be_served(tmp_path):
    # 192.0.2.1 (TEST-NET-1) is no address of this machine: nothing can be bound there (with a
    # token, as any address beyond loopback needs one)
    result = bintrack("up", str(DARPA1), "--speed", "0", "--exit-at-end", "--listen", f"tcp/127.0.0.1:{free_port()}",
                      "--map-bind", "192.0.2.1", "--map-token", "t0ken", "--record", str(tmp_path / "run.mcap"))
    assert result.returncode == 0, result.stderr[-3000:]
    without = [line for line in result.stderr.splitlines() if "without the map" in line]
    assert len(without) == 1 and without[0].startswith("up: cannot serve the map on 192.0.2.1:8080"), without
    assert "view" not in result.stderr.split("services: ", 1)[1].splitlines()[0]
    assert (tmp_path / "run.mcap").stat().st_size > 0
