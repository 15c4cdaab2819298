"""Faults in pairs: every pair of a stack's services SIGKILLed at once, mid-run, under ``bintrack
up``; each restarted service waits until the peers it fetches from have caught up. Each run ends
with the offline track rows, or with log lines naming every row it lost (the test holds their
count to the difference), and the recording never holds a track row twice."""

from __future__ import annotations

import itertools
import os
import random
import re
import signal

import pytest

from test_faults import Up, exported_tracks, grid_slice, offline_rows  # noqa: F401 (fixtures)

MCMCDA = ("sensor_agent", "basestation", "recorder", "replay")
PEERS = ("sensor_agent", "peer_agent", "basestation", "recorder", "replay")
LOST = re.compile(r"lost (\d+) track rows")


def kill_together(up: Up, victims: tuple[str, ...], at: float) -> None:
    """SIGKILL ``victims`` at once when event time reached ``at`` (s); wait for their restarts."""
    up.event_time_at_least(at)
    pids = [up.service_pid(victim) for victim in victims]
    for pid in pids:
        os.kill(pid, signal.SIGKILL)
    for victim in victims:
        up.wait_for(lambda line: line.startswith(f"up: {victim} killed by SIGKILL"), f"{victim}'s death logged")
        up.wait_for(lambda line: line.startswith(f"up: {victim} restarted"), f"{victim}'s restart logged")


def check_rows(up: Up, live: list, offline: list) -> None:
    """The live rows are the offline ones, but for rows the log names as lost (as many as it
    says), and none is recorded twice."""
    keyed = [(r.t, r.track) for r in live]
    assert len(keyed) == len(set(keyed)), f"{len(keyed) - len(set(keyed))} track rows recorded twice\n{up.log[-6000:]}"
    said = sum(int(m.group(1)) for m in map(LOST.search, up.lines) if m)
    missing = [r for r in offline if r not in set(live)]
    extra = [r for r in live if r not in set(offline)]
    assert not extra, f"{len(extra)} rows the offline run does not have, e.g. {extra[:3]}\n{up.log[-6000:]}"
    assert said == len(missing), f"{len(missing)} rows missing, the log names {said}\n{up.log[-6000:]}"


def kill_time(seed: int) -> float:
    """Where in the 20 s slice a seed's kill lands, s of event time: 4–14 s."""
    return round(random.Random(seed).uniform(4.0, 14.0), 2)


@pytest.mark.parametrize("victims", list(itertools.combinations(MCMCDA, 2)), ids="+".join)
@pytest.mark.parametrize("seed", [1, 2])
def test_mcmcda_pairs_killed_together_at_speed_0(grid_slice, offline_rows, victims, seed, tmp_path):
    recording = tmp_path / "run.mcap"
    up = Up(str(grid_slice), "--tracker", "mcmcda", "--speed", "0", "--clock-period", "0.05", "--record",
            str(recording), "--exit-at-end")
    kill_together(up, victims, kill_time(seed))
    assert up.finish() == 0, up.log[-4000:]
    check_rows(up, exported_tracks(recording, tmp_path), offline_rows("mcmcda"))
