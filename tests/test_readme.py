"""The README and docs/ as a newcomer reads them: short, self-contained, and every command in
the README runs as written.

The commands are the lines of the README's ``sh`` blocks. They run in order, block by block, in
a scratch folder that holds the repository's ``datasets`` and ``examples``; ``bintrack`` is this
interpreter's. A command whose comment says "until Ctrl-C" is started, waited for until it
has said something (``up``: until its progress shows data flowing), left running while the rest
of its block runs, and stopped with SIGINT at the end of the block. ``make demo`` runs the
command it stands for; ``make test`` (this suite) and ``docker …`` (tests/test_compose.py runs
compose's commands) are left out.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from bintrack.keys import parse_key
from support import HUNG, REPO

README = REPO / "README.md"
DOCS = REPO / "docs"
MAX_LINES = 300


def sh_blocks(text: str) -> list[list[tuple[str, str]]]:
    """The README's ``sh`` blocks, each a list of (command, comment)."""
    blocks = []
    for body in re.findall(r"```sh\n(.*?)```", text, flags=re.S):
        commands = []
        for line in body.splitlines():
            command, _, comment = line.partition("  #")
            if command.strip() and not command.strip().startswith("#"):
                commands.append((command.strip(), comment.strip()))
        blocks.append(commands)
    return blocks


def test_the_readme_is_short_and_links_only_inside_the_repository():
    text = README.read_text()
    assert len(text.splitlines()) <= MAX_LINES
    for path in [README, *DOCS.glob("*.md")]:
        body = path.read_text()
        assert "../shared" not in body, path
        for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", body):
            if re.match(r"https?://", target):
                continue
            assert (path.parent / target).resolve().is_relative_to(REPO), (path, target)
            assert (path.parent / target).exists(), (path, target)
    assert (REPO / "LICENSE").read_text().lstrip().startswith("Apache License")


def test_the_design_key_table_is_the_key_grammar():
    rows = re.findall(r"^\| `(bintrack/<net>/[^`]+)` \| `(\w+)` \|", (DOCS / "design.md").read_text(), flags=re.M)
    assert len(rows) >= 19
    names = {"<net>": "net1", "<sensor>": "n17", "<service>": "peer_agent", "<id>": "host-1", "<r>": "r0c1"}
    for key, kind in rows:
        concrete = key
        for placeholder, value in names.items():
            concrete = concrete.replace(placeholder, value)
        assert parse_key(concrete).kind == kind, key


class Running:
    """A command left running; ``lines`` collects its output."""

    def __init__(self, argv: list[str], cwd: Path):
        self.argv = argv
        self.proc = subprocess.Popen(argv, cwd=cwd, text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        self.lines: list[str] = []
        self.changed = threading.Condition()
        self.reader = threading.Thread(target=self._drain, daemon=True)
        self.reader.start()

    def _drain(self) -> None:
        for line in self.proc.stdout:
            with self.changed:
                self.lines.append(line.rstrip())
                self.changed.notify_all()
        with self.changed:
            self.changed.notify_all()

    def wait_until(self, ready) -> None:
        with self.changed:
            self.changed.wait_for(lambda: ready(self.lines) or not self.reader.is_alive(), HUNG)
        assert ready(self.lines), f"{shlex.join(self.argv)} ended or said nothing:\n" + "\n".join(self.lines[-30:])

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        code = self.proc.wait(timeout=HUNG)
        self.reader.join(HUNG)
        return code


def argv_of(command: str) -> list[str] | None:
    """What to run for a README command (None: left out)."""
    words = shlex.split(command)
    if words[:2] == ["make", "demo"]:
        return [sys.executable, "-m", "bintrack.cli", "demo"]
    if words[0] in ("make", "docker", "source"):
        return None
    if words[0] == "bintrack":
        return [sys.executable, "-m", "bintrack.cli", *words[1:]]
    if words[0] == "python":
        return [sys.executable, *words[1:]]
    raise AssertionError(f"a README command this test does not know how to run: {command}")


def ready_check(argv: list[str]):
    if argv[3:4] == ["up"]:
        return lambda lines: any(line.startswith("up: t=") and "events 0 " not in line for line in lines)
    return lambda lines: bool(lines)


NETNS_ENV = "BINTRACK_README_NETNS"


def _own_network_namespace() -> list[str] | None:
    """A command prefix that runs a command in a network namespace of its own (only loopback,
    nothing else listening), or None where that cannot be had (not root, no unshare)."""
    if os.environ.get(NETNS_ENV) or os.geteuid() != 0 or not (shutil.which("unshare") and shutil.which("ip")):
        return None
    probe = subprocess.run(["unshare", "--net", "true"], capture_output=True)
    return ["unshare", "--net", "sh", "-c", 'ip link set lo up && exec "$@"', "sh"] if probe.returncode == 0 else None


@pytest.mark.slow
def test_every_command_in_the_readme_runs_as_written(tmp_path):
    # The README's commands take the default ports (router 7447, map 8080) as a user would; in
    # a network namespace of their own they meet no other program and no other test.
    isolated = _own_network_namespace()
    if isolated is not None:
        result = subprocess.run([*isolated, sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p",
                                 "no:xdist", "-s", f"{Path(__file__)}::test_every_command_in_the_readme_runs_as_written",
                                 "--basetemp", str(tmp_path / "inner")],
                                cwd=REPO, capture_output=True, text=True, timeout=HUNG,
                                env={**os.environ, NETNS_ENV: "1"})
        assert result.returncode == 0, result.stdout[-6000:] + result.stderr[-2000:]
        return
    with socket.socket() as probe:
        try:
            probe.bind(("127.0.0.1", 7447))
        except OSError:
            pytest.skip("the README's commands use the router port 7447, which another program holds")
    for name in ("datasets", "examples"):
        (tmp_path / name).symlink_to(REPO / name)
    text = README.read_text()
    demo_output = None
    for block in sh_blocks(text):
        running: list[Running] = []
        try:
            for command, comment in block:
                argv = argv_of(command)
                if argv is None:
                    continue
                if "until Ctrl-C" in comment:
                    process = Running(argv, tmp_path)
                    running.append(process)
                    process.wait_until(ready_check(argv))
                    continue
                result = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=HUNG)
                assert result.returncode == 0, f"{command}:\n{result.stderr[-3000:]}"
                if argv[3:4] == ["demo"]:
                    demo_output = result.stdout
        finally:
            codes = [(process, process.stop()) for process in reversed(running)]
        for process, code in codes:
            assert code in (0, 130), f"{shlex.join(process.argv)} exited {code}:\n" + "\n".join(process.lines[-30:])
    # What the README says the demo prints, it prints.
    assert demo_output is not None
    shown = re.search(r"metrics against the truth:\n\n```\n(.*?)```", text, flags=re.S).group(1)
    printed = {line.rstrip() for line in demo_output.splitlines()}
    for line in shown.splitlines():
        if line.strip():
            assert line.rstrip() in printed, line
