"""``bintrack up [DIR] [--tracker NAME] [--speed X] [--record FILE] [--exit-at-end] [--no-view]``.

The whole stack on this machine without Docker: a Zenoh router in this process on loopback,
and every service as a subprocess with the commands docker-compose uses
(:mod:`bintrack.live.stack`), the map (``bintrack view``) among them unless ``--no-view``.
Shows live progress; stops everything on Ctrl-C, SIGTERM or SIGHUP
or, with ``--exit-at-end``, once the replay's end has been processed by every service.
With ``--source mqtt://HOST:PORT --sensor-table FILE`` the MQTT bridge takes replay's place:
binary sensors on that broker are the source (README, "Real sensors on MQTT").

Supervision: a service that dies is restarted with the same instance id after a backoff
(0.5 s, doubling to 30 s; back to 0.5 s once it ran 30 s), with a log line each time; it
resumes from its checkpoint in a state folder (``--state-dir`` of the services) and from
what the others hold. A service that exits with status 2 (bad options or data) or fails
:data:`MAX_QUICK_FAILURES` times in a row stops the stack. The services run in one process
group and end themselves when ``up`` dies (parent-death check in :mod:`bintrack.live.parent_watch`), so no
orphan is left. ``up`` refuses to run next to another stack of the same network on its router;
a token of another instance that joins later is logged and ignored, by ``up`` and its services.
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path

import zenoh

from bintrack.argtypes import add_alias, int_at_least, output_file, port_number, positive_float
from bintrack.hosts.mesh_links import LEASE_MS
from bintrack.live.checkpoint import memory_folder
from bintrack.live.disk_full import EXIT_WRITE_FAILED, MODES as DISK_FULL_MODES
from bintrack.live.parent_watch import PARENT_ENV
from bintrack.live.presence import Presence
from bintrack.live.session_options import DEFAULT_ENDPOINT, STACK_OPTION, STATE_DIR_OPTION, router_config
from bintrack.errors import CommandError
from bintrack.formats import DEPLOYMENT_FILE, open_dataset, write_deployment
from bintrack.keys import Keys, ParsedKey, parse_key
from bintrack.bus_payloads import Clock
from bintrack.message_codec import MessageError, decode_view
from bintrack.live.stack import ServiceCommand, is_broker, region_stack_commands, stack_commands
from bintrack.trackers.tracker_arguments import add_tracker_arguments, tracker_arguments, tracker_options
from bintrack.trackers import TRACKER_NAMES, check_options as make_tracker_check, sensor_mismatch
from bintrack.view.map_socket import DEFAULT_BIND, DEFAULT_PORT, listening_socket

SHOWN = (("raw", "events"), ("transition", "transitions"), ("estimate", "estimates"), ("tracks", "tracks"))
STOP_TIMEOUT = 15.0
BACKOFF_FIRST, BACKOFF_MAX = 0.5, 30.0  # s between a death and the restart
STABLE_RUN = 30.0  # s a service must run for its backoff to start again from BACKOFF_FIRST
MAX_QUICK_FAILURES = 8  # deaths in a row, each within STABLE_RUN of its start, before up gives up
FOXGLOVE_PORT = 8765  # Foxglove's default WebSocket port
FOREIGN_CHECK = 1.0  # s to wait for liveliness replies of another stack before starting
# the roles that make a stack: another instance of one of them on the network is another stack
# (observers — a recorder, a map, the Foxglove bridge started by hand — may join)
OPEN_BUS = ("up: without --secure the bus on {listen} is open to any client that reaches it: tokens of other "
            "instances are ignored, but a client that copies the id of one of this run's services ({stack}-…, "
            "shown on the bus) into a message's attachment can still end the run or move its clock")
STACK_ROLES = frozenset({"replay", "sensor_agent", "peer_agent", "basestation", "estimate_relay", "merge"})


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", nargs="?", metavar="DIR", help="dataset folder or recording (.mcap) to replay")
    mqtt = parser.add_argument_group("sensors on MQTT (README, Real sensors on MQTT)")
    mqtt.add_argument("--source", dest="broker", metavar="mqtt://HOST:PORT",
                      help="take the samples from binary sensors on this MQTT broker (the MQTT bridge), not a DIR")
    mqtt.add_argument("--sensor-table", metavar="FILE", help="with --source: which topic is which sensor (TOML)")
    mqtt.add_argument("--mqtt-config", metavar="FILE", help="with --source: the broker's login and TLS ([broker] table)")
    mqtt.add_argument("--end-topic", metavar="TOPIC", help="with --source: a message on TOPIC ends the stream")
    mqtt.add_argument("--clock", choices=("wall", "payload"), default="wall",
                      help="with --source: event time follows the wall clock, or the latest payload time (a "
                      "played-back stream) (default: %(default)s)")
    parser.add_argument("--tracker", choices=TRACKER_NAMES, default="equal-weight", help="tracker (default: %(default)s)")
    add_tracker_arguments(parser)
    parser.add_argument("--speed", type=float, default=1.0,
                        help="replay speed: 1 real time, 0 as fast as flow control allows (default: %(default)s)")
    parser.add_argument("--clock-period", type=positive_float, metavar="S",
                        help="event time between the replay's clock ticks, s (default: replay's own, which "
                        "follows --speed)")
    parser.add_argument("--loop", action="store_true", help="replay in a loop")
    parser.add_argument("--record", metavar="FILE.mcap", help="record everything into this file")
    parser.add_argument("--on-disk-full", choices=DISK_FULL_MODES, default="stop",
                        help="with --record, when the recording cannot be written (a full or failing disk): end the "
                        "stack with the file finalised (stop), or hold event time until space is back (pause) "
                        "(default: %(default)s)")
    parser.add_argument("--exit-at-end", action="store_true", help="stop once the replay's end has been processed")
    parser.add_argument("--listen", default=DEFAULT_ENDPOINT, metavar="ENDPOINT",
                        help="where the embedded router listens (default: %(default)s)")
    parser.add_argument("--net", help="network name (default: the dataset's deployment name, else 'default')")
    add_map_arguments(parser)
    parser.add_argument("--foxglove", type=port_number, nargs="?", const=FOXGLOVE_PORT, metavar="PORT",
                        help=f"also serve the stack to Foxglove (its WebSocket protocol) on PORT (default {FOXGLOVE_PORT}, "
                        "or a free one if that is taken), on --map-bind's address")
    parser.add_argument("--secure", action="store_true",
                        help="mutual TLS and per-role access control (deploy/secure/); --listen must be a tls/ endpoint "
                        "(with --regions, the region routers too listen on tls/ and show each other the router "
                        "certificate)")
    parser.add_argument("--certs", default="certs", metavar="DIR",
                        help="with --secure: the certificates of `bintrack certs --out DIR` (default: %(default)s)")
    parser.add_argument("--regions", type=int, metavar="N",
                        help="mcmcda in N regions: a router per region on 127.0.0.2… (meshed with the one on "
                        "--listen, with its scheme: tcp/ or, with --secure, tls/), a sensor agent and a base station "
                        "per region, and the merge; the dataset's own regions if it names N, else its field cut into "
                        "a grid of N")
    parser.add_argument("--hosts", action="store_true",
                        help="with --regions: each region's site on a host of its own, a Linux network namespace "
                        "(its router, sensor agent and base station in it), linked to this machine by veth pairs "
                        "on 198.19.K.0/24 (needs root; everything made is removed at the end)")
    parser.add_argument("--mesh-lease", type=int_at_least(100), default=None, metavar="MS",
                        help="with --hosts: a link between two sites' routers silent this long is closed and logged "
                        f"(default {LEASE_MS} ms); longer rides out routers too loaded to send keep-alives, at the "
                        "cost of noticing a cut later")
    parser.add_argument("--progress-interval", type=positive_float, default=1.0, metavar="S",
                        help="seconds between progress lines (default: %(default)s)")


def add_map_arguments(parser: argparse.ArgumentParser) -> None:
    """The map's options, as ``up``, ``demo`` and ``view`` name them."""
    parser.add_argument("--no-map", dest="view", action="store_false", help="do not start the map (the view service)")
    add_alias(parser, "--no-view", "--no-map", "view", flag_value=False)
    parser.add_argument("--map-port", dest="view_port", type=port_number, default=DEFAULT_PORT, metavar="PORT",
                        help="HTTP port of the map (default: %(default)s, or a free one if that is taken)")
    add_alias(parser, "--view-port", "--map-port", "view_port", type=port_number)
    parser.add_argument("--map-bind", dest="view_bind", default=DEFAULT_BIND, metavar="ADDRESS",
                        help="address the map is served on (default: %(default)s, this machine only)")
    add_alias(parser, "--view-bind", "--map-bind", "view_bind")
    parser.add_argument("--map-token", dest="view_token", metavar="TOKEN", help="a secret the map asks for, needed to serve it beyond 127.0.0.1: open the printed URL, which carries it "
                        "(default: $BINTRACK_MAP_TOKEN)")
    add_alias(parser, "--view-token", "--map-token", "view_token")


