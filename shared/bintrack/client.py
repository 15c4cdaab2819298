"""The public client API, kept at ``bintrack.client`` for programs that import it; it lives in
:mod:`bintrack.live.network_client`."""

from bintrack.live.network_client import BintrackClient, Subscription

__all__ = ["BintrackClient", "Subscription"]
