"""The live stack at scale on hosts of its own (issue 43, item 5): a simulated field cut into N
regions and run by ``bintrack up --regions N --hosts --speed 1``, each region's router and
services in a network namespace of its own, the merge and the recorder on this machine's hub.

    sudo python benchmarks/scale_live.py [--grid 50] [--people 25] [--regions 4] [--until 60]

The field is ``bintrack simulate darpa-grid --grid G --people P --entry-gap 0.1 --dead 0`` (as
``benchmarks/scale.py``; kept in ``--cache``), replayed from its start to ``--until`` s of event
time (the people are all in the field after P/10 s). Measured, side by side for each field:

* **lag**, event to merged track: for each merged scan at event time t, the wall time the
  recorder received it less the wall time the replay reached t (its clock ticks as the recorder
  received them: the earliest ``received − t`` over the ticks, the replay's own start), p50 and
  p99 over the scans, and the lag over the last tenth of the run beside the first tenth: a
  stack that keeps up holds its lag, one that falls behind sees it grow with the run;
* **event/wall**: the merged output's event span over the wall span in which it was received; the
  stack keeps up where this is at least ``--speed``;
* **CPU per service**, as a share of one core over the run (``/proc/PID/stat`` of every
  process ``up`` started, read every ½ s), by role, the sum over the regions and the busiest;
* **messages per router** per event second: what each site's sensor agent and base station
  heard through their site's router (each says so at its stop), mean over the sites;
* the CPU of each site's router and of ``up`` itself, which runs the hub's router.

``up``'s own log is kept beside the recording under ``--out``; a run that has not ended after
``--timeout`` s is stopped and reported as such. Needs root (network namespaces);
says so in one line otherwise.
"""

from __future__ import annotations

import argparse
import ast
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

from bench_support import REPO, free_port, say
from scale import simulate  # the same field as benchmarks/scale.py (beside it)
from bintrack.formats import DEPLOYMENT_FILE
from bintrack.hosts.netns import unavailable
from bintrack.live.recording import open_recording

TICK = os.sysconf("SC_CLK_TCK")


