"""What the bus costs: raw Zenoh throughput in this Python beside the services' own figures.

Everything runs on loopback (127.0.0.1) through one Zenoh router embedded in this process
(``bintrack.live.session_options.router_config`` on a free port); the services are real subprocesses
(``python -m bintrack.services.<name> … -e ENDPOINT``), each on its own network name.

1. **Raw Zenoh**: one client session publishes N small messages (a msgpack ``Transition``,
   ~85 bytes) through the router to a second client session that counts them in a callback;
   reliable delivery, congestion control BLOCK (nothing dropped). Messages/s from the first
   put to the last receipt, median of 3 runs, for a declared publisher and for
   ``session.put`` (what the services call).
2. **Pipeline**: ``replay SOURCE --speed 0 --wait-for sensor_agent,recorder`` → ``sensor_agent``
   → ``recorder --out X.mcap`` on a simulated DARPA-style grid (144 PIR nodes, 40 people,
   1200 s of event time), 3 runs, the median reported. Wall time from the first raw sample
   (its receipt time in the recording) to the recorder's ``control/done`` (sent once the file
   is finalised, after the sensor agent is done); transitions and raw samples are counted in
   the recording.
   Replay is flow controlled: a clock tick (every ``--clock-period``; by default 0.5 s of
   event time at ``--speed 0``, 0.05 s at ``--speed 1``)
   waits until every consumer acknowledged the tick ``--max-ahead`` (16) before it; the
   services acknowledge every 8 ticks or 5 ms. Also: CPU seconds of each service per 1 000
   transitions (user + system of the process, start-up included).
   Beside it, in the same run, ``benchmarks/bare_chain.py``: the same number of messages
   through three bare Python processes of the pipeline's shape (put pre-encoded samples →
   unpack, pack, put → keep in memory), no validation, flow control or file; the least a
   pipeline of one Zenoh message per transition costs in this Python (median of 3).
3. **Full stack**: ``replay --speed 0`` → ``sensor_agent`` → ``basestation --tracker mcmcda``
   → ``recorder`` on a simulated grid of 10 people for 3600 s of event time; event time / wall
   time (× real time), CPU per service per 1 000 transitions, beside the same tracker run
   offline in this process (its CPU time: the tracker's own bound), and whether the recorded
   track rows are the offline ones.
4. **Latency**: ``replay --speed 1`` of a 30 s slice of ``datasets/darpa-grid-3`` through
   sensor_agent → peer_agent → basestation (``--tracker equal-weight``), the services'
   default options; a subscriber in this process timestamps raw samples, the peers'
   estimates and the base station's tracks. Latency = receipt time − the time the event was
   due under real-time pacing (receipt of the first raw sample + (t − t of that sample)). A
   peer agent releases a transition once the watermark passes it: the least of the clock
   tick − ``--lateness`` (default 0) and the sensor agents' reported progress; the base
   station likewise waits for the peers' released watermark. So an estimate's latency is up
   to one clock period by design plus what the bus and the services add; also shown:
   receipt − when the tick that released the output was due. Outputs released only by the
   end-of-stream flush are left out.

5. **The user's path** (``benchmarks/user_path.py``): on part 3's dataset, whole commands as a
   user runs them, start-up included: ``bintrack track`` offline, ``bintrack up … --speed 0
   --exit-at-end --record`` (and its start-up to the first raw sample) and ``bintrack demo``;
   three rounds, each beside a run of part 3, medians.

Run: ``nice -n 10 .venv/bin/python benchmarks/bus.py`` (a few minutes; progress on stderr, table
on stdout). ``--keep DIR`` keeps the datasets, recording and service logs there; ``--no-stack``
leaves out parts 3 and 5; ``--user-only`` runs only part 5 with its three runs of part 3.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zenoh

from bintrack.live.session_options import client_config, router_config
from bintrack.formats import open_dataset, write_dataset
from bintrack.keys import Keys
from bintrack.bus_payloads import LocalEstimate, RawSample, TrackSet, Transition
from bintrack.message_codec import decode, encode
from bintrack.live.recording import open_recording
from bintrack.live.replay_schedule import default_clock_period
from bintrack.cli.export_command import track_rows
from bintrack.pipeline import output_rows, run_tracker
from bintrack.services import basestation as basestation_service
from bintrack.services import peer_agent as peer_agent_service
from bintrack.sim.scenarios import simulate
from bintrack.trackers import make_tracker

from bench_support import REPO, free_port
from user_path import user_round, user_rows
LOOPBACK = "127.0.0.1"

RAW_MESSAGES = 200_000  # per run of the raw Zenoh figure
RAW_RUNS = 3
PIPELINE_RUNS = 3
PIPELINE_SCENARIO = dict(name="darpa-grid", seed=1, people=40, duration=1200.0)
LATENCY_SOURCE = REPO / "datasets" / "darpa-grid-3"
LATENCY_SLICE = 30.0  # s of event time
FAST_PERIOD = default_clock_period(0.0)  # replay's default --clock-period at --speed 0, s
LIVE_PERIOD = default_clock_period(1.0)  # and at --speed 1
PEER_DEFAULT_LATENESS = peer_agent_service.build_parser().get_default("lateness")
BASESTATION_DEFAULT_LATENESS = basestation_service.build_parser().get_default("lateness")
LATENCY_RUNS = (  # (label, peer --lateness, basestation --lateness; None for the service's default)
    ("the services' defaults", None, None),
)
USER_ROUNDS = 3  # part 5: rounds of the user's commands, each beside a run of part 3
STACK_SCENARIO = dict(name="darpa-grid", seed=1, people=10, duration=3600.0)  # full stack with mcmcda

_started = time.monotonic()
LOAD_BEFORE = " / ".join(f"{x:.2f}" for x in os.getloadavg())


def say(text: str) -> None:
    """Progress on stderr."""
    print(f"[{time.monotonic() - _started:6.1f} s] {text}", file=sys.stderr, flush=True)



def client_session(endpoint: str) -> zenoh.Session:
    return zenoh.open(client_config([endpoint]))


# --------------------------------------------------------------------------- subprocesses


@dataclass
class Child:
    """A service subprocess with its log file; ``cpu`` (user + system s) once reaped."""

    name: str
    proc: subprocess.Popen
    log_path: Path
    cpu: float | None = None

    def poll(self) -> int | None:
        """Exit status if it has exited (reaping it and taking its CPU time), else None."""
        if self.proc.returncode is not None:
            return self.proc.returncode
        try:
            pid, status, usage = os.wait4(self.proc.pid, os.WNOHANG)
        except ChildProcessError:
            return self.proc.poll()
        if pid == 0:
            return None
        self.proc.returncode = os.waitstatus_to_exitcode(status)
        self.cpu = usage.ru_utime + usage.ru_stime
        return self.proc.returncode

    def wait(self, timeout: float, poll_interval: float = 0.005) -> int:
        """Exit status; TimeoutError after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        while (code := self.poll()) is None:
            if time.monotonic() >= deadline:
                raise TimeoutError(f"{self.name} still running after {timeout:g} s (log: {self.log_path})")
            time.sleep(poll_interval)
        return code

    def stop(self, grace: float = 10.0) -> None:
        """SIGTERM, then SIGKILL after ``grace`` s."""
        if self.poll() is not None:
            return
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.wait(grace, 0.02)
        except TimeoutError:
            say(f"{self.name} ignored SIGTERM for {grace:g} s; killing it")
            self.proc.kill()
            self.wait(5.0, 0.02)

    def tail(self, lines: int = 15) -> str:
        try:
            return "\n".join(self.log_path.read_text().splitlines()[-lines:])
        except OSError:
            return ""


