"""Faults in pairs, the fault matrix: every pair of the mcmcda stack's services SIGKILLed at once
mid-run under ``bintrack up``, at ``--speed 0`` (two seeds each) and ``--speed 2`` (a third), and
the sensor agent with the tracker at ``--speed 0``'s default clock period;
the peers' stack in tests/test_fault_peers.py, each router of ``--regions 2`` (at both speeds)
in tests/test_fault_routers.py.
A restarted service fetches what it missed only once the peer it fetches from has caught up, so
each run ends with the offline track rows, or with log lines naming every row it lost (their
count is held to the difference); the recording never holds a track row twice. A seed picks
where in event time the kill lands."""

from __future__ import annotations

import itertools
import os
import random
import re
import signal
from pathlib import Path

import pytest

from support import DATASETS
from test_faults import Up, cut, exported_tracks, offline_tracks

MCMCDA = ("sensor_agent", "basestation", "recorder", "replay")
LOST = re.compile(r"lost (\d+) track rows")
SPAN = 40.0  # s of darpa-grid-3: three people, 113 mcmcda rows
FINE = ("--clock-period", "0.1")  # at --speed 0, ticks that pace the slice over seconds (a kill lands mid-run)


@pytest.fixture(scope="module")
def field(tmp_path_factory) -> Path:
    return cut(DATASETS / "darpa-grid-3", tmp_path_factory.mktemp("pairs") / "darpa-grid-3", SPAN)


@pytest.fixture(scope="module")
def offline(field, tmp_path_factory):
    return offline_tracks(field, tmp_path_factory)


def kill_together(up: Up, victims: tuple[str, ...], at: float, pid_of=None) -> None:
    """SIGKILL ``victims`` at once when event time reached ``at`` (s); wait for their restarts."""
    up.event_time_at_least(at)
    pids = [(pid_of or up.service_pid)(victim) for victim in victims]
    for pid in pids:
        os.kill(pid, signal.SIGKILL)
    for victim in victims:
        up.wait_for(lambda line: line.startswith(f"up: {victim} killed by SIGKILL"), f"{victim}'s death logged")
        up.wait_for(lambda line: line.startswith(f"up: {victim} restarted"), f"{victim}'s restart logged")


def check_rows(up: Up, live: list, offline: list) -> None:
    """The live rows are the offline ones, but for rows the log names as lost (as many as it
    says); none is recorded twice, none is one the offline run does not give."""
    keys = [(r.t, r.track) for r in live]
    assert len(keys) == len(set(keys)), f"{len(keys) - len(set(keys))} track rows recorded twice\n{up.log[-6000:]}"
    extra = [r for r in live if r not in set(offline)]
    assert not extra, f"{len(extra)} rows the offline run does not give, e.g. {extra[:3]}\n{up.log[-6000:]}"
    missing = [r for r in offline if r not in set(live)]
    said = sum(int(m.group(1)) for m in map(LOST.search, up.lines) if m)
    assert said == len(missing), f"{len(missing)} rows missing, the log names {said}\n{up.log[-6000:]}"


def kill_time(seed: int, start: float = 12.0, end: float = 30.0) -> float:
    """Where a seed's kill lands, s of event time (while the tracks are there)."""
    return round(random.Random(seed).uniform(start, end), 2)


def run_with_a_kill(field: Path, tmp_path: Path, tracker: str, speed: float, victims, at: float,
                    *options: str, fine: bool = True) -> tuple[Up, list]:
    """``up`` of ``field`` recording, ``victims`` killed together at ``at`` s; (up, recorded rows).
    At ``--speed 0`` the clock ticks every 0.1 s unless not ``fine`` (then ``up``'s default)."""
    recording = tmp_path / "run.mcap"
    fine = FINE if speed == 0 and fine else ()
    up = Up(str(field), "--tracker", tracker, "--speed", str(speed), *fine, "--record", str(recording),
            "--exit-at-end", *options)
    kill_together(up, victims, at)
    assert up.finish() == 0, up.log[-4000:]
    return up, exported_tracks(recording, tmp_path)