class RouterPortTaken(CommandError):
    """The embedded router could not listen on its endpoint."""


@dataclass
class Monitor:
    """What the stack has done, from the services' own reports, not from its traffic: replay's
    clock ticks (event time, and the raw samples it has published), the progress reports (what
    each instance has sent: ``stages`` names the kind of SHOWN each service's count is) and the
    done reports. From Zenoh callbacks: counters only, no Zenoh calls."""

    keys: Keys
    ours: set[str] = field(default_factory=set)  # instance ids of this stack's services
    stages: dict[str, str] = field(default_factory=dict)  # service → the kind it sends
    counts: Counter = field(default_factory=Counter)
    event_time: float | None = None
    done: set[str] = field(default_factory=set)
    foreign: set[str] = field(default_factory=set)  # alive/<service>/<id> of other instances, not yet said
    said: set[str] = field(default_factory=set)  # those said already
    lock: threading.Lock = field(default_factory=threading.Lock)
    _sent: dict[tuple[str, str], tuple[int, int]] = field(default_factory=dict)  # instance → (before restarts, now)

    def on_presence(self, parsed: ParsedKey, present: bool) -> None:
        """A service's token came or went (a Presence listener, on a Zenoh thread)."""
        if parsed.kind == "alive" and present and parsed.instance not in self.ours:
            with self.lock:
                self.foreign.add(f"{parsed.service}/{parsed.instance}")

    def subscribe(self, session: zenoh.Session) -> list:
        """Its subscribers on ``session``: the clock, the progress and the done reports."""
        return [session.declare_subscriber(self.keys.clock(), self.on_clock),
                session.declare_subscriber(self.keys.progress(), self.on_progress),
                session.declare_subscriber(self.keys.done(), self.on_done)]

    def on_clock(self, sample: zenoh.Sample) -> None:
        try:
            tick = decode_view(Clock, sample.payload.to_bytes())
        except MessageError:
            return
        with self.lock:
            self.event_time = tick.t
            if tick.sent is not None:
                self._count(("replay", ""), "raw", tick.sent)

    def on_progress(self, sample: zenoh.Sample) -> None:
        try:
            parsed = parse_key(str(sample.key_expr))
            report = decode_view(Clock, sample.payload.to_bytes())
        except (ValueError, MessageError):
            return
        kind = self.stages.get(parsed.service)
        if kind is not None and report.sent is not None:
            with self.lock:
                self._count((parsed.service, parsed.instance), kind, report.sent)

    def _count(self, instance: tuple[str, str], kind: str, sent: int) -> None:
        """``instance`` has sent ``sent`` so far (a restarted one counts again from its checkpoint,
        or from 0: what it had counted before stays counted)."""
        before, now = self._sent.get(instance, (0, 0))
        total = before + now
        if sent < now:
            before = total
        self._sent[instance] = before, sent
        self.counts[kind] += before + sent - total

    def on_done(self, sample: zenoh.Sample) -> None:
        try:
            parsed = parse_key(str(sample.key_expr))
        except ValueError:
            return
        with self.lock:
            self.done.add(parsed.service)

    def snapshot(self) -> tuple[Counter, float | None, set[str]]:
        with self.lock:
            return Counter(self.counts), self.event_time, set(self.done)

    def foreign_services(self) -> list[str]:
        """The tokens of other instances that joined since the last call (each once)."""
        with self.lock:
            new, self.foreign = sorted(self.foreign - self.said), set()
            self.said.update(new)
            return new


