"""docker-compose.yml, deploy/Dockerfile and deploy/router.json5, checked without Docker.

The compose file is parsed with PyYAML; each bintrack service's command is combined with the
image's ENTRYPOINT into the argv a container would run, and that argv is run here as a local
process against a local router (endpoints and volume paths rewritten), all services
together, with the compose healthcheck (``bintrack.services.health``) as the probe; then
tracks are read through :class:`bintrack.client.BintrackClient` and the services are stopped
with SIGTERM.
"""

from __future__ import annotations

import asyncio
import fnmatch
import importlib.metadata
import importlib.util
import ipaddress
import json
import re
import shlex
import signal
import subprocess
import sys
import time
import tomllib
import urllib.request
from pathlib import Path

import pytest
import yaml
import zenoh

from bintrack.client import BintrackClient
from bintrack.keys import Keys
from bintrack.bus_payloads import TrackSet
from support import HUNG, REPO, free_port

COMPOSE = yaml.safe_load((REPO / "docker-compose.yml").read_text())
SERVICES: dict = COMPOSE["services"]
DOCKERFILE = REPO / "deploy" / "Dockerfile"
ROUTER_CONFIG = REPO / "deploy" / "router.json5"
ROUTER_ENDPOINT = "tcp/router:7447"
MODULE_PREFIX = "bintrack.services."


def dockerfile_instructions(path: Path) -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) of a Dockerfile, continuation lines joined, comments dropped."""
    instructions, current = [], ""
    for line in path.read_text().splitlines():
        stripped = line.strip()
        if not current and (not stripped or stripped.startswith("#")):
            continue
        if stripped.endswith("\\"):
            current += stripped[:-1] + " "
            continue
        current += stripped
        keyword, _, rest = current.partition(" ")
        instructions.append((keyword.upper(), rest.strip()))
        current = ""
    return instructions


INSTRUCTIONS = dockerfile_instructions(DOCKERFILE)


def exec_form(instruction: str) -> list[str]:
    """The JSON (exec) form of the last ``instruction`` in the Dockerfile."""
    values = [rest for keyword, rest in INSTRUCTIONS if keyword == instruction]
    assert values, f"deploy/Dockerfile has no {instruction}"
    argv = json.loads(values[-1])
    assert isinstance(argv, list) and all(isinstance(a, str) for a in argv)
    return argv


def uses_our_build(service: dict) -> bool:
    build = service.get("build")
    return isinstance(build, dict) and build.get("context") == "." and build.get("dockerfile") == "deploy/Dockerfile"


ROUTER_MODULE = "bintrack.services.router"
# the bintrack services but the router (the tests' own router stands in for it)
BINTRACK = {name: service for name, service in SERVICES.items()
            if uses_our_build(service) and service["command"][0] != ROUTER_MODULE}
PUBLIC_BENCHMARK_NET = ipaddress.ip_network("198.18.0.0/15")


def container_argv(service: dict) -> list[str]:
    """What the container runs: the image's ENTRYPOINT followed by the compose command."""
    command = service["command"]
    assert isinstance(command, list), "commands are exec-form lists"
    return exec_form("ENTRYPOINT") + command


def module_of(service: dict) -> str:
    argv = container_argv(service)
    assert argv[:2] == ["python", "-m"], f"{argv} does not run `python -m MODULE`"
    return argv[2]


def option_values(argv: list[str], *flags: str) -> list[str]:
    return [argv[i + 1] for i, a in enumerate(argv[:-1]) if a in flags]


def dependency_order(services: dict) -> list[str]:
    """Service names so that each comes after everything it depends on (file order otherwise)."""
    order: list[str] = []

    def visit(name: str, path: tuple[str, ...]) -> None:
        assert name not in path, f"dependency cycle: {' -> '.join(path + (name,))}"
        if name in order:
            return
        for dependency in services[name].get("depends_on", {}):
            visit(dependency, path + (name,))
        order.append(name)

    for name in services:
        visit(name, ())
    return order


