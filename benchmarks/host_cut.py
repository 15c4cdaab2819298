"""How soon a cut link between sites on hosts of their own is noticed, and the heal (issue 43).

    sudo python benchmarks/host_cut.py [--cuts 5] [--sites 4] [--down 10]

Four sites in network namespaces (:class:`bintrack.hosts.site_network.SiteNetwork`), each with
a ``bintrack.services.router`` meshed as under ``up --regions N --hosts`` and a client holding a
liveliness token, as a region's services do; this machine's router (the hub) and a client
holding a token, as replay does. The last site's link is taken down (``ip link set … down`` on
its bridge port) for ``--down`` s, ``--cuts`` times. Measured on the monotonic clock, from the
cut: when the hub's client sees the site's token go (what the merge logs: "region …'s base
station is gone"; replay holds event time then), when the site's client sees the hub's go (the
sensor agent's "replay was out of reach" starts here), and from the heal until the hub sees the
site's token again. Beside the mesh's 1 s lease, Zenoh's default 10 s, in the same run.
Needs root (network namespaces); says so in one line otherwise.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import threading
import time

import zenoh

from bench_support import free_port
from bintrack.hosts.netns import unavailable
from bintrack.hosts.site_network import SiteNetwork
from bintrack.live.session_options import client_config, router_config

DEFAULT_LEASE_MS = 10_000  # Zenoh's own
PROBE = """
import sys, time, zenoh
from bintrack.live.session_options import client_config, open_session
session = open_session(client_config([sys.argv[1]]), 60.0, "probe")  # retried while its router starts
token = session.liveliness().declare_token(sys.argv[2])
def seen(sample):
    print(f"{str(sample.kind).rpartition('.')[2]} {sample.key_expr} {time.monotonic():.6f}", flush=True)
listener = session.liveliness().declare_subscriber(sys.argv[3], seen, history=True)
sys.stdin.read()
"""


class Probe:
    """A client holding token ``mine`` and noting when tokens under ``watch`` come and go."""

    def __init__(self, argv: list[str], endpoint: str, mine: str, watch: str):
        self.events: list[tuple[str, str, float]] = []
        self.changed = threading.Condition()
        self.proc = subprocess.Popen([*argv, sys.executable, "-c", PROBE, endpoint, mine, watch],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            kind, key, at = line.split()
            with self.changed:
                self.events.append((kind, key, float(at)))
                self.changed.notify_all()

    def when(self, kind: str, key: str, after: float, timeout: float = 120.0) -> float | None:
        """The monotonic time ``key``'s token was seen ``kind`` (PUT/DELETE) after ``after``; None
        if not within ``timeout`` s from now."""
        deadline = time.monotonic() + timeout
        with self.changed:
            while True:
                for k, name, at in self.events:
                    if k == kind and name == key and at > after:
                        return at
                left = deadline - time.monotonic()
                if left <= 0 or not self.changed.wait(left):
                    return None

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.terminate()
        self.proc.wait()


def run(lease_ms: int, args: argparse.Namespace) -> dict[str, list[float]]:
    sites = [f"s{i}" for i in range(args.sites)]
    cut_site = sites[-1]
    figures: dict[str, list[float | None]] = {"hub sees the site go": [], "site sees the hub go": [], "hub sees it back": []}
    cfg = f"transport/link/tx/lease:{lease_ms}"
    with SiteNetwork(sites) as network:
        port = free_port()
        hub_endpoint = f"tcp/{network.hub_address}:{port}"
        config = router_config([hub_endpoint])
        config.insert_json5("transport/link/tx/lease", str(lease_ms))
        hub = zenoh.open(config)
        routers, probes = [], []
        try:
            endpoints = [f"tcp/{network.address(s)}:{port}" for s in sites]
            for i, site in enumerate(sites):
                mesh = [a for peer in (hub_endpoint, *endpoints[:i]) for a in ("-e", peer)]
                routers.append(subprocess.Popen(network.argv(site, [sys.executable, "-m", "bintrack.services.router",
                                                                    "-l", endpoints[i], *mesh, "--name", site, "--cfg",
                                                                    cfg]), stderr=subprocess.DEVNULL))
            probes.append(Probe([], hub_endpoint, "probe/hub", "probe/**"))
            probes.append(Probe(network.argv(cut_site, []), endpoints[-1], f"probe/{cut_site}", "probe/**"))
            hub_probe, site_probe = probes
            if hub_probe.when("PUT", f"probe/{cut_site}", 0.0, timeout=600.0) is None:
                raise RuntimeError("the site's token never reached the hub")
            for _ in range(args.cuts):
                cut = time.monotonic()
                network.cut(cut_site)
                for what, probe, key in (("hub sees the site go", hub_probe, f"probe/{cut_site}"),
                                         ("site sees the hub go", site_probe, "probe/hub")):
                    gone = probe.when("DELETE", key, cut, timeout=args.down)  # None: not while the link was down
                    figures[what].append(None if gone is None else gone - cut)
                time.sleep(max(0.0, cut + args.down - time.monotonic()))
                heal = time.monotonic()
                network.heal(cut_site)
                back = hub_probe.when("PUT", f"probe/{cut_site}", heal)
                figures["hub sees it back"].append(None if back is None else back - heal)
                site_probe.when("PUT", "probe/hub", heal)
                time.sleep(1.0)  # settled before the next cut
        finally:
            for probe in probes:
                probe.close()
            for router in routers:
                router.terminate()
                router.wait()
            hub.close()
    return figures


def cell(values: list[float], cuts: int) -> str:
    """mean ± sd, max of ``values`` (s), and how many of the cuts they are if not all."""
    if not values:
        return f"not within the cut (0 of {cuts})"
    text = f"{statistics.mean(values):.2f} ± {statistics.pstdev(values):.2f}, {max(values):.2f}"
    return text if len(values) == cuts else f"{text} ({len(values)} of {cuts}; the others not within the cut)"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cuts", type=int, default=5)
    parser.add_argument("--sites", type=int, default=4)
    parser.add_argument("--down", type=float, default=10.0, help="s each cut lasts (default: %(default)s)")
    args = parser.parse_args(argv)
    problem = unavailable()
    if problem is not None:
        print(f"host_cut: {problem}", file=sys.stderr)
        return 2
    results = {lease: run(lease, args) for lease in (1000, DEFAULT_LEASE_MS)}
    print(f"\n| {args.cuts} cuts of {args.down:g} s, {args.sites} sites, s (mean ± sd, max) | lease 1 s (--hosts) "
          f"| lease 10 s (Zenoh's default) | ratio |")
    print("| --- | ---: | ---: | ---: |")
    for what in results[1000]:
        ours, theirs = ([v for v in results[lease][what] if v is not None] for lease in (1000, DEFAULT_LEASE_MS))
        cells = [cell(v, args.cuts) for v in (ours, theirs)]
        ratio = f"{statistics.mean(theirs) / statistics.mean(ours):.1f}" if ours and theirs else "–"
        print(f"| {what} | {cells[0]} | {cells[1]} | {ratio} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
