"""The fault matrix under ``up --regions 2`` (tests/test_fault_pairs.py has the pairs of one
region's stack): each region's router SIGKILLed mid-run at ``--speed 0`` and ``2``, and the
merge and the recorder killed together. The merge waits for a region whose link went (replay
holds event time meanwhile) and fetches the scans it published while it was cut off; the
recorder fetches the merged track sets once the merge is done. Each run ends with the offline
``track --regions`` rows, or log lines naming every row lost; none is recorded twice."""

from __future__ import annotations

from pathlib import Path

import pytest

from bintrack.formats import read_tracks

from support import bintrack
from test_fault_pairs import FINE, check_rows, kill_time, kill_together
from test_faults import Up, children, cut, exported_tracks

SEED = 21  # a simulated field cut into two regions; not a seed the merge's defaults were chosen on


def region_field(folder: Path, regions: str, seed: int) -> tuple[Path, list]:
    """In ``folder``: the first 40 s of a simulated darpa-grid field cut into ``regions``
    (``simulate --regions``), and its offline rows (mcmcda by region, merged)."""
    bintrack("simulate", "darpa-grid", "--out", "whole", "--regions", regions, "--seed", str(seed), cwd=folder, check=True)
    field = cut(folder / "whole", folder / "field", 40.0)
    bintrack("track", str(field), "--tracker", "mcmcda", "--regions", "--out", "offline.csv", cwd=folder, check=True)
    return field, read_tracks(folder / "offline.csv")


@pytest.fixture(scope="module")
def regions_field(tmp_path_factory) -> tuple[Path, list]:
    """The first 40 s of a simulated darpa-grid field with two regions, and its offline rows."""
    return region_field(tmp_path_factory.mktemp("regions"), "2", SEED)


@pytest.mark.parametrize("victims, speed", [pytest.param(v, speed, id=f"{'+'.join(v)}-speed{speed}") for v, speed in (
    (("router-r0c0",), 0), (("router-r0c0",), 2), (("router-r0c1",), 0), (("router-r0c1",), 2),
    (("merge", "recorder"), 0), (("merge", "recorder"), 2))])
def test_a_region_router_or_the_merge_and_recorder_killed(regions_field, victims, speed, tmp_path):
    field, offline = regions_field
    recording = tmp_path / "run.mcap"
    fine = FINE if speed == 0 else ()
    up = Up(str(field), "--tracker", "mcmcda", "--regions", "2", "--speed", str(speed), *fine, "--record",
            str(recording), "--exit-at-end")

    def pid_of(victim: str) -> int:
        if not victim.startswith("router-"):
            return up.service_pid(victim)
        name = f"--name {victim.removeprefix('router-')} "
        pids = [pid for pid, cmd in children(up.proc.pid).items()
                if "bintrack.services.router" in cmd and name in cmd + " "]
        assert len(pids) == 1, (victim, children(up.proc.pid))
        return pids[0]

    kill_together(up, victims, kill_time(SEED + speed), pid_of)
    assert up.finish() == 0, up.log[-4000:]
    check_rows(up, exported_tracks(recording, tmp_path), offline)
