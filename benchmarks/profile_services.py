"""Where each live service spends its time: a sampling profile per service (py-spy).

Runs ``replay --speed 0`` → ``sensor_agent`` → ``basestation --tracker mcmcda`` → ``recorder``
on a simulated DARPA-style grid (seed 1, 10 people, 600 s of event time) through a Zenoh
router embedded here (loopback), each service under ``py-spy record --gil`` (only samples
where the service's threads hold the GIL: the Python work), then prints per service the
functions with the largest share of own samples, and the share of a few cost groups.

Run: ``.venv/bin/python benchmarks/profile_services.py`` (needs ``pip install py-spy``;
``--keep DIR`` keeps the raw stacks, which ``flamegraph.pl`` turns into flame graphs).
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import zenoh

from bintrack.formats import write_dataset
from bintrack.keys import Keys
from bintrack.live.session_options import client_config, router_config
from bintrack.sim.scenarios import simulate

from bench_support import REPO, free_port
SCENARIO = dict(seed=1, people=10, duration=600.0)
RATE = 250  # samples/s
TOP = 12
# cost groups: a sample counts in the group of the innermost frame that names one of its words
GROUPS = (
    ("tracker (mcmcda)", ("trackers/",)),
    ("transition detector", ("transition_detector",)),
    ("MCAP write", ("mcap/", "RecordingWriter")),
    ("decode / validate / encode (msgspec, pydantic, msgpack)", ("decode", "encode (", "validate_python", "model_",
                                                                 "BaseModel.__init__")),
    (ROUTING := "key parsing, routing, control guard (own time)", ("parse_key", "_route", "claimed_sender", "admit",
                                                                  "_from_replay")),
    ("Zenoh put", ("put (",)),
    ("reading the dataset", ("formats.py", "csv")),
)



def start(name: str, args: list[str], endpoint: str, work: Path, pyspy: str) -> subprocess.Popen:
    out = work / f"{name}.stacks"
    command = [pyspy, "record", "--gil", "--format", "raw", "-r", str(RATE), "-o", str(out), "--",
               sys.executable, "-m", f"bintrack.services.{name}", *args, "-e", endpoint]
    log = open(work / f"{name}.log", "w")
    env = {k: v for k, v in os.environ.items() if k != "ZENOH_CONFIG"}
    return subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, cwd=REPO, env=env)


def service_pids(pyspy_pid: int) -> list[int]:
    """The process(es) py-spy started (its children)."""
    try:
        return [int(pid) for pid in Path(f"/proc/{pyspy_pid}/task/{pyspy_pid}/children").read_text().split()]
    except (OSError, ValueError):
        return []


def frame_name(frame: str) -> str:
    """``func (path:line)`` → ``func (file)``."""
    func, _, where = frame.partition(" (")
    path = where.rsplit(":", 1)[0]
    parts = Path(path).parts
    short = "/".join(parts[-2:]) if len(parts) > 1 else path
    return f"{func} ({short})"


def group_of(frames: list[str]) -> str:
    """The cost group of the innermost frame of a stack that belongs to one (routing only for
    the sample's own frame: every handler runs under it)."""
    for depth, frame in enumerate(reversed(frames)):
        for group, words in GROUPS:
            if (depth == 0 or group != ROUTING) and any(word in frame for word in words):
                return group
    return "the rest: asyncio loop, hand-off, the services' own logic"


def summarise(stacks: Path) -> tuple[int, list[tuple[str, int]], list[tuple[str, int]]]:
    """(samples, top functions by own samples, samples per cost group)."""
    own: Counter[str] = Counter()
    groups: Counter[str] = Counter()
    total = 0
    for line in stacks.read_text().splitlines():
        stack, _, count = line.rpartition(" ")
        if not stack or not count.isdigit():
            continue
        n = int(count)
        total += n
        frames = stack.split(";")
        own[frame_name(frames[-1])] += n
        groups[group_of(frames)] += n
    return total, own.most_common(TOP), sorted(groups.items(), key=lambda item: -item[1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keep", type=Path, metavar="DIR", help="keep the stacks and logs in DIR")
    args = parser.parse_args()
    pyspy = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    if not Path(pyspy).exists():
        print("py-spy is not installed: pip install py-spy", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="bintrack-profile-") as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        sim = simulate("darpa-grid", **SCENARIO)
        source = write_dataset(work / "dataset", sim.deployment, sim.events, sim.truth)
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        router = zenoh.open(router_config([endpoint]))
        session = zenoh.open(client_config([endpoint]))
        keys = Keys("profile")
        done: list[float] = []
        subscriber = session.declare_subscriber(keys.done("recorder"), lambda _s: done.append(time.time()))
        net = ["--net", keys.net]
        procs = {}
        try:
            procs["recorder"] = start("recorder", ["--out", str(work / "run.mcap"), *net], endpoint, work, pyspy)
            procs["sensor_agent"] = start("sensor_agent", net, endpoint, work, pyspy)
            procs["basestation"] = start("basestation", ["--tracker", "mcmcda", *net], endpoint, work, pyspy)
            procs["replay"] = start("replay", [str(source), "--speed", "0", "--wait-for",
                                               "sensor_agent,basestation,recorder", *net], endpoint, work, pyspy)
            print(f"profiling {len(sim.events)} events of {SCENARIO}", file=sys.stderr)
            procs["recorder"].wait(900)
            procs["replay"].wait(60)
        finally:
            for proc in procs.values():  # the service ends on SIGTERM; py-spy then writes its file
                for pid in service_pids(proc.pid):
                    os.kill(pid, signal.SIGTERM)
            for proc in procs.values():
                try:
                    proc.wait(30)
                except subprocess.TimeoutExpired:
                    for pid in service_pids(proc.pid):
                        os.kill(pid, signal.SIGKILL)
                    proc.kill()
            subscriber.undeclare()
            session.close()
            router.close()
        report(work)
    return 0


def report(work: Path) -> None:
    """The tables of the stacks in ``work``."""
    for name in ("replay", "sensor_agent", "basestation", "recorder"):
        stacks = work / f"{name}.stacks"
        if not stacks.exists():
            print(f"\n{name}: no profile (see {name}.log)")
            continue
        total, top, groups = summarise(stacks)
        print(f"\n### {name} ({total} samples at {RATE}/s with the GIL held)\n")
        print("| cost group | share |\n| --- | ---: |")
        for group, n in groups:
            print(f"| {group} | {100 * n / total:.0f} % |")
        print("\n| function (own time) | share |\n| --- | ---: |")
        for func, n in top:
            print(f"| `{func}` | {100 * n / total:.1f} % |")


if __name__ == "__main__":
    sys.exit(main())
