"""The compose files run for real in a container engine: rootful podman and podman-compose.

The image is built from deploy/Dockerfile on a Debian bookworm base made from Debian's packages
(mmdebstrap, then ``podman import``: no image registry is needed), both cached in the engine's
storage under a tag naming the hash of what goes into them, so a second run builds nothing.
Each compose file is then run as a user would (``podman-compose up -d``): the map answers on
127.0.0.1:8080, ``bintrack watch`` on the host gets tracks through the published router port,
a SIGKILLed base station is brought back by the restart policy, the recording in the
``recordings`` volume equals ``bintrack track`` on the dataset (with the compose file's own
tracker) up to its last scan, ``down`` then ``up`` resumes from the checkpoints in the volume
and ``down -v`` starts afresh.

Podman here needs what the README's Docker section says: runtime runc and the open-files and
process limits at most the host's (a containers.conf with ``default_ulimits``, given through
``CONTAINERS_CONF``); podman-compose 1.0.3 ignores a network's ``ipam``, so the network is
created first with the compose file's subnet. Without podman, podman-compose, mmdebstrap or
runc (``make test`` installs them with apt-get where it can) the module is skipped.
"""

from __future__ import annotations

import hashlib
import ipaddress
import json
import os
import shutil
import signal
import socket
import ssl
import subprocess
import sys
import threading
import time
import urllib.request
from collections import Counter
from operator import attrgetter
from pathlib import Path

import pytest
import yaml

from bintrack.cli import main as cli
from bintrack.formats import read_tracks
from support import HUNG, REPO

if not os.environ.get("BINTRACK_ENGINE_TESTS"):
    pytest.skip("the compose files in a container engine run with `make test` or `make test-engine` "
                "(BINTRACK_ENGINE_TESTS=1)", allow_module_level=True)
PACKAGES = {"podman": "podman", "podman-compose": "podman-compose", "mmdebstrap": "mmdebstrap", "runc": "runc"}
_missing = [package for package, command in PACKAGES.items() if shutil.which(command) is None]
if _missing:
    pytest.skip(f"{', '.join(_missing)} not installed (apt-get install {' '.join(PACKAGES)}): "
                "the compose files are not run in a container engine", allow_module_level=True)
if os.geteuid() != 0:
    pytest.skip("the compose files run under rootful podman: run as root", allow_module_level=True)
# The first test builds the base and the image (each may take 3 HUNG) before it runs.
pytestmark = pytest.mark.timeout(5 * HUNG)

# The base: Python 3.11 from Debian's own packages (docs, manuals and translations left out).
SUITE = "bookworm"
MMDEBSTRAP = ["mmdebstrap", "--variant=minbase", "--include=python3,python3-venv",  # the venv brings its own pip
              "--hook-dir=/usr/share/mmdebstrap/hooks/merged-usr",  # merged /usr without usrmerge (and its perl)
              *(f"--dpkgopt=path-exclude=/usr/share/{d}/*" for d in ("doc", "man", "info", "locale")),
              "--dpkgopt=path-include=/usr/share/doc/*/copyright", SUITE]
DOCKERFILE = REPO / "deploy" / "Dockerfile"
# What `COPY` takes from the repository (tests/test_compose.py holds the Dockerfile to it).
IMAGE_SOURCES = ("pyproject.toml", "README.md", "shared", "services")
PUBLIC = ipaddress.ip_network("198.18.0.0/15")
MAP = "http://127.0.0.1:8080"
ROUTER = "tcp/127.0.0.1:7447"
NET = "darpa-grid"
CONTAINERS_CONF = """\
# bintrack's compose tests: runc, and limits the host allows (crun and runc fail on setrlimit otherwise)
[containers]
default_ulimits = ["nofile=4096:4096", "nproc=4096:4096"]
[engine]
runtime = "runc"
"""


# --------------------------------------------------------------------------- the engine


