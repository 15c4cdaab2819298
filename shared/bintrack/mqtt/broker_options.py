"""Where the broker is and how to log in: an ``mqtt://HOST:PORT`` (``mqtts://`` for TLS) URL, and
secrets from a config file (TOML), never from the command line:

    [broker]
    username = "bintrack"
    password_file = "/run/secrets/mqtt"   # or password = "…" in this file (mode 600)
    ca = "ca.pem"                          # TLS: the CA that signed the broker's certificate
    cert = "client.pem"                    # TLS client certificate and key, if the broker asks
    key = "client.key"
    client_id = "bintrack-bridge"          # the persistent session's name

Relative paths are relative to the file. The password is kept out of ``repr`` and logs.
"""

from __future__ import annotations

import os
import stat
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlsplit

DEFAULT_PORT = {"mqtt": 1883, "mqtts": 8883}
KEYS = {"username", "password", "password_file", "ca", "cert", "key", "tls", "client_id", "keepalive"}


class BrokerConfigError(ValueError):
    """A broker URL or config file that cannot be used; ``str()`` is one line, without secrets."""


@dataclass(frozen=True)
class BrokerOptions:
    host: str
    port: int
    tls: bool = False
    username: str | None = None
    password: str | None = field(default=None, repr=False)
    ca: str | None = None
    cert: str | None = None
    key: str | None = None
    client_id: str | None = None
    keepalive: int = 30

    @property
    def url(self) -> str:
        """The broker as ``mqtt[s]://HOST:PORT``, with no user or secret: what logs show."""
        return f"{'mqtts' if self.tls else 'mqtt'}://{self.host}:{self.port}"


def parse_broker_url(text: str) -> tuple[str, int, bool]:
    """``mqtt://HOST[:PORT]`` or ``mqtts://HOST[:PORT]`` → (host, port, tls). A URL with a
    user or password is refused: secrets go in the config file."""
    parts = urlsplit(text)
    if parts.scheme not in DEFAULT_PORT or not parts.hostname:
        raise BrokerConfigError(f"expected mqtt://HOST:PORT or mqtts://HOST:PORT, got {text.split('@')[-1]!r}")
    if parts.username or parts.password:
        raise BrokerConfigError("a broker URL must not carry a user or password; put them in the --mqtt-config file")
    if parts.path not in ("", "/") or parts.query:
        raise BrokerConfigError(f"a broker URL is mqtt://HOST:PORT, got {text!r}")
    try:
        port = parts.port or DEFAULT_PORT[parts.scheme]
    except ValueError:
        raise BrokerConfigError(f"bad port in {text!r}") from None
    return parts.hostname, port, parts.scheme == "mqtts"


def broker_options(url: str, config: str | Path | None = None) -> BrokerOptions:
    """The options of ``url`` with the ``[broker]`` table of the file ``config`` (if any)."""
    host, port, tls = parse_broker_url(url)
    if config is None:
        return BrokerOptions(host, port, tls)
    path = Path(config)
    try:
        data = tomllib.loads(path.read_text())
    except OSError as exc:
        raise BrokerConfigError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise BrokerConfigError(f"{path}: not TOML: {exc}") from None
    section = data.get("broker")
    if not isinstance(section, dict):
        raise BrokerConfigError(f"{path}: no [broker] table")
    unknown = sorted(set(section) - KEYS)
    if unknown:
        raise BrokerConfigError(f"{path}: unknown key(s) in [broker]: {', '.join(unknown)} (known: {', '.join(sorted(KEYS))})")
    base = path.parent

    def file(name: str) -> str | None:
        value = section.get(name)
        if value is None:
            return None
        found = (base / value) if not os.path.isabs(value) else Path(value)
        if not found.is_file():
            raise BrokerConfigError(f"{path}: {name}: no file {found}")
        return str(found)

    password = section.get("password")
    if password is not None and _shared(path):
        raise BrokerConfigError(f"{path}: holds a password but others can read it; chmod 600 {path}")
    secret_file = file("password_file")
    if secret_file is not None:
        if password is not None:
            raise BrokerConfigError(f"{path}: give password or password_file, not both")
        password = Path(secret_file).read_text().strip()
    for name in ("username", "client_id"):
        if name in section and not isinstance(section[name], str):
            raise BrokerConfigError(f"{path}: {name} must be a string")
    keepalive = section.get("keepalive", 30)
    if not isinstance(keepalive, int) or keepalive < 5:
        raise BrokerConfigError(f"{path}: keepalive must be a whole number of seconds >= 5")
    ca, cert, key = file("ca"), file("cert"), file("key")
    if (cert is None) != (key is None):
        raise BrokerConfigError(f"{path}: give cert and key together")
    return BrokerOptions(host, port, tls or bool(section.get("tls")) or ca is not None, section.get("username"),
                         password, ca, cert, key, section.get("client_id"), keepalive)


def _shared(path: Path) -> bool:
    return bool(path.stat().st_mode & (stat.S_IRWXG | stat.S_IRWXO))
