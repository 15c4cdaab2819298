"""Sites on hosts of their own (``bintrack up --regions N --hosts``): each region's router and
services in a Linux network namespace, linked by veth pairs and a bridge on 198.19.K.0/24. The
merged tracks over four hosts are the offline ``bintrack track --regions`` rows; every namespace
and link a run made is gone after it ends, fails, or is stopped with SIGTERM. Where namespaces
cannot be made (not root, no ``ip``) these tests skip with one line; that ``up --hosts`` then
refuses in one line is tested everywhere.
"""

from __future__ import annotations

import ipaddress
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh

from bintrack.bus_payloads import TrackSet
from bintrack.formats import open_dataset
from bintrack.hosts.netns import NetnsError, ip, namespaces, unavailable
from bintrack.hosts.site_network import PREFIX, SiteNetwork, leftovers
from bintrack.hosts.site_stack import SiteStack
from bintrack.keys import Keys
from bintrack.live.session_options import client_config
from bintrack.message_codec import decode

from support import HUNG, REPO, bintrack, free_port, wait_logged
from test_fault_routers import region_field
from test_faults import Up, children, exported_tracks

SEED = 21  # a simulated 2 × 2 field; not a seed the merge's defaults were chosen on
LAN = ipaddress.IPv4Network("198.18.0.0/15")
needs_namespaces = pytest.mark.skipif(unavailable() is not None, reason=f"no network namespaces: {unavailable()}")


@pytest.fixture(scope="module")
def regions_field(tmp_path_factory) -> tuple[Path, list]:
    """The first 40 s of a simulated darpa-grid field cut into 2 × 2 regions, and its offline rows."""
    return region_field(tmp_path_factory.mktemp("hosts"), "2x2", SEED)


def made_by(tag: str) -> list[str]:
    """The namespaces and interfaces of this machine that the run of ``tag`` (bthost<K>) made."""
    return [name for name in leftovers() if name == tag or name.startswith(f"{tag}-")]


def addresses(namespace: str | None) -> list[tuple[str, str]]:
    """(interface, address) of every address in ``namespace`` (None: this machine's), loopback aside."""
    found = []
    for link in json.loads(ip("-j", "address", "show", namespace=namespace) or "[]"):
        if link["ifname"] != "lo":
            found += [(link["ifname"], a["local"]) for a in link.get("addr_info", [])]
    return found


def hosts_tag(up: Up) -> str:
    """The bthost<K> of ``up``'s run, from its ``up: hosts:`` line."""
    line = up.wait_for(lambda line: line.startswith("up: hosts:"), "the hosts line")
    return line.split("linked to this machine's ")[1].split()[0]


def recorded_run_past_ten_seconds(field: Path, tmp_path: Path) -> tuple[Up, Path, str]:
    """``up --regions 4 --hosts --speed 2`` of ``field``, recording; (up, the recording, its
    bthost<K>) once event time has passed 10 s."""
    recording = tmp_path / "run.mcap"
    up = Up(str(field), "--tracker", "mcmcda", "--regions", "4", "--hosts", "--speed", "2", "--record",
            str(recording), "--exit-at-end")
    tag = hosts_tag(up)
    up.event_time_at_least(10.0)
    return up, recording, tag


@needs_namespaces
def test_up_on_four_hosts_gives_the_offline_rows_and_removes_its_network(regions_field, tmp_path):
    field, offline = regions_field
    recording = tmp_path / "run.mcap"
    up = Up(str(field), "--tracker", "mcmcda", "--regions", "4", "--hosts", "--speed", "0", "--record",
            str(recording), "--exit-at-end", "--mesh-lease", "3000")
    tag = hosts_tag(up)
    # each site's router and services run in its namespace; every address made is in 198.18.0.0/15
    up.wait_for(lambda line: "router r1c1: router " in line, "the last site's router in the mesh")
    sites = [f"{tag}-{region}" for region in ("r0c0", "r0c1", "r1c0", "r1c1")]
    assert set(made_by(tag)) == {tag, f"{tag}-switch", *sites}
    made = [a for ns in (None, *sites) for a in addresses(ns) if ns is not None or a[0] == tag]
    assert len(made) == 5 and all(ipaddress.IPv4Address(a) in LAN for _, a in made), made
    for region, namespace in zip(("r0c0", "r0c1", "r1c0", "r1c1"), sites):
        in_site = subprocess.run(["ip", "netns", "pids", namespace], capture_output=True, text=True).stdout.split()
        commands = [children(up.proc.pid).get(int(pid), "") for pid in in_site]
        assert sum(f"--region {region}" in c or f"--name {region}" in c for c in commands) == 3, commands
        assert any(f"--name {region}" in c and "transport/link/tx/lease:3000" in c for c in commands), commands
    assert up.finish() == 0, up.log[-4000:]
    assert made_by(tag) == []
    live = exported_tracks(recording, tmp_path)
    assert [(r.t, r.track) for r in live] == [(r.t, r.track) for r in offline], up.log[-6000:]
    assert max(abs(a.x - b.x) + abs(a.y - b.y) for a, b in zip(live, offline)) < 1e-6