class Stopped(Exception):
    """SIGINT, SIGTERM or SIGHUP arrived."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


@dataclass
class Supervised:
    """One service of the stack: its process, and when it is due to be restarted."""

    command: ServiceCommand
    argv: list[str]
    proc: subprocess.Popen | None = None
    started: float = 0.0
    quick_failures: int = 0
    restarts: int = 0
    due: float | None = None
    finished: bool = False

    @property
    def name(self) -> str:
        return self.command.key

    def start(self, env: dict[str, str], group: int | None, pass_fds: tuple[int, ...] = ()) -> int:
        """Start (or restart) the process in process group ``group`` (a new one if None), handing
        it the open files ``pass_fds``; its pid."""
        self.proc = subprocess.Popen(self.argv, env=env, process_group=0 if group is None else group,
                                     pass_fds=pass_fds)
        self.started, self.due = time.monotonic(), None
        return self.proc.pid

    def died(self, code: int, now: float) -> float:
        """Record a death with status ``code``; the backoff (s) before the restart."""
        ran = now - self.started
        self.quick_failures = self.quick_failures + 1 if ran < STABLE_RUN else 1
        backoff = min(BACKOFF_MAX, BACKOFF_FIRST * 2 ** (self.quick_failures - 1))
        self.due = now + backoff
        return backoff


def _status(code: int) -> str:
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exited with status {code}"


def _progress_line(now: Counter, before: Counter, dt: float, event_time: float | None,
                   shown: tuple[tuple[str, str], ...] = SHOWN) -> str:
    parts = [f"t={event_time:9.2f} s" if event_time is not None else "t=        - s"]
    for kind, label in shown:
        rate = (now[kind] - before[kind]) / dt if dt > 0 else 0.0
        parts.append(f"{label} {now[kind]} ({rate:.0f}/s)")
    return "up: " + " | ".join(parts)


def _source_net(source: str | None, sensor_table: str | None = None) -> str | None:
    if source is None:
        return None
    if is_broker(source):
        from bintrack.mqtt.sensor_table import load_table

        return load_table(sensor_table).name
    path = Path(source)
    if path.suffix == ".mcap":
        from bintrack.live.recording import open_recording

        return open_recording(path).net
    return open_dataset(path).deployment.name


def _stop(procs: dict[str, subprocess.Popen], group: int | None) -> dict[str, int]:
    """SIGTERM every child (replay first, agents last), wait, kill what hangs, and last the
    whole process group (anything a service left behind); exit statuses."""
    for proc in reversed(list(procs.values())):
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + STOP_TIMEOUT
    status = {}
    for name, proc in procs.items():
        try:
            status[name] = proc.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            proc.kill()
            status[name] = proc.wait()
            print(f"up: {name} did not stop within {STOP_TIMEOUT:.0f} s and was killed", file=sys.stderr)
    if group is not None:
        try:
            os.killpg(group, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
    return status


def _raise_stopped(signum: int, frame) -> None:
    raise Stopped(signum)


def _foreign_now(router: zenoh.Session, keys: Keys, ours: set[str]) -> list[str]:
    """alive/<service>/<id> of the services of ``keys``' network on the bus that are not ``ours``."""
    found = []
    for reply in router.liveliness().get(keys.alive(), timeout=FOREIGN_CHECK):
        if reply.ok is not None:
            parsed = parse_key(str(reply.ok.key_expr))
            if parsed.instance not in ours and parsed.service in STACK_ROLES:
                found.append(f"{parsed.service}/{parsed.instance}")
    return sorted(found)


