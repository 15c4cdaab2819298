"""What the benchmarks share: paths, a free loopback port, the ``bintrack`` command in a
subprocess, a process's resident memory, progress lines.

Imported as ``bench_support`` by a script run as ``.venv/bin/python benchmarks/x.py`` (the
script's folder is on ``sys.path``; ``bintrack`` is installed in the venv, editable).
"""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATASETS = REPO / "datasets"
DOCS = REPO / "docs"


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now (a benchmark runs alone: no other process races for it)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def bintrack(*args: str) -> None:
    """Run the ``bintrack`` command in a subprocess; raises if it fails."""
    subprocess.run([sys.executable, "-m", "bintrack.cli", *args], check=True)


def rss_mib(pid: int, missing_ok: bool = True) -> float | None:
    """Resident memory of process ``pid``, MiB (``VmRSS``); None if the process is gone
    (``missing_ok``), else RuntimeError."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    if missing_ok:
        return None
    raise RuntimeError(f"no VmRSS for {pid}")


def say(text: str) -> None:
    """A progress line on stderr."""
    print(text, file=sys.stderr, flush=True)
