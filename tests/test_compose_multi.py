"""docker-compose.multi.yml (two sites, a router each), checked without Docker: parsed, each
router's command run by ``python -m bintrack.services.router`` with the compose file's own
options (config file, ``-e`` to the other site) on loopback, every bintrack service's command
run as a local process against its site's router; the merged picture and the other site's
region tracks reach site A, then everything stops cleanly on SIGTERM."""

from __future__ import annotations

import signal
import threading

import pytest
import yaml
import zenoh

from bintrack.keys import Keys
from bintrack.live.session_options import client_config
from bintrack.bus_payloads import TrackSet
from bintrack.message_codec import decode
from support import DATASETS, HUNG, REPO, free_port
from test_compose import MODULE_PREFIX, container_argv, dependency_order, local_args, option_values, uses_our_build
from test_mesh import RouterProcess

COMPOSE = yaml.safe_load((REPO / "docker-compose.multi.yml").read_text())
SERVICES: dict = COMPOSE["services"]
ROUTERS = {name: s for name, s in SERVICES.items() if uses_our_build(s) and s["command"][0] == MODULE_PREFIX + "router"}
BINTRACK = {name: s for name, s in SERVICES.items() if uses_our_build(s) and name not in ROUTERS}


def test_two_sites_each_with_a_router_of_our_image():
    assert set(ROUTERS) == {"router-a", "router-b"}
    assert set(ROUTERS) | set(BINTRACK) == set(SERVICES)
    single = yaml.safe_load((REPO / "docker-compose.yml").read_text())["services"]["router"]
    assert {s["image"] for s in SERVICES.values()} == {single["image"]}
    for router in ROUTERS.values():
        assert option_values(router["command"], "-l") == option_values(single["command"], "-l")
    assert option_values(ROUTERS["router-b"]["command"], "-e") == ["tcp/router-a:7447"]
    for name, service in BINTRACK.items():
        endpoints = option_values(service["command"], "-e", "--connect")
        assert len(endpoints) == 1 and endpoints[0].split("/")[1].split(":")[0] in ROUTERS, name
        assert option_values(service["command"], "--net") == ["darpa-grid"]
        assert container_argv(service)[:3] == ["python", "-m", service["command"][0]]
    regions = sorted(option_values(s["command"], "--region")[0] for s in BINTRACK.values()
                     if s["command"][0] == MODULE_PREFIX + "basestation")
    from bintrack.formats import open_dataset

    assert regions == [r.name for r in open_dataset(DATASETS / "darpa-grid-3-sites").deployment.regions]


def test_each_service_but_the_map_keeps_its_checkpoint_in_its_sites_state_volume():
    """A restarted container resumes (README, "When things fail"): a fixed, unique --id and
    --state-dir on a named volume of the service's own site (the sites are other machines)."""
    volumes = COMPOSE["volumes"]
    ids = []
    for name, service in BINTRACK.items():
        command = service["command"]
        if command[0] == MODULE_PREFIX + "view":
            continue
        ids += option_values(command, "--id")
        (state,) = option_values(command, "--state-dir")
        (mount,) = [v for v in service["volumes"] if v.split(":")[1] == state]
        site = option_values(command, "-e")[0].split("/")[1].split(":")[0]  # router-a, router-b
        assert mount.split(":")[0] == "state-" + site.removeprefix("router-") and mount.split(":")[0] in volumes, name
    assert sorted(ids) == sorted(n for n, s in BINTRACK.items() if s["command"][0] != MODULE_PREFIX + "view")


def router_args(service: dict, local: dict[str, str]) -> tuple[str, list[str]]:
    """The compose router's config file (repository path) and its -e peers, mapped to local routers."""
    command = service["command"]
    mounts = {v.split(":")[1]: v.split(":")[0] for v in service["volumes"]}
    config = str(REPO / mounts[option_values(command, "-c")[0]])
    peers = [local[e.split("/")[1].split(":")[0]] for e in option_values(command, "-e")]
    return config, peers


@pytest.mark.slow
def test_the_two_site_stack_runs_as_local_processes(services, tmp_path):
    port = free_port()
    local: dict[str, str] = {}
    routers: list[RouterProcess] = []
    try:
        for i, name in enumerate(n for n in dependency_order(SERVICES) if n in ROUTERS):
            local[name] = f"tcp/127.0.0.{i + 1}:{port}"
            config, peers = router_args(ROUTERS[name], local)
            routers.append(RouterProcess(name, local[name], peers, tmp_path, config=config))
        routers[0].wait_logged(": router ", "site B's router")

        started = {}
        for name in (n for n in dependency_order(SERVICES) if n in BINTRACK):
            service = BINTRACK[name]
            site = option_values(service["command"], "-e")[0]
            router = site.split("/")[1].split(":")[0]
            args = local_args(service, site, tmp_path)
            i = args.index(site)
            module = service["command"][0][len(MODULE_PREFIX):]
            started[name] = services(module, *(args[:i - 1] + args[i + 1:]), endpoint=local[router])

        keys = Keys("darpa-grid")
        merged, remote = threading.Event(), threading.Event()
        session = zenoh.open(client_config([local["router-a"]]))
        subscribers = [
            session.declare_subscriber(keys.tracks(), lambda s: decode(TrackSet, s.payload.to_bytes()) and merged.set()),
            session.declare_subscriber(keys.region_tracks("r0c1"),
                                       lambda s: decode(TrackSet, s.payload.to_bytes()) and remote.set()),
        ]
        try:
            assert remote.wait(HUNG), "site B's region tracks never reached site A:\n" + started["basestation_b"].log
            assert merged.wait(HUNG), "no merged tracks:\n" + started["merge"].log
        finally:
            for subscriber in subscribers:
                subscriber.undeclare()
            session.close()
        for name, proc in started.items():
            assert proc.proc.poll() is None, f"{name} exited early:\n{proc.log}"
        for name in reversed(list(started)):
            started[name].proc.send_signal(signal.SIGTERM)
        for name in reversed(list(started)):
            assert started[name].wait() == 0, f"{name} on SIGTERM:\n{started[name].log}"
        for router in reversed(routers):
            assert router.stop() == 0
        # each service left its checkpoint in its own site's volume
        for name, service in BINTRACK.items():
            if "--state-dir" in service["command"]:
                site = option_values(service["command"], "-e")[0].split("/")[1].split(":")[0].removeprefix("router-")
                module = service["command"][0][len(MODULE_PREFIX):]
                assert (tmp_path / f"state-{site}" / f"{module}-{name}.pickle").is_file(), name
    finally:
        for router in routers:
            if router.proc.poll() is None:
                router.proc.kill()
                router.proc.wait()
