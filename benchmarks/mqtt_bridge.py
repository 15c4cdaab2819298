"""The MQTT bridge's throughput beside raw paho-mqtt through the same broker, in one run.

    python benchmarks/mqtt_bridge.py [--copies K] [--repeats R]

darpa-grid-3 as Zigbee2MQTT devices would publish it (``bintrack simulate --publish``'s
payloads), K copies one after the other in event time (K × 3067 messages), is queued in a
mosquitto (Debian's, on loopback) for a persistent session while its subscriber is away (QoS 1).
Then the subscriber connects and drains the queue:

* **raw paho-mqtt**: a bare paho client that only counts the messages;
* **bridge**: ``python -m bintrack.services.mqtt_bridge`` (``--clock payload``), counted as raw
  samples on Zenoh by a subscriber of the bus, up to its end of stream.

Each rate is messages / (last arrival − connection), s of wall clock: from the moment the
subscriber (the bare client, or the bridge once it logs that it subscribes) has connected to
the last message counted; the best of R runs each.
Goal (issue 45): the bridge at least 1/3 of the raw rate.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import paho.mqtt.client as mqtt
import zenoh

from bintrack.formats import Event, open_dataset
from bintrack.live.session_options import client_config, router_config
from bintrack.mqtt.broker_options import broker_options
from bintrack.mqtt.mqtt_client import publish_messages
from bintrack.mqtt.sensor_table import parse_instant, table_text
from bintrack.mqtt.zigbee_playback import END_TOPIC, zigbee_messages

REPO = Path(__file__).resolve().parents[1]
DARPA3 = REPO / "datasets" / "darpa-grid-3"
EPOCH = "2026-01-01T00:00:00Z"
WAIT = 300.0


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def start_broker(folder: Path) -> tuple[subprocess.Popen, int]:
    port = free_port()
    conf = folder / "mosquitto.conf"
    conf.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\nmax_queued_messages 0\n"
                    "log_dest stderr\nlog_type information\n" + ("user root\n" if os.geteuid() == 0 else ""))
    proc = subprocess.Popen([shutil.which("mosquitto") or "/usr/sbin/mosquitto", "-c", str(conf)],
                            stderr=subprocess.PIPE, text=True)
    for line in proc.stderr:
        if " running" in line:
            break
    threading.Thread(target=lambda: [None for _ in proc.stderr], daemon=True).start()
    return proc, port


def events(copies: int) -> list[Event]:
    base = list(open_dataset(DARPA3).events())
    span = 100.0  # s between copies (the dataset lasts 90 s)
    return [Event(round(e.t + k * span, 6), e.sensor, e.value) for k in range(copies) for e in base]


class Arrivals:
    """Counts arrivals and the wall-clock time of the first and the last."""

    def __init__(self, expected: int):
        self.expected, self.count, self.first, self.last = expected, 0, None, None
        self.done = threading.Event()

    def connected(self) -> None:
        self.first = time.perf_counter()

    def arrived(self, *_) -> None:
        now = time.perf_counter()
        self.count += 1
        self.last = now
        if self.count >= self.expected:
            self.done.set()

    def rate(self) -> float:
        assert self.done.wait(WAIT), f"only {self.count} of {self.expected} arrived"
        return self.count / (self.last - self.first)


def raw_paho(port: int, messages: list, topics: list[str]) -> float:
    client_id = f"bench-raw-{time.monotonic_ns()}"

    def client() -> mqtt.Client:
        c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=False,
                        protocol=mqtt.MQTTv311)
        c.max_inflight_messages_set(1000)
        return c

    subscribed = threading.Event()
    first = client()
    first.on_subscribe = lambda *a: subscribed.set()
    first.connect("127.0.0.1", port)
    first.loop_start()
    first.subscribe([(t, 1) for t in topics])
    assert subscribed.wait(WAIT)
    first.loop_stop()
    first.disconnect()
    publish_messages(broker_options(f"mqtt://127.0.0.1:{port}"), messages, speed=0, client_id=f"{client_id}-pub")
    arrivals = Arrivals(len(messages))
    drain = client()
    drain.on_message = arrivals.arrived
    arrivals.connected()
    drain.connect("127.0.0.1", port)
    drain.loop_start()
    try:
        return arrivals.rate()
    finally:
        drain.loop_stop()
        drain.disconnect()


def bridge(port: int, messages: list, table: Path, folder: Path) -> float:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = zenoh.open(router_config([endpoint]))
    session = zenoh.open(client_config([endpoint]))
    instance = f"bench{time.monotonic_ns()}"
    argv = [sys.executable, "-m", "bintrack.services.mqtt_bridge", f"mqtt://127.0.0.1:{port}", "--sensor-table",
            str(table), "--clock", "payload", "--end-topic", END_TOPIC, "--max-rate", "1000", "--id", instance,
            "-e", endpoint]
    try:
        # a first run makes the persistent session and its subscriptions, then stops
        first = subprocess.Popen(argv, stderr=subprocess.PIPE, text=True)
        for line in first.stderr:
            if "subscribing to" in line:
                break
        first.send_signal(signal.SIGTERM)
        first.communicate(timeout=WAIT)
        publish_messages(broker_options(f"mqtt://127.0.0.1:{port}"), messages, speed=0, client_id=f"{instance}-pub")
        arrivals = Arrivals(len(messages) - 1)  # all but the end of stream become raw samples
        subscriber = session.declare_subscriber("bintrack/darpa-grid/raw/*", arrivals.arrived)
        drain = subprocess.Popen(argv, stderr=subprocess.PIPE, text=True)
        for line in drain.stderr:
            if "subscribing to" in line:
                arrivals.connected()
                break
        threading.Thread(target=lambda: [None for _ in drain.stderr], daemon=True).start()
        try:
            return arrivals.rate()
        finally:
            drain.send_signal(signal.SIGTERM)
            drain.wait(WAIT)
            subscriber.undeclare()
    finally:
        session.close()
        router.close()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--copies", type=int, default=10, help="copies of darpa-grid-3 (3067 messages each)")
    parser.add_argument("--repeats", type=int, default=3, help="runs of each; the best is reported")
    args = parser.parse_args()
    if shutil.which("mosquitto") is None and not os.path.exists("/usr/sbin/mosquitto"):
        print("needs Debian's mosquitto broker (apt-get install mosquitto)")
        return 1
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        dataset = open_dataset(DARPA3)
        table = folder / "table.toml"
        table.write_text(table_text(dataset.deployment, EPOCH))
        messages = list(zigbee_messages(events(args.copies), parse_instant(EPOCH)))
        topics = ["zigbee2mqtt/+", END_TOPIC]
        broker, port = start_broker(folder)
        try:
            raw = max(raw_paho(port, messages, topics) for _ in range(args.repeats))
            ours = max(bridge(port, messages, table, folder) for _ in range(args.repeats))
        finally:
            broker.terminate()
            broker.wait()
    print(f"{len(messages)} Zigbee2MQTT messages (QoS 1) drained from mosquitto, best of {args.repeats}:")
    print(f"  raw paho-mqtt client : {raw:9.0f} messages/s")
    print(f"  MQTT bridge → Zenoh  : {ours:9.0f} messages/s   ({ours / raw:.2f} of raw; goal >= 0.33)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