def _region_source(args: argparse.Namespace) -> tuple[tempfile.TemporaryDirectory | None, str, list[str]]:
    """For ``--regions N``: (a folder to remove afterwards or None, the dataset to replay, the
    region names). A dataset without regions is replayed from a folder beside it whose
    deployment.json names a grid of N (events and truth linked, not copied)."""
    from bintrack.regions import grid_areas, grid_shape  # shapely: only for regions

    if args.tracker != "mcmcda":
        raise CommandError(f"--regions runs mcmcda at the region base stations; --tracker {args.tracker} cannot")
    if args.regions < 1:
        raise CommandError(f"--regions must be at least 1, got {args.regions}")
    if args.source is None or Path(args.source).suffix == ".mcap":
        raise CommandError("--regions needs a dataset folder to replay")
    dataset = open_dataset(args.source)
    deployment = dataset.deployment
    if deployment.regions:
        if len(deployment.regions) != args.regions:
            raise CommandError(f"--regions {args.regions}: {args.source} names {len(deployment.regions)} regions")
        return None, args.source, [r.name for r in deployment.regions]
    folder = tempfile.TemporaryDirectory(prefix="bintrack-regions-")
    deployment = deployment.model_copy(update={"regions": grid_areas(deployment.region, *grid_shape(args.regions))})
    write_deployment(Path(folder.name) / DEPLOYMENT_FILE, deployment)
    for item in Path(args.source).iterdir():
        if item.name != DEPLOYMENT_FILE:
            (Path(folder.name) / item.name).symlink_to(item.resolve())
    return folder, folder.name, [r.name for r in deployment.regions]