@needs_namespaces
def test_sigterm_on_up_removes_every_namespace_and_link(regions_field):
    field, _ = regions_field
    up = Up(str(field), "--tracker", "mcmcda", "--regions", "4", "--hosts", "--speed", "1")
    tag = hosts_tag(up)
    up.event_time_at_least(1.0)
    pids = list(children(up.proc.pid))
    up.proc.send_signal(signal.SIGTERM)
    assert up.finish() == 128 + signal.SIGTERM, up.log[-3000:]
    assert made_by(tag) == []
    assert [pid for pid in pids if Path(f"/proc/{pid}").exists()] == []


@needs_namespaces
def test_a_site_network_that_fails_half_made_is_removed():
    switches = [n for n in namespaces() if n.startswith(PREFIX) and n.endswith("-switch")]
    network = SiteNetwork(["half", "x" * 300])  # the second site's namespace cannot be named so
    with pytest.raises(NetnsError):
        network.create()
    assert network.k is None  # its subnet released
    assert [n for n in leftovers() if n.endswith("-half")] == []
    assert [n for n in namespaces() if n.startswith(PREFIX) and n.endswith("-switch")] == switches


UP_HOSTS = ("up", "datasets/darpa-grid-3-sites", "--tracker", "mcmcda", "--regions", "2", "--hosts", "--no-map")


def test_up_hosts_without_the_ip_command_says_so_in_one_line(tmp_path):
    result = bintrack(*UP_HOSTS, env={**os.environ, "PATH": str(tmp_path)})  # no ip on this PATH
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "bintrack up: error: --hosts: the ip command (iproute2) is not installed"], result.stderr


@pytest.mark.skipif(os.geteuid() != 0 or shutil.which("setpriv") is None, reason="needs root and setpriv to drop it")
def test_up_hosts_as_a_user_who_is_not_root_says_so_in_one_line():
    import sys

    nobody = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", sys.executable]
    if subprocess.run([*nobody, "-c", "import bintrack"], capture_output=True, cwd=REPO, timeout=HUNG).returncode:
        pytest.skip("user 65534 cannot read this checkout (a folder above it is private, as mktemp -d makes it)")
    result = subprocess.run([*nobody, "-m", "bintrack.cli", *UP_HOSTS], capture_output=True, text=True, cwd=REPO,
                            timeout=HUNG)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "bintrack up: error: --hosts: network namespaces need root (run as root, or without --hosts)"], result.stderr


# ------------------------------------------------------------------ faults across hosts

REGIONS = ("r0c0", "r0c1", "r1c0", "r1c1")
NET = "darpa-grid"
CUT = 10.0  # s the link stays down
# s a healed mesh may take to carry a cut site's token again (its lease is 1 s, its routers redial
# within 4 s); longer is a partition that did not heal, not a slow machine
HEAL_BOUND = 60.0


def set_link(tag: str, site: int, state: str) -> None:
    """Site ``site``'s cable at the switch of run ``tag``: "down" (pulled) or "up"."""
    ip("link", "set", "dev", f"p{site}", state, namespace=f"{tag}-switch")


def lines_with(up: Up, text: str) -> list[str]:
    return [line for line in up.lines if text in line]


