"""The secure profile (``deploy/secure/``): mutual TLS and per-role access control on Zenoh.

The profile's JSON5 files name the certificates by their compose mount paths (``/certs/…``);
:func:`router_config` and :func:`client_options` put a local certificate folder (made by
``bintrack certs``) in their place, so that ``bintrack up --secure`` runs the same profile on
loopback. A client's role is its certificate's common name, which the router's
``access_control`` matches. The routers of ``up --regions`` run router.json5 too
(:func:`router_options`), each showing the ``router`` certificate both to its clients and to
the routers it connects to; the ``router`` policy lets routers exchange ``bintrack/**``.
"""

from __future__ import annotations

import ipaddress
import json
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path

import zenoh
from cryptography import x509

from bintrack.errors import CommandError
from bintrack.keys import Keys
from bintrack.live.stack import ServiceCommand

PROFILE = Path(__file__).resolve().parents[3] / "deploy" / "secure"
TLS = "transport/link/tls"


def _paths(certs: Path, role: str, side: str) -> dict[str, str]:
    certs = certs.resolve()
    return {f"{TLS}/root_ca_certificate": str(certs / "ca.pem"),
            f"{TLS}/{side}_certificate": str(certs / f"{role}.pem"),
            f"{TLS}/{side}_private_key": str(certs / f"{role}-key.pem")}


def check_certs(certs: Path, roles: Iterable[str]) -> None:
    """Raise FileNotFoundError naming the first certificate or key missing from ``certs``."""
    for role in ("router", *roles):
        for path in _paths(certs, role, "connect").values():
            if not Path(path).is_file():
                raise FileNotFoundError(f"{path} is missing; make the certificates with `bintrack certs --out {certs}`")


def exposed_keys(certs: Path) -> str | None:
    """One line naming what in ``certs`` other users may read or replace — private keys
    (``*-key.pem``) not 0600, the folder writable by them — else None."""
    problems = []
    mode = certs.stat().st_mode & 0o777
    if mode & 0o022:
        problems.append(f"the folder {certs} is {mode:03o} (others may replace its files)")
    keys = [(key.name, key.stat().st_mode & 0o777) for key in sorted(certs.glob("*-key.pem"))]
    open_keys = [f"{name} {mode:03o}" for name, mode in keys if mode & 0o077]
    if open_keys:
        problems.append("private keys readable by others: " + ", ".join(open_keys))
    if not problems:
        return None
    return f"{'; '.join(problems)}: chmod 600 {certs}/*-key.pem and chmod 700 {certs}"


def router_config(certs: Path, listen: Iterable[str], profile: Path = PROFILE) -> zenoh.Config:
    """The secure router's config (``profile``/router.json5) with the certificates of ``certs``
    and listening on ``listen`` (``tls/…`` endpoints)."""
    config = zenoh.Config.from_file(str(profile / "router.json5"))
    for key, value in _paths(certs, "router", "listen").items():
        config.insert_json5(key, json.dumps(value))
    config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    return config


def router_options(certs: Path, profile: Path = PROFILE) -> tuple[str, ...]:
    """The options (``-c``, ``--cfg``) that make ``python -m bintrack.services.router`` a router
    of the secure profile: ``profile``/router.json5 (mutual TLS, the access control) with the
    ``router`` certificate of ``certs`` to listen on its ``-l`` and to connect to the routers of
    its ``-e`` (tls/… endpoints), whose access control sees it as the ``router`` role."""
    options: list[str] = ["-c", str(profile / "router.json5")]
    for key, value in {**_paths(certs, "router", "listen"), **_paths(certs, "router", "connect")}.items():
        options += ["--cfg", f"{key}:{json.dumps(value)}"]
    return tuple(options)


def check_router_names(certs: Path, endpoints: Iterable[str]) -> None:
    """Raise ValueError unless the ``router`` certificate of ``certs`` names the host of each of
    ``endpoints`` (``tls/HOST:PORT``): its clients and the other routers check it when they connect."""
    cert = x509.load_pem_x509_certificate((certs / "router.pem").read_bytes())
    try:
        names = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        names = x509.SubjectAlternativeName([])
    ips, hosts = set(names.get_values_for_type(x509.IPAddress)), set(names.get_values_for_type(x509.DNSName))
    for endpoint in endpoints:
        host = endpoint.partition("/")[2].rpartition(":")[0].strip("[]")
        try:
            named = ipaddress.ip_address(host) in ips
        except ValueError:
            named = host in hosts
        if not named:
            raise ValueError(f"{certs / 'router.pem'} does not name {host}, where a router of --regions listens; "
                             f"make it again with `bintrack certs --out {certs} --roles router --ca {certs}`")


def client_options(role: str, certs: Path, profile: Path = PROFILE) -> tuple[str, ...]:
    """The bus options (``-c``, ``--cfg``) that make a service a ``role`` client of the secure router."""
    options: list[str] = ["-c", str(profile / f"{role}.json5")]
    for key, value in _paths(certs, role, "connect").items():
        options += ["--cfg", f"{key}:{json.dumps(value)}"]
    return tuple(options)


def client_config(role: str, certs: Path, endpoints: Iterable[str], profile: Path = PROFILE) -> zenoh.Config:
    """A ``role`` client session's config of the secure router at ``endpoints``."""
    config = zenoh.Config.from_file(str(profile / f"{role}.json5"))
    for key, value in _paths(certs, role, "connect").items():
        config.insert_json5(key, json.dumps(value))
    config.insert_json5("connect/endpoints", json.dumps(list(endpoints)))
    return config


# services whose role is not their own name: the map and the Foxglove bridge are read-only viewers
ROLE_OF_SERVICE = {"view": "viewer", "foxglove_bridge": "viewer"}