def planned_stack(args: argparse.Namespace, net: str, view_port: int | None,
                  state_dir: str | None = None, bridge_args: tuple[str, ...] = ()) -> list[ServiceCommand]:
    """The services ``up`` starts for ``args`` (one region), as :func:`stack_commands` builds
    them; docker-compose.yml runs the same with ``state_dir`` (a test holds the two together)."""
    options = replace(tracker_options(args), speed=None)  # --speed here is the replay's
    return stack_commands(tracker=args.tracker, endpoint=args.listen, net=net, source=args.source,
                          speed=args.speed, loop=args.loop, record=args.record, estimates=options.estimates,
                          tracker_args=tracker_arguments(options), view_port=view_port,
                          view_bind=getattr(args, "view_bind", DEFAULT_BIND), state_dir=state_dir,
                          clock_period=args.clock_period, foxglove_port=getattr(args, "foxglove", None),
                          bridge_args=bridge_args, on_disk_full=getattr(args, "on_disk_full", "stop"))


def _site_options(network, listen: str, lease_ms: int) -> dict:
    """region_stack_commands' options for sites on the hosts of ``network`` (none without),
    their links' lease ``lease_ms`` ms."""
    if network is None:
        return {}
    from bintrack.hosts.mesh_links import hub_endpoint, router_options, site_endpoints

    return {"routers": site_endpoints(network, listen), "hub": hub_endpoint(network, listen),
            "router_args": router_options(lease_ms)}


def _map_socket(bind: str, port: int) -> socket.socket | None:
    """The map's listening socket, bound here and kept open for the view (and its restarts): the
    port asked for, else a free one. None, said in one line, if neither can be had: the stack then
    runs without the map."""
    try:
        sock = listening_socket(bind, port)
    except OSError as exc:
        print(f"up: {exc}; the stack runs without the map", file=sys.stderr)
        return None
    sock.set_inheritable(True)
    return sock


def _bridge_args(args: argparse.Namespace) -> tuple[str, ...]:
    """For ``--source mqtt://…``: the MQTT bridge's options (checked here, so that a bad table
    or config file is one line from ``up``, not a service's exit)."""
    from bintrack.mqtt.broker_options import BrokerConfigError, broker_options
    from bintrack.mqtt.sensor_table import TableError, load_table

    if args.source is not None:
        raise CommandError("give a DIR to replay or --source mqtt://HOST:PORT, not both")
    if args.sensor_table is None:
        raise CommandError("--source mqtt://… needs --sensor-table FILE (which topic is which sensor)")
    if args.exit_at_end and args.end_topic is None:
        raise CommandError("--exit-at-end with --source mqtt://… needs --end-topic TOPIC (what ends the stream)")
    try:
        broker_options(args.broker, args.mqtt_config)
        load_table(args.sensor_table)
    except (BrokerConfigError, TableError) as exc:
        raise CommandError(str(exc)) from None
    extra = ("--mqtt-config", str(Path(args.mqtt_config).resolve())) if args.mqtt_config else ()
    end = ("--end-topic", args.end_topic) if args.end_topic else ()
    return ("--sensor-table", str(Path(args.sensor_table).resolve()), *extra, *end, "--clock", args.clock)


