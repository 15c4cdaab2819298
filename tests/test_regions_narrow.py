"""Traffic by region (DESIGN §11): a region's sensor agent hears only its own sensors' raw
samples and its base station only the transitions of the sensors it takes (its own and its
border band's), over real routers on loopback (a hub on 127.0.0.1 with replay and the merge, a
site router on 127.0.0.2 for regions r0c0 and r0c1, another on 127.0.0.3 for r1c0 and r1c1);
and the merged rows are still the offline ones, ordered by the counts in the reports alone.
Each service says at its stop which sensors it heard samples of, by kind of key."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from bintrack.formats import TrackRow, open_dataset, read_tracks
from bintrack.regions import RegionMap

from test_fault_routers import region_field
from test_mesh import start_chain, stop_chain
from test_regions_live import merged_scans_of_a_replay

pytestmark = pytest.mark.slow

REGIONS = ["r0c0", "r0c1", "r1c0", "r1c1"]
SEED = 23  # a simulated 2 × 2 field; not a seed the merge's defaults were chosen on


def heard(log: str) -> dict[str, set[str]]:
    """kind → the sensors a service heard samples of (its summary line at the stop)."""
    line = next(line for line in log.splitlines() if ": heard " in line)
    return {m.group(1): set(m.group(3).split()) for m in re.finditer(r"; (\w+) of (\d+) sensors: ([^;]*)", line)}


def test_a_region_hears_its_own_raw_samples_and_its_bands_transitions_only(services, tmp_path):
    field, offline = region_field(tmp_path, "2x2", SEED)
    regions = RegionMap(open_dataset(field).deployment)
    routers = start_chain(tmp_path)
    hub, *sites = routers
    try:
        net = "darpa-grid"
        agents, stations = {}, {}
        for i, region in enumerate(REGIONS):
            router = sites[i // 2]
            agents[region] = services("sensor_agent", "--region", region, "--net", net, endpoint=router.listen)
            stations[region] = services("basestation", "--tracker", "mcmcda", "--region", region, "--net", net,
                                        endpoint=router.listen)
        merge = services("merge", "--net", net, endpoint=hub.listen)
        merged = merged_scans_of_a_replay(services, field, net, hub.listen, merge)
        live = [TrackRow(m.t, tr.track, tr.x, tr.y, tr.vx, tr.vy) for m in merged for tr in m.tracks]
        assert [(r.t, r.track) for r in live] == [(r.t, r.track) for r in offline]
        assert max(abs(a.x - b.x) + abs(a.y - b.y) for a, b in zip(live, offline)) < 1e-6
        for region in REGIONS:
            assert agents[region].stop() == 0 and stations[region].stop() == 0
    finally:
        stop_chain(routers)

    every = {s.id for s in regions.deployment.sensors}
    for region in REGIONS:
        own, taken = set(regions.own_sensors(region)), set(regions.taken_sensors(region))
        assert own < taken < every  # the band takes some of the others' sensors, not all
        agent, station = heard(agents[region].log), heard(stations[region].log)
        assert agent.get("raw") and agent["raw"] <= own, (region, sorted(agent.get("raw", set()) - own))
        assert set(agent) == {"raw"}, agent.keys()  # no transition, no other key of a sensor
        assert station.get("transition") and station["transition"] <= taken, \
            (region, sorted(station.get("transition", set()) - taken))
        assert station["transition"] - own, region  # its band's, heard from the neighbours' agents
        assert set(station) == {"transition"}, station.keys()
        # and the other regions' sensors did publish: what it did not hear was there to hear
        others = set().union(*(heard(agents[r].log)["raw"] for r in REGIONS if r != region))
        assert others - own