def window(source: Path, until: float, folder: Path) -> Path:
    """``source`` with its events and truth cut at ``until`` s of event time, in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copy(source / DEPLOYMENT_FILE, folder / DEPLOYMENT_FILE)
    for name in ("events.csv", "truth.csv"):
        if not (source / name).exists():
            continue
        with open(source / name) as read, open(folder / name, "w") as write:
            write.write(read.readline())
            for line in read:
                if float(line.split(",", 1)[0]) >= until:
                    break
                write.write(line)
    return folder


def _children() -> dict[int, list[int]]:
    tree: dict[int, list[int]] = defaultdict(list)
    for entry in os.scandir("/proc"):
        if entry.name.isdigit():
            try:
                stat = Path(f"/proc/{entry.name}/stat").read_text()
            except OSError:
                continue
            tree[int(stat.rpartition(")")[2].split()[1])].append(int(entry.name))
    return tree


def _label(pid: int) -> str | None:
    """The service instance ``pid`` runs (its ``--id`` less the stack's prefix), or None."""
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().decode().split("\0")
    except OSError:
        return None
    if "--id" in argv:
        return argv[argv.index("--id") + 1].partition("-")[2]
    if "bintrack.services.router" in argv:
        return f"router-{pid}"
    return None


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU seconds of ``pid`` so far, None if it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / TICK


def run_up(folder: Path, regions: int, speed: float, out: Path, timeout: float,
           lease: int | None = None) -> tuple[dict[str, float], float, str] | None:
    """``up`` on ``folder`` with its regions on hosts (their links' lease ``lease`` ms, up's
    default if None); CPU seconds per service instance, the wall seconds of the run and up's
    log; None if it had not ended after ``timeout`` s (it is then stopped, as Ctrl-C would)."""
    record = out / "run.mcap"
    record.unlink(missing_ok=True)
    log_path = out / "up.log"
    argv = [sys.executable, "-m", "bintrack.cli", "up", str(folder), "--tracker", "mcmcda", "--regions",
            str(regions), "--hosts", "--speed", str(speed), "--record", str(record), "--exit-at-end", "--no-map",
            "--listen", f"tcp/127.0.0.1:{free_port()}", "--progress-interval", "10",
            *(() if lease is None else ("--mesh-lease", str(lease)))]
    cpu: dict[int, tuple[str, float]] = {}
    with open(log_path, "w") as log:
        started = time.monotonic()
        up = subprocess.Popen(argv, stderr=log, stdout=log, cwd=REPO)
        said = started
        while up.poll() is None:
            if time.monotonic() - started > timeout:
                say(f"scale_live: up had not ended after {timeout:g} s; stopping it (its log: {log_path})")
                up.send_signal(signal.SIGINT)
                up.wait()
                return None
            seconds = cpu_seconds(up.pid)
            if seconds is not None:
                cpu[up.pid] = ("up-hub", seconds)  # up runs the hub's router in its own process
            tree = _children()
            todo = list(tree.get(up.pid, ()))
            while todo:
                pid = todo.pop()
                todo.extend(tree.get(pid, ()))
                label = cpu[pid][0] if pid in cpu else _label(pid)
                seconds = cpu_seconds(pid)
                if label is not None and seconds is not None:
                    cpu[pid] = (label, seconds)
            time.sleep(0.5)
            if time.monotonic() - said >= 30:
                said = time.monotonic()
                say(f"  [{said - started:5.0f} s] up is running ({len(cpu)} services seen)")
        wall = time.monotonic() - started
    text = log_path.read_text()
    if up.returncode != 0:
        raise SystemExit(f"scale_live: up exited with status {up.returncode}; its log: {log_path}\n{text[-2000:]}")
    per: dict[str, float] = defaultdict(float)
    for label, seconds in cpu.values():
        per[label] += seconds  # a restarted service's runs add up
    return dict(per), wall, text


def lags(record: Path) -> tuple[np.ndarray, np.ndarray]:
    """Per merged scan: its event time (s) and its lag (s) from the replay reaching that time."""
    ticks, merged = [], []
    for item, message in open_recording(record).messages({"clock", "tracks"}):
        (ticks if item.kind == "clock" else merged).append((message.t, item.received_ns / 1e9))
    if not ticks or not merged:
        raise SystemExit(f"scale_live: {record} holds {len(ticks)} clock ticks and {len(merged)} merged scans")
    start = min(wall - t for t, wall in ticks)  # wall time of event time 0
    t = np.array([m[0] for m in merged])
    return t, np.array([m[1] for m in merged]) - (t + start)


def heard(text: str) -> Counter:
    """What the sites' sensor agents and base stations say they heard, in all, by kind."""
    total: Counter = Counter()
    for found in re.finditer(r" (?:sensor_agent|basestation): heard \d+ samples (\{[^}]*\})", text):
        total += Counter(ast.literal_eval(found.group(1)))
    return total


def measure(args: argparse.Namespace, grid: int, people: int) -> dict:
    source = simulate(Path(args.cache) / f"scale-{grid}-{people}-{args.seed}", grid, people, args.seed)
    out = args.out / f"grid{grid}-people{people}-regions{args.regions}"
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="bintrack-scale-") as tmp:
        folder = window(source, args.until, Path(tmp) / source.name)
        say(f"{grid * grid} sensors, {people} people, {args.regions} regions on hosts, --speed {args.speed}, "
            f"event time 0–{args.until:g} s …")
        ran = run_up(folder, args.regions, args.speed, out, args.timeout, args.mesh_lease)
    if ran is None:
        return {"sensors": grid * grid, "people": people, "stalled": args.timeout, "log": str(out / "up.log")}
    cpu, wall, text = ran
    t, lag = lags(out / "run.mcap")
    tenth = max(len(t) // 10, 1)
    span = float(t[-1] - t[0]) if len(t) > 1 else float("nan")
    roles: dict[str, list[float]] = defaultdict(list)
    for label, seconds in cpu.items():
        roles[label.partition("-")[0]].append(seconds / wall)
    return {"sensors": grid * grid, "people": people, "scans": len(t),
            "p50": float(np.percentile(lag, 50)), "p99": float(np.percentile(lag, 99)),
            "first": float(np.median(lag[:tenth])), "last": float(np.median(lag[-tenth:])),
            "rate": span / max(span + float(lag[-1] - lag[0]), 1e-9),
            "roles": {r: (sum(v), max(v), len(v)) for r, v in sorted(roles.items())},
            "router": sum(heard(text).values()) / args.regions / args.until}


def report(rows: list[dict], args: argparse.Namespace) -> str:
    lines = [f"up --regions {args.regions} --hosts --speed {args.speed:g}, mcmcda, event time 0–{args.until:g} s "
             f"(seed {args.seed}); lag: merged scan received − replay at its event time",
             f"{'sensors':>8} {'people':>6} {'scans':>6} {'lag p50':>8} {'lag p99':>8} {'first 10%':>9} "
             f"{'last 10%':>9} {'event/wall':>10} {'msgs/router/s':>14}"]
    for r in rows:
        if "stalled" in r:
            lines.append(f"{r['sensors']:>8} {r['people']:>6}  did not end within {r['stalled']:g} s (log: {r['log']})")
            continue
        lines.append(f"{r['sensors']:>8} {r['people']:>6} {r['scans']:>6} {r['p50']:>7.2f}s {r['p99']:>7.2f}s "
                     f"{r['first']:>8.2f}s {r['last']:>8.2f}s {r['rate']:>10.2f} {r['router']:>14.0f}")
    lines.append("CPU, share of one core over the run: role: sum over its instances (busiest, instances)")
    for r in (r for r in rows if "stalled" not in r):
        roles = "; ".join(f"{role} {total:.2f} ({busiest:.2f}, {n})" for role, (total, busiest, n) in r["roles"].items())
        lines.append(f"{r['sensors']:>8}: {roles}")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--grid", type=int, action="append", help="nodes per side (repeatable; default 50)")
    parser.add_argument("--people", type=int, action="append", help="people, one per --grid (default grid²/100)")
    parser.add_argument("--regions", type=int, default=4, help="regions, each on a host of its own (default 4)")
    parser.add_argument("--until", type=float, default=60.0, help="event seconds replayed (default 60)")
    parser.add_argument("--speed", type=float, default=1.0, help="replay speed (default 1)")
    parser.add_argument("--timeout", type=float, default=900.0,
                        help="stop a run that has not ended after this many s of wall time (default 900)")
    parser.add_argument("--mesh-lease", type=int, default=None, metavar="MS",
                        help="up's --mesh-lease: the lease of the links between sites (default: up's)")
    parser.add_argument("--seed", type=int, default=1, help="simulation seed (default 1)")
    parser.add_argument("--cache", default=str(REPO / "benchmarks" / ".cache"), help="where the fields are kept")
    parser.add_argument("--out", type=Path, default=Path(tempfile.gettempdir()) / "bintrack-scale-live",
                        help="recordings and logs (default under the temp folder)")
    args = parser.parse_args()
    problem = unavailable()
    if problem is not None:
        print(f"scale_live: skipped: {problem}", file=sys.stderr)
        return 0
    grids = args.grid or [50]
    people = args.people or [max(g * g // 100, 1) for g in grids]
    if len(people) != len(grids):
        parser.error("give --people once per --grid, or not at all")
    rows = [measure(args, g, p) for g, p in zip(grids, people)]
    print(report(rows, args))
    return 0


if __name__ == "__main__":
    sys.exit(main())