# --------------------------------------------------------------------------- static checks


def test_every_service_has_an_image_or_our_build():
    assert set(BINTRACK) == {"replay", "sensor_agent", "basestation", "recorder", "view", "foxglove_bridge"}
    for name, service in SERVICES.items():
        assert service.get("image") or uses_our_build(service), name
        for dependency in service.get("depends_on", {}):
            assert dependency in SERVICES, f"{name} depends on unknown {dependency}"
    images = {service.get("image") for service in SERVICES.values()}
    assert len(images) == 1 and None not in images, f"every service, the router too, runs one image: {images}"


def test_router_runs_from_our_image_with_our_config_and_the_official_one_is_documented():
    router = SERVICES["router"]
    assert uses_our_build(router) and router["command"][0] == ROUTER_MODULE
    command = router["command"]
    assert option_values(command, "-l", "--listen") == ["tcp/[::]:7447"]
    config_path = option_values(command, "-c", "--config")
    assert config_path, command
    mounts = {volume.split(":")[1]: volume.split(":")[0] for volume in router["volumes"]}
    assert (REPO / mounts[config_path[0]]).resolve() == ROUTER_CONFIG
    # the alternative, the official zenohd image, in a comment: the version of our eclipse-zenoh
    ours = importlib.metadata.version("eclipse-zenoh").split(".")[:2]
    for name in ("docker-compose.yml", "docker-compose.multi.yml"):
        tags = re.findall(r"#.*image: eclipse/zenoh:(\S+)", (REPO / name).read_text())
        assert tags and all(tag.split(".")[:2] == ours for tag in tags), f"{name}: {tags} vs eclipse-zenoh {ours}"


@pytest.mark.parametrize("name", ["docker-compose.yml", "docker-compose.secure.yml", "docker-compose.multi.yml"])
def test_every_compose_file_declares_its_network_on_a_benchmarking_subnet(name):
    """198.18.0.0/15 (RFC 2544) is no LAN's: the stack's network never collides with the user's."""
    networks = yaml.safe_load((REPO / name).read_text())["networks"]
    assert set(networks) == {"default"}, networks
    (config,) = networks["default"]["ipam"]["config"]
    assert ipaddress.ip_network(config["subnet"]).subnet_of(PUBLIC_BENCHMARK_NET), config
    if name == "docker-compose.secure.yml":  # an override of the base file: the same network
        assert networks == COMPOSE["networks"]


def test_router_config_parses_and_runs_a_router():
    config = zenoh.Config.from_file(str(ROUTER_CONFIG))
    assert json.loads(config.get_json("mode")) == "router"
    assert json.loads(config.get_json("listen/endpoints")) == ["tcp/[::]:7447"]
    assert json.loads(config.get_json("scouting/multicast/enabled")) is False
    assert json.loads(config.get_json("scouting/gossip/enabled")) is False
    # Run it, moved to a free loopback port, and reach it from a client session.
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config.insert_json5("listen/endpoints", json.dumps([endpoint]))
    router = zenoh.open(config)
    try:
        client = zenoh.Config()
        client.insert_json5("mode", '"client"')
        client.insert_json5("connect/endpoints", json.dumps([endpoint]))
        session = zenoh.open(client)
        assert session.info.routers_zid() == [router.zid()]
        session.close()
    finally:
        router.close()