def role_of(service: str) -> str:
    """The secure profile's role of service ``service``."""
    return ROLE_OF_SERVICE.get(service, service)


def secure_commands(commands: Iterable[ServiceCommand], certs: Path, profile: Path = PROFILE) -> list[ServiceCommand]:
    """``commands`` (:func:`bintrack.live.stack.stack_commands` or ``region_stack_commands``),
    each service a client of the secure router in its role (:func:`role_of`), each region's
    router a router of the profile (:func:`router_options`)."""
    return [replace(c, args=(*c.args, *router_options(certs, profile))) if c.name == "router" else
            replace(c, args=(*awaiting_token_holders(c.args), *client_options(role_of(c.name), certs, profile)))
            for c in commands]


def awaiting_token_holders(args: tuple[str, ...] | list[str]) -> tuple[str, ...]:
    """A command's options with replay's ``--wait-for`` without the viewer: a read-only role holds no liveliness token,
    so replay would wait for it for ever."""
    args = list(args)
    if "--wait-for" in args:
        i = args.index("--wait-for") + 1
        args[i] = ",".join(name for name in args[i].split(",") if role_of(name) != "viewer")
    return tuple(args)


def secure_up(commands: Iterable[ServiceCommand], certs: str, listen: str) -> tuple[list[ServiceCommand], zenoh.Config]:
    """``bintrack up --secure``: the services as clients of their roles (the routers of
    ``--regions`` as routers of the profile), and the hub router's config. Raises CommandError
    for a listen endpoint that is not TLS, a missing certificate or a router certificate that
    does not name a region router's address."""
    if not listen.startswith("tls/"):
        raise CommandError(f"--secure needs a tls/ endpoint to listen on, e.g. --listen tls/127.0.0.1:7447; got {listen}")
    commands = list(commands)
    try:
        check_certs(Path(certs), [role_of(c.name) for c in commands])
        check_router_names(Path(certs), [c.args[c.args.index("-l") + 1] for c in commands if c.name == "router"])
        return secure_commands(commands, Path(certs)), router_config(Path(certs), [listen])
    except (FileNotFoundError, ValueError) as exc:
        raise CommandError(str(exc)) from None
    except zenoh.ZError as exc:
        raise CommandError(f"bad secure profile: {exc}") from None


def restrict_sensor_agents(config: zenoh.Config, agents: dict[str, Iterable[str]]) -> None:
    """Add to a secure router's ``config`` one role per sensor agent: certificate common name
    ``name`` may publish the transitions of its ``sensors`` only (and read, serve state and
    report progress as the ``sensor_agent`` role does). ``agents``: common name -> sensor ids."""
    rules = json.loads(config.get_json("access_control/rules"))
    subjects = json.loads(config.get_json("access_control/subjects"))
    policies = json.loads(config.get_json("access_control/policies"))
    base = next(p for p in policies if p["id"] == "sensor_agent")
    for name, sensors in agents.items():
        rules.append({"id": f"{name}-transitions", "messages": ["put"], "flows": ["ingress"], "permission": "allow",
                      "key_exprs": [f"bintrack/*/sensor/{s}/transition" for s in sensors]})
        subjects.append({"id": name, "cert_common_names": [name]})
        policies.append({"id": name, "subjects": [name],
                         "rules": [r for r in base["rules"] if r != "sensor_agent-puts"]
                         + ["sensor_agent-control", f"{name}-transitions"]})
    rules.append({"id": "sensor_agent-control", "messages": ["put"], "flows": ["ingress"], "permission": "allow",
                  "key_exprs": ["bintrack/*/control/progress/sensor_agent/*", "bintrack/*/control/done/sensor_agent/*"]})
    for key, value in (("rules", rules), ("subjects", subjects), ("policies", policies)):
        config.insert_json5(f"access_control/{key}", json.dumps(value))


def pin_tokens(config: zenoh.Config, tokens: dict[str, Iterable[str]]) -> str:
    """Narrow a secure router's ``config`` so that each role may declare only the liveliness
    tokens of its own instances in this run: ``tokens`` maps a role to the token keys of its
    instances (``bintrack/<net>/alive/<service>/<id>``). A client holding a role's certificate can
    then declare no other instance of it (a forged ``alive/sensor_agent/evil`` is denied by the
    router). The region alive tokens stay as they were. Returns the rules as JSON (for the
    routers of ``--regions``, as a ``--cfg access_control/rules:…``)."""
    rules = json.loads(config.get_json("access_control/rules"))
    for rule in rules:
        role = rule["id"].removesuffix("-token")
        if rule["id"].endswith("-token"):
            rule["key_exprs"] = [*sorted(tokens.get(role, ())),
                                 *(k for k in rule["key_exprs"] if "/alive/" not in k)]
            if not rule["key_exprs"]:  # a role with no instance in this run may declare none
                rule["permission"] = "deny"
                rule["key_exprs"] = ["bintrack/**"]
    text = json.dumps(rules)
    config.insert_json5("access_control/rules", text)
    return text


def pin_run_tokens(config: zenoh.Config, commands: Iterable[ServiceCommand], net: str, stack: str) -> tuple[str, ...]:
    """:func:`pin_tokens` for the services of ``up --secure`` (instance ids ``<stack>-<key>``);
    the options that pin them in the routers of ``--regions`` too."""
    tokens: dict[str, list[str]] = {}
    for c in commands:
        if c.name != "router":
            tokens.setdefault(role_of(c.name), []).append(Keys(net).alive(c.name, f"{stack}-{c.key}"))
    return ("--cfg", f"access_control/rules:{pin_tokens(config, tokens)}")
