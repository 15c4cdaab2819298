"""How the routers of sites on separate hosts reach each other (:mod:`bintrack.hosts.site_network`):
each listens on its site's address with the port of the hub's endpoint, and every link of the
mesh runs a short lease, so that a cut link is noticed (and logged by the routers at both ends,
and by the merge for the regions behind it) within about a second rather than Zenoh's default 10 s."""

from __future__ import annotations

import zenoh

from bintrack.hosts.site_network import SiteNetwork

LEASE_MS = 1000  # a link silent this long is closed; keep-alives every LEASE_MS / 4
LEASE_KEY = "transport/link/tx/lease"


def short_lease(config: zenoh.Config, lease_ms: int = LEASE_MS) -> zenoh.Config:
    """``config`` with the mesh's lease, ms (for the hub router ``up`` embeds)."""
    config.insert_json5(LEASE_KEY, str(lease_ms))
    return config


def router_options(lease_ms: int = LEASE_MS) -> tuple[str, ...]:
    """The options that give a site router (``bintrack.services.router``) the mesh's lease, ms.
    A longer one rides out a router too busy to send its keep-alives (a loaded machine) at the
    cost of noticing a cut link later."""
    return ("--cfg", f"{LEASE_KEY}:{lease_ms}")


def port_of(endpoint: str) -> str:
    """The port of a ``tcp/ADDRESS:PORT`` endpoint."""
    scheme, _, address = endpoint.partition("/")
    port = address.rpartition(":")[2]
    if scheme != "tcp" or not port.isdigit():
        raise ValueError(f"sites on hosts need a tcp/ADDRESS:PORT endpoint for the hub, got {endpoint}")
    return port


def hub_endpoint(network: SiteNetwork, listen: str) -> str:
    """Where the hub router listens on the sites' LAN (``listen``'s port on this machine's address)."""
    return f"tcp/{network.hub_address}:{port_of(listen)}"


def site_endpoints(network: SiteNetwork, listen: str) -> list[str]:
    """Where each site's router listens (its address, ``listen``'s port), in the sites' order."""
    port = port_of(listen)
    return [f"tcp/{network.address(site)}:{port}" for site in network.sites]
