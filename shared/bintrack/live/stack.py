"""The whole stack's service command lines, for ``bintrack up`` and docker-compose alike.

``docker-compose.yml`` runs each of these as ``python -m <module> <args>`` in our image; a test
holds the compose file to :func:`stack_commands`, so both start the same processes.
"""

from __future__ import annotations

from dataclasses import dataclass

from bintrack.keys import Keys
from bintrack.trackers import runs_on_peers
from bintrack.view.map_access import is_loopback


@dataclass(frozen=True)
class ServiceCommand:
    name: str
    args: tuple[str, ...]
    label: str = ""  # unique in a stack where a service runs more than once (default: name)
    site: str = ""  # the region whose site runs it, "" for the hub's (what `up --hosts` puts in a namespace)

    @property
    def key(self) -> str:
        return self.label or self.name

    @property
    def module(self) -> str:
        return f"bintrack.services.{self.name}"

    def argv(self, python: str) -> list[str]:
        """The command line with the interpreter ``python``; ``-P``: the module is the installed
        one, never a ``bintrack/`` folder in the directory ``up`` was run from."""
        return [python, "-P", "-m", self.module, *self.args]


def stack_commands(*, tracker: str, endpoint: str, net: str, source: str | None = None, speed: float = 1.0,
                   loop: bool = False, record: str | None = None, estimates: str | None = None,
                   tracker_args: tuple[str, ...] = (), view_port: int | None = None,
                   view_bind: str = "127.0.0.1", state_dir: str | None = None,
                   clock_period: float | None = None, foxglove_port: int | None = None,
                   bridge_args: tuple[str, ...] = (), on_disk_full: str = "stop") -> list[ServiceCommand]:
    """The services in start order: the sensor agents, the peer agents if ``tracker`` runs on
    them, the base station, the recorder if ``record``, the view if ``view_port``, and last the replay of ``source`` (if
    any), which waits for all the others. ``estimates``: the peer tracker whose estimates
    join mcmcda's reports (the peer agents run it); ``tracker_args``: further base-station
    options of the tracker, for the service that runs it; ``view_port``: the map (the view
    service) on http://``view_bind``:``view_port``/, None for no map; ``state_dir``: each service
    but the view keeps its checkpoint there under a fixed ``--id`` (its name), so that a
    restarted container resumes (compose; ``up`` gives its own); ``clock_period``: the replay's
    ``--clock-period`` (s of event time), None for its default; ``foxglove_port``: the Foxglove
    bridge on ws://``view_bind``:``foxglove_port``, None for none. A ``source`` that is an MQTT
    broker (``mqtt://HOST:PORT``, ``mqtts://…``) is read by the MQTT bridge instead of replay,
    with its further options ``bridge_args`` (the sensor table, …); ``on_disk_full``: the
    recorder's ``--on-disk-full``."""
    bus = ("-e", endpoint, "--net", net)
    services = [ServiceCommand("sensor_agent", bus)]
    if runs_on_peers(tracker):
        services.append(ServiceCommand("peer_agent", ("--tracker", tracker, *tracker_args, *bus)))
        services.append(ServiceCommand("basestation", ("--tracker", tracker, *bus)))
    else:
        if estimates is not None:
            services.append(ServiceCommand("peer_agent", ("--tracker", estimates, *bus)))
        extra = (*tracker_args, *(("--estimates", estimates) if estimates is not None else ()))
        services.append(ServiceCommand("basestation", ("--tracker", tracker, *extra, *bus)))
    services += _recorder_and_view(record, loop and source is not None, view_port, view_bind, bus, foxglove_port,
                                   on_disk_full)
    if source is not None and is_broker(source):
        period = [] if clock_period is None else ["--clock-period", _number(clock_period)]
        waits = ("--wait-for", ",".join(s.name for s in services))
        services.append(ServiceCommand("mqtt_bridge", (source, *bridge_args, *period, *waits, *bus)))
    elif source is not None:
        replay = [*_replay_pace(source, net, speed, loop, clock_period), "--wait-for", ",".join(s.name for s in services)]
        services.append(ServiceCommand("replay", (*replay, *bus)))
    if state_dir is not None:
        services = [s if s.name in STATELESS else ServiceCommand(s.name, (*s.args, "--id", s.name, "--state-dir", state_dir))
                    for s in services]
    return services


STATELESS = ("view", "foxglove_bridge")  # nothing to resume: no checkpoint


def is_broker(source: str) -> bool:
    """Whether a stack's source is an MQTT broker URL (else a dataset or a recording)."""
    return source.startswith(("mqtt://", "mqtts://"))


def _replay_pace(source: str, net: str, speed: float, loop: bool, clock_period: float | None) -> list[str]:
    """Replay's source and pacing options. Of a recording (``.mcap``, on network ``net``), the
    raw samples and the truth only: the stack makes the rest again, which the recording's own
    transitions and track sets would otherwise double."""
    period = [] if clock_period is None else ["--clock-period", _number(clock_period)]
    keys = ["--keys", Keys(net).raw(), "--keys", Keys(net).truth()] if source.endswith(".mcap") else []
    return [source, "--speed", _number(speed), *period, *(["--loop"] if loop else []), *keys]