@pytest.fixture(scope="module")
def engine(tmp_path_factory) -> dict[str, str]:
    """The environment for podman and podman-compose: our containers.conf."""
    conf = tmp_path_factory.mktemp("engine") / "containers.conf"
    conf.write_text(CONTAINERS_CONF)
    env = {**os.environ, "CONTAINERS_CONF": str(conf)}
    info = podman(env, "info", check=False)
    if info.returncode != 0:  # installed, but this host cannot run it (no storage driver, no cgroups…)
        lines = info.stderr.strip().splitlines() or [f"exit {info.returncode}"]
        pytest.skip(f"podman cannot run on this host ({lines[-1]}): the compose files are not run in an engine")
    return env


def podman(env: dict[str, str], *args: str, check: bool = True, timeout: float = HUNG) -> subprocess.CompletedProcess:
    result = subprocess.run(["podman", *args], env=env, capture_output=True, text=True, timeout=timeout)
    if check and result.returncode != 0:
        raise AssertionError(f"podman {' '.join(args)}: exit {result.returncode}\n{result.stderr[-3000:]}")
    return result


def image_exists(env: dict[str, str], tag: str) -> bool:
    return podman(env, "image", "exists", tag, check=False).returncode == 0


def digest(paths: list[tuple[str, Path]], *extra: str) -> str:
    """sha256 over (name, content) of each file, then ``extra``: the cache key of an image."""
    h = hashlib.sha256()
    for name, path in sorted(paths):
        h.update(name.encode() + b"\0" + path.read_bytes() + b"\0")
    for item in extra:
        h.update(item.encode() + b"\0")
    return h.hexdigest()[:16]


def image_context(folder: Path) -> list[tuple[str, Path]]:
    """Copy what the image is built from (the Dockerfile and IMAGE_SOURCES, no caches) into
    ``folder``; its files as (relative name, path)."""
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
    shutil.copy2(DOCKERFILE, folder / "Dockerfile")
    for source in IMAGE_SOURCES:
        if (REPO / source).is_dir():
            shutil.copytree(REPO / source, folder / source, ignore=ignore)
        else:
            shutil.copy2(REPO / source, folder / source)
    return [(p.relative_to(folder).as_posix(), p) for p in folder.rglob("*") if p.is_file()]


def host_ca_bundle() -> str | None:
    """The host's CA bundle, for pip inside the build (a TLS-intercepting proxy's CA is in it)."""
    paths = ssl.get_default_verify_paths()
    for candidate in (os.environ.get("PIP_CERT"), paths.cafile, "/etc/ssl/certs/ca-certificates.crt"):
        if candidate and Path(candidate).is_file():
            return candidate
    return None


@pytest.fixture(scope="module")
def base_image(engine, tmp_path_factory) -> str:
    """The Debian base, made with mmdebstrap and imported; cached under the hash of the command."""
    tag = "localhost/bintrack-base:" + hashlib.sha256(json.dumps(MMDEBSTRAP).encode()).hexdigest()[:16]
    if not image_exists(engine, tag):
        rootfs = tmp_path_factory.mktemp("base") / "rootfs.tar"
        made = subprocess.run([*MMDEBSTRAP, str(rootfs)], stdin=subprocess.DEVNULL, capture_output=True, text=True,
                              timeout=3 * HUNG)
        assert made.returncode == 0, f"mmdebstrap: exit {made.returncode}\n{made.stderr[-3000:]}"
        podman(engine, "import", "--change", "CMD [\"/bin/bash\"]", str(rootfs), tag)
        rootfs.unlink()
    return tag