@needs_namespaces
@pytest.mark.slow
def test_a_site_cut_off_for_ten_seconds_loses_nothing(regions_field, tmp_path):
    """Site r1c1's link is taken down for 10 s mid-run (``ip link set … down`` on its bridge
    port) and brought up again. The routers at the other end log the link's loss naming the
    site's address, the merge logs its region's base station gone, and replay holds event time
    while the site's services are out of reach (so nothing is shown past the last scan: no
    track turns stale). After the heal the site's sensor agent takes from replay the raw samples
    published while it was cut off, the base stations fetch the transitions that never arrived
    and the merge the region's scans, each saying how many: the run ends with the offline rows,
    identities included."""
    field, offline = regions_field
    up, recording, tag = recorded_run_past_ten_seconds(field, tmp_path)
    site = f"{tag}-r1c1"
    address = ip("-j", "address", "show", "dev", "uplink", namespace=site)
    address = json.loads(address)[0]["addr_info"][0]["local"]
    set_link(tag, 3, "down")
    up.wait_for(lambda line: f" left (tcp/{address}:" in line, "a router naming the lost site")
    up.wait_for(lambda line: "region r1c1's base station is gone" in line, "the merge logging the region gone")
    up.wait_for(lambda line: "replay: " in line and "holding event time" in line, "replay holding event time")
    time.sleep(CUT)  # the fault itself: the link stays down this long
    set_link(tag, 3, "up")
    back = up.wait_for(lambda line: "region r1c1's base station is back" in line, "the region back at the merge")
    taken = up.wait_for(lambda line: "replay was out of reach" in line, "the sensor agent's catch-up")
    assert up.finish() == 0, up.log[-4000:]
    assert taken.endswith("; none was lost"), taken
    live = exported_tracks(recording, tmp_path)
    assert [(r.t, r.track) for r in live] == [(r.t, r.track) for r in offline], up.log[-6000:]
    assert max(abs(a.x - b.x) + abs(a.y - b.y) for a, b in zip(live, offline)) < 1e-6
    print(f"\ncut of r1c1 for {CUT:g} s: {taken.split(': ', 1)[1]}; {back.split(': ', 1)[1]}; "
          + "; ".join(line.split(" ", 1)[1] for line in lines_with(up, "fetched from the sensors' state")))


def site_stack(field: Path, log_dir: Path, **options) -> SiteStack:
    """The stack of ``up --regions 4 --hosts`` on ``field``, process by process (on a port no
    other test is handed)."""
    return SiteStack(list(REGIONS), str(field), NET, log_dir, port=free_port(), **options)


@needs_namespaces
@pytest.mark.slow
def test_a_whole_site_killed_and_restarted_loses_nothing(regions_field, tmp_path):
    """Every process of site r0c1 (its router, sensor agent and base station) is SIGKILLed at
    once mid-run, as when its host loses power; ``up`` restarts each in the site's namespace,
    they resume from their checkpoints and fetch what they missed, and the run ends with the
    offline rows."""
    field, offline = regions_field
    up, recording, tag = recorded_run_past_ten_seconds(field, tmp_path)
    pids = ip("netns", "pids", f"{tag}-r0c1").split()
    assert len(pids) == 3, pids
    for pid in pids:
        os.kill(int(pid), signal.SIGKILL)
    for name in ("router-r0c1", "sensor_agent-r0c1", "basestation-r0c1"):
        up.wait_for(lambda line: line.startswith(f"up: {name} restarted"), f"{name}'s restart")
    assert up.finish() == 0, up.log[-4000:]
    assert made_by(tag) == []
    live = exported_tracks(recording, tmp_path)
    assert [(r.t, r.track) for r in live] == [(r.t, r.track) for r in offline], up.log[-6000:]
    assert max(abs(a.x - b.x) + abs(a.y - b.y) for a, b in zip(live, offline)) < 1e-6


@pytest.fixture(scope="module")
def clock_offset(tmp_path_factory) -> Path:
    """A preload library that shifts CLOCK_REALTIME (and gettimeofday) by $CLOCK_OFFSET_NS, built
    from tests/data/clock_offset.c: a host whose clock is off. (libfaketime 0.9.10, Debian's,
    breaks Python's timed waits: EINVAL from sleeps with its monotonic clock left alone, a hang in
    ``Event.wait`` without.)"""
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        pytest.skip("no C compiler (cc) to build the clock-offset preload")
    library = tmp_path_factory.mktemp("clock") / "clock_offset.so"
    subprocess.run([compiler, "-shared", "-fPIC", "-O2", "-o", str(library), str(REPO / "tests/data/clock_offset.c"),
                    "-ldl"], check=True, capture_output=True)
    return library


def realtime_lead(env: dict[str, str], namespace: str) -> float:
    """How far CLOCK_REALTIME is ahead of CLOCK_TAI in ``namespace`` under ``env``, s (read in one
    process, so no time passes between the two)."""
    code = "import time; print(time.time() - time.clock_gettime(time.CLOCK_TAI))"
    argv = ["ip", "netns", "exec", namespace, "env", *(f"{k}={v}" for k, v in env.items()), sys.executable, "-c", code]
    return float(subprocess.run(argv, capture_output=True, text=True, check=True).stdout)


