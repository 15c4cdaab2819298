"""Who may use the map: the checks of a web application that may be reached from elsewhere.

* **Host.** A request must name this machine: an IP address, ``localhost``, or this host's own
  name. Another name is refused: a page of another site whose name an attacker points at this
  address (DNS rebinding) would otherwise read the map as if it were its own.
* **Origin.** A browser names the page that opened a request (WebSocket, fetch) in ``Origin``;
  only the map's own origin is admitted. A request without one (``curl``, a script) passes this
  check: no browser page stands behind it.
* **Token.** Served on anything but loopback the map needs a token (``--map-token``): given in
  the URL once (``?token=…``), then kept in a cookie (HttpOnly, SameSite=Strict) for the page's
  later requests. Without one, the map refuses to start there.

Pages never change the stack: what they send only asks for a fresh snapshot, or moves a
recording's own player.
"""

from __future__ import annotations

import hmac
import ipaddress
import logging
import os
import socket
from urllib.parse import urlsplit

from aiohttp import web

from bintrack.errors import CommandError

TOKEN_COOKIE = "bintrack_map_token"
TOKEN_ENV = "BINTRACK_MAP_TOKEN"  # how `up` hands the token to its map, out of the process list
LOOPBACK_NAMES = ("localhost",)

log = logging.getLogger("bintrack")


def is_loopback(bind: str) -> bool:
    """Whether address ``bind`` is reachable from this machine only ('' and 0.0.0.0 are every interface)."""
    if bind.lower() in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(bind.strip("[]")).is_loopback
    except ValueError:
        return False


def token_from(option: str | None) -> str | None:
    """The map's token: the option's, else ``$BINTRACK_MAP_TOKEN``'s, else None."""
    return option or os.environ.get(TOKEN_ENV) or None


def check_bind(bind: str, token: str | None, who: str = "map") -> None:
    """CommandError (one line) if the map would be served beyond loopback without a token."""
    if not is_loopback(bind) and not token:
        raise CommandError(f"the {who} on {bind or 'every interface'} would be open to any machine that reaches it: "
                           "give --map-token TOKEN (the page's URL then carries it), or serve it on 127.0.0.1")


def _host_name(host: str) -> str:
    """The name in a Host header or an origin's netloc, without the port."""
    host = host.strip().lower()
    if host.startswith("["):
        return host[1:host.find("]")] if "]" in host else host
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


class MapAccess:
    """The checks above for a map served with ``token`` (None: no token asked for)."""

    def __init__(self, token: str | None):
        self.token = token
        self.names = {*LOOPBACK_NAMES, socket.gethostname().lower(), socket.getfqdn().lower()}
        self.refused: dict[str, int] = {}

    def host_ok(self, host: str | None) -> bool:
        if not host:
            return False
        name = _host_name(host)
        if name in self.names:
            return True
        try:
            ipaddress.ip_address(name)
            return True
        except ValueError:
            return False

    @staticmethod
    def origin_ok(origin: str | None, host: str | None) -> bool:
        if origin is None:
            return True
        parts = urlsplit(origin)
        return parts.scheme in ("http", "https") and bool(host) and parts.netloc.lower() == host.lower()

    def _refuse(self, reason: str, status: type[web.HTTPException] = web.HTTPForbidden) -> web.HTTPException:
        count = self.refused[reason] = self.refused.get(reason, 0) + 1
        if count == 1:
            log.warning("view: refused a request: %s (further ones are only counted)", reason)
        return status(text=f"bintrack map: {reason}\n")

    def middleware(self):
        @web.middleware
        async def check(request: web.Request, handler):
            host = request.headers.get("Host")
            if not self.host_ok(host):
                raise self._refuse(f"Host {host!r} does not name this machine (DNS rebinding?)")
            origin = request.headers.get("Origin")
            if not self.origin_ok(origin, host):
                raise self._refuse(f"a page of {origin} is not the map's own")
            given = request.query.get("token")
            if self.token is not None:
                supplied = given if given is not None else request.cookies.get(TOKEN_COOKIE, "")
                if not hmac.compare_digest(supplied.encode(), self.token.encode()):
                    raise self._refuse("no valid map token (open the URL with ?token=…)", web.HTTPUnauthorized)
            response = await handler(request)
            if self.token is not None and given is not None and not isinstance(response, web.WebSocketResponse):
                response.set_cookie(TOKEN_COOKIE, self.token, httponly=True, samesite="Strict", path="/")
            return response

        return check