class Children:
    """Every subprocess this benchmark started; ``stop_all`` ends them (SIGTERM, then kill)."""

    def __init__(self, endpoint: str, log_dir: Path):
        self.endpoint = endpoint
        self.log_dir = log_dir
        self.all: list[Child] = []
        # Children must not pick up a Zenoh config file that could leave loopback.
        self.env = {k: v for k, v in os.environ.items() if k != "ZENOH_CONFIG"}

    def start(self, name: str, *args: str, tag: str) -> Child:
        log_path = self.log_dir / f"{tag}-{name}.log"
        with open(log_path, "w") as log:
            proc = subprocess.Popen([sys.executable, "-m", f"bintrack.services.{name}", *args, "-e", self.endpoint],
                                    stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                    cwd=REPO, env=self.env)
        child = Child(name, proc, log_path)
        self.all.append(child)
        return child

    def stop_all(self) -> None:
        running = [c for c in self.all if c.poll() is None]
        for child in running:
            child.proc.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + 10.0
        for child in running:
            try:
                child.wait(max(0.1, deadline - time.monotonic()), 0.02)
            except TimeoutError:
                say(f"{child.name} ignored SIGTERM; killing it")
                child.proc.kill()
                child.wait(5.0, 0.02)

    def check(self, child: Child, code: int) -> None:
        if code != 0:
            raise RuntimeError(f"{child.name} exited with status {code}; its log ends:\n{child.tail()}")


# --------------------------------------------------------------------------- 1. raw Zenoh


