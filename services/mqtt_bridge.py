"""MQTT bridge: binary sensors on an MQTT broker as the stack's source (replay's role, live).

``python -m bintrack.services.mqtt_bridge mqtt://HOST:PORT --sensor-table FILE [options]`` serves
``deployment`` (the table's), subscribes with QoS 1 in a persistent session and wires
:class:`bintrack.mqtt.bridge_core.BridgeCore`: raw samples on ``raw/<sensor>`` before each
``clock`` tick, a tick once the consumers acknowledged the one ``--max-ahead`` before it (at
replay's gate, :class:`~bintrack.live.replay_gate.ReplayGate`: the last tick said again while an
acknowledgement is overdue), ``control/eos`` after a message on ``--end-topic``, said again until
every awaited service has reported done. With ``--state-dir`` it checkpoints
the core and journals each message before paho acknowledges it: a restart loses nothing.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import secrets
import threading
import time
from collections import deque
from pathlib import Path

import zenoh

from bintrack.errors import CommandError
from bintrack.live.checkpoint import BridgeCheckpoint
from bintrack.live.service import Service, log, service_main
from bintrack.live.control_guard import control_attachment
from bintrack.live.replay_gate import ReplayGate, wanted_services
from bintrack.bus_payloads import Clock, EndOfStream
from bintrack.message_codec import RESENT, encode, encode_raw_sample
from bintrack.mqtt.bridge_arguments import build_parser
from bintrack.mqtt.bridge_core import BridgeCore, FaultLines, RecentSamples
from bintrack.mqtt.broker_options import BrokerConfigError, broker_options
from bintrack.mqtt.message_journal import MessageJournal, take_journal
from bintrack.mqtt.mqtt_client import Subscription
from bintrack.mqtt.sensor_table import TableError, load_table

TICK_WALL = 0.05  # s of wall clock between looks at the clock
CHECKPOINT_WALL = 0.0  # each tick: replayed ticks its consumers passed get no progress, and the gate would hang


class MqttBridge(Service):
    name = "mqtt_bridge"

    def __init__(self, args: argparse.Namespace):
        self.table = load_table(args.sensor_table)
        self.broker = broker_options(args.broker, args.mqtt_config)
        args.net = args.net or self.table.name
        super().__init__(args)
        self.core = BridgeCore(self.table, period=args.clock_period, lateness=args.lateness, clock=args.clock,
                               max_rate=args.max_rate, end_topic=args.end_topic)
        self.raw_keys = {s.id: self.keys.raw(s.id) for s in self.table.sensors}
        self.gate = ReplayGate(wanted_services(args.wait_for), lambda: False, self.stopping, source=self.name)
        self.sent: deque[float] = deque(maxlen=args.max_ahead)  # the last ticks out (s)
        self.recent, self.lines = RecentSamples(), FaultLines()
        self.lock = threading.Lock()  # the core and the journal, between paho's thread and the loop
        self.journal, self.seq, self.resend_before = None, 0, None

    def listen_key(self) -> str:
        """The services' progress and done reports (not the traffic it causes)."""
        return f"{self.keys.prefix}/control/*/*/*"

    async def setup(self) -> None:
        checkpoints, saved = self.checkpoints, self.checkpoints.load(BridgeCheckpoint)
        checkpoints.run_id = checkpoints.run_id or secrets.token_hex(8)  # as replay: the source names the run
        if checkpoints.path is not None:
            journal = Path(checkpoints.path).with_suffix(".journal")
            if saved is not None:
                self.core.restore(saved.core)
                taken = take_journal(journal, self.core.journal_seq, self._take)
                # it checkpointed each tick once put: it may have put the samples of one tick more (as replay)
                self.resend_before = self.core.last_tick + self.core.period
                log.info("mqtt_bridge: restarted at the tick t=%s s; took the %d messages its journal kept since; "
                         "lost none the broker had acknowledged", self.core.last_tick, taken)
            self.seq, self.journal = self.core.journal_seq, MessageJournal(journal, CHECKPOINT_WALL)
        payload, run = encode(self.table.deployment()), checkpoints.run_id.encode()
        self.serve(self.keys.deployment(), lambda q: q.reply(self.keys.deployment(), payload, attachment=run))
        self.serve(self.keys.recent(), self._on_recent)
        self.gate.follow(self)

    def _on_recent(self, query) -> None:
        try:
            payloads = self.recent.after(query.parameters.get("after"))
        except ValueError:
            return query.reply_err(b"after must be a number of seconds")
        for payload in payloads:
            query.reply(self.keys.recent(), payload)
        query.reply(self.keys.recent(), encode(Clock(t=self.core.last_tick or 0.0)))

    def stop(self) -> None:
        super().stop()
        self.gate.changed.set()

    def _on_message(self, topic: str, payload: bytes, retained: bool) -> None:
        """paho's thread: journal the message (before paho acknowledges it), then take it."""
        received = time.time_ns() // 1000
        with self.lock:
            self.seq += 1
            if self.journal is not None:
                self.journal.append(self.seq, topic, payload, retained, received)
            self._take(self.seq, topic, payload, retained, received)

    def _take(self, seq: int, topic: str, payload: bytes, retained: bool, received: int) -> None:
        outcome = self.core.receive(topic, payload, retained=retained, received_us=received, seq=seq)
        # the end topic's message sets core.ended, which the loop sees within TICK_WALL
        if (line := self.lines.describe(outcome, self.core)) is not None:
            log.warning("mqtt_bridge: %s", line)

    async def main(self) -> None:
        if not await self.gate.all_present(self.args.ready_timeout):
            if not self.stopping.is_set():
                log.error("mqtt_bridge: no liveliness token from %s after %g s", ", ".join(self.gate.missing()),
                          self.args.ready_timeout)
                self.exit_status = 1
            return
        topics = self.table.subscriptions() + ([self.args.end_topic] if self.args.end_topic else [])
        mqtt = Subscription(self.broker, f"bintrack-{self.keys.net}-{self.args.id or self.name}", topics,
                            self._on_message, self.name)
        try:
            await asyncio.to_thread(mqtt.start, self.args.wait, self._stop_thread)
        except ConnectionError as exc:
            log.error("%s", exc)
            self.exit_status = 1
            return
        control = control_attachment(self.name, self.instance, self.args.clock_period * self.args.max_ahead)
        try:
            while not self.stopping.is_set() and not self.core.ended:
                await asyncio.sleep(TICK_WALL)  # the next look at the clock (wall or payload time)
                while not self.core.ended and await self.gate.window_open(self.sent) and self._tick(control):
                    await asyncio.sleep(0)
            if self.core.ended and not self.stopping.is_set():
                await self._finish(control)
        finally:
            mqtt.stop()
            log.info("mqtt_bridge: %s; connection lost %d times", self.core.summary(), mqtt.losses)

    def _tick(self, control: bytes) -> bool:
        """Publish the next due tick after its samples (once the gate let it); False if none is due."""
        with self.lock:
            due = self.core.next_tick(time.time_ns() // 1000)
            if due is None:
                return False
            tick, samples = due
            before = self.sent[-1] if self.sent else -math.inf
            for s in samples:
                key, payload = self.raw_keys[s.sensor], encode_raw_sample(s.t, s.sensor, s.value)
                again = self.resend_before is not None and s.t <= self.resend_before
                self._put(key, payload, RESENT if again else None)
                self.recent.add(before, key, payload)
            clock = encode(Clock(t=tick, sent=self.core.released))
            self._put(self.keys.clock(), clock, control)
            self.sent.append(tick)
            self.gate.last_tick = tick
            self.gate.tick_again = lambda: self._put(self.keys.clock(), clock, control)
            self.recent.forget_before(self.sent[0])
            if self.journal is not None:
                self.journal.checkpoint(lambda: self.checkpoints.save(BridgeCheckpoint(self.core.snapshot())))
        return True

    async def _finish(self, control: bytes) -> None:
        """End of stream: the ticks up to the final one, then EOS once every consumer has it, said
        again until each awaited service has reported done (as replay)."""
        with self.lock:
            final, t_end = self.core.end()
        while await self.gate.window_open(self.sent) and self._tick(control):
            await asyncio.sleep(0)
        if await self.gate.acknowledged(final) and await self.gate.window_open(self.sent):
            eos = encode(EndOfStream(t=t_end, awaited=sorted(self.gate.awaited()) or None))
            self._put(self.keys.eos(), eos, control)
            log.info("mqtt_bridge: end of stream at t=%g s after %d samples", t_end, self.core.released)
            await self.gate.linger(t_end, lambda: self._put(self.keys.eos(), eos, control))

    def _put(self, key: str, payload: bytes, attachment: bytes | None) -> None:
        self.session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK, attachment=attachment)


def main(argv: list[str] | None = None) -> int:
    try:
        return service_main(MqttBridge, build_parser, argv)
    except (TableError, BrokerConfigError, CommandError) as exc:
        log.error("mqtt_bridge: %s", exc)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