@pytest.fixture(scope="module")
def image(engine, base_image, tmp_path_factory) -> str:
    """bintrack's image on that base, built from a copy of what it is made of; cached under the
    hash of the Dockerfile, the sources and the base, and tagged as the compose files name it."""
    context = tmp_path_factory.mktemp("context")
    files = image_context(context)
    tag = "localhost/bintrack:src-" + digest(files, base_image)
    if not image_exists(engine, tag):
        ca = host_ca_bundle()
        trust = ["-v", f"{ca}:/run/host-ca.crt:ro", "--build-arg", "PIP_CERT=/run/host-ca.crt"] if ca else []
        podman(engine, "build", "--network", "host", *trust, "--build-arg", f"BASE={base_image}",
               "-f", str(context / "Dockerfile"), "-t", tag, str(context), timeout=3 * HUNG)
    images = {s["image"] for f in ("docker-compose.yml", "docker-compose.multi.yml")
              for s in yaml.safe_load((REPO / f).read_text())["services"].values()}
    assert len(images) == 1, f"the compose files name several images: {images}"
    podman(engine, "tag", tag, "localhost/" + images.pop())
    return tag


# --------------------------------------------------------------------------- a compose project


def merge(base, override, key: str = ""):
    """``override`` over ``base`` as docker compose merges files: mappings key by key, a
    service's ``volumes`` by the path in the container and ``ports`` added, any other list or
    value (``command``, a healthcheck's ``test``) replaced."""
    if isinstance(base, dict) and isinstance(override, dict):
        return {k: merge(base[k], override[k], k) if k in base and k in override else override.get(k, base.get(k))
                for k in {**base, **override}}
    if key == "volumes" and isinstance(base, list):
        return list({v.split(":")[1]: v for v in base + override}.values())
    if key == "ports" and isinstance(base, list):
        return base + [p for p in override if p not in base]
    return override


def merged(files: list[Path]) -> dict:
    """The compose files merged, as docker compose merges them."""
    result: dict = {}
    for path in files:
        result = merge(result, yaml.safe_load(path.read_text()))
    return result


def option(argv: list[str], flag: str) -> str:
    (value,) = [argv[i + 1] for i, a in enumerate(argv[:-1]) if a == flag]
    return value


