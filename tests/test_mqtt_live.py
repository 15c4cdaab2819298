"""Sensors on MQTT through a real broker (Debian's mosquitto on loopback) into the whole stack:
darpa-grid-3 played as Zigbee2MQTT devices gives the tracks `bintrack track` gives, through
bad payloads, retained messages, a broker restart and a bridge killed under `up`."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import zenoh

from bintrack.cli import main as cli
from bintrack.formats import read_tracks
from bintrack.live.session_options import client_config

from support import HUNG, REPO, free_port

DARPA3 = REPO / "datasets" / "darpa-grid-3"
EPOCH = "2026-01-01T00:00:00Z"
PACKAGE = "mosquitto"
MOSQUITTO = shutil.which("mosquitto") or next((p for p in ("/usr/sbin/mosquitto",) if os.path.exists(p)), None)

pytestmark = pytest.mark.skipif(MOSQUITTO is None, reason=f"needs the {PACKAGE} broker (apt-get install {PACKAGE})")


class Lines:
    """The lines a process writes to a pipe, followed by a thread; wait for one that matches."""

    def __init__(self, stream):
        self.lines: list[str] = []
        self.changed = threading.Condition()
        self.thread = threading.Thread(target=self._follow, args=(stream,), daemon=True)
        self.thread.start()

    def _follow(self, stream) -> None:
        for line in stream:
            with self.changed:
                self.lines.append(line)
                self.changed.notify_all()
        with self.changed:
            self.lines.append("")  # the end
            self.changed.notify_all()

    def wait_for(self, pattern: str, count: int = 1) -> str:
        regex = re.compile(pattern)
        with self.changed:
            assert self.changed.wait_for(lambda: sum(bool(regex.search(l)) for l in self.lines) >= count
                                         or (self.lines and self.lines[-1] == ""), HUNG), f"no {pattern!r} in time"
            found = [l for l in self.lines if regex.search(l)]
        assert len(found) >= count, f"no {pattern!r}:\n{self.text[-3000:]}"
        return found[count - 1]

    @property
    def text(self) -> str:
        with self.changed:
            return "".join(self.lines)


class Broker:
    """mosquitto on a free loopback port, persistent (its database in ``folder``), without the
    per-client queue limits (the bridge's session may queue a whole run)."""

    def __init__(self, folder: Path):
        self.port = free_port()
        self.url = f"mqtt://127.0.0.1:{self.port}"
        self.config = folder / "mosquitto.conf"
        self.config.write_text(f"listener {self.port} 127.0.0.1\nallow_anonymous true\npersistence true\n"
                               f"persistence_location {folder}/\nmax_queued_messages 0\nlog_dest stderr\n"
                               "log_type error\nlog_type warning\nlog_type notice\nlog_type information\n"
                               # as root mosquitto would run as user mosquitto, who cannot write its database here
                               + ("user root\n" if os.geteuid() == 0 else ""))
        self.proc = None
        self.start()

    def start(self) -> None:
        self.proc = subprocess.Popen([MOSQUITTO, "-c", str(self.config)], stderr=subprocess.PIPE, text=True)
        self.log = Lines(self.proc.stderr)
        self.log.wait_for(r"mosquitto version .* running")

    def stop(self) -> None:
        """SIGTERM: mosquitto writes its database (the queued messages) and exits."""
        self.proc.send_signal(signal.SIGTERM)
        assert self.proc.wait(HUNG) == 0


@pytest.fixture
def broker(tmp_path):
    folder = tmp_path / "broker"
    folder.mkdir()
    running = Broker(folder)
    yield running
    if running.proc.poll() is None:
        running.proc.kill()
        running.proc.wait()


def bintrack(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bintrack.cli", *args], capture_output=True, text=True,
                          timeout=HUNG, cwd=REPO)


def start_up(tmp: Path, broker: Broker, table: Path) -> tuple[subprocess.Popen, Lines, str, Path]:
    """`bintrack up --source mqtt://…` with mcmcda and a recording; waits until the bridge
    is subscribed (the broker acknowledged). (process, its stderr lines, its router endpoint, the recording)."""
    endpoint, recording = f"tcp/127.0.0.1:{free_port()}", tmp / "live.mcap"
    proc = subprocess.Popen([sys.executable, "-m", "bintrack.cli", "up", "--source", broker.url, "--sensor-table",
                             str(table), "--end-topic", "bintrack/end", "--clock", "payload", "--tracker", "mcmcda",
                             "--record", str(recording), "--exit-at-end", "--no-map", "--listen", endpoint],
                            stderr=subprocess.PIPE, text=True, cwd=REPO)
    lines = Lines(proc.stderr)
    lines.wait_for(r"mqtt_bridge: subscribed to 2 topics \(the broker acknowledged\)")
    return proc, lines, endpoint, recording


def publish(broker: Broker, tmp: Path, speed: str) -> subprocess.Popen:
    """darpa-grid-3 (simulated again, byte for byte) played as Zigbee2MQTT devices."""
    return subprocess.Popen([sys.executable, "-m", "bintrack.cli", "simulate", "darpa-grid", "--people", "3", "--seed",
                             "3", "--out", str(tmp / "d3"), "--publish", broker.url, "--play-speed", speed,
                             "--epoch", EPOCH], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=REPO)


def offline_tracks(tmp: Path):
    out = tmp / "offline.csv"
    assert cli.main(["track", str(DARPA3), "--tracker", "mcmcda", "--out", str(out)]) == 0
    return read_tracks(out)


def live_tracks(proc: subprocess.Popen, lines: Lines, recording: Path, tmp: Path):
    try:
        status = proc.wait(HUNG)
    except subprocess.TimeoutExpired:
        (tmp / "up-hung.log").write_text(lines.text)
        pytest.fail(f"up did not end within {HUNG} s; its whole log is in {tmp / 'up-hung.log'}, and ends:\n"
                    f"{lines.text[-6000:]}")
    assert status == 0, lines.text[-4000:]
    lines.thread.join(HUNG)
    out = tmp / "live.csv"
    assert cli.main(["export", str(recording), "--what", "tracks", "--out", str(out)]) == 0
    return read_tracks(out)


@pytest.fixture
def table(tmp_path) -> Path:
    path = tmp_path / "table.toml"
    done = bintrack("simulate", "darpa-grid", "--people", "3", "--seed", "3", "--out", str(tmp_path / "d3"),
                    "--sensor-table", str(path), "--epoch", EPOCH)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "d3" / "events.csv").read_bytes() == (DARPA3 / "events.csv").read_bytes()
    return path


