"""The network of a run's sites on one machine, as separate hosts would have it.

Each site gets a Linux network namespace ``bthost<k>-<site>`` with one interface, ``uplink``,
addressed 198.19.<k>.<i + 2>/24; its veth peer is a port of a bridge in the namespace
``bthost<k>-switch`` (the sites' LAN). This machine itself is the hub site (the operator's host,
where ``up``, replay, the merge and the map run): its interface ``bthost<k>``, 198.19.<k>.1, is
the bridge's last port. Every address is in 198.19.0.0/16, half of 198.18.0.0/15 (RFC 2544, kept
for network benchmarks: never a real LAN's), and no IPv6 address is generated. ``<k>``, the
run's subnet, is claimed with a lock file, so two runs never share one; whatever an earlier
run that was killed left under its claimed ``<k>`` is removed first.

A site's link is cut (:meth:`SiteNetwork.cut`) by taking its bridge port down: its uplink loses
its carrier, its services still reach their router, and nothing crosses to the other sites.
"""

from __future__ import annotations

import fcntl
import ipaddress
import json
import os
import tempfile
from pathlib import Path

from bintrack.hosts.netns import add_namespace, delete_namespace, exec_argv, ip, links, namespaces

PREFIX = "bthost"  # the start of every namespace and interface name a run makes
SUBNETS = 256  # 198.19.<k>.0/24, k < SUBNETS
MAX_SITES = 250  # .2 … .251
UPLINK = "uplink"  # a site's interface
_LOCKS = Path(tempfile.gettempdir()) / f"bintrack-hosts-{os.getuid()}"


def subnet(k: int) -> ipaddress.IPv4Network:
    """Subnet ``k`` of the sites' LAN, in 198.18.0.0/15."""
    return ipaddress.IPv4Network(f"198.19.{k}.0/24")


def leftovers() -> list[str]:
    """The namespaces and this machine's interfaces whose names start with :data:`PREFIX`: none
    once every run has ended."""
    return sorted(n for n in (*namespaces(), *links()) if n.startswith(PREFIX))