@needs_namespaces
@pytest.mark.slow
def test_sites_whose_clocks_are_off_by_half_a_second_give_the_same_rows(regions_field, clock_offset, tmp_path):
    """Site r0c1's clock runs 0.5 s ahead of the hub's and site r1c0's 0.5 s behind (their
    routers and services see CLOCK_REALTIME shifted). Event time is the replay's, carried in
    every message, and no service reads a wall clock to order or place anything: the merged
    rows are the offline ones. (What the offset does change: a site's router stamps the samples
    of its services with its own clock, so Zenoh's timestamps from r0c1 are 0.5 s ahead; bintrack
    does not read them.)"""
    field, offline = regions_field
    shifted = {region: {"LD_PRELOAD": str(clock_offset), "CLOCK_OFFSET_NS": str(ns)}
               for region, ns in (("r0c1", 500_000_000), ("r1c0", -500_000_000))}
    recording = tmp_path / "run.mcap"
    stack = site_stack(field, tmp_path, speed=0.0, record=recording, site_env=shifted)
    try:
        here = realtime_lead({}, stack.network.namespace("r0c0"))
        for region, shift in (("r0c1", 0.5), ("r1c0", -0.5)):
            lead = realtime_lead(shifted[region], stack.network.namespace(region)) - here
            assert abs(lead - shift) < 0.01, (region, lead)
        wait_logged(stack.procs["recorder"], "messages recorded", "the recording closed")
        assert stack.procs["replay"].proc.wait(timeout=HUNG) == 0, stack.procs["replay"].log[-3000:]
    finally:
        stack.stop()
    live = exported_tracks(recording, tmp_path)
    assert [(r.t, r.track) for r in live] == [(r.t, r.track) for r in offline]
    assert max(abs(a.x - b.x) + abs(a.y - b.y) for a, b in zip(live, offline)) < 1e-6


