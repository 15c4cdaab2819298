"""Where the map is served: its default address and port, and its listening socket (bound before
the server starts, by ``bintrack up`` for the view it starts, without loading the web server)."""

from __future__ import annotations

import socket

DEFAULT_PORT = 8080
DEFAULT_BIND = "127.0.0.1"


def listening_socket(bind: str, port: int, *, fallback: bool = True) -> socket.socket:
    """A TCP socket bound to ``bind``:``port`` and listening, kept open by the caller so that no
    other program can take the port between this and the serving. If ``port`` is taken and
    ``fallback``, a free port on ``bind`` instead (``getsockname()`` says which). OSError with a
    one-line text if neither can be had."""
    try:
        family, kind, proto, _, address = socket.getaddrinfo(bind or None, port, type=socket.SOCK_STREAM,
                                                             flags=socket.AI_PASSIVE)[0]
    except socket.gaierror as exc:
        raise OSError(f"cannot serve the map on {bind}:{port}: {exc.strerror or exc}") from None
    tried = (port, 0) if fallback and port != 0 else (port,)
    error: OSError | None = None
    for candidate in tried:
        sock = socket.socket(family, kind, proto)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # a page's TIME_WAIT must not block a restart
        try:
            sock.bind((address[0], candidate, *address[2:]))
            sock.listen(128)
        except OSError as exc:
            sock.close()
            error = error or exc
            continue
        return sock
    raise OSError(f"cannot serve the map on {bind}:{port}: {error.strerror or error}")