class SiteNetwork:
    """The namespaces, bridge and veth links of ``sites`` (names, each a region), made by
    :meth:`create` (or ``with``) and removed by :meth:`remove`, also when making them failed."""

    def __init__(self, sites: list[str]):
        if not sites or len(sites) > MAX_SITES:
            raise ValueError(f"a site network holds 1 to {MAX_SITES} sites, got {len(sites)}")
        if len(set(sites)) != len(sites) or any(not s or "/" in s or s == "switch" for s in sites):
            raise ValueError(f"site names must be distinct, non-empty, without '/' and not 'switch': {sites}")
        self.sites = list(sites)
        self.k: int | None = None
        self._lock = None

    # -- names and addresses -------------------------------------------------------------------

    @property
    def tag(self) -> str:
        """``bthost<k>``: this run's prefix, and the name of this machine's interface."""
        return f"{PREFIX}{self.k}"

    @property
    def switch(self) -> str:
        return f"{self.tag}-switch"

    def namespace(self, site: str) -> str:
        return f"{self.tag}-{site}"

    def namespaces(self) -> list[str]:
        """Every namespace of the run: the switch's, then the sites' in order."""
        return [self.switch, *map(self.namespace, self.sites)]

    def _host(self, i: int) -> str:
        return str(subnet(self.k).network_address + i)

    @property
    def hub_address(self) -> str:
        """This machine's address on the sites' LAN."""
        return self._host(1)

    def address(self, site: str) -> str:
        """Site ``site``'s address (its router listens on it; its services connect to it)."""
        return self._host(self.sites.index(site) + 2)

    def argv(self, site: str, argv: list[str]) -> list[str]:
        """``argv`` run on site ``site`` (in its namespace)."""
        return exec_argv(self.namespace(site), argv)

    # -- making and removing ---------------------------------------------------------------------

    def create(self) -> SiteNetwork:
        """Claim a subnet, remove an earlier run's leftovers under it, make the switch, this
        machine's link and each site's namespace and link. Everything made is removed again if a
        step fails (:class:`~bintrack.hosts.netns.NetnsError`)."""
        self._claim()
        try:
            self._sweep()
            add_namespace(self.switch)
            ip("link", "add", "bridge", "type", "bridge", namespace=self.switch)
            self._quiet_up("bridge", self.switch)
            self._link(self.tag, None, "hub", self.hub_address)
            for i, site in enumerate(self.sites):
                add_namespace(self.namespace(site))
                self._link(UPLINK, self.namespace(site), f"p{i}", self.address(site))
        except BaseException:
            self.remove()
            raise
        return self

    def _link(self, name: str, namespace: str | None, port: str, address: str) -> None:
        """A veth pair: ``name`` in ``namespace`` (None: this machine's) with ``address``, its
        peer ``port`` on the bridge."""
        ip("link", "add", name, *(("netns", namespace) if namespace else ()), "type", "veth", "peer", "name", port,
           "netns", self.switch)
        ip("link", "set", port, "master", "bridge", namespace=self.switch)
        self._quiet_up(port, self.switch)
        ip("address", "add", f"{address}/{subnet(self.k).prefixlen}", "dev", name, namespace=namespace)
        self._quiet_up(name, namespace)

    @staticmethod
    def _quiet_up(name: str, namespace: str | None) -> None:
        """Bring ``name`` up without an IPv6 link-local address (only the addresses given)."""
        ip("link", "set", "dev", name, "addrgenmode", "none", namespace=namespace)
        ip("link", "set", "dev", name, "up", namespace=namespace)

    def remove(self) -> None:
        """Remove every namespace of the run (the sites' and the switch's, which takes this
        machine's link with it) and release the subnet; idempotent."""
        if self.k is None:
            return
        try:
            self._sweep()
        finally:
            self._lock.close()
            self.k, self._lock = None, None

    def _sweep(self) -> None:
        mine = f"{self.tag}-"
        for name in namespaces():
            if name.startswith(mine):
                delete_namespace(name)
        if self.tag in links():
            # the switch's namespace going takes this end of its veth pair with it, asynchronously:
            # it may vanish between the listing and the delete
            ip("link", "delete", self.tag, check=False)
            if self.tag in links():
                ip("link", "delete", self.tag)

    def _claim(self) -> None:
        """Hold the lock of a free subnet ``k`` (a file per subnet, locked while this run lives)."""
        _LOCKS.mkdir(exist_ok=True)
        start = os.getpid() % SUBNETS
        for step in range(SUBNETS):
            k = (start + step) % SUBNETS
            handle = open(_LOCKS / str(k), "a")
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                handle.close()
                continue
            self.k, self._lock = k, handle
            return
        raise RuntimeError(f"all {SUBNETS} site subnets are in use")

    def __enter__(self) -> SiteNetwork:
        return self.create()

    def __exit__(self, *exc) -> None:
        self.remove()

    # -- traffic and faults ------------------------------------------------------------------------

    def link_traffic(self, site: str | None = None) -> dict[str, int]:
        """What crossed site ``site``'s link (None: this machine's, the hub's) so far, as the
        kernel counts it: ``rx_bytes``, ``tx_bytes``, ``rx_packets``, ``tx_packets`` (received
        and sent by that site)."""
        name, namespace = (self.tag, None) if site is None else (UPLINK, self.namespace(site))
        stats = json.loads(ip("-s", "-j", "link", "show", "dev", name, namespace=namespace))[0]["stats64"]
        return {f"{way}_{what}": stats[way][what] for way in ("rx", "tx") for what in ("bytes", "packets")}

    def cut(self, site: str) -> None:
        """Take site ``site``'s link down (its bridge port): it is cut off from every other site."""
        ip("link", "set", "dev", f"p{self.sites.index(site)}", "down", namespace=self.switch)

    def heal(self, site: str) -> None:
        """Bring site ``site``'s link up again."""
        ip("link", "set", "dev", f"p{self.sites.index(site)}", "up", namespace=self.switch)