# every pair at two seeds of its own at --speed 0 (where the kill lands), and at a third at --speed 2
PAIRS = list(itertools.combinations(MCMCDA, 2))
MCMCDA_PAIRS = [pytest.param(pair, seed, id=f"{'+'.join(pair)}-seed{seed}")
                for n, pair in enumerate(PAIRS) for seed in (n + 1, n + 1 + len(PAIRS))]


@pytest.mark.parametrize("victims, seed", MCMCDA_PAIRS)
def test_mcmcda_pairs_killed_together(field, offline, victims, seed, tmp_path):
    up, live = run_with_a_kill(field, tmp_path, "mcmcda", 0, victims, kill_time(seed))
    check_rows(up, live, offline("mcmcda"))


@pytest.mark.parametrize("victims, seed", [pytest.param(pair, n + 1 + 2 * len(PAIRS), id="+".join(pair))
                                           for n, pair in enumerate(PAIRS)])
def test_mcmcda_pairs_killed_together_at_speed_2(field, offline, victims, seed, tmp_path):
    up, live = run_with_a_kill(field, tmp_path, "mcmcda", 2, victims, kill_time(seed, 12.0, 20.0))
    check_rows(up, live, offline("mcmcda"))


@pytest.mark.parametrize("tracker, victims, seed", [
    pytest.param(tracker, victims, seed, id=f"{tracker}-{'+'.join(victims)}")
    for tracker, victims, seed in [("mcmcda", ("sensor_agent", "basestation"), 41),
                                   ("equal-weight", ("sensor_agent", "peer_agent"), 42)]])
def test_killed_with_the_sensor_agent_at_the_default_clock_period(field, offline, tracker, victims, seed, tmp_path):
    """At --speed 0 with the default clock period (0.5 s) replay may run 16 ticks, 8 s, ahead of
    the slowest acknowledgement: the tracker's throttled checkpoint (up to 8 s of ticks old)
    then lacks transitions up to 8 s older still, and the sensor agent may die 8 s ahead of the
    tracker's last tick. The sensor agent's checkpoint keeps what that asks for (it used to keep
    10 s, and the tracker restarted with it lost transitions no longer in its memory)."""
    up, live = run_with_a_kill(field, tmp_path, tracker, 0, victims, kill_time(seed, 6.0, 20.0), fine=False)
    assert "no longer in its memory" not in up.log, up.log[-4000:]
    check_rows(up, live, offline(tracker))


@pytest.mark.parametrize("tracker, victims", [("mcmcda", ("basestation",)), ("mcmcda", ("sensor_agent", "basestation")),
                                              ("equal-weight", ("basestation",)),
                                              ("equal-weight", ("peer_agent", "basestation"))])
def test_killed_after_the_end_of_stream_went_out(field, offline, tracker, victims, tmp_path):
    """Killed once replay has published its end: replay says it again to the restarted ones,
    the services downstream wait for them, and the run ends with the offline rows (it used to
    hang, or to end without the rows the killed ones still owed). On a loaded machine the whole
    chain can finish between the end's log line and the kill: then the killed ones had reported
    done, nothing is owed, and the run may end before up restarts them; the rows must be whole
    either way."""
    recording = tmp_path / "run.mcap"
    up = Up(str(field), "--tracker", tracker, "--speed", "0", *FINE, "--record", str(recording), "--exit-at-end")
    up.wait_for(lambda line: "replay: end of stream at t=" in line, "the end of stream")
    # the recorder paused, the run cannot end before up has seen the kills and the restarts
    recorder = up.service_pid("recorder")
    os.kill(recorder, signal.SIGSTOP)
    ended = "up: the end of the replay has been processed"
    try:
        for pid in [up.service_pid(victim) for victim in victims]:  # they live on after done, until up stops
            os.kill(pid, signal.SIGKILL)
        for victim in victims:
            line = up.wait_for(lambda line: line.startswith((f"up: {victim} restarted", ended)),
                               f"{victim}'s restart logged")
            if line.startswith(ended):
                break
    finally:
        os.kill(recorder, signal.SIGCONT)
    assert up.finish() == 0, up.log[-4000:]
    check_rows(up, exported_tracks(recording, tmp_path), offline(tracker))