def test_dockerfile_installs_the_project_as_a_non_root_user():
    # the base is a build argument, python:3.11-slim unless given
    assert INSTRUCTIONS[0] == ("ARG", "BASE=python:3.11-slim")
    bases = [rest.split()[0] for keyword, rest in INSTRUCTIONS if keyword == "FROM"]
    assert bases and set(bases) == {"${BASE}"}, bases
    project = tomllib.loads((REPO / "pyproject.toml").read_text())
    needed = {"pyproject.toml", project["project"]["readme"],
              *project["tool"]["setuptools"]["package-dir"].values()}
    copied = set()
    for keyword, rest in INSTRUCTIONS:
        if keyword == "COPY" and not rest.startswith("--from="):  # not another stage's files
            sources = shlex.split(rest)[:-1]
            for source in sources:
                assert (REPO / source).exists(), f"COPY {source}: not in the repository"
            copied |= {Path(s).as_posix().rstrip("/") for s in sources}
    for source in needed:
        assert any(source == c or source.startswith(c + "/") for c in copied), f"the image lacks {source}"
    ignore = (DOCKERFILE.parent / (DOCKERFILE.name + ".dockerignore")).read_text().splitlines()
    patterns = [line.strip() for line in ignore if line.strip() and not line.startswith("#")]
    for source in needed:
        assert not any(fnmatch.fnmatch(source, pattern) for pattern in patterns), f"{source} is ignored"
    installs = [rest for keyword, rest in INSTRUCTIONS if keyword == "RUN" and re.search(r"\bpip install\b", rest)]
    assert any(re.search(r"\bpip install (\S+ )*\.( |$)", rest) for rest in installs), installs
    users = [rest for keyword, rest in INSTRUCTIONS if keyword == "USER"]
    assert users and users[-1] not in ("root", "0"), users
    assert exec_form("ENTRYPOINT") == ["python", "-m"]
    assert importlib.util.find_spec(exec_form("CMD")[0]) is not None


@pytest.mark.parametrize("name", sorted(BINTRACK))
def test_compose_service_runs_a_bintrack_service_module(name):
    service = BINTRACK[name]
    module = module_of(service)
    assert module == MODULE_PREFIX + name
    assert importlib.util.find_spec(module) is not None, f"{module} does not exist (yet)"
    argv = service["command"]
    assert option_values(argv, "-e", "--connect") == [ROUTER_ENDPOINT]
    assert option_values(argv, "--net") == ["darpa-grid"]
    assert "router" in service["depends_on"]
    assert service["restart"] == "unless-stopped"
    health = service["healthcheck"]["test"]
    assert health[:5] == ["CMD", "python", "-m", MODULE_PREFIX + "health", name]
    assert option_values(health, "-e", "--connect") == [ROUTER_ENDPOINT]
    assert option_values(health, "--net") == ["darpa-grid"]


def test_every_module_answers_help():
    modules = sorted({module_of(s) for s in BINTRACK.values()} | {MODULE_PREFIX + "health"})
    runs = {m: subprocess.Popen([sys.executable, "-m", m, "--help"], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, cwd=REPO) for m in modules}
    for module, proc in runs.items():
        out, err = proc.communicate(timeout=HUNG)
        assert proc.returncode == 0, f"{module} --help: {err}"
        assert "--connect" in out and "--net" in out, f"{module} --help lacks the bus options"


# --------------------------------------------------------------------------- the stack, live


def local_args(service: dict, endpoint: str, tmp_path: Path) -> list[str]:
    """The compose command's options for a local run: the router endpoint and the volumes'
    container paths rewritten to the test router and to host folders, a published port to a
    free loopback port (``service["local_port"]``)."""
    mounts = {}
    for volume in service.get("volumes", []):
        source, target = volume.split(":")[:2]
        if source.startswith("."):   # a bind mount of a repository folder
            host = REPO / source
        else:                        # a named volume: a fresh folder
            host = tmp_path / source
            host.mkdir(parents=True, exist_ok=True)
        mounts[target] = host
    published = {mapping.rsplit(":", 1)[1] for mapping in service.get("ports", [])}
    args = []
    for arg in service["command"][1:]:
        if arg == ROUTER_ENDPOINT:
            arg = endpoint
        elif args and args[-1] == "--port" and arg in published:
            arg = service.setdefault("local_port", str(free_port()))
        elif args and args[-1] == "--bind":
            arg = "127.0.0.1"
        for target, host in mounts.items():
            if arg == target or arg.startswith(target + "/"):
                arg = str(host) + arg[len(target):]
        args.append(arg)
    return args