def raw_zenoh(endpoint: str, payload: bytes, n: int, runs: int) -> dict[str, list[float]]:
    """Messages/s publisher session → router → subscriber session, per run, for a declared
    publisher and for session.put; both reliable with congestion control BLOCK."""
    publisher_session = client_session(endpoint)
    subscriber_session = client_session(endpoint)
    key = "bench/raw/transition"
    state = {"count": 0, "target": math.inf, "last": 0.0}
    reached = threading.Event()

    def on_sample(_sample) -> None:
        state["count"] += 1  # one subscriber: callbacks of a subscriber are not concurrent
        if state["count"] >= state["target"]:
            state["last"] = time.perf_counter()
            reached.set()

    subscriber = subscriber_session.declare_subscriber(key, on_sample)
    publisher = publisher_session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK,
                                                    reliability=zenoh.Reliability.RELIABLE)
    results: dict[str, list[float]] = {"publisher": [], "session.put": []}
    try:
        deadline = time.monotonic() + 10.0
        while state["count"] == 0:  # until the route to the subscriber is up
            if time.monotonic() > deadline:
                raise RuntimeError("raw Zenoh: the subscriber never received a warm-up message")
            publisher.put(payload)
            time.sleep(0.01)
        time.sleep(0.2)
        put = publisher_session.put
        block = zenoh.CongestionControl.BLOCK
        for run in range(runs):
            for how in results:
                reached.clear()
                state["target"] = state["count"] + n
                started = time.perf_counter()
                if how == "publisher":
                    for _ in range(n):
                        publisher.put(payload)
                else:
                    for _ in range(n):
                        put(key, payload, congestion_control=block)
                if not reached.wait(60.0):
                    raise RuntimeError(f"raw Zenoh: {state['target'] - state['count']} of {n} messages never arrived")
                state["target"] = math.inf
                rate = n / (state["last"] - started)
                results[how].append(rate)
                say(f"raw Zenoh run {run + 1}/{runs}, {how}: {rate:,.0f} msgs/s")
    finally:
        publisher.undeclare()
        subscriber.undeclare()
        publisher_session.close()
        subscriber_session.close()
    return results


# --------------------------------------------------------------------------- 2. pipeline


@dataclass
class PipelineRun:
    transitions: int
    raw: int
    wall: float  # s, first raw sample → recorder done
    cpu: dict[str, float | None]  # user + system s per service, start-up included

    @property
    def rate(self) -> float:
        return self.transitions / self.wall