class Project:
    """A compose project run with podman-compose from a folder that holds the compose files, the
    repository folders they mount (links) and, for the secure profile, ``certs``."""

    def __init__(self, env: dict[str, str], files: list[str], folder: Path):
        self.env, self.folder = env, folder
        folder.mkdir(exist_ok=True)
        for name in ("datasets", "deploy"):
            (folder / name).symlink_to(REPO / name)
        self.compose = merged([REPO / f for f in files])
        self.name = self.compose["name"]
        if len(files) == 1:
            shutil.copy2(REPO / files[0], folder / files[0])
            self.files = files
        else:  # podman-compose 1.0.3 appends an override's command to the base's: it gets them merged
            (folder / "compose.merged.yml").write_text(yaml.safe_dump(self.compose, sort_keys=False))
            self.files = ["compose.merged.yml"]
        self.logs: dict[str, str] = {}  # each service's log, kept over `down`
        self.runs = 0

    def service(self, name: str) -> dict:
        return self.compose["services"][name]

    def container(self, service: str) -> str:
        return f"{self.name}_{service}_1"

    def compose_cmd(self, *args: str) -> None:
        argv = ["podman-compose", "-p", self.name, *(a for f in self.files for a in ("-f", f)), *args]
        result = subprocess.run(argv, cwd=self.folder, env=self.env, capture_output=True, text=True, timeout=HUNG)
        assert result.returncode == 0, f"{' '.join(argv)}: exit {result.returncode}\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"

    def networks(self) -> None:
        """Create the project's networks with the compose file's subnet (podman-compose 1.0.3
        creates them without the ipam block); a stale one with another subnet goes first."""
        for name, network in self.compose["networks"].items():
            subnet = network["ipam"]["config"][0]["subnet"]
            assert ipaddress.ip_network(subnet).subnet_of(PUBLIC), f"{name}: {subnet} is outside {PUBLIC}"
            full = f"{self.name}_{name}"
            found = podman(self.env, "network", "inspect", full, check=False)
            if found.returncode == 0:
                subnets = [s["subnet"] for s in json.loads(found.stdout)[0]["subnets"]]
                if subnets == [subnet]:
                    continue
                podman(self.env, "network", "rm", "-f", full)
            podman(self.env, "network", "create", "--subnet", subnet, "--label",
                   f"io.podman.compose.project={self.name}", full)

    def up(self) -> None:
        for port in (8080, 7447):
            wait_until(lambda: not listened_on(port), f"127.0.0.1:{port} free (the compose files publish it)")
        self.networks()
        self.compose_cmd("up", "-d", "--no-build")
        self.runs += 1

    def keep_logs(self) -> None:
        for name in self.compose["services"]:
            out = podman(self.env, "logs", self.container(name), check=False)
            self.logs[name] = self.logs.get(name, "") + f"--- run {self.runs}\n" + out.stdout + out.stderr

    def down(self, volumes: bool = False) -> None:
        self.keep_logs()
        self.compose_cmd("down", "-t", "20", *(["-v"] if volumes else []))

    def log(self, service: str) -> str:
        out = podman(self.env, "logs", self.container(service), check=False)
        return out.stdout + out.stderr

    def state(self, service: str) -> dict:
        return json.loads(podman(self.env, "inspect", self.container(service)).stdout)[0]

    def volume_file(self, volume: str, name: str) -> Path:
        mountpoint = podman(self.env, "volume", "inspect", f"{self.name}_{volume}", "--format",
                            "{{.Mountpoint}}").stdout.strip()
        return Path(mountpoint) / name

    def diagnosis(self) -> str:
        """What a hung run shows: each container's state and log, with every thread's Python stack
        (the services write them on SIGUSR1), and the host's connections to the published ports."""
        names = list(self.compose["services"])
        found = {n: podman(self.env, "inspect", self.container(n), check=False) for n in names}
        # a container can be gone altogether (seen once, in a full run): say so rather than fail here
        running = [n for n, out in found.items() if out.returncode == 0 and json.loads(out.stdout)[0]["State"]["Running"]]
        gone = [self.container(n) for n, out in found.items() if out.returncode != 0]
        for name in running:
            podman(self.env, "kill", "-s", "USR1", self.container(name), check=False)
        stack = "most recent call first"
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and not all(stack in self.log(n) for n in running):
            time.sleep(0.2)
        states = podman(self.env, "ps", "-a", "--format", "{{.Names}} {{.Status}}", check=False).stdout
        sockets = subprocess.run(["ss", "-tnp"], capture_output=True, text=True).stdout if shutil.which("ss") else ""
        published = [line for line in sockets.splitlines() if ":7447 " in line or ":8080 " in line] or ["none (or no ss)"]
        logs = "\n".join(f"--- {n}\n{self.log(n)[-6000:]}" for n in names)
        return (f"{states}--- containers that no longer exist: {', '.join(gone) or 'none'}\n"
                f"--- the map's last answer: {MAP_ANSWERS or 'none'}\n--- host connections to 7447 and 8080\n"
                + "\n".join(published) + f"\n{logs}")

    def close(self) -> None:
        self.compose_cmd("down", "-t", "20", "-v")
        for name in self.compose["networks"]:
            podman(self.env, "network", "rm", "-f", f"{self.name}_{name}", check=False)


def listened_on(port: int) -> bool:
    with socket.socket() as sock:
        return sock.connect_ex(("127.0.0.1", port)) == 0


