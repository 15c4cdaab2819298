"""The whole stack's service command lines, for ``bintrack up`` and docker-compose alike.

``docker-compose.yml`` runs each of these as ``python -m <module> <args>`` in our image; a test
holds the compose file to :func:`stack_commands`, so both start the same processes.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ServiceCommand:
    name: str
    args: tuple[str, ...]

    @property
    def module(self) -> str:
        return f"bintrack.services.{self.name}"

    def argv(self, python: str) -> list[str]:
        """The command line with the interpreter ``python``."""
        return [python, "-m", self.module, *self.args]


def stack_commands(*, tracker: str, endpoint: str, net: str, source: str | None = None, speed: float = 1.0,
                   loop: bool = False, record: str | None = None) -> list[ServiceCommand]:
    """The services in start order: agents and base station, the recorder if ``record``, and
    last the replay of ``source`` (if any), which waits for all the others."""
    bus = ("-e", endpoint, "--net", net)
    services = [
        ServiceCommand("sensor_agent", bus),
        ServiceCommand("peer_agent", ("--tracker", tracker, *bus)),
        ServiceCommand("basestation", ("--tracker", tracker, *bus)),
    ]
    if record is not None:
        services.append(ServiceCommand("recorder", ("--out", record, *bus)))
    if source is not None:
        replay = [source, "--speed", _number(speed), *(["--loop"] if loop else []),
                  "--wait-for", ",".join(s.name for s in services)]
        services.append(ServiceCommand("replay", (*replay, *bus)))
    return services


def _number(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else str(value)
