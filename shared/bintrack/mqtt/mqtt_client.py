"""paho-mqtt clients with bintrack's options: a persistent session (MQTT 3.1.1, clean session
off, QoS 1), TLS and login from :class:`~bintrack.mqtt.broker_options.BrokerOptions`, and the
publisher that plays messages onto a broker (``bintrack simulate --publish``)."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable

import paho.mqtt.client as mqtt

from bintrack.mqtt.broker_options import BrokerOptions

log = logging.getLogger("bintrack")

RECONNECT_DELAY = (0.1, 2.0)  # s: paho's first and longest wait between reconnection attempts


def make_client(options: BrokerOptions, client_id: str) -> mqtt.Client:
    """A client of a persistent session named ``client_id`` (unless the options name one),
    with the options' login and TLS; not connected yet."""
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=options.client_id or client_id,
                         clean_session=False, protocol=mqtt.MQTTv311)
    if options.username is not None:
        client.username_pw_set(options.username, options.password)
    if options.tls:
        client.tls_set(ca_certs=options.ca, certfile=options.cert, keyfile=options.key)
    client.reconnect_delay_set(*RECONNECT_DELAY)
    client.max_inflight_messages_set(1000)
    return client


def connect(client: mqtt.Client, options: BrokerOptions, wait: float, who: str,
            stop: threading.Event | None = None) -> None:
    """Connect, retrying for ``wait`` s while the broker is not up; ConnectionError after.
    Reconnection after that is paho's (its loop thread)."""
    deadline = time.monotonic() + wait
    attempt = 0
    while True:
        attempt += 1
        try:
            client.connect(options.host, options.port, keepalive=options.keepalive)
            return
        except (OSError, ValueError) as exc:
            if time.monotonic() >= deadline or (stop is not None and stop.is_set()):
                raise ConnectionError(f"{who}: no MQTT broker at {options.url} after {attempt} attempts: {exc}") from None
            if attempt == 1:
                log.warning("%s: waiting for the MQTT broker at %s (%s); retrying", who, options.url, exc)
            time.sleep(0.2)


def publish_messages(options: BrokerOptions, messages: Iterable[tuple[float, str, bytes]], *, speed: float,
                     client_id: str, wait: float = 30.0, retain: bool = False,
                     progress: Callable[[int], None] | None = None) -> int:
    """Publish (event time s, topic, payload) messages in order with QoS 1 at ``speed`` × real
    time (0: as fast as the broker takes them) and wait until the broker has acknowledged
    each (across reconnections: paho keeps the unacknowledged ones and sends them again).
    While the connection is down it waits, and after a reconnection it publishes nothing new
    until paho's resent messages are acknowledged: a message published at the reconnection
    could otherwise overtake them (each device's messages stay in order, as a device sends
    them). How many were published."""
    client = make_client(options, client_id)
    connected = threading.Event()
    connections = [0]

    def on_connect(c, u, flags, reason, props) -> None:
        if not reason.is_failure:
            connections[0] += 1
            connected.set()

    client.on_connect = on_connect
    client.on_disconnect = lambda c, u, flags, reason, props: connected.clear()
    acked = threading.Condition()
    count = [0]

    def on_publish(c, u, mid, reason, props) -> None:
        with acked:
            count[0] += 1
            acked.notify_all()

    client.on_publish = on_publish
    connect(client, options, wait, "simulate")
    client.loop_start()
    try:
        if not connected.wait(wait):
            raise ConnectionError(f"simulate: the MQTT broker at {options.url} did not accept the connection")
        published, seen = 0, connections[0]
        start = origin = None
        for t, topic, payload in messages:
            if not connected.is_set() or connections[0] != seen:
                connected.wait()
                with acked:  # the ones paho sends again go first
                    acked.wait_for(lambda: count[0] >= published)
                seen = connections[0]
            if speed > 0:
                if origin is None:
                    origin, start = t, time.monotonic()
                delay = start + (t - origin) / speed - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            client.publish(topic, payload, qos=1, retain=retain)  # kept by paho until acknowledged
            published += 1
            if progress is not None:
                progress(published)
        with acked:  # each acknowledged by the broker, whatever reconnections it took
            acked.wait_for(lambda: count[0] >= published)
        return published
    finally:
        client.loop_stop()
        client.disconnect()


class Subscription:
    """A client subscribed with QoS 1 to ``topics`` in its persistent session, again on each
    reconnection (paho reconnects by itself). ``on_message(topic, payload, retained)`` runs
    on paho's thread, and paho acknowledges the message once it returns. A lost connection
    and a return are logged in one line each, with the count of losses (:attr:`losses`)."""

    def __init__(self, options: BrokerOptions, client_id: str, topics: list[str],
                 on_message: Callable[[str, bytes, bool], None], who: str):
        self.options, self.topics, self.who = options, topics, who
        self.connections = self.losses = 0
        self._closing = False
        self.client = make_client(options, client_id)
        self.client.on_connect, self.client.on_disconnect = self._on_connect, self._on_disconnect
        self.client.on_subscribe = self._on_subscribe
        self.client.on_message = lambda c, u, m: on_message(m.topic, m.payload, bool(m.retain))

    def start(self, wait: float, stop: threading.Event | None = None) -> None:
        """Connect (retrying ``wait`` s; ConnectionError after) and run paho's thread; blocking."""
        connect(self.client, self.options, wait, self.who, stop)
        self.client.loop_start()
        log.info("%s: subscribing to %d topics on %s", self.who, len(self.topics), self.options.url)

    def stop(self) -> None:
        self._closing = True
        self.client.loop_stop()
        self.client.disconnect()

    def _on_connect(self, client, userdata, flags, reason, props) -> None:
        if reason.is_failure:
            log.warning("%s: the broker %s refused the connection: %s", self.who, self.options.url, reason)
            return
        self.connections += 1
        if self.connections > 1:
            log.warning("%s: reconnected to %s (connection %d); the broker %s", self.who, self.options.url,
                        self.connections, "kept this session: nothing it queued for it is lost"
                        if flags.session_present else "had lost this session: what it received meanwhile is lost")
        if not flags.session_present:  # (a kept session has the subscriptions; subscribing again resends the retained)
            client.subscribe([(topic, 1) for topic in self.topics])

    def _on_subscribe(self, client, userdata, mid, reasons, props) -> None:
        refused = [str(reason) for reason in reasons if reason.is_failure]
        if refused:
            log.warning("%s: the broker %s refused %d of the subscriptions: %s", self.who, self.options.url,
                        len(refused), ", ".join(refused))
        else:
            log.info("%s: subscribed to %d topics (the broker acknowledged)", self.who, len(self.topics))

    def _on_disconnect(self, client, userdata, flags, reason, props) -> None:
        if not self._closing:
            self.losses += 1
            log.warning("%s: connection to %s lost (%d so far): %s; reconnecting", self.who, self.options.url,
                        self.losses, reason)
