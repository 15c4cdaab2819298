"""What each region's router carries when one field is cut into N regions on hosts of their own
(issue 43, item 1: the measurement, before any change of design).

    sudo python benchmarks/region_traffic.py [--regions 1,2,4] [--grid 24] [--people 8] [--seed 7]

One field, ``bintrack simulate darpa-grid --grid G --people P --seed S`` (kept in ``--cache``),
cut into a grid of N regions for each N and run as ``up --regions N --hosts`` runs it
(:mod:`bintrack.hosts.site_stack`: a network namespace per site), at ``--speed 0`` to its end.
Per site, per event second, mean over the sites (min–max), beside N = 1:

* **messages**, every one heard on the hub by a subscriber of this script's (the hub's services
  subscribe to all of them anyway), by the site that published it: a sensor's transitions by
  its region's site, ``region/<r>/…`` by site r, a service's progress and done by its
  instance's site; raw samples, the clock and the merged tracks by the hub. A site's router
  sends *out* what its site publishes and takes *in* what its site's services subscribe to from
  elsewhere: today every service subscribes to ``bintrack/<net>/**`` (one subscriber keeps a
  publisher's order across keys), so *in* is every message published elsewhere;
* **bytes and packets** on the site's link, as the kernel counts them on its veth (Zenoh's
  framing, keep-alives, declarations and queries included), received and sent;
* **messages needed in**, counted from the same messages: what the site's services would take
  from elsewhere under the design of docs/design.md §11 (narrow subscriptions): the raw samples
  of its own sensors, the transitions of its border band's sensors, the clock, the end of
  stream and the sensor agents' progress and done reports.

Needs root (network namespaces); says so in one line otherwise.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import threading
from collections import Counter
from pathlib import Path

import zenoh

from bench_support import REPO
from bintrack.formats import DEPLOYMENT_FILE, open_dataset, write_deployment
from bintrack.hosts.netns import unavailable
from bintrack.hosts.site_stack import SiteStack
from bintrack.keys import Keys, parse_key
from bintrack.live.session_options import client_config
from bintrack.regions import RegionMap, grid_areas, grid_shape

HUNG = 1800.0  # s: only a hung run takes this long
HUB = "hub"


def field(args: argparse.Namespace) -> Path:
    """The simulated field (no regions), made once."""
    folder = Path(args.cache) / f"traffic-grid{args.grid}-people{args.people}-seed{args.seed}"
    if not (folder / "events.csv").exists():
        subprocess.run([sys.executable, "-m", "bintrack.cli", "simulate", "darpa-grid", "--grid", str(args.grid),
                        "--people", str(args.people), "--seed", str(args.seed), "--out", str(folder)],
                       check=True, capture_output=True)
    return folder


def cut_into(source: Path, count: int, folder: Path) -> list[str]:
    """``source`` with its field cut into a grid of ``count`` regions, in ``folder`` (events and
    truth linked, as ``up --regions N`` does); the region names."""
    deployment = open_dataset(source).deployment
    deployment = deployment.model_copy(update={"regions": grid_areas(deployment.region, *grid_shape(count))})
    write_deployment(folder / DEPLOYMENT_FILE, deployment)
    for item in source.iterdir():
        if item.name != DEPLOYMENT_FILE:
            (folder / item.name).symlink_to(item.resolve())
    return [r.name for r in deployment.regions]


class Census:
    """Counts the messages of a network heard on the hub, by the site that published them."""

    def __init__(self, net: str, regions: RegionMap):
        self.home = {s.id: regions.home(s) or regions.names[0] for s in regions.deployment.sensors}
        self.regions = set(regions.names)
        self.counts: Counter = Counter()
        self.sizes: Counter = Counter()
        self.by_key: Counter = Counter()
        self.lock = threading.Lock()
        self.keys = Keys(net)

    def origin(self, key: str) -> str:
        parsed = parse_key(key)
        if parsed.kind in ("transition", "state"):
            return self.home.get(parsed.sensor, HUB)
        if parsed.region is not None:
            return parsed.region
        if parsed.kind in ("progress", "done"):
            site = parsed.instance.rpartition("-")[2]
            return site if site in self.regions else HUB
        return HUB

    def on_sample(self, sample: zenoh.Sample) -> None:
        site = self.origin(str(sample.key_expr))
        with self.lock:
            self.counts[site] += 1
            self.sizes[site] += len(sample.payload)
            self.by_key[str(sample.key_expr)] += 1

    def needed(self, region: str, regions: RegionMap) -> int:
        """Messages published outside ``region``'s site that its services would need under narrow
        subscriptions (docs/design.md §11)."""
        own, taken = set(regions.own_sensors(region)), set(regions.taken_sensors(region))
        count = 0
        for key, n in self.by_key.items():
            parsed = parse_key(key)
            if self.origin(key) == region:
                continue
            if (parsed.kind == "raw" and parsed.sensor in own) or (parsed.kind == "transition" and parsed.sensor in taken) \
                    or parsed.kind in ("clock", "eos") \
                    or (parsed.kind in ("progress", "done") and parsed.service == "sensor_agent"):
                count += n
        return count


def run(source: Path, count: int, args: argparse.Namespace) -> dict:
    """One run with ``count`` regions; per site and for the hub: messages out and in, link traffic."""
    with tempfile.TemporaryDirectory(prefix="bintrack-traffic-") as tmp:
        folder = Path(tmp) / "field"
        folder.mkdir()
        names = cut_into(source, count, folder)
        deployment = open_dataset(folder).deployment
        census = Census(deployment.name, RegionMap(deployment))
        logs = Path(tmp) / "logs"
        logs.mkdir()
        stack = SiteStack(names, str(folder), deployment.name, logs, speed=0.0)
        done = threading.Event()
        session = zenoh.open(client_config([stack.listen]))
        try:
            entities = [session.declare_subscriber(census.keys.all(), census.on_sample),
                        session.declare_subscriber(census.keys.done("merge"), lambda sample: done.set())]
            if not done.wait(HUNG):
                raise RuntimeError(f"the merge never finished:\n{stack.procs['merge'].log[-2000:]}")
            links = {site: stack.network.link_traffic(site) for site in names}
            links[HUB] = stack.network.link_traffic(None)
            for entity in entities:
                entity.undeclare()
        finally:
            session.close()
            stack.stop()
    total = sum(census.counts.values())
    regions = RegionMap(deployment)
    return {site: {"out": census.counts[site], "in": total - census.counts[site], **links[site],
                   "needed": census.needed(site, regions) if site != HUB else 0}
            for site in [*names, HUB]} | {"total": total}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--regions", default="1,2,4", help="the N to run (default: %(default)s)")
    parser.add_argument("--grid", type=int, default=24, help="nodes per side (default: %(default)s)")
    parser.add_argument("--people", type=int, default=8)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--cache", default=str(REPO / "benchmarks" / ".cache"))
    parser.add_argument("--plot", metavar="FILE.png", help="also plot messages in per router against N")
    args = parser.parse_args(argv)
    problem = unavailable()
    if problem is not None:
        print(f"region_traffic: {problem}", file=sys.stderr)
        return 2
    source = field(args)
    times = [e.t for e in open_dataset(source).events()]
    span = max(times) - min(times)
    print(f"field: {source.name}, {len(open_dataset(source).deployment.sensors)} sensors, {len(times)} raw samples over "
          f"{span:.0f} s of event time", flush=True)
    results = {}
    for count in (int(n) for n in args.regions.split(",")):
        results[count] = run(source, count, args)
        print(f"N={count}: {results[count]}", flush=True)

    def per_site(result: dict, what: str) -> list[float]:
        return [v[what] / span for site, v in result.items() if site not in (HUB, "total")]

    def cell(values: list[float], scale: float = 1.0, unit: str = "") -> str:
        values = [v / scale for v in values]
        spread = f" ({min(values):.0f}–{max(values):.0f})" if len(values) > 1 else ""
        return f"{statistics.mean(values):.0f}{unit}{spread}"

    base = results[min(results)]
    print(f"\n| per event s, mean over a site's router (min–max) | messages in | × N=1 | messages out | all messages "
          "| kB received | kB sent | packets received | packets sent | hub link: kB sent | needed in (§11) | × N=1 |")
    print("| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for count, result in results.items():
        ratio = statistics.mean(per_site(result, "in")) / statistics.mean(per_site(base, "in"))
        needed = statistics.mean(per_site(result, "needed")) / statistics.mean(per_site(base, "needed"))
        print(f"| N = {count} | {cell(per_site(result, 'in'))} | {ratio:.2f} | {cell(per_site(result, 'out'))} | "
              f"{result['total'] / span:.0f} | {cell(per_site(result, 'rx_bytes'), 1000)} | "
              f"{cell(per_site(result, 'tx_bytes'), 1000)} | {cell(per_site(result, 'rx_packets'))} | "
              f"{cell(per_site(result, 'tx_packets'))} | {result[HUB]['tx_bytes'] / span / 1000:.0f} | "
              f"{cell(per_site(result, 'needed'))} | {needed:.2f} |")
    if args.plot:
        plot(results, span, args.plot)
    return 0


def plot(results: dict, span: float, path: str) -> None:
    """Messages taken in per site's router and event second against N: today, and needed under §11."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    counts = sorted(results)
    fig, ax = plt.subplots(figsize=(5, 3.4))
    for what, label in (("in", "taken in today (every message published elsewhere)"),
                        ("needed", "needed in (own raw samples, band transitions, control)")):
        means = [statistics.mean(v[what] / span for site, v in results[n].items() if site not in (HUB, "total"))
                 for n in counts]
        ax.plot(counts, means, marker="o", label=label)
    ax.set_xlabel("regions N (a router each)")
    ax.set_ylabel("messages per event s, per router")
    ax.set_xticks(counts)
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    sys.exit(main())
