"""What each region's router carries when one field is cut into N regions on hosts of their own
(issue 43, item 1: traffic by region, docs/design.md §11).

    sudo python benchmarks/region_traffic.py [--regions 1,2,4] [--grid 24] [--people 8] [--seeds 7-11]

A field per seed, ``bintrack simulate darpa-grid --grid G --people P --seed S`` (kept in
``--cache``), cut into a grid of N regions for each N and run as ``up --regions N --hosts`` runs it
(:mod:`bintrack.hosts.site_stack`: a network namespace per site), at ``--speed 0`` to its end.
Per site, per event second, the mean over the sites, then the mean ± sd over the seeds,
beside N = 1:

* **messages in**: what the site's sensor agent and base station heard (each says so at its
  stop: ``heard N samples``), less what their own site published (the base station hears its
  own agent's transitions and reports through the site's router): what the site's router took
  in from elsewhere for them;
* **messages out**, every one heard on the hub by a subscriber of this script's, by the site
  that published it: a sensor's transitions by its region's site, ``region/<r>/…`` by site r,
  a service's progress and done by its instance's site. The hub's services (merge, recorder)
  subscribe to all of the network, so what a site publishes leaves it once;
* **bytes and packets** on the site's link, as the kernel counts them on its veth (Zenoh's
  framing, keep-alives, declarations and queries included), received and sent;
* **in, by kind**: its own sensors' raw samples (÷ N), its band's transitions published by
  the other sites (the border share), and the control plane (the clock, the end of stream and
  the other agents' progress and done reports, which do not fall with N);
* **needed in**, counted from the same messages: the raw samples of the site's own sensors,
  the transitions of its border band's sensors, the clock, the end of stream and the sensor
  agents' progress and done reports (what design §11 says a site needs), and **all published
  elsewhere**: what a site took in when every service subscribed to ``bintrack/<net>/**``.

Needs root (network namespaces); says so in one line otherwise.
"""

from __future__ import annotations

import argparse
import ast
import re
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
HEARD = re.compile(r": heard \d+ samples (\{[^}]*\})")


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

    def own_heard(self, region: str) -> Counter:
        """Messages of ``region``'s site that its own base station hears, by kind: its sensors'
        transitions and its sensor agent's progress and done reports."""
        count: Counter = Counter()
        for key, n in self.by_key.items():
            parsed = parse_key(key)
            if self.origin(key) == region and (parsed.kind == "transition" or (
                    parsed.kind in ("progress", "done") and parsed.service == "sensor_agent")):
                count[parsed.kind] += n
        return count

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
        heard = {site: sum((heard_in(stack.procs[f"{role}-{site}"].log) for role in ("sensor_agent", "basestation")),
                           Counter()) for site in names}
    total = sum(census.counts.values())
    regions = RegionMap(deployment)
    result = {HUB: {"out": census.counts[HUB], "everything": total - census.counts[HUB], **links[HUB]}, "total": total}
    for site in names:
        taken = heard[site] - census.own_heard(site)  # from elsewhere, by kind
        result[site] = {"out": census.counts[site], "everything": total - census.counts[site], **links[site],
                        "in": sum(taken.values()), "raw": taken["raw"], "band": taken["transition"],
                        "control": sum(taken.values()) - taken["raw"] - taken["transition"],
                        "needed": census.needed(site, regions)}
    return result


def heard_in(log: str) -> Counter:
    """The samples a service says it heard at its stop, by kind (none if it did not say)."""
    found = HEARD.search(log)
    if found is None:
        print(f"region_traffic: a service did not say what it heard:\n{log[-1500:]}", file=sys.stderr)
        return Counter()
    return Counter(ast.literal_eval(found.group(1)))


METRICS = ("in", "out", "rx_bytes", "tx_bytes", "rx_packets", "tx_packets", "needed", "everything", "raw", "band",
           "control")


def per_event_second(result: dict, span: float) -> dict[str, float]:
    """One run's figures per event second: each metric's mean over the sites, the hub link's
    kB sent and every message of the network."""
    sites = [v for site, v in result.items() if site not in (HUB, "total")]
    out = {what: statistics.mean(v[what] for v in sites) / span for what in METRICS}
    return out | {"hub_kb": result[HUB]["tx_bytes"] / span / 1000, "total": result["total"] / span}