def raw_counter(endpoint: str, net: str = "darpa-grid"):
    """A Zenoh session counting the raw samples on the stack's bus; (session, wait(n))."""
    session = zenoh.open(client_config([endpoint]))
    seen = threading.Condition()
    count = [0]

    def on_raw(sample) -> None:
        with seen:
            count[0] += 1
            seen.notify_all()

    session.declare_subscriber(f"bintrack/{net}/raw/*", on_raw)

    def wait(n: int) -> None:
        with seen:
            assert seen.wait_for(lambda: count[0] >= n, HUNG), f"only {count[0]} raw samples"

    return session, wait


def test_darpa_grid_3_through_mosquitto_gives_the_offline_tracks_despite_bad_payloads(tmp_path, broker, table):
    """Retained states published before the bridge starts are its state at start, never a
    detection; junk on the sensors' topics and an unknown topic get one line each with a count."""
    import paho.mqtt.publish as single

    retained = [{"topic": f"zigbee2mqtt/n00{i}", "payload": json.dumps({"occupancy": True}), "qos": 1, "retain": True}
                for i in range(3)]
    single.multiple(retained, hostname="127.0.0.1", port=broker.port)
    proc, lines, endpoint, recording = start_up(tmp_path, broker, table)
    junk = [("zigbee2mqtt/n010", b"{oops"), ("zigbee2mqtt/n011", b'{"battery": 80}'),
            ("zigbee2mqtt/n012", b'{"occupancy": "dunno"}'), ("zigbee2mqtt/garage_door", b'{"contact": true}')]
    single.multiple([{"topic": t, "payload": p, "qos": 1} for t, p in junk], hostname="127.0.0.1", port=broker.port)
    lines.wait_for("unknown topic #1 on zigbee2mqtt/garage_door")
    played = publish(broker, tmp_path, "0")
    assert played.wait(HUNG) == 0, played.stdout.read()
    assert live_tracks(proc, lines, recording, tmp_path) == offline_tracks(tmp_path)
    log = lines.text
    for n, (topic, _) in enumerate(junk[:3], 1):
        assert re.search(rf"malformed payload #{n} on {topic}: ", log), log[-3000:]
    assert "state at start from retained messages (3 detecting)" in log
    assert re.search(r"3067 samples published, 3 retained, 3 sensors' state at start .* faults \{'malformed payload': 3, "
                     r"'unknown topic': 1\}", log), log[-2000:]


def test_a_broker_restart_and_a_bridge_killed_under_up_lose_nothing(tmp_path, broker, table):
    """mosquitto stopped and started again mid-run (its persistent sessions kept the queued
    messages), then the bridge killed with SIGKILL and restarted by `up` (its checkpoint and
    journal): the tracks are still the offline ones, and the log names what each did."""
    proc, lines, endpoint, recording = start_up(tmp_path, broker, table)
    session, wait_raw = raw_counter(endpoint)
    try:
        played = publish(broker, tmp_path, "15")
        wait_raw(600)
        broker.stop()
        broker.start()
        lines.wait_for("mqtt_bridge: reconnected to .* kept this session")
        wait_raw(1600)
        bridge = next(pid for pid in map(int, filter(str.isdigit, os.listdir("/proc")))
                      if _is_bridge_of(pid, proc.pid))
        os.kill(bridge, signal.SIGKILL)
        lines.wait_for(r"mqtt_bridge: restarted at the tick t=\S+ s; took the \d+ messages its journal kept since; "
                       "lost none the broker had acknowledged")
        assert played.wait(HUNG) == 0, played.stdout.read()
        live = live_tracks(proc, lines, recording, tmp_path)
        (tmp_path / "up.log").write_text(lines.text)
        assert live == offline_tracks(tmp_path), lines.text[-6000:]
    finally:
        session.close()
        if proc.poll() is None:
            proc.kill()


def _is_bridge_of(pid: int, parent: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return False
    return int(stat.rpartition(")")[2].split()[1]) == parent and b"bintrack.services.mqtt_bridge" in cmdline