def _number(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else str(value)


MAX_REGIONS = 250  # their routers on 127.0.0.2 … 127.0.0.251


def region_address(i: int) -> str:
    """The loopback address of the router of region ``i`` (from 0) on this machine."""
    return f"127.0.0.{i + 2}"


def region_endpoints(listen: str, count: int) -> list[str]:
    """Where the routers of ``count`` regions listen on this machine: ``listen``'s scheme and
    port on 127.0.0.2, 127.0.0.3, … (``listen`` itself is the hub router's, on 127.0.0.1)."""
    scheme, _, address = listen.partition("/")
    port = address.rpartition(":")[2]
    if not port.isdigit() or count > MAX_REGIONS:
        raise ValueError(f"regions need a tcp/ADDRESS:PORT (or tls/…) endpoint and at most {MAX_REGIONS} regions, "
                         f"got {listen}, {count}")
    return [f"{scheme}/{region_address(i)}:{port}" for i in range(count)]


def region_stack_commands(*, regions: list[str], endpoint: str, net: str, source: str | None = None,
                          speed: float = 1.0, loop: bool = False, record: str | None = None,
                          tracker_args: tuple[str, ...] = (), view_port: int | None = None,
                          view_bind: str = "127.0.0.1", clock_period: float | None = None,
                          foxglove_port: int | None = None, on_disk_full: str = "stop",
                          routers: list[str] | None = None, hub: str | None = None,
                          router_args: tuple[str, ...] = ()) -> list[ServiceCommand]:
    """The stack of a deployment cut into ``regions`` (mcmcda at the base stations): per region
    a router (meshed with the hub router and the regions' routers before it), a sensor agent
    and a base station on that router, each labelled with its region's site; then on the hub
    the merge, the recorder if ``record``, the view if ``view_port`` and the replay of
    ``source``, which waits for all (``clock_period``: its ``--clock-period``, s, None for its
    default). The hub's services connect to ``endpoint``; the region routers listen on
    ``routers`` (default: :func:`region_endpoints` on loopback), reach the hub router at ``hub``
    (default ``endpoint``) and take the further options ``router_args``."""
    routers = routers or region_endpoints(endpoint, len(regions))
    services = []
    for i, region in enumerate(regions):
        mesh = [a for peer in (hub or endpoint, *routers[:i]) for a in ("-e", peer)]
        services.append(ServiceCommand("router", ("-l", routers[i], *mesh, "--name", region, *router_args),
                                       f"router-{region}", region))
    for i, region in enumerate(regions):
        bus = ("-e", routers[i], "--net", net)
        services.append(ServiceCommand("sensor_agent", ("--region", region, *bus), f"sensor_agent-{region}", region))
        services.append(ServiceCommand("basestation", ("--tracker", "mcmcda", "--region", region, *tracker_args,
                                                       *bus), f"basestation-{region}", region))
    bus = ("-e", endpoint, "--net", net)
    services.append(ServiceCommand("merge", bus))
    services += _recorder_and_view(record, loop and source is not None, view_port, view_bind, bus, foxglove_port,
                                   on_disk_full)
    if source is not None:
        n = len(regions)
        wanted = [f"sensor_agent*{n}", f"basestation*{n}", *(c.name for c in services if c.name not in
                                                              ("router", "sensor_agent", "basestation"))]
        replay = [*_replay_pace(source, net, speed, loop, clock_period), "--wait-for", ",".join(wanted)]
        services.append(ServiceCommand("replay", (*replay, *bus)))
    return services


def _recorder_and_view(record: str | None, looping: bool, view_port: int | None, view_bind: str,
                       bus: tuple[str, ...], foxglove_port: int | None = None,
                       on_disk_full: str = "stop") -> list[ServiceCommand]:
    """The recorder (into ``record``, with ``--on-disk-full`` if not stop), the view (on
    ``view_port``) and the Foxglove bridge (on ``foxglove_port``), those asked for."""
    services = []
    if record is not None:
        # a looping replay never ends: record across the loops until stopped
        until = ("--until", "stopped") if looping else ()
        foxglove = ("--foxglove",) if foxglove_port is not None else ()  # and Foxglove's copy of the file
        disk = ("--on-disk-full", on_disk_full) if on_disk_full != "stop" else ()
        services.append(ServiceCommand("recorder", ("--out", record, *until, *foxglove, *disk, *bus)))
    if view_port is not None:
        # beyond loopback: `up` has checked for a token itself (and hands it over in the
        # environment); a container's map is published on the host's loopback alone
        open_bind = () if is_loopback(view_bind) else ("--no-token",)
        services.append(ServiceCommand("view", ("--port", str(view_port), "--bind", view_bind, *open_bind, *bus)))
    if foxglove_port is not None:
        services.append(ServiceCommand("foxglove_bridge", ("--port", str(foxglove_port), "--bind", view_bind, *bus)))
    return services