def seeds_of(text: str) -> list[int]:
    """``7-11`` or ``7,9``: the seeds."""
    first, _, last = text.partition("-")
    return list(range(int(first), int(last) + 1)) if last else [int(s) for s in text.split(",")]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--regions", default="1,2,4", help="the N to run (default: %(default)s)")
    parser.add_argument("--grid", type=int, default=24, help="nodes per side (default: %(default)s)")
    parser.add_argument("--people", type=int, default=8)
    parser.add_argument("--seeds", default="7", help="the fields' seeds, e.g. 7-11 (default: %(default)s)")
    parser.add_argument("--cache", default=str(REPO / "benchmarks" / ".cache"))
    parser.add_argument("--plot", metavar="FILE.png", help="also plot messages in per router against N")
    args = parser.parse_args(argv)
    problem = unavailable()
    if problem is not None:
        print(f"region_traffic: {problem}", file=sys.stderr)
        return 2
    counts = [int(n) for n in args.regions.split(",")]
    figures: dict[int, list[dict]] = {n: [] for n in counts}  # N → one dict per seed
    for seed in seeds_of(args.seeds):
        args.seed = seed
        source = field(args)
        times = [e.t for e in open_dataset(source).events()]
        span = max(times) - min(times)
        print(f"field: {source.name}, {len(open_dataset(source).deployment.sensors)} sensors, {len(times)} raw samples "
              f"over {span:.0f} s of event time", flush=True)
        for count in counts:
            result = run(source, count, args)
            figures[count].append(per_event_second(result, span))
            print(f"seed {seed}, N={count}: {result}", flush=True)
    table(figures, len(seeds_of(args.seeds)))
    if args.plot:
        plot(figures, args.plot)
    return 0


def table(figures: dict[int, list[dict]], seeds: int) -> None:
    """Per event second and site's router, mean ± sd over the seeds (each a mean over the sites);
    × N=1 per seed, then averaged."""
    base = figures[min(figures)]

    def cell(runs: list[dict], what: str, scale: float = 1.0) -> str:
        values = [r[what] / scale for r in runs]
        return f"{statistics.mean(values):.0f} ± {statistics.stdev(values):.0f}" if len(values) > 1 \
            else f"{values[0]:.0f}"

    def ratio(runs: list[dict], what: str) -> str:
        values = [r[what] / b[what] for r, b in zip(runs, base)]
        return f"{statistics.mean(values):.2f} ± {statistics.stdev(values):.2f}" if len(values) > 1 \
            else f"{values[0]:.2f}"

    print(f"\n| per event s and site's router, mean ± sd over {seeds} fields | messages in | × N=1 | in: own raw "
          "samples | in: band's transitions | in: control | needed in (§11) | all published elsewhere (`**`) | × N=1 "
          "| messages out | kB received | kB sent | hub link: kB sent |")
    print("| ---: " * 13 + "|")
    for count, runs in figures.items():
        print(f"| N = {count} | {cell(runs, 'in')} | {ratio(runs, 'in')} | {cell(runs, 'raw')} | "
              f"{cell(runs, 'band')} | "
              f"{cell(runs, 'control')} | {cell(runs, 'needed')} | {cell(runs, 'everything')} | "
              f"{ratio(runs, 'everything')} | {cell(runs, 'out')} | {cell(runs, 'rx_bytes', 1000)} | "
              f"{cell(runs, 'tx_bytes', 1000)} | {cell(runs, 'hub_kb')} |")


def plot(figures: dict[int, list[dict]], path: str) -> None:
    """Messages taken in per site's router and event second against N (mean ± sd over the
    seeds): measured, its own raw samples, and what a site took with every service on ``**``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    counts = sorted(figures)
    fig, ax = plt.subplots(figsize=(5.4, 3.6))
    for what, label in (("everything", "all published elsewhere (every service on **, before)"),
                        ("in", "taken in (narrow subscriptions, measured)"),
                        ("raw", "of it, own raw samples (÷ N)"),
                        ("band", "of it, the band's transitions from other sites"),
                        ("control", "of it, the control plane")):
        means = [statistics.mean(r[what] for r in figures[n]) for n in counts]
        sds = [statistics.stdev(r[what] for r in figures[n]) if len(figures[n]) > 1 else 0.0 for n in counts]
        ax.errorbar(counts, means, yerr=sds, marker="o", capsize=3, label=label)
    ax.set_xlabel("regions N (a router each)")
    ax.set_ylabel("messages per event s, per router")
    ax.set_xticks(counts)
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    sys.exit(main())
