"""Linux network namespaces and links through iproute2's ``ip`` command: what the site network
(:mod:`bintrack.hosts.site_network`) is made of. Needs root (CAP_NET_ADMIN and CAP_SYS_ADMIN);
:func:`unavailable` says in one line why namespaces cannot be made here."""

from __future__ import annotations

import json
import os
import shutil
import subprocess

from bintrack.errors import BintrackError

IP = "ip"
TCP_RETRIES = 2  # retransmissions before a connection is given up: about 1.4 s (200 ms doubling)


class NetnsError(BintrackError):
    """An ``ip`` command failed; the text is its command and its error, one line."""


def ip(*args: str, namespace: str | None = None, check: bool = True) -> str:
    """Run ``ip [-n NAMESPACE] ARGS``; its stdout. Raises :class:`NetnsError` if it fails and ``check``."""
    argv = [IP, *(("-n", namespace) if namespace else ()), *args]
    done = subprocess.run(argv, capture_output=True, text=True)
    if check and done.returncode != 0:
        reason = " ".join(done.stderr.split()) or f"status {done.returncode}"
        raise NetnsError(f"{' '.join(argv)}: {reason}")
    return done.stdout


def unavailable() -> str | None:
    """Why network namespaces cannot be made on this machine (not root, no ``ip``), or None."""
    if shutil.which(IP) is None:
        return "the ip command (iproute2) is not installed"
    if os.geteuid() != 0:
        return "network namespaces need root (run as root, or without --hosts)"
    return None


def namespaces() -> list[str]:
    """The names of the machine's named network namespaces (``ip netns list``)."""
    return [line.split()[0] for line in ip("netns", "list").splitlines() if line.strip()]


def links(namespace: str | None = None) -> list[str]:
    """The names of the network interfaces of ``namespace`` (None: this process's own)."""
    return [link["ifname"] for link in json.loads(ip("-j", "link", "show", namespace=namespace) or "[]")]


def add_namespace(name: str) -> None:
    """A new network namespace ``name`` with its loopback up (a site's services reach its router
    over the site's own address, which is local traffic)."""
    ip("netns", "add", name)
    ip("link", "set", "lo", "up", namespace=name)
    # a peer that stops acknowledging is given up after about 1.4 s of retransmissions (the
    # default, 15 retries, takes 15 minutes): Zenoh's lease does not end a link whose sends
    # are blocked on a full socket, and reconnects on a link so left do not work (eclipse-zenoh/zenoh#1886)
    subprocess.run(exec_argv(name, ["sysctl", "-q", "-w", f"net.ipv4.tcp_retries2={TCP_RETRIES}"]), check=True,
                   capture_output=True)


def delete_namespace(name: str) -> None:
    """Remove namespace ``name`` (its interfaces go with it, and so do the veth peers of those
    interfaces in other namespaces); nothing if it is gone already."""
    if name in namespaces():
        ip("netns", "delete", name)


def exec_argv(namespace: str, argv: list[str]) -> list[str]:
    """``argv`` run inside ``namespace``: ``ip netns exec`` enters it and execs the command, so
    the process keeps its pid and its parent."""
    return [IP, "netns", "exec", namespace, *argv]