def wait_until(condition, what: str, project: Project | None = None, timeout: float = HUNG):
    """Poll ``condition()`` until it is truthy (returned); fail naming ``what`` after ``timeout``
    s, which only a hung run reaches."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.2)
    raise AssertionError(f"{what}: not within {timeout:.0f} s\n{'' if project is None else project.diagnosis()}")


MAP_ANSWERS: list[str] = []  # what the map's last answer was: "state.json" or the error


def map_state() -> dict | None:
    try:
        with urllib.request.urlopen(MAP + "/state.json", timeout=5) as response:
            state = json.load(response)
    except (OSError, ValueError) as exc:
        MAP_ANSWERS[:] = [f"{type(exc).__name__}: {exc}"]
        return None
    MAP_ANSWERS[:] = ["state.json" + ("" if state.get("deployment") else " without a deployment")]
    return state


class Watch:
    """``bintrack watch --net darpa-grid`` on the host (the README's command), its track lines
    collected as (t, tracker) as they come."""

    def __init__(self, *options: str):
        self.proc = subprocess.Popen([sys.executable, "-m", "bintrack.cli", "watch", "--net", NET, *options],
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=REPO)
        self.scans: list[tuple[float, str]] = []
        self.tracked: list[float] = []  # event times of the scans with a track
        self.lines: list[str] = []
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line)
            if line.startswith("t="):
                t, tracker, count = line.split()[:3]
                self.scans.append((float(t[2:]), tracker.removeprefix("tracker=")))
                if count != "tracks=0":
                    self.tracked.append(float(t[2:]))

    def last_t(self) -> float:
        return self.scans[-1][0] if self.scans else -1.0

    def stop(self) -> None:
        self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(timeout=HUNG)
        finally:
            self.reader.join(timeout=10)


def offline_rows(dataset: Path, tracker: str, tmp: Path):
    out = tmp / f"offline-{tracker}.csv"
    if not out.exists():
        assert cli.main(["track", str(dataset), "--tracker", tracker, "--out", str(out)]) == 0
    return read_tracks(out)


def recorded_rows(recording: Path, tmp: Path, name: str):
    copy = tmp / f"{name}.mcap"
    shutil.copy2(recording, copy)
    out = tmp / f"{name}.csv"
    assert cli.main(["export", str(copy), "--what", "tracks", "--out", str(out)]) == 0
    return read_tracks(out)


def up_to(rows, t: float):
    return [row for row in rows if row.t <= t]


def kill_and_await_restart(project: Project, service: str) -> None:
    """SIGKILL the service's process (a crash, not a `stop`) and wait for the restart policy to
    start it again."""
    before = project.state(service)
    assert before["State"]["Running"], f"{service} is not running"
    os.kill(before["State"]["Pid"], signal.SIGKILL)
    wait_until(lambda: (lambda s: s["State"]["Running"] and s["State"]["Pid"] != before["State"]["Pid"]
                        and s["RestartCount"] > before["RestartCount"])(project.state(service)),
               f"{service} restarted by its restart policy", project)


def dataset_of(project: Project) -> Path:
    """The dataset replay plays, on the host: its container path through replay's bind mount."""
    replay = project.service("replay")
    mounts = {v.split(":")[1]: v.split(":")[0] for v in replay["volumes"]}
    container_path = replay["command"][1]
    for target, source in mounts.items():
        if container_path.startswith(target + "/") and source.startswith("./"):
            return REPO / source / container_path[len(target) + 1:]
    raise AssertionError(f"replay's {container_path} is not on a bind mount of the repository")


def tracker_of(project: Project, service: str = "basestation") -> str:
    """The tracker the compose file gives the base station: the tests follow the file."""
    return option(project.service(service)["command"], "--tracker")


# --------------------------------------------------------------------------- the image


def test_image_is_built_from_the_repository_on_a_debian_base(engine, image):
    inspect = json.loads(podman(engine, "image", "inspect", image).stdout)[0]
    size_mb = inspect["Size"] / 1e6
    print(f"image {image}: {size_mb:.0f} MB")
    assert inspect["Config"]["Entrypoint"] == ["python", "-m"]
    assert inspect["Config"]["User"] == "bintrack"
    # the sources in the image are the repository's (not a wheel of an older version)
    ours = (REPO / "services" / "router.py").read_text()
    inside = podman(engine, "run", "--rm", "--network", "none", "--entrypoint", "python", image, "-c",
                    "import bintrack.services.router as m, pathlib; print(pathlib.Path(m.__file__).read_text(), end='')")
    assert inside.stdout == ours


# --------------------------------------------------------------------------- the compose files


def run_with_a_kill(project: Project, watch_options: tuple[str, ...], victim: str) -> float:
    """`up`; the map answers, the host's `bintrack watch` gets the compose tracker's tracks, the
    ``victim`` container is SIGKILLed and its restart policy brings it back, tracks go on;
    `down`. The last event time watched."""
    project.up()
    for name, network in project.compose["networks"].items():
        found = json.loads(podman(project.env, "network", "inspect", f"{project.name}_{name}").stdout)[0]
        assert [s["subnet"] for s in found["subnets"]] == [network["ipam"]["config"][0]["subnet"]]
    state = wait_until(lambda: (map_state() or {}).get("deployment"), "the map on 127.0.0.1:8080", project)
    assert state["name"] == NET and len(state["sensors"]) == 144
    watch = Watch(*watch_options)
    try:
        wait_until(lambda: watch.tracked and watch.last_t() >= 6.0, "tracks from `bintrack watch` on the host", project)
        if "basestation" in project.compose["services"]:
            assert {t for _, t in watch.scans} == {tracker_of(project)}, watch.lines[-5:]
        kill_and_await_restart(project, victim)
        killed_at = watch.last_t()
        wait_until(lambda: watch.last_t() >= killed_at + 6.0, f"tracks after {victim}'s restart", project)
        assert "gone; holding event time" in project.log("replay"), project.log("replay")[-3000:]
    finally:
        watch.stop()
    project.down()
    return watch.last_t()


def resume(project: Project, watch_options: tuple[str, ...], ended_at: float) -> float:
    """`up` again on the volumes of a run that ended at ``ended_at`` s: every service resumes
    from its checkpoint, replay where it was; tracks go on; `down`. The last event time watched."""
    project.up()
    watch = Watch(*watch_options)
    try:
        wait_until(lambda: watch.scans, "tracks after `down` and `up`", project)
        resumed_at = watch.scans[0][0]
        assert resumed_at >= ended_at - 1.0, f"the second run began at t={resumed_at}, the first ended at {ended_at}"
        wait_until(lambda: watch.last_t() >= resumed_at + 4.0, "tracks after `up`", project)
    finally:
        watch.stop()
    assert "replay replay: restarted; resuming from its checkpoint" in project.log("replay"), project.log("replay")
    project.down()
    return watch.last_t()


def differences(rows, offline) -> tuple[list, list]:
    """(rows of `bintrack track` up to the last scan of ``rows`` missing from them, rows of
    ``rows`` it does not have), duplicates counted."""
    expected, got = Counter(up_to(offline, rows[-1].t)), Counter(rows)
    return sorted((expected - got).elements(), key=attrgetter("t")), sorted((got - expected).elements(), key=attrgetter("t"))


def recordings_equal_offline(project: Project, offline, first, second) -> None:
    """The recording after the run with the kill (``first``) and after its continuation past
    `down` and `up` (``second``) against `bintrack track`: in the end, the same rows up to the
    last scan recorded, each once (a row in flight at `down` may come after `up`)."""
    assert second[-1].t > first[-1].t and not Counter(first) - Counter(second), "the recording was not continued"
    missing, extra = differences(second, offline)
    ours = set(offline)
    foreign = [row for row in extra if row not in ours]
    assert not foreign, f"{len(foreign)} rows `bintrack track` does not give: {foreign[:3]}"
    tracker = tracker_of(project)
    # the relay of a tracker on the peers resumes from its checkpoint and fetches the peers'
    # estimates; the recorder records each track set once, across `down` and `up` too
    assert not missing, f"{len(missing)} rows of `bintrack track` missing ({tracker}): {missing[:3]}"
    assert not extra, f"{len(extra)} rows recorded twice: {extra[:3]}"


@pytest.mark.slow
def test_docker_compose_yml(engine, image, tmp_path):
    """docker-compose.yml: a killed base station, `down` and `up`, `down -v` and `up`."""
    project = Project(engine, ["docker-compose.yml"], tmp_path / "project")
    offline = offline_rows(dataset_of(project), tracker_of(project), tmp_path)
    watch_options = ("-e", ROUTER)
    try:
        ended_at = run_with_a_kill(project, watch_options, "basestation")
        recording = project.volume_file("recordings", "recording.mcap")
        first = recorded_rows(recording, tmp_path, "first")
        assert first[-1].t >= ended_at - 1.0
        resume(project, watch_options, ended_at)
        second = recorded_rows(recording, tmp_path, "second")

        # `down -v` removes the volumes: the next `up` starts afresh, a new recording from t = 0
        project.compose_cmd("down", "-v")
        project.up()
        watch = Watch(*watch_options)
        try:
            wait_until(lambda: watch.tracked, "tracks after `down -v` and `up`", project)
        finally:
            watch.stop()
        assert "resuming from its checkpoint" not in project.log("replay")
        project.down()
        third = recorded_rows(recording, tmp_path, "third")
        assert third and third[0].t == offline[0].t and third == up_to(offline, third[-1].t)

        recordings_equal_offline(project, offline, first, second)
    finally:
        project.close()


@pytest.mark.slow
def test_docker_compose_secure_yml(engine, image, tmp_path):
    """The secure profile over the base file: certificates from `bintrack certs`, readable by the
    image's user; the host watches through TLS with the viewer's certificate."""
    folder = tmp_path / "project"
    folder.mkdir()
    certs = folder / "certs"
    assert cli.main(["certs", "--out", str(certs)]) == 0
    uid = int(podman(engine, "run", "--rm", "--network", "none", "--entrypoint", "id", image, "-u").stdout)
    for path in (certs, *certs.iterdir()):
        os.chown(path, uid, uid)
    viewer = (REPO / "deploy" / "secure" / "viewer.json5").read_text()
    host_config = tmp_path / "viewer.json5"
    host_config.write_text(viewer.replace("/certs/", f"{certs}/").replace("tls/router:7447", "tls/127.0.0.1:7447"))
    project = Project(engine, ["docker-compose.yml", "docker-compose.secure.yml"], folder)
    offline = offline_rows(dataset_of(project), tracker_of(project), tmp_path)
    watch_options = ("-c", str(host_config))
    try:
        ended_at = run_with_a_kill(project, watch_options, "basestation")
        assert "tls/[::]:7447" in project.logs["router"]
        recording = project.volume_file("recordings", "recording.mcap")
        first = recorded_rows(recording, tmp_path, "first")
        resume(project, watch_options, ended_at)
        second = recorded_rows(recording, tmp_path, "second")
        recordings_equal_offline(project, offline, first, second)
    finally:
        project.close()


@pytest.mark.slow
def test_docker_compose_multi_yml(engine, image, tmp_path):
    """Two sites: site B's base station killed and back, the merge resumes after `down` and `up`.
    (The file has no recorder: the merged tracks are followed with `bintrack watch`.)"""
    project = Project(engine, ["docker-compose.multi.yml"], tmp_path / "project")
    watch_options = ("-e", ROUTER)
    try:
        ended_at = run_with_a_kill(project, watch_options, "basestation_b")
        assert "region r0c1's base station is gone" in project.logs["merge"], project.logs["merge"][-3000:]
        resume(project, watch_options, ended_at)
        assert "resumed after t=" in project.logs["merge"], project.logs["merge"][-3000:]
    finally:
        project.close()
