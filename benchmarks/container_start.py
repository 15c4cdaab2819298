"""The container image's size and how fast a service starts in it, beside the same on the host.

    python benchmarks/container_start.py [--image localhost/bintrack:0.1.0] [--runs 3]

Needs rootful podman and the image (``make test`` builds it: tests/test_compose_engine.py).
Two starts, each timed from the command to the moment it is done, median of ``--runs``:

* the router (``python -m bintrack.services.router -l tcp/127.0.0.1:7447``) until it logs
  ``listening on``: a service up and serving;
* the base station's ``--help``: Python, the trackers, numpy and scipy imported.

Each in a new container (``podman run --rm --network none``, runtime runc, open files and
processes 4096, as the README's podman notes say) and, as the baseline, as a process on the
host with this interpreter.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time

PODMAN_RUN = ["podman", "run", "--rm", "--network", "none", "--runtime", "runc",
              "--ulimit", "nofile=4096:4096", "--ulimit", "nproc=4096:4096"]


def until_line(argv: list[str], marker: str | None) -> float:
    """Seconds from starting ``argv`` to a line containing ``marker`` (to its exit if None)."""
    start = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        if marker is None:
            out, _ = proc.communicate(timeout=120)
            if proc.returncode != 0:
                raise SystemExit(f"{' '.join(argv)}: exit {proc.returncode}\n{out[-2000:]}")
            return time.perf_counter() - start
        for line in proc.stdout:
            if marker in line:
                return time.perf_counter() - start
        raise SystemExit(f"{' '.join(argv)}: ended without {marker!r}")
    finally:
        if proc.poll() is None:
            proc.terminate()
            proc.wait(timeout=60)


def median_of(runs: int, argv: list[str], marker: str | None) -> tuple[float, list[float]]:
    times = [until_line(argv, marker) for _ in range(runs)]
    return statistics.median(times), times


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--image", default="localhost/bintrack:0.1.0")
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()

    inspect = subprocess.run(["podman", "image", "inspect", args.image], capture_output=True, text=True)
    if inspect.returncode != 0:
        print(f"container_start: no image {args.image} (make test builds it): {inspect.stderr.strip()}", file=sys.stderr)
        return 2
    size = json.loads(inspect.stdout)[0]["Size"]
    print(f"image {args.image}: {size / 1e6:.1f} MB (uncompressed, as `podman images` shows it; the target: < 400 MB)")

    cases = {
        "router until `listening on`": (["bintrack.services.router", "-l", "tcp/127.0.0.1:7447"], "listening on"),
        "basestation --help": (["bintrack.services.basestation", "--help"], None),
    }
    print(f"{'start (median of ' + str(args.runs) + ')':38} {'container':>10} {'host':>8}   runs in the container")
    for name, (command, marker) in cases.items():
        inside, times = median_of(args.runs, [*PODMAN_RUN, args.image, *command], marker)
        host, _ = median_of(args.runs, [sys.executable, "-m", *command], marker)
        print(f"{name:38} {inside:9.2f}s {host:7.2f}s   {', '.join(f'{t:.2f}' for t in times)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
