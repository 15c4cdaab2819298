"""The stack survives its faults and says so: `bintrack up` as a real process tree on a real
router; a service killed with SIGKILL mid-run is restarted and the run still ends with the
rows `bintrack track` gives offline (track identities included); SIGTERM on `up` leaves no
process behind.

Every wait is on an event (a line on up's stderr, a process's exit); the timeouts are only
there to fail a hung run, generously.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import tempfile
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import pytest
import zenoh

from bintrack.formats import TruthRow, open_dataset, read_tracks, write_dataset
from bintrack.live.session_options import client_config
from bintrack.live.control_guard import control_attachment
from bintrack.keys import Keys
from bintrack.bus_payloads import Clock, RawSample
from bintrack.message_codec import decode, encode
from bintrack.live.recording import open_recording
from bintrack.live.stack import stack_commands

from support import DATASETS, HUNG, REPO, bintrack, free_port, rss_kb, wait_logged

DARPA3 = DATASETS / "darpa-grid-3"


def cut(source: Path, out: Path, span: float) -> Path:
    """The first ``span`` s of dataset ``source``, written to ``out``."""
    ds = open_dataset(source)
    return write_dataset(out, ds.deployment, [e for e in ds.events() if e.t < span],
                         [TruthRow(*r) for r in ds.truth() if r.t < span])


def offline_tracks(dataset: Path, tmp_path_factory):
    """tracks.csv rows of `bintrack track` on ``dataset``, per tracker (each computed once)."""
    cache: dict[str, list] = {}

    def rows(tracker: str) -> list:
        if tracker not in cache:
            out = tmp_path_factory.mktemp("offline") / f"{tracker}.csv"
            result = bintrack("track", str(dataset), "--tracker", tracker, "--out", str(out))
            assert result.returncode == 0, result.stderr
            cache[tracker] = read_tracks(out)
        return cache[tracker]

    return rows


@pytest.fixture(scope="module")
def grid_slice(tmp_path_factory) -> Path:
    """The first 20 s of darpa-grid-3: three people, enough transitions for identities to matter."""
    return cut(DARPA3, tmp_path_factory.mktemp("slice") / "darpa-grid-3", 20.0)


@pytest.fixture(scope="module")
def offline_rows(grid_slice, tmp_path_factory):
    return offline_tracks(grid_slice, tmp_path_factory)


def children(pid: int) -> dict[int, str]:
    """pid → command line of the processes whose parent is ``pid`` (from /proc)."""
    found = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            if ppid == pid:
                found[int(entry)] = Path(f"/proc/{entry}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, ValueError, IndexError):
            continue
    return found


def alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


class Up:
    """`bintrack up` in a subprocess; its stderr is read line by line on a thread, and tests
    wait for a line that satisfies a condition."""

    def __init__(self, *args: str, scheme: str = "tcp"):
        self.endpoint = f"{scheme}/127.0.0.1:{free_port()}"
        self.proc = subprocess.Popen([sys.executable, "-m", "bintrack.cli", "up", *args, "--no-view",
                                      "--listen", self.endpoint, "--progress-interval", "0.2"],
                                     stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, cwd=REPO)
        self.lines: list[str] = []
        self.changed = threading.Condition()
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        for line in self.proc.stderr:
            with self.changed:
                self.lines.append(line.rstrip("\n"))
                self.changed.notify_all()
        with self.changed:
            self.lines.append("<eof>")
            self.changed.notify_all()

    @property
    def log(self) -> str:
        return "\n".join(self.lines)

    def wait_for(self, condition, what: str) -> str:
        """The first line (from the start) for which ``condition(line)`` holds."""
        seen = 0
        with self.changed:
            while True:
                for line in self.lines[seen:]:
                    if condition(line):
                        return line
                    if line == "<eof>":
                        raise AssertionError(f"up ended before {what}:\n{self.log[-4000:]}")
                seen = len(self.lines)
                assert self.changed.wait(HUNG), f"no {what} within {HUNG} s:\n{self.log[-4000:]}"

    def event_time_at_least(self, t: float) -> None:
        def reached(line: str) -> bool:
            if not line.startswith("up: t="):
                return False
            value = line[len("up: t="):].split("s")[0].strip()
            return value != "-" and float(value) >= t
        self.wait_for(reached, f"event time {t} s")

    def service_pid(self, name: str) -> int:
        """The pid of this run's service ``name``. There is no event for a process appearing in
        /proc, so it is looked up until it is there (once, in CI, the first look after "router
        on" missed a service that the second found), for at most HUNG s."""
        deadline = time.monotonic() + HUNG
        while True:
            found = children(self.proc.pid)
            pids = [pid for pid, cmd in found.items() if f"--id up{self.proc.pid}-{name} " in cmd + " "]
            if len(pids) == 1:
                return pids[0]
            if time.monotonic() > deadline or self.proc.poll() is not None:
                raise AssertionError(f"no single process of {name} among {found}:\n{self.log[-4000:]}")
            time.sleep(0.02)

    def finish(self) -> int:
        """up's exit status; a run that has not ended within HUNG s is stopped (SIGTERM, as
        Ctrl-C would) and fails with its log."""
        try:
            code = self.proc.wait(timeout=HUNG)
        except subprocess.TimeoutExpired:
            self.proc.terminate()
            self.proc.wait(timeout=HUNG)
            self.reader.join(timeout=HUNG)
            kept = Path(tempfile.gettempdir()) / f"bintrack-up-hung-{self.proc.pid}.log"
            kept.write_text(self.log)
            raise AssertionError(f"up did not end within {HUNG} s (its whole log: {kept}):\n"
                                 f"{self.log[-8000:]}") from None
        self.reader.join(timeout=HUNG)
        return code


def exported_tracks(recording: Path, tmp: Path) -> list:
    out = tmp / "exported.csv"
    result = bintrack("export", str(recording), "--what", "tracks", "--out", str(out))
    assert result.returncode == 0, result.stderr
    return read_tracks(out)


REAL_TIME = pytest.mark.slow


@contextmanager
def kills_on_the_clock(endpoint: str, net: str, due: list[tuple[float, int]]):
    """SIGKILL each (t, pid) of ``due`` (t ascending) on the first clock tick of ``net`` (read
    through ``endpoint``) at or past t s of event time: up's progress lines come 0.2 s apart,
    and at --speed 0 a run can reach its end between two of them, before a kill seen from them
    lands. Yields an event set once all are killed; the subscription ends with the block."""
    due = list(due)
    killed = threading.Event()

    def on_clock(sample) -> None:
        t = decode(Clock, sample.payload.to_bytes()).t
        while due and due[0][0] <= t:
            os.kill(due.pop(0)[1], signal.SIGKILL)
        if not due:
            killed.set()

    session = zenoh.open(client_config([endpoint]))
    subscriber = session.declare_subscriber(Keys(net).clock(), on_clock)
    try:
        yield killed
    finally:
        subscriber.undeclare()
        session.close()


@pytest.mark.parametrize("tracker, victims, speed", [
    ("mcmcda", ["sensor_agent"], 0),
    ("mcmcda", ["basestation"], 0),
    ("equal-weight", ["peer_agent"], 0),
    ("mcmcda", ["replay"], 0),
    ("mcmcda", ["recorder"], 0),
    ("mcmcda", ["sensor_agent", "replay"], 0),  # both restarting at once: each waits for the other
    pytest.param("mcmcda", ["sensor_agent", "basestation", "replay", "recorder"], 1, marks=REAL_TIME),
    pytest.param("equal-weight", ["peer_agent"], 1, marks=REAL_TIME),
])
def test_services_killed_mid_run_lose_only_what_is_logged(grid_slice, offline_rows, tracker, victims, speed,
                                                          tmp_path):
    """A service is SIGKILLed mid-run (at 8 s of event time; at --speed 1 every kind in turn, at
    4, 8, 12 and 16 s; the sensor agent and replay also both at once). Replay holds event time while one is
    gone (its pacing too, at --speed 1) and a restarted service resumes from its checkpoint and
    fetches what it missed, so the track sets, identities included, are the offline ones at
    either speed. What a killed recorder loses (the other messages of its open chunk; track sets
    are fetched back) is logged with its span, which the recorder's flush interval bounds."""
    from bintrack.live.recording_files import FLUSH_INTERVAL, FLUSH_SPAN

    recording = tmp_path / "run.mcap"
    # at --speed 0 the default 0.5 s ticks play the 20 s slice in a fraction of a second; 0.01 s
    # ticks pace it over about two seconds
    fine = ("--clock-period", "0.01") if speed == 0 else ()
    up = Up(str(grid_slice), "--tracker", tracker, "--speed", str(speed), *fine, "--record", str(recording),
            "--exit-at-end")
    up.wait_for(lambda line: line.startswith("up: router on"), "the services started")
    due = [(8.0 if speed == 0 else 4.0 * (n + 1), up.service_pid(victim)) for n, victim in enumerate(victims)]
    with kills_on_the_clock(up.endpoint, open_dataset(grid_slice).deployment.name, due) as killed:
        assert killed.wait(HUNG), up.log[-4000:]
    for victim in victims:
        up.wait_for(lambda line: line.startswith(f"up: {victim} killed by SIGKILL"), f"{victim}'s death logged")
        up.wait_for(lambda line: line.startswith(f"up: {victim} restarted"), f"{victim}'s restart logged")
    assert up.finish() == 0, up.log[-4000:]
    assert exported_tracks(recording, tmp_path) == offline_rows(tracker), up.log[-6000:]
    if "recorder" in victims:
        gap = up.wait_for(lambda line: "recorder: recording again from t=" in line, "the recorder's loss logged")
        resumed = float(gap.split("recording again from t=")[1].split(" s")[0])
        lost_from = float(gap.split("published between t=")[1].split(" s")[0])
        bound = FLUSH_SPAN if speed == 0 else min(FLUSH_SPAN, FLUSH_INTERVAL * speed)
        assert 0.0 <= resumed - lost_from <= bound + 2.0, gap


def test_sigterm_on_up_leaves_no_process_behind(grid_slice):
    up = Up(str(grid_slice), "--tracker", "mcmcda", "--speed", "1")
    up.event_time_at_least(2.0)
    pids = list(children(up.proc.pid))
    assert len(pids) == 3, children(up.proc.pid)  # sensor agent, base station, replay
    up.proc.send_signal(signal.SIGTERM)
    assert up.finish() == 128 + signal.SIGTERM
    assert "SIGTERM received; stopping" in up.log
    assert [pid for pid in pids if alive(pid)] == []  # reaped by up before it exited


def wait_gone(pid: int, timeout: float) -> bool:
    """Wait for ``pid`` (not necessarily our child) to end, on its pidfd; True if it did."""
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        return True
    try:
        return bool(select.select([fd], [], [], timeout)[0])
    finally:
        os.close(fd)


def test_services_end_when_up_is_killed(grid_slice):
    """SIGKILL gives up no chance to stop them: they end by themselves (parent-death signal)."""
    up = Up(str(grid_slice), "--tracker", "mcmcda", "--speed", "1")
    up.event_time_at_least(2.0)
    pids = list(children(up.proc.pid))
    assert len(pids) == 3
    up.proc.kill()
    up.finish()
    assert [pid for pid in pids if not wait_gone(pid, HUNG)] == []


ROUTER = """
import signal, sys, zenoh
from bintrack.live.session_options import router_config
router = zenoh.open(router_config([sys.argv[1]]))
print("router up", flush=True)
signal.sigwait({signal.SIGTERM, signal.SIGINT})
router.close()
"""


def start_router(endpoint: str) -> subprocess.Popen:
    """A Zenoh router in a process of its own (to be killed), once it listens."""
    proc = subprocess.Popen([sys.executable, "-c", ROUTER, endpoint], stdout=subprocess.PIPE, text=True, cwd=REPO)
    assert proc.stdout.readline().strip() == "router up"
    return proc


@pytest.mark.parametrize("speed", [0, pytest.param(1, marks=pytest.mark.slow)])
def test_router_killed_and_restarted_loses_nothing(grid_slice, offline_rows, tmp_path, services, speed):
    """Services started by hand on a router of their own; the router is killed mid-run and
    started again: every service logs the loss and the return, replay holds its clock
    meanwhile (at --speed 1 too: pacing resumes where it stopped, so the outage makes nothing
    unknowable), and the run ends with the offline rows."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    net = open_dataset(grid_slice).deployment.name
    recording = tmp_path / "run.mcap"
    router = start_router(endpoint)
    procs = {c.name: services(c.name, *[a for a in c.args if a != "-e" and a != "tcp/router:7447"],
                              endpoint=endpoint)
             for c in stack_commands(tracker="mcmcda", endpoint="tcp/router:7447", net=net, source=str(grid_slice),
                                     speed=speed, record=str(recording))}
    try:
        with kills_on_the_clock(endpoint, net, [(10.0, router.pid)]) as killed:  # the router, at 10 s
            assert killed.wait(HUNG), procs["replay"].log
            router.wait()
            for proc in procs.values():
                wait_logged(proc, lambda log: "lost its router" in log, f"{proc.name} logging the loss")
            router = start_router(endpoint)
            for proc in procs.values():
                wait_logged(proc, lambda log: "reached again" in log, f"{proc.name} logging the return")
            assert procs["replay"].wait(HUNG) == 0, procs["replay"].log
            assert procs["recorder"].wait(HUNG) == 0, procs["recorder"].log
    finally:
        router.terminate()
        router.wait()
    assert "holding event time" in procs["replay"].log
    assert exported_tracks(recording, tmp_path) == offline_rows("mcmcda"), "\n".join(
        p.log[-3000:] for p in procs.values())


BURSTS = 8


def test_oversized_payloads_are_refused_unread_and_memory_stays_flat(zenoh_router, services, tmp_path):
    """Eight bursts of two 10 MB payloads on a sensor's raw key: refused before decoding with
    one line and counted; the service goes on, and its memory does not grow with the bursts.
    The first bursts size Zenoh's receive buffers (about 20 MB, and the allocator may keep one
    more buffer a little later), so the bound is on the last six: below 2.5 payloads, where
    keeping what was refused would be 120 MB."""
    ds = open_dataset(DARPA3)
    keys = Keys(ds.deployment.name)
    session = zenoh.open(client_config([zenoh_router]))
    progress = threading.Event()
    transitions = []
    entities = [
        session.declare_queryable(keys.deployment(), lambda q: q.reply(keys.deployment(), encode(ds.deployment))),
        session.declare_subscriber(keys.progress(), lambda s: progress.set()),
        session.declare_subscriber(keys.transition(), lambda s: transitions.append(str(s.key_expr))),
        # the test plays the replay's part: its clock comes from a replay token's holder
        session.liveliness().declare_token(keys.alive("replay", "test")),
    ]
    control = control_attachment("replay", "test")
    agent = services("sensor_agent", "--net", keys.net, endpoint=zenoh_router)
    try:
        wait_logged(agent, lambda log: "ready on" in log, "the sensor agent to come up")
        sensor = ds.deployment.sensors[0].id
        rss = []
        for burst in range(BURSTS):
            rss.append(rss_kb(agent.proc.pid))
            # every put blocking, as replay's: with the default (drop), Zenoh drops a put that finds
            # the queue still full of the 20 MB, here or at the router, and the tick never comes
            block = zenoh.CongestionControl.BLOCK
            for _ in range(2):
                session.put(keys.raw(sensor), b"\x00" * (10 * 1024 * 1024), congestion_control=block)
            session.put(keys.raw(sensor), encode(RawSample(t=1.0 + burst, sensor=sensor, value=(burst + 1) % 2)),
                        congestion_control=block)
            progress.clear()
            session.put(keys.clock(), encode(Clock(t=1.5 + burst)), attachment=control, congestion_control=block)
            assert progress.wait(HUNG), agent.log
        rss.append(rss_kb(agent.proc.pid))
        before, after = rss[2], rss[-1]
    finally:
        for entity in entities:
            entity.undeclare()
        session.close()
    assert transitions == [keys.transition(sensor)] * BURSTS  # the good samples after them were taken
    assert agent.stop() == 0
    lines = [line for line in agent.log.splitlines() if "dropped a bad payload" in line]
    assert len(lines) == 1 and f"too large: {10 * 1024 * 1024} bytes > 65536 (refused unread)" in lines[0], agent.log
    assert f"{2 * BURSTS} bad payloads {{'too large': {2 * BURSTS}}}" in agent.log
    assert after - before < 25 * 1024, (rss, agent.log)  # kB


def test_recorder_splits_its_files_by_event_time(grid_slice, zenoh_router, services, tmp_path):
    """--split-duration 5: the 20 s slice goes into run.mcap, run_1.mcap, … each finalised,
    each spanning at most 5 s of clock ticks, and together holding every raw sample once."""
    out = tmp_path / "run.mcap"
    net = open_dataset(grid_slice).deployment.name
    recorder = services("recorder", "--out", str(out), "--split-duration", "5", "--net", net, endpoint=zenoh_router)
    replay = services("replay", str(grid_slice), "--speed", "0", "--wait-for", "recorder", endpoint=zenoh_router)
    assert replay.wait(HUNG) == 0, replay.log
    assert recorder.wait(HUNG) == 0, recorder.log
    parts = [out] + sorted(tmp_path.glob("run_*.mcap"), key=lambda p: int(p.stem.split("_")[1]))
    assert [p.name for p in parts] == ["run.mcap"] + [f"run_{k}.mcap" for k in range(1, len(parts))]
    assert len(parts) >= 4, recorder.log
    raw = 0
    for part in parts:
        recording = open_recording(part)
        assert recording.complete, part
        ticks = [r.t for r in recording.records() if r.kind == "clock"]
        assert ticks and ticks[-1] - ticks[0] <= 5.0, (part, ticks[0], ticks[-1])
        raw += sum(r.kind == "raw" for r in recording.records())
    assert raw == sum(1 for _ in open_dataset(grid_slice).events())


def test_checkpoints_of_another_run_are_discarded(grid_slice, offline_rows, tmp_path, zenoh_router, services):
    """The compose way: every service with a fixed --id and one --state-dir. A second run on
    the same folder after replay's checkpoint is gone (a new run) must not resume what the
    first run left: the others log it and start afresh, and the rows are the offline ones."""
    state = tmp_path / "state"
    state.mkdir(mode=0o700)
    net = open_dataset(grid_slice).deployment.name
    for run in (1, 2):
        recording = tmp_path / f"run{run}.mcap"
        procs = {c.name: services(c.name, *[a for a in c.args if a not in ("-e", "tcp/router:7447")],
                                  endpoint=zenoh_router)
                 for c in stack_commands(tracker="mcmcda", endpoint="tcp/router:7447", net=net,
                                         source=str(grid_slice), speed=0, record=str(recording),
                                         state_dir=str(state))}
        assert procs["replay"].wait(HUNG) == 0, procs["replay"].log
        assert procs["recorder"].wait(HUNG) == 0, procs["recorder"].log
        for name in ("sensor_agent", "basestation"):
            assert procs[name].stop() == 0, procs[name].log
        assert exported_tracks(recording, tmp_path) == offline_rows("mcmcda"), procs["basestation"].log
        if run == 1:
            assert sorted(p.name for p in state.iterdir()) == [
                f"{name}-{name}.pickle" for name in ("basestation", "recorder", "replay", "sensor_agent")]
            (state / "replay-replay.pickle").unlink()
        else:
            for name in ("basestation", "sensor_agent"):
                assert "is of another run" in procs[name].log, procs[name].log