@needs_namespaces
@pytest.mark.slow
def test_a_site_cut_off_while_event_time_goes_on_turns_stale_and_names_every_loss(regions_field, tmp_path):
    """As sensors in the field would, event time goes on while a site is cut off: replay (at
    real time, ``--no-hold``) waits for every site's services at the start only. The site whose
    region has a track at t = 12 s is cut off for 10 s. The merge logs its base station gone
    and, 2 s of event time later, shows its tracks stale; the other regions go on. After the
    heal every loss is named in a log line: the site's sensor agent takes from replay the raw
    samples it still holds (the last 30 s of event time: all of them here) and counts any it no
    longer held (that count is the dataset's, between the times it names); the merge names the
    region's scans that came after their time was merged; the other base stations name the
    transitions that came after their watermark. Before the first loss named the rows are the offline ones,
    and the identities shown stale are shown again, live, after the heal."""
    field, offline = regions_field
    recording = tmp_path / "run.mcap"
    stack = site_stack(field, tmp_path, speed=1.0, record=recording, hold=False)
    merged: list = []
    cut_region: list[str] = []
    reached, stale = threading.Event(), threading.Event()

    def on_tracks(sample) -> None:
        scan = decode(TrackSet, sample.payload.to_bytes())
        merged.append(scan)
        if not cut_region and scan.t >= 12.0 and scan.tracks:
            cut_region.append(scan.tracks[0].region)
            reached.set()
        if cut_region and any(tr.stale and tr.region == cut_region[0] for tr in scan.tracks):
            stale.set()

    session = zenoh.open(client_config([stack.listen]))
    subscriber = session.declare_subscriber(Keys(NET).tracks(), on_tracks)
    try:
        assert reached.wait(HUNG), "no track at t >= 12 s"
        region = cut_region[0]
        stack.network.cut(region)
        merge, agent = stack.procs["merge"], stack.procs[f"sensor_agent-{region}"]
        wait_logged(merge, f"region {region}'s base station is gone")
        assert stale.wait(HUNG), f"no stale track of {region}:\n{merge.log[-3000:]}"
        time.sleep(CUT)  # the fault itself: the link stays down this long
        stack.network.heal(region)
        wait_logged(merge, f"region {region}'s base station is back", f"the heal of {region}'s link seen by the merge "
                    f"within {HEAL_BOUND:g} s (the mesh did not heal)", timeout=HEAL_BOUND)
        wait_logged(agent, "replay was out of reach")
        assert stack.procs["replay"].proc.wait(timeout=HUNG) == 0
        wait_logged(stack.procs["recorder"], "messages recorded", "the recording closed")
    finally:
        subscriber.undeclare()
        session.close()
        stack.stop()
    # the sensor agent's count of the raw samples lost is the dataset's, between the times it names
    line = next(line for line in agent.log.splitlines() if "replay was out of reach" in line)
    lost = re.search(r"; (\d+) raw samples of all sensors, published after t=(\S+) s and before t=(\S+) s, were lost",
                     line)
    if lost is not None:
        count, after, before = (float(x) for x in lost.groups())
        times = [e.t for e in open_dataset(field).events()]
        assert sum(after < t < before for t in times) <= count <= sum(after <= t <= before for t in times), line
    else:
        assert line.endswith("; none was lost"), line
    cut_at = float(re.search(r"published after t=(\S+) s,", line).group(1))  # the last tick before the cut
    # the merge names the region's scans it left out; the other base stations the late transitions
    left_out = re.search(rf"(\d+) scans of region {region} \(t=(\S+)–(\S+) s\) came after", merge.log)
    assert left_out is not None and int(left_out.group(1)) > 0, merge.log[-3000:]
    late = {name: sum(int(n) for n in re.findall(r"'late': (\d+)", proc.log))
            for name, proc in stack.procs.items() if name.startswith("basestation")}
    # identities across the cut: the region's tracks shown stale keep their identities when it is back
    shown_stale = {tr.track for m in merged for tr in m.tracks if tr.stale and tr.region == region}
    back = [m for m in merged if m.t > float(left_out.group(3))]
    after_heal = {tr.track for m in back[:5] for tr in m.tracks if tr.region == region and not tr.stale}
    assert shown_stale and shown_stale <= {tr.track for m in back for tr in m.tracks if not tr.stale}, \
        (shown_stale, after_heal)
    # before the first loss named, the rows are the offline ones: the last tick before the cut,
    # or the first scan of the region the merge left out (a scan the region's base station had
    # not released before the cut: it waits for its border band's agents beyond the cut)
    first_loss = min(cut_at, float(left_out.group(2)))
    live = exported_tracks(recording, tmp_path)
    before_loss = [(r.t, r.track, round(r.x, 6), round(r.y, 6)) for r in live if r.t < first_loss]
    assert before_loss == [(r.t, r.track, round(r.x, 6), round(r.y, 6)) for r in offline if r.t < first_loss]
    print(f"\ncut of {region} for {CUT:g} s with event time going on: {line.split(': ', 1)[1]}; "
          f"merge: {left_out.group(0)}; base stations naming late transitions: {late}; identities shown stale "
          f"{sorted(shown_stale)}, the region's after the heal {sorted(after_heal)}")


def test_a_catch_up_counts_what_was_neither_received_nor_held():
    """The sensor agent's count of lost raw samples (no bus: replay's ``recent`` answer as bytes).
    Replay had published 10 samples by the last tick the agent acknowledged and 30 since; 4
    arrived after that tick, and replay still holds the last 20: 6 were lost."""
    from bintrack.bus_payloads import Clock, RawSample
    from bintrack.keys import Keys
    from bintrack.live.recent_catchup import take_recent
    from bintrack.live.sensor_hosting import HostedSensors
    from bintrack.message_codec import encode
    from bintrack.transition_detector import TransitionDetector

    deployment = open_dataset(REPO / "datasets" / "darpa-grid-3").deployment
    hosted = [deployment.sensors[0].id]
    put: list[str] = []
    hosts = HostedSensors(Keys(NET), "agent", TransitionDetector(deployment, hosted), hosted,
                          lambda key, payload, attachment=None: put.append(key), lambda key, reason: None, 0)
    held = [encode(RawSample(t=20.0 + i, sensor=hosted[0] if i % 5 == 0 else "other", value=i % 10 == 0))
            for i in range(20)]
    catch_up = take_recent([*held, encode(Clock(t=39.5, sent=40))], hosts, newer=True)
    assert (catch_up.held, catch_up.taken, catch_up.first_held, catch_up.complete) == (20, 4, 20.0, True)
    assert catch_up.lost(published_by_tick=10, arrived=4) == 6
    assert catch_up.lost(published_by_tick=None, arrived=4) is None
    assert take_recent(held, hosts, newer=True).complete is False  # no closing Clock: ask again