def probe(names: list[str], endpoint: str) -> dict[str, str]:
    """Run the healthcheck for each service until it passes (or, a hung stack, for HUNG s); last lines."""
    last: dict[str, str] = {}
    waiting = list(names)
    deadline = time.monotonic() + HUNG
    while waiting and time.monotonic() < deadline:
        runs = {name: subprocess.Popen([sys.executable, "-m", MODULE_PREFIX + "health", name, "-e", endpoint,
                                        "--net", "darpa-grid", "--timeout", "1", "--wait", "1"],
                                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=REPO)
                for name in waiting}
        for name, proc in runs.items():
            out, _ = proc.communicate(timeout=HUNG)
            last[name] = out.strip()
            if proc.returncode == 0:
                waiting.remove(name)
        if waiting:
            time.sleep(0.3)
    return last


def test_the_whole_stack_starts_is_healthy_and_stops_cleanly(zenoh_router, services, tmp_path):
    missing = [n for n, s in BINTRACK.items() if importlib.util.find_spec(module_of(s)) is None]
    assert not missing, f"services not written yet: {', '.join(missing)}"
    order = [name for name in dependency_order(SERVICES) if name in BINTRACK]
    started = {}
    for name in order:   # the router is the zenoh_router fixture
        args = local_args(BINTRACK[name], zenoh_router, tmp_path)
        endpoint = option_values(args, "-e", "--connect")[0]
        i = args.index(endpoint)
        started[name] = services(name, *(args[:i - 1] + args[i + 1:]), endpoint=endpoint)

    last = probe(order, zenoh_router)
    for name, proc in started.items():
        assert proc.proc.poll() is None, f"{name} exited early ({proc.proc.returncode}):\n{proc.log}"
        assert last[name].startswith(f"health: {name}: alive"), f"{name}: {last[name]}\n{proc.log}"

    # The stack does its job: tracks arrive, the base station's queryable answers, all decode.
    scan, latest, bad = asyncio.run(first_tracks(zenoh_router))
    assert scan.tracker == "mcmcda" and latest is not None and latest.t >= scan.t and bad == 0
    # The view serves the map on its published port, with the deployment in its state.
    port = BINTRACK["view"]["local_port"]
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/state.json", timeout=HUNG) as response:
        state = json.load(response)
    assert state["deployment"]["name"] == "darpa-grid" and len(state["deployment"]["sensors"]) == 144

    for name in reversed(order):   # as compose stops them
        started[name].proc.send_signal(signal.SIGTERM)
    for name in reversed(order):
        status = started[name].wait(timeout=HUNG)
        assert status == 0, f"{name} exited with {status} on SIGTERM:\n{started[name].log_path.read_text()}"

    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps([zenoh_router]))
    session = zenoh.open(config)
    try:
        left = [str(r.ok.key_expr) for r in session.liveliness().get(Keys("darpa-grid").alive(), timeout=HUNG)
                if r.ok is not None]
    finally:
        session.close()
    assert left == [], f"tokens still held after the stop: {left}"
    recording = tmp_path / "recordings" / "recording.mcap"
    assert recording.stat().st_size > 0, "the recorder wrote nothing"


async def first_tracks(endpoint: str) -> tuple[TrackSet, TrackSet | None, int]:
    """The next TrackSet published on darpa-grid, then the ``tracks`` queryable's answer."""
    async with BintrackClient(net="darpa-grid", connect=[endpoint], wait=5.0) as client:
        scan = await asyncio.wait_for(anext(client.tracks()), HUNG)
        latest = await client.latest_tracks(timeout=HUNG)
        return scan, latest, client.bad.total
