"""Foxglove bridge: the running network in Foxglove, live, through the foxglove-sdk WebSocket server.

    python -m bintrack.services.foxglove_bridge [--port 8765] [--bind 127.0.0.1] [bus options]

Serves Foxglove's WebSocket protocol (``foxglove.websocket.v1``) on ws://BIND:PORT (a free
port if that one is taken, said in one line). Foxglove: *Open connection → Foxglove WebSocket*.
Channels: ``/scene``, ``foxglove.SceneUpdate`` messages of the sensors, the detecting sensors,
fused reports, tracks and truth (:mod:`bintrack.live.foxglove_scene`, the same scene the export
and the recorder write); and every key of the network (``bintrack/<net>/…``) as a JSON channel
with its message's JSON Schema, for the Raw Messages and Plot panels. A client that subscribes
to ``/scene`` is sent the whole current scene at once. Like the view, it acknowledges each clock
tick once it has passed it on, so replay's flow control counts it.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading

import foxglove
import zenoh

from bintrack.argtypes import port_number
from bintrack.errors import CommandError
from bintrack.keys import parse_key
from bintrack.live.service import Service, service_main
from bintrack.live.session_options import add_bus_arguments
from bintrack.live.foxglove_scene import SCENE_SCHEMA, SCENE_TOPIC, SceneBuilder
from bintrack.live.recording import KIND_TYPES

DEFAULT_PORT = 8765  # Foxglove's own default for a WebSocket connection
NOT_PASSED_ON = {"progress", "done"}   # flow-control chatter of the services


class SceneState:
    """The latest SceneUpdate of each scene entity, to send a newly subscribed client."""

    def __init__(self) -> None:
        self.entities: dict[str, dict] = {}
        self.lock = threading.Lock()

    def apply(self, update: dict) -> None:
        with self.lock:
            for deletion in update["deletions"]:
                self.entities.pop(deletion["id"], None)
            for entity in update["entities"]:
                self.entities[entity["id"]] = {"deletions": [], "entities": [entity]}

    def updates(self) -> list[dict]:
        with self.lock:
            return list(self.entities.values())


class Listener(foxglove.ServerListener):
    def __init__(self, bridge: FoxgloveBridge):
        self.bridge = bridge

    def on_subscribe(self, client, channel) -> None:
        if channel.topic == SCENE_TOPIC:
            for update in self.bridge.scene_state.updates():
                self.bridge.scene.log(json.dumps(update, separators=(",", ":")).encode())


def start_foxglove_server(bind: str, port: int, net: str, listener: foxglove.ServerListener):
    """foxglove-sdk's WebSocket server on ``bind``:``port``, else on a free port; CommandError
    (one line) if neither can be had."""
    tried = (port, 0) if port != 0 else (0,)
    for candidate in tried:
        try:
            return foxglove.start_server(name=f"bintrack {net}", host=bind, port=candidate, server_listener=listener)
        except RuntimeError as exc:
            error = str(exc).split(": ", 1)[-1]
    raise CommandError(f"cannot serve Foxglove on {bind}:{port}: {error}")


class FoxgloveBridge(Service):
    name = "foxglove_bridge"

    async def setup(self) -> None:
        self.server = None
        self.scene_state = SceneState()
        self.builder: SceneBuilder | None = None
        self.channels: dict[str, foxglove.Channel] = {}
        self.schemas: dict[type, foxglove.Schema] = {}
        self.scene = foxglove.Channel(SCENE_TOPIC, message_encoding="json", schema=foxglove.Schema(
            name="foxglove.SceneUpdate", encoding="jsonschema", data=SCENE_SCHEMA.read_bytes()))
        self.server = start_foxglove_server(self.args.bind, self.args.port, self.args.net, Listener(self))
        host = "127.0.0.1" if self.args.bind in ("0.0.0.0", "") else self.args.bind
        taken = f" (port {self.args.port} was taken)" if self.args.port not in (0, self.server.port) else ""
        print(f"foxglove_bridge: Foxglove on ws://{host}:{self.server.port}{taken}", file=sys.stderr, flush=True)
        self.subscribe(self.keys.all(), self.on_sample)

    def channel(self, key: str, cls: type) -> foxglove.Channel:
        """The JSON channel of ``key``, with the JSON Schema of ``cls``."""
        channel = self.channels.get(key)
        if channel is None:
            schema = self.schemas.get(cls)
            if schema is None:
                schema = self.schemas[cls] = foxglove.Schema(
                    name=f"bintrack.{cls.__name__}", encoding="jsonschema",
                    data=json.dumps(cls.model_json_schema(by_alias=True), sort_keys=True).encode())
            channel = self.channels[key] = foxglove.Channel(key, message_encoding="json", schema=schema)
        return channel

    def on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            kind = parse_key(key).kind
        except ValueError:
            return
        if kind not in KIND_TYPES or kind in NOT_PASSED_ON:
            return
        message = self.decode(KIND_TYPES[kind], sample)
        if message is None:
            return
        self.channel(key, type(message)).log(message.model_dump_json(by_alias=True).encode())
        t = getattr(message, "t", None)
        if self.builder is not None and t is not None:
            for update in self.builder.updates(t, message):
                self.scene_state.apply(update)
                self.scene.log(json.dumps(update, separators=(",", ":")).encode())
        if kind == "clock":
            self.report_progress(message.t)
        elif kind == "eos":  # every time: replay repeats it until each awaited service reports done
            self.report_done(message.t)

    async def main(self) -> None:
        deployment = await self.wait_for_deployment()
        if deployment is not None:
            self.builder = SceneBuilder(deployment)
        await self.stopping.wait()

    async def teardown(self) -> None:
        if self.server is not None:
            self.server.stop()


def add_foxglove_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", type=port_number, default=DEFAULT_PORT,
                        help="WebSocket port (default: %(default)s, or a free one if that is taken)")
    parser.add_argument("--bind", default="127.0.0.1", metavar="ADDRESS",
                        help="address to serve on (default: %(default)s, this machine only)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bintrack.services.foxglove_bridge",
                                     description=__doc__.splitlines()[0])
    add_foxglove_arguments(parser)
    parser.add_argument("--id", help="instance id (default: host-pid)")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    add_bus_arguments(parser)
    return parser


if __name__ == "__main__":
    sys.exit(service_main(FoxgloveBridge, build_parser))