def _lease(args: argparse.Namespace) -> int:
    """The lease of the links between sites, ms."""
    return LEASE_MS if args.mesh_lease is None else args.mesh_lease


def run(args: argparse.Namespace) -> int:
    if getattr(args, "mesh_lease", None) is not None and not getattr(args, "hosts", False):
        raise CommandError("--mesh-lease sets the lease of the links between the sites of --hosts; give --hosts")
    if not getattr(args, "hosts", False):
        return _run(args)
    from bintrack.hosts.netns import NetnsError, unavailable
    from bintrack.hosts.site_network import SiteNetwork

    problem = unavailable()
    if problem is not None:
        raise CommandError(f"--hosts: {problem}")
    if args.regions is None:
        raise CommandError("--hosts runs the sites of --regions N on hosts of their own; give --regions N")
    if args.secure:
        raise CommandError("--hosts does not run the secure profile yet; leave out --secure or --hosts")
    regions = _region_source(args)
    network = SiteNetwork(regions[2])
    handlers = {sig: signal.signal(sig, _raise_stopped) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        with network:  # removed on every way out: the end, an error, a signal
            return _run(args, regions, network)
    except NetnsError as exc:
        raise CommandError(f"--hosts: {exc}") from None
    except Stopped as exc:  # before the stack's own handling began
        print(f"\nup: {exc} received; stopping", file=sys.stderr)
        return 128 + exc.signum
    finally:
        if regions[0] is not None:
            regions[0].cleanup()
        for sig, handler in handlers.items():
            signal.signal(sig, handler)


def _run(args: argparse.Namespace, regions=None, network=None) -> int:
    """The stack of ``args``; ``regions``: what :func:`_region_source` gave, if it was called
    already; ``network``: the sites' hosts (a created SiteNetwork) for ``--hosts``."""
    bridge_args = ()
    if getattr(args, "broker", None) is not None:
        bridge_args = _bridge_args(args)
        if getattr(args, "regions", None) is not None:
            raise CommandError("--regions replays a dataset; it does not take --source mqtt://…")
        args.source = args.broker
    if args.exit_at_end and args.source is None:
        raise CommandError("--exit-at-end needs a DIR to replay")
    if args.speed < 0:
        raise CommandError(f"--speed must be ≥ 0, got {args.speed}")
    if args.record is not None and not args.record.endswith(".mcap"):
        raise CommandError(f"--record {args.record}: a recording's name must end in .mcap")
    if args.record is not None:
        output_file(args.record)
    net = args.net or _source_net(args.source, getattr(args, "sensor_table", None)) or "default"
    try:
        Keys(net)
    except ValueError as exc:
        raise CommandError(f"{exc}; give a network name with --net") from None
    if args.source is not None and not is_broker(args.source) and Path(args.source).suffix != ".mcap":
        mismatch = sensor_mismatch(args.tracker, open_dataset(args.source).deployment)
        if mismatch is not None:
            print(f"up: warning: {mismatch}", file=sys.stderr)
    options = replace(tracker_options(args), speed=None)  # --speed here is the replay's
    try:
        make_tracker_check(args.tracker, options, regional=getattr(args, "regions", None) is not None)
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    view_bind = getattr(args, "view_bind", "127.0.0.1")
    map_env: dict[str, str] = {}  # the map's token, handed to it out of the process list
    if getattr(args, "view", False):
        from bintrack.view.map_access import TOKEN_ENV, check_bind, token_from  # aiohttp: only with the map

        view_token = token_from(getattr(args, "view_token", None))
        check_bind(view_bind, view_token)
        map_env = {TOKEN_ENV: view_token} if view_token else {}
    regions_dir = None
    with_regions = getattr(args, "regions", None) is not None
    if with_regions:
        regions_dir, source, names = regions or _region_source(args)
        if regions is not None:
            regions_dir = None  # the caller removes it
    view_socket = _map_socket(view_bind, args.view_port) if getattr(args, "view", False) else None
    view_port = args.view_port if view_socket is not None else None
    if with_regions:
        try:
            commands = region_stack_commands(regions=names, endpoint=args.listen, net=net, source=source,
                                             speed=args.speed, loop=args.loop, record=args.record,
                                             tracker_args=tracker_arguments(options), view_port=view_port,
                                             view_bind=view_bind, clock_period=args.clock_period,
                                             foxglove_port=args.foxglove, on_disk_full=args.on_disk_full,
                                             **_site_options(network, args.listen, _lease(args)))
        except ValueError as exc:
            if view_socket is not None:
                view_socket.close()
            raise CommandError(f"--regions: {exc}") from None
    else:
        commands = planned_stack(args, net, view_port, bridge_args=bridge_args)
    if args.secure:
        # cryptography: loaded only for --secure
        from bintrack.live.secure_profile import exposed_keys, pin_run_tokens, secure_up

        try:
            commands, config = secure_up(commands, args.certs, args.listen)
            exposed = exposed_keys(Path(args.certs))
            if exposed is not None:
                print(f"up: warning: {exposed}", file=sys.stderr)
        except CommandError:
            if view_socket is not None:
                view_socket.close()
            raise
    elif network is not None:
        from bintrack.hosts.mesh_links import hub_endpoint, short_lease

        config = short_lease(router_config([args.listen, hub_endpoint(network, args.listen)]), _lease(args))
    else:
        config = router_config([args.listen])
    stack_id = f"up{os.getpid()}"
    # under --secure each role may declare the tokens of its own instances in this run only
    pinned = pin_run_tokens(config, commands, net, stack_id) if args.secure else ()
    zenoh.try_init_log_from_env()  # as the router service does (see services/router.py)
    try:
        router = zenoh.open(config)
    except zenoh.ZError as exc:
        if view_socket is not None:
            view_socket.close()
        raise RouterPortTaken(f"cannot start the router on {args.listen} ({str(exc).split(' at ')[0]}); "
                           "is another one running? choose another with --listen") from None
    keys = Keys(net)
    state_dir = tempfile.TemporaryDirectory(prefix="bintrack-up-", dir=memory_folder())  # the services' checkpoints
    supervised = {c.key: Supervised(c, [*c.argv(sys.executable), *pinned] if c.name == "router" else
                                    [*c.argv(sys.executable), "--id", f"{stack_id}-{c.key}", STATE_DIR_OPTION,
                                     state_dir.name, STACK_OPTION, stack_id, *(("--socket-fd", str(view_socket.fileno()))
                                                       if c.name == "view" else ())])
                  for c in commands}
    if network is not None:  # each site's processes on its host
        for service in supervised.values():
            if service.command.site:
                service.argv = network.argv(service.command.site, service.argv)
    passed = {"view": (view_socket.fileno(),)} if view_socket is not None else {}
    monitor = Monitor(keys, ours={f"{stack_id}-{name}" for name in supervised},
                      stages={"sensor_agent": "transition", "peer_agent": "estimate",
                              "merge" if with_regions else "basestation": "tracks"})
    foreign = _foreign_now(router, keys, monitor.ours)
    if foreign:
        router.close()
        state_dir.cleanup()
        if view_socket is not None:
            view_socket.close()
        raise CommandError(f"another stack of network {net} is alive on {args.listen}: {', '.join(foreign)}; "
                           "stop it first, or use another --listen or --net")
    presence = Presence(keys)
    presence.listen(monitor.on_presence)
    presence.declare(router, lambda handler: handler)
    entities = [*monitor.subscribe(router), presence]
    env = {**os.environ, PARENT_ENV: str(os.getpid()), **map_env}
    group: int | None = None
    stopped_by: Stopped | None = None
    failed: str | None = None
    ended_said = False
    # the figures this stack produces: peer estimates only where peer agents run
    shown = tuple(item for item in SHOWN if item[0] != "estimate" or "peer_agent" in {c.name for c in commands})
    last_stage = "recorder" if args.record else "merge" if with_regions else "basestation"
    handlers = {sig: signal.signal(sig, _raise_stopped) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        for service in supervised.values():
            pid = service.start(env, group, passed.get(service.command.name, ()))
            group = pid if group is None else group
        print(f"up: router on {args.listen}, network {net}, services: {', '.join(supervised)}", file=sys.stderr)
        if network is not None:
            print(f"up: hosts: {', '.join(f'{network.namespace(s)} ({network.address(s)})' for s in names)}, linked to "
                  f"this machine's {network.tag} ({network.hub_address}) by a bridge in {network.switch}", file=sys.stderr)
        if not args.secure:
            print(OPEN_BUS.format(listen=args.listen, stack=stack_id), file=sys.stderr)
        before, t_before = Counter(), time.monotonic()
        while True:
            time.sleep(0.1)
            now = time.monotonic()
            for service in supervised.values():
                if service.finished:
                    continue
                if service.due is not None:
                    if now >= service.due:
                        service.restarts += 1
                        pid = service.start(env, group, passed.get(service.command.name, ()))
                        print(f"up: {service.name} restarted (pid {pid}, restart {service.restarts})", file=sys.stderr)
                    continue
                code = service.proc.poll()
                if code is None:
                    continue
                if code == 0 and service.name in ("replay", "mqtt_bridge", "recorder"):
                    service.finished = True  # they end by themselves at the end of the stream
                elif code == 2:
                    failed = f"{service.name} exited with status 2 (bad options or data)"
                elif code == EXIT_WRITE_FAILED and service.command.name == "recorder":
                    failed = f"{service.name} could not write its recording (its line above says what the file holds)"
                elif service.quick_failures + 1 >= MAX_QUICK_FAILURES and now - service.started < STABLE_RUN:
                    failed = f"{service.name} {_status(code)}, {MAX_QUICK_FAILURES} times in a row; giving up"
                else:
                    backoff = service.died(code, now)
                    print(f"up: {service.name} {_status(code)} after {now - service.started:.1f} s; "
                          f"restarting it in {backoff:g} s", file=sys.stderr)
            for token in monitor.foreign_services():
                print(f"up: ignoring {token}, which joined the bus: not one of this run's services (they ignore it "
                      "too)", file=sys.stderr)
            if failed:
                break
            counts, event_time, done = monitor.snapshot()
            if now - t_before >= args.progress_interval:
                if counts != before:
                    print(_progress_line(counts, before, now - t_before, event_time, shown), file=sys.stderr)
                before, t_before = counts, now
            finished = last_stage in done or (last_stage == "recorder" and supervised["recorder"].finished)
            if args.exit_at_end and finished:
                if counts != before:
                    print(_progress_line(counts, before, max(now - t_before, 1e-9), event_time, shown),
                          file=sys.stderr)
                print("up: the end of the replay has been processed; stopping", file=sys.stderr)
                break
            if not ended_said and finished:
                ended_said = True
                print("up: the replay has ended and been processed; the services keep running (Ctrl-C to stop)",
                      file=sys.stderr)
    except Stopped as exc:
        stopped_by = exc
        print(f"\nup: {exc} received; stopping", file=sys.stderr)
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            signal.signal(sig, signal.SIG_IGN)  # a second signal must not cut the stop short
        status = _stop({name: s.proc for name, s in supervised.items() if s.proc is not None}, group)
        for entity in entities:
            entity.undeclare()
        router.close()
        state_dir.cleanup()
        if view_socket is not None:
            view_socket.close()
        if regions_dir is not None:
            regions_dir.cleanup()
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    if failed:
        print(f"up: {failed}; stopped the others", file=sys.stderr)
        return 1
    bad = {name: code for name, code in status.items()
           if code not in (0, -signal.SIGTERM, -signal.SIGINT) and supervised[name].due is None}
    if bad:
        print(f"up: services ended with errors: {bad}", file=sys.stderr)
        return 1
    return 128 + stopped_by.signum if stopped_by is not None else 0