@dataclass
class PipelineResult:
    events: int
    event_span: float
    ticks: int
    runs: list[PipelineRun]
    bare: list[float]  # transitions/s of the bare chain, per run

    @property
    def median(self) -> PipelineRun:
        return sorted(self.runs, key=lambda run: run.rate)[len(self.runs) // 2]


def pipeline(children: Children, session: zenoh.Session, work: Path) -> PipelineResult:
    options = dict(PIPELINE_SCENARIO)
    name = options.pop("name")
    say(f"simulating {name} {options} for the pipeline runs")
    sim = simulate(name, **options)
    source = write_dataset(work / "pipeline-dataset", sim.deployment, sim.events, sim.truth)
    events = len(sim.events)
    span = sim.events[-1].t - sim.events[0].t
    ticks = int(math.floor(sim.events[-1].t / FAST_PERIOD) - math.floor(sim.events[0].t / FAST_PERIOD)) + 2
    say(f"pipeline dataset: {events} events over {span:.0f} s of event time ({events / ticks:.1f} per clock tick)")
    runs, bare = [], []
    for k in range(1, PIPELINE_RUNS + 1):
        runs.append(pipeline_run(children, session, source, work, k))
        bare.append(bare_chain(children, events, work, k))
    return PipelineResult(events, span, ticks, runs, bare)


def bare_chain(children: Children, n: int, work: Path, k: int) -> float:
    """Transitions/s of ``benchmarks/bare_chain.py`` with ``n`` messages (sink, relay, source)."""
    script = str(Path(__file__).with_name("bare_chain.py"))
    procs = {}
    for role in ("sink", "relay", "source"):
        with open(work / f"bare{k}-{role}.log", "w") as log:
            procs[role] = subprocess.Popen([sys.executable, script, role, children.endpoint, str(n)],
                                           stdout=subprocess.PIPE if role == "sink" else log, stderr=log,
                                           stdin=subprocess.DEVNULL, cwd=REPO, env=children.env, text=True)
    try:
        out, _ = procs["sink"].communicate(timeout=300.0)
        for proc in procs.values():
            if proc.wait(30.0) != 0:
                raise RuntimeError(f"bare chain run {k}: {proc.args[2]} exited with status {proc.returncode}")
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    fields = out.split()
    if len(fields) != 4 or fields[0] != "RATE" or int(fields[2]) != n:
        raise RuntimeError(f"bare chain run {k}: unexpected output {out!r}")
    rate = float(fields[1])
    say(f"bare chain run {k}/{PIPELINE_RUNS}: {n} transitions at {rate:,.0f} transitions/s")
    return rate


def pipeline_run(children: Children, session: zenoh.Session, source: Path, work: Path, k: int) -> PipelineRun:
    tag = f"pipeline{k}"
    keys = Keys(f"bench-{tag}")
    recording = work / f"{tag}.mcap"
    done_at: list[float] = []
    done_sub = session.declare_subscriber(keys.done("recorder"), lambda _s: done_at.append(time.time()))
    try:
        recorder = children.start("recorder", "--out", str(recording), "--net", keys.net, tag=tag)
        agent = children.start("sensor_agent", "--net", keys.net, tag=tag)
        replay = children.start("replay", str(source), "--speed", "0", "--wait-for", "sensor_agent,recorder",
                                "--net", keys.net, tag=tag)
        say(f"pipeline run {k}/{PIPELINE_RUNS}: replay → sensor_agent → recorder started")
        children.check(recorder, recorder.wait(180.0))
        exited = time.time()
        children.check(replay, replay.wait(30.0))
        agent.stop()
    finally:
        done_sub.undeclare()
    end = done_at[0] if done_at else exited

    counts = {"raw": 0, "transition": 0}
    first_raw_ns = None
    for record in open_recording(recording).records(lambda key: "/raw/" in key or key.endswith("/transition")):
        kind = record.kind
        if kind in counts:
            counts[kind] += 1
            if kind == "raw" and (first_raw_ns is None or record.received_ns < first_raw_ns):
                first_raw_ns = record.received_ns
    if first_raw_ns is None:
        raise RuntimeError(f"pipeline run {k}: the recording holds no raw sample")
    run = PipelineRun(counts["transition"], counts["raw"], end - first_raw_ns / 1e9,
                      {c.name: c.cpu for c in (replay, agent, recorder)})
    say(f"pipeline run {k}/{PIPELINE_RUNS}: {run.transitions} transitions, {run.raw} raw samples recorded "
        f"in {run.wall:.2f} s = {run.rate:,.0f} transitions/s")
    return run


# --------------------------------------------------------------------------- 4. full stack


@dataclass
class StackResult:
    """replay → sensor_agent → basestation (mcmcda) → recorder at --speed 0, beside the same
    tracker offline in this process."""

    events: int
    span: float  # s of event time
    transitions: int
    track_sets: int
    wall: float  # s, first raw sample → recorder done
    cpu: dict[str, float | None]
    offline_cpu: float  # s of CPU for the same tracker offline (bintrack track's code path)
    identical: bool  # the recorded track rows are the offline ones

    @property
    def speed(self) -> float:
        return self.span / self.wall


@dataclass
class StackData:
    """The full stack's dataset, and the same tracker run on it offline in this process."""

    source: Path
    events: int
    span: float  # s of event time
    offline_rows: list
    offline_cpu: float  # s of CPU (bintrack track's code path)


def stack_data(work: Path) -> StackData:
    options = dict(STACK_SCENARIO)
    name = options.pop("name")
    say(f"simulating {name} {options} for the full stack")
    sim = simulate(name, **options)
    source = write_dataset(work / "stack-dataset", sim.deployment, sim.events, sim.truth)
    say("full stack: the same tracker offline")
    dataset = open_dataset(source)
    cpu0 = time.process_time()
    offline_rows = sorted(output_rows(run_tracker(dataset, make_tracker("mcmcda", dataset.deployment))))
    offline_cpu = time.process_time() - cpu0
    return StackData(source, len(sim.events), sim.events[-1].t - sim.events[0].t, offline_rows, offline_cpu)


def full_stack(children: Children, session: zenoh.Session, work: Path, data: StackData | None = None,
               k: int = 1) -> StackResult:
    data = data or stack_data(work)
    keys = Keys(f"bench-stack{k}")
    recording = work / f"stack{k}.mcap"
    done_at: list[float] = []
    done_sub = session.declare_subscriber(keys.done("recorder"), lambda _s: done_at.append(time.time()))
    tag = f"stack{k}"
    try:
        recorder = children.start("recorder", "--out", str(recording), "--net", keys.net, tag=tag)
        agent = children.start("sensor_agent", "--net", keys.net, tag=tag)
        base = children.start("basestation", "--tracker", "mcmcda", "--net", keys.net, tag=tag)
        replay = children.start("replay", str(data.source), "--speed", "0", "--wait-for",
                                "sensor_agent,basestation,recorder", "--net", keys.net, tag=tag)
        say(f"full stack: replay → sensor_agent → basestation mcmcda → recorder on {data.events} events started")
        children.check(recorder, recorder.wait(1800.0))
        exited = time.time()
        children.check(replay, replay.wait(30.0))
        agent.stop()
        base.stop()
    finally:
        done_sub.undeclare()
    end = done_at[0] if done_at else exited
    recorded = open_recording(recording)
    first_raw_ns = min(r.received_ns for r in recorded.records(lambda key: "/raw/" in key))
    transitions = sum(1 for _ in recorded.records(lambda key: key.endswith("/transition")))
    live_rows = track_rows(recorded, "tracks")
    track_sets = sum(1 for _ in recorded.records(lambda key: key.endswith("/tracks")))
    result = StackResult(data.events, data.span, transitions, track_sets, end - first_raw_ns / 1e9,
                         {c.name: c.cpu for c in (replay, agent, base, recorder)}, data.offline_cpu,
                         live_rows == data.offline_rows)
    say(f"full stack: {data.span:.0f} s of event time in {result.wall:.1f} s = {result.speed:.0f} × real time; "
        f"offline {data.offline_cpu:.1f} s of CPU; rows identical: {result.identical}")
    return result


# --------------------------------------------------------------------------- 3. latency


@dataclass
class Latencies:
    """Latencies (s) of one kind of output: event → receipt, and receipt − when the clock tick
    that released it was due (what the bus and the services add beyond the designed hold)."""

    received: int
    total: np.ndarray
    beyond_tick: np.ndarray
    flushed: int  # released only by the end-of-stream flush: left out of both


@dataclass
class LatencyResult:
    label: str
    peer_lateness: float
    base_lateness: float
    estimates: Latencies
    tracks: Latencies


def slice_dataset(source: Path, seconds: float, out: Path) -> tuple[Path, float, float]:
    """The first ``seconds`` of event time of ``source`` as a dataset in ``out``; its first
    and last event times."""
    dataset = open_dataset(source)
    events = list(dataset.events())
    t0 = events[0].t
    kept = [e for e in events if e.t < t0 + seconds]
    truth = [row for row in dataset.truth() if row.t <= t0 + seconds] if dataset.has_truth else None
    if truth is not None:
        truth.sort(key=lambda row: row.t)
    write_dataset(out, dataset.deployment, kept, truth)
    return out, kept[0].t, kept[-1].t


def latency(children: Children, session: zenoh.Session, source: Path, t_last: float, label: str,
            peer_lateness: float | None, base_lateness: float | None, tag: str) -> LatencyResult:
    net = f"bench-{tag}"
    keys = Keys(net)
    raw: list[tuple[float, bytes]] = []
    estimates: list[tuple[float, bytes]] = []
    tracks: list[tuple[float, bytes]] = []
    base_done = threading.Event()

    def recorder_of(into: list) -> Callable[[zenoh.Sample], None]:
        return lambda sample: into.append((time.monotonic(), sample.payload.to_bytes()))

    subscribers = [
        session.declare_subscriber(keys.raw(), recorder_of(raw)),
        session.declare_subscriber(keys.estimate(), recorder_of(estimates)),
        session.declare_subscriber(keys.tracks(), recorder_of(tracks)),
        session.declare_subscriber(keys.done("basestation"), lambda _s: base_done.set()),
    ]
    started: list[Child] = []
    try:
        started.append(children.start("sensor_agent", "--net", net, tag=tag))
        peer_args = ["--tracker", "equal-weight", "--net", net]
        if peer_lateness is not None:
            peer_args += ["--lateness", str(peer_lateness)]
        started.append(children.start("peer_agent", *peer_args, tag=tag))
        base_args = ["--tracker", "equal-weight", "--net", net]
        if base_lateness is not None:
            base_args += ["--lateness", str(base_lateness)]
        started.append(children.start("basestation", *base_args, tag=tag))
        replay = children.start("replay", str(source), "--speed", "1",
                                "--wait-for", "sensor_agent,peer_agent,basestation", "--net", net, tag=tag)
        started.append(replay)
        say(f"latency [{label}]: replay at --speed 1 of {LATENCY_SLICE:g} s started")
        deadline = time.monotonic() + LATENCY_SLICE + 90.0
        last_said = time.monotonic()
        while (code := replay.poll()) is None:
            if time.monotonic() > deadline:
                raise TimeoutError(f"replay still running (log: {replay.log_path})")
            for child in started[:-1]:
                if (status := child.poll()) is not None:
                    children.check(child, status)
                    raise RuntimeError(f"{child.name} exited early (log: {child.log_path})")
            if time.monotonic() - last_said >= 5.0 and raw:
                last_said = time.monotonic()
                say(f"latency [{label}]: {time.monotonic() - raw[0][0]:4.1f} s of {LATENCY_SLICE:g} s played, "
                    f"{len(estimates)} estimates and {len(tracks)} tracks received")
            time.sleep(0.05)
        children.check(replay, code)
        if not base_done.wait(30.0):
            raise TimeoutError("the base station never reported done after the end of stream")
    finally:
        for child in started:
            child.stop()
        for subscriber in subscribers:
            subscriber.undeclare()
    if not raw:
        raise RuntimeError(f"latency [{label}]: no raw sample arrived")

    wall0, first = min(raw, key=lambda item: item[0])
    t0 = decode(RawSample, first).t
    # The last tick is the first grid point past the last event; what it does not release
    # goes out with the end-of-stream flush.
    last_tick = (math.floor(t_last / LIVE_PERIOD) + 1) * LIVE_PERIOD

    def measure(items: list[tuple[float, bytes]], cls, hold: float) -> Latencies:
        total, beyond, flushed = [], [], 0
        for received, payload in items:
            t = decode(cls, payload).t
            # released by the first tick T with t < T − hold (ReorderBuffer.release), due on
            # the wall clock (T − t0) after the first raw sample
            tick = (math.floor((t + hold) / LIVE_PERIOD) + 1) * LIVE_PERIOD
            if tick > last_tick:
                flushed += 1
                continue
            total.append(received - (wall0 + (t - t0)))
            beyond.append(received - (wall0 + (tick - t0)))
        return Latencies(len(items), np.asarray(total), np.asarray(beyond), flushed)

    base_hold = BASESTATION_DEFAULT_LATENESS if base_lateness is None else base_lateness
    peer_hold = PEER_DEFAULT_LATENESS if peer_lateness is None else peer_lateness
    result = LatencyResult(label, peer_hold, base_hold, measure(estimates, LocalEstimate, peer_hold),
                           measure(tracks, TrackSet, base_hold))
    say(f"latency [{label}]: {result.estimates.received} estimates ({result.estimates.flushed} at end of stream), "
        f"{result.tracks.received} tracks ({result.tracks.flushed} at end of stream) received")
    return result


# --------------------------------------------------------------------------- report


def _ms(values: np.ndarray) -> str:
    p50, p99 = np.percentile(values, [50, 99])
    return f"{p50 * 1e3:,.0f} / {p99 * 1e3:,.0f}"


def user_path(children: Children, session: zenoh.Session, work: Path,
              data: StackData) -> tuple[list[tuple[str, str, str]], list[StackResult]]:
    """Part 5: USER_ROUNDS rounds of part 3 and of the user's commands, alternating; the table's
    rows and part 3's runs."""
    stacks, rounds = [], []
    for k in range(1, USER_ROUNDS + 1):
        say(f"5/5 user's path, round {k}/{USER_ROUNDS}")
        stacks.append(full_stack(children, session, work, data, k=10 + k))
        rounds.append(user_round(data.source, data.offline_rows, work, k, say))
    return user_rows(rounds, [s.speed for s in stacks], data.span), stacks


def table(raw: dict[str, list[float]], pipe: PipelineResult, lat: list[LatencyResult], payload_size: int,
          stack: StackResult | None, user: list[tuple[str, str, str]] = ()) -> str:
    rows: list[tuple[str, str, str]] = []
    raw_median = statistics.median(raw["publisher"])
    put_median = statistics.median(raw["session.put"])
    rows.append((f"raw Zenoh, declared publisher ({payload_size} B, reliable, BLOCK), median of {RAW_RUNS}",
                 f"{raw_median:,.0f}", "msgs/s"))
    rows.append((f"raw Zenoh, session.put (the call the services use), median of {RAW_RUNS}",
                 f"{put_median:,.0f}", "msgs/s"))
    run = pipe.median
    transitions_rate = run.rate
    rows.append((f"pipeline replay → sensor_agent → recorder, --speed 0, median of {len(pipe.runs)}",
                 f"{transitions_rate:,.0f}", "transitions/s"))
    bare_median = statistics.median(pipe.bare)
    rows.append((f"  beside it: bare Python chain of the same shape (bare_chain.py), median of {len(pipe.bare)}",
                 f"{bare_median:,.0f}", "transitions/s"))
    rows.append(("  same run: raw samples", f"{run.raw / run.wall:,.0f}", "samples/s"))
    rows.append(("  same run: clock ticks (flow-control round trips)", f"{pipe.ticks / run.wall:,.0f}", "ticks/s"))
    rows.append(("  same run: wall time, first raw sample → recorder done", f"{run.wall:.2f}", "s"))
    for name, cpu in run.cpu.items():
        rows.append((f"  same run: CPU per 1 000 transitions, {name}",
                     "?" if cpu is None else f"{cpu / run.transitions * 1000:.3f}", "CPU-s"))
    if stack is not None:
        rows.append((f"full stack replay → sensor_agent → basestation mcmcda → recorder, --speed 0, "
                     f"{STACK_SCENARIO['people']} people, {STACK_SCENARIO['duration']:g} s",
                     f"{stack.speed:,.0f}", "× real time"))
        rows.append(("  same run: wall time, first raw sample → recorder done", f"{stack.wall:.1f}", "s"))
        for name, cpu in stack.cpu.items():
            rows.append((f"  same run: CPU per 1 000 transitions, {name}",
                         "?" if cpu is None else f"{cpu / stack.transitions * 1000:.3f}", "CPU-s"))
        rows.append(("  the same tracker offline (one process, CPU time)",
                     f"{stack.span / stack.offline_cpu:,.0f}", "× real time"))
        rows.append(("  recorded track rows identical to offline", "yes" if stack.identical else "NO", ""))
    for result in lat:
        for what, hold, values in (("estimate (peer/*/estimate)", result.peer_lateness, result.estimates),
                                   ("track (tracks)", result.base_lateness, result.tracks)):
            name = f"latency event → {what}, {result.label}"
            if len(values.total):
                rows.append((name, _ms(values.total), f"ms p50 / p99 (n={len(values.total)})"))
                rows.append((f"  beyond the hold ({hold:g} s) and the tick that released it", _ms(values.beyond_tick),
                             "ms p50 / p99"))
            else:
                rows.append((name, "–", "none received"))
    rows += user
    width = max(len(r[0]) for r in rows)
    vwidth = max(len(r[1]) for r in rows)
    lines = [f"{'figure':<{width}}  {'value':>{vwidth}}  unit", "-" * (width + vwidth + 26)]
    lines += [f"{f:<{width}}  {v:>{vwidth}}  {u}" for f, v, u in rows]
    lines.append("")
    lines.append(f"ratio pipeline / raw Zenoh: {transitions_rate:,.0f} / {raw_median:,.0f} = "
                 f"{transitions_rate / raw_median:.4f} (1 : {raw_median / transitions_rate:,.0f})")
    lines.append(f"ratio bare chain / raw Zenoh: {bare_median:,.0f} / {raw_median:,.0f} = "
                 f"{bare_median / raw_median:.4f} (1 : {raw_median / bare_median:,.1f}); "
                 f"pipeline / bare chain: 1 : {bare_median / transitions_rate:,.1f}")
    lines.append("")
    lines.append(f"pipeline runs: {', '.join(f'{r.rate:,.0f}' for r in pipe.runs)} transitions/s; per transition "
                 "the bus carries 2 puts and 3 deliveries (raw → sensor_agent and recorder, transition → "
                 "recorder), plus per clock tick one put and two deliveries, and a progress report per service "
                 "every 8 ticks or 5 ms")
    lines.append(f"pipeline dataset: simulated darpa-grid, seed {PIPELINE_SCENARIO['seed']}, "
                 f"{PIPELINE_SCENARIO['people']} people, {PIPELINE_SCENARIO['duration']:g} s: {pipe.events} events "
                 f"(all transitions), {pipe.ticks} clock ticks of {FAST_PERIOD:g} s = "
                 f"{pipe.events / pipe.ticks:.1f} events per tick; recorded: {run.transitions} transitions, "
                 f"{run.raw} raw samples")
    cpu = ", ".join(f"{name} {value:.1f} s" if value is not None else f"{name} ?" for name, value in run.cpu.items())
    lines.append(f"pipeline CPU time of the median run (user + system, ~0.3 s start-up included): {cpu}; "
                 f"{os.cpu_count()} cores; load average before the benchmark {LOAD_BEFORE}")
    lines.append(f"latency dataset: first {LATENCY_SLICE:g} s of {LATENCY_SOURCE.relative_to(REPO)} "
                 "(replay --speed 1, tracker equal-weight)")
    lines.append(f"latency includes, by design, up to one clock period ({LIVE_PERIOD:g} s) plus the lateness hold "
                 f"(peer_agent --lateness {PEER_DEFAULT_LATENESS:g} s for an estimate, basestation --lateness "
                 f"{BASESTATION_DEFAULT_LATENESS:g} s for a track): a transition is released at the first tick T with "
                 "t < T − lateness once the upstream services reported progress to T. 'beyond' = receipt − when "
                 "that tick was due: what the bus and the services add. Outputs released only by the end-of-stream "
                 "flush are left out.")
    return "\n".join(lines)


def run(keep: Path | None, skip_stack: bool = False, stack_only: bool = False, user_only: bool = False) -> int:
    with tempfile.TemporaryDirectory(prefix="bintrack-bench-") as tmp:
        work = keep if keep is not None else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        endpoint = f"tcp/{LOOPBACK}:{free_port()}"
        say(f"router on {endpoint}; work folder {work}; load average {LOAD_BEFORE}")
        if os.getloadavg()[0] > 0.5:
            say("warning: this machine is busy with other work; the figures will be lower than on an idle machine")
        router = zenoh.open(router_config([endpoint]))
        children = Children(endpoint, work)
        session = None
        try:
            if stack_only:
                session = client_session(endpoint)
                stack = full_stack(children, session, work)
                print(f"full stack: {stack.span:.0f} s of event time in {stack.wall:.1f} s = {stack.speed:,.0f} × real "
                      f"time; CPU per 1 000 transitions: " + ", ".join(
                          f"{n} {c / stack.transitions * 1000:.3f} s" for n, c in stack.cpu.items() if c is not None)
                      + f"; offline {stack.span / stack.offline_cpu:,.0f} × real time; rows identical: {stack.identical}")
                return 0
            if user_only:
                session = client_session(endpoint)
                rows, _ = user_path(children, session, work, stack_data(work))
                width = max(len(r[0]) for r in rows)
                print("\n".join(f"{f:<{width}}  {v:>14}  {u}" for f, v, u in rows))
                print(f"load average before: {LOAD_BEFORE}; after: {' / '.join(f'{x:.2f}' for x in os.getloadavg())}")
                return 0
            payload = encode(Transition(t=123.456789, sensor="n123", value=1, previous=0, seq=17,
                                        source=f"{socket.gethostname()}-{os.getpid()}", source_seq=1234))
            say(f"1/5 raw Zenoh: {RAW_RUNS} runs of {RAW_MESSAGES:,} messages of {len(payload)} bytes")
            raw = raw_zenoh(endpoint, payload, RAW_MESSAGES, RAW_RUNS)

            session = client_session(endpoint)
            say("2/5 pipeline throughput")
            pipe = pipeline(children, session, work)

            say("3/5 full stack with mcmcda")
            data = None if skip_stack else stack_data(work)
            stack = None if skip_stack else full_stack(children, session, work, data)

            say("4/5 latency at --speed 1")
            sliced, _t_first, t_last = slice_dataset(LATENCY_SOURCE, LATENCY_SLICE, work / "latency-dataset")
            lat = [latency(children, session, sliced, t_last, label, peer, base, tag=f"latency{k}")
                   for k, (label, peer, base) in enumerate(LATENCY_RUNS, start=1)]
            user = [] if skip_stack else user_path(children, session, work, data)[0]
        finally:
            children.stop_all()
            if session is not None:
                session.close()
            router.close()
        say(f"done in {time.monotonic() - _started:.0f} s")
        print(table(raw, pipe, lat, len(payload), stack, user))
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keep", type=Path, metavar="DIR",
                        help="keep the datasets, the recording and the service logs in DIR")
    parser.add_argument("--no-stack", action="store_true", help="leave out the full-stack mcmcda run")
    parser.add_argument("--stack-only", action="store_true", help="only the full-stack mcmcda run")
    parser.add_argument("--user-only", action="store_true",
                        help="only the user's path (part 5), beside its three full-stack runs")
    args = parser.parse_args()
    # SIGTERM ends the run through the finally blocks, which stop every subprocess.
    signal.signal(signal.SIGTERM, _terminated)
    try:
        return run(args.keep, args.no_stack, args.stack_only, args.user_only)
    except KeyboardInterrupt:
        say("interrupted; subprocesses stopped")
        return 130
    except Terminated:
        say("terminated; subprocesses stopped")
        return 143
    except (RuntimeError, TimeoutError, ConnectionError) as exc:
        say(f"failed: {exc} (rerun with --keep DIR to keep the service logs)")
        return 1


class Terminated(Exception):
    """SIGTERM arrived."""


def _terminated(_signum, _frame) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # once: let the clean-up finish
    raise Terminated


if __name__ == "__main__":
    sys.exit(main())
