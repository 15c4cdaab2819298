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
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest

from bintrack.formats import read_tracks
from bintrack.hosts.netns import NetnsError, ip, namespaces, unavailable
from bintrack.hosts.site_network import PREFIX, SiteNetwork, leftovers

from support import HUNG, REPO, bintrack
from test_faults import Up, children, cut, exported_tracks

SEED = 21  # a simulated 2 × 2 field; not a seed the merge's defaults were chosen on
LAN = ipaddress.IPv4Network("198.18.0.0/15")
needs_namespaces = pytest.mark.skipif(unavailable() is not None, reason=f"no network namespaces: {unavailable()}")


@pytest.fixture(scope="module")
def regions_field(tmp_path_factory) -> tuple[Path, list]:
    """The first 40 s of a simulated darpa-grid field cut into 2 × 2 regions, and its offline rows."""
    folder = tmp_path_factory.mktemp("hosts")
    bintrack("simulate", "darpa-grid", "--out", "whole", "--regions", "2x2", "--seed", str(SEED), cwd=folder, check=True)
    field = cut(folder / "whole", folder / "field", 40.0)
    bintrack("track", str(field), "--tracker", "mcmcda", "--regions", "--out", "offline.csv", cwd=folder, check=True)
    return field, read_tracks(folder / "offline.csv")


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


@needs_namespaces
def test_up_on_four_hosts_gives_the_offline_rows_and_removes_its_network(regions_field, tmp_path):
    field, offline = regions_field
    recording = tmp_path / "run.mcap"
    up = Up(str(field), "--tracker", "mcmcda", "--regions", "4", "--hosts", "--speed", "0", "--record",
            str(recording), "--exit-at-end")
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

    result = subprocess.run(["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", sys.executable, "-m",
                             "bintrack.cli", *UP_HOSTS], capture_output=True, text=True, cwd=REPO, timeout=HUNG)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "bintrack up: error: --hosts: network namespaces need root (run as root, or without --hosts)"], result.stderr


# ------------------------------------------------------------------ faults across hosts

REGIONS = ("r0c0", "r0c1", "r1c0", "r1c1")
CUT = 10.0  # s the link stays down


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
    recording = tmp_path / "run.mcap"
    up = Up(str(field), "--tracker", "mcmcda", "--regions", "4", "--hosts", "--speed", "2", "--record",
            str(recording), "--exit-at-end")
    tag = hosts_tag(up)
    up.event_time_at_least(10.0)
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
    assert "; 0 raw samples of all sensors neither arrived" in taken, taken
    live = exported_tracks(recording, tmp_path)
    assert [(r.t, r.track) for r in live] == [(r.t, r.track) for r in offline], up.log[-6000:]
    assert max(abs(a.x - b.x) + abs(a.y - b.y) for a, b in zip(live, offline)) < 1e-6
    print(f"\ncut of r1c1 for {CUT:g} s: {taken.split(': ', 1)[1]}; {back.split(': ', 1)[1]}; "
          + "; ".join(line.split(" ", 1)[1] for line in lines_with(up, "fetched from the sensors' state")))
