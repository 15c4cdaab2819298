"""Presence that cannot be forged: a liveliness token declared by another client while the stack
runs, on an open bus and under the secure profile with a service's own certificate, leaves the
run complete (the offline rows, exit 0). On an open bus ``up`` and its services log it once and
ignore it (they count only the tokens of the run's own instances); under ``--secure`` the
router lets each role declare the tokens of its instances in this run only."""

from __future__ import annotations

import contextlib

import pytest
import zenoh

from bintrack.cli import main as cli
from bintrack.keys import Keys
from bintrack.live.secure_profile import client_config as secure_client_config
from bintrack.live.session_options import client_config

from test_faults import Up, exported_tracks, grid_slice, offline_rows  # noqa: F401 (fixtures)

FORGED = ("sensor_agent", "replay", "basestation", "recorder")


@contextlib.contextmanager
def forged_tokens(up: Up, config: zenoh.Config, net: str, services=FORGED):
    """Once ``up``'s router listens: a session of its own declaring ``alive/<service>/evil``,
    held until the block ends. (Declared then, the tokens are there before the replay's first
    sample on any load; at a given event time they could come after a run at ``--speed 0`` ended.)"""
    up.wait_for(lambda line: line.startswith("up: router on "), "up's router")
    session = zenoh.open(config)
    tokens = [session.liveliness().declare_token(Keys(net).alive(s, "evil")) for s in services]
    try:
        yield
    finally:
        for token in tokens:
            token.undeclare()
        session.close()


def test_a_token_forged_on_an_open_bus_is_logged_and_ignored(grid_slice, offline_rows, tmp_path):
    recording = tmp_path / "run.mcap"
    up = Up(str(grid_slice), "--tracker", "mcmcda", "--speed", "0", "--clock-period", "0.05", "--record",
            str(recording), "--exit-at-end")
    with forged_tokens(up, client_config([up.endpoint]), "darpa-grid"):
        assert up.finish() == 0, up.log[-4000:]
    assert exported_tracks(recording, tmp_path) == offline_rows("mcmcda"), up.log[-4000:]
    assert "up: without --secure the bus on tcp/" in up.log
    for service in FORGED:
        assert up.log.count(f"up: ignoring {service}/evil, which joined the bus") == 1, up.log[-4000:]
    # the services too: the base station would otherwise wait for the forged agent's progress
    assert "basestation: ignoring the liveliness token bintrack/darpa-grid/alive/sensor_agent/evil" in up.log


@pytest.fixture(scope="module")
def certs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("certs")
    assert cli.main(["certs", "--out", str(folder)]) == 0
    return folder


def test_a_token_forged_with_the_sensor_agent_certificate_is_refused_by_the_router(grid_slice, offline_rows,
                                                                                   certs, tmp_path):
    recording = tmp_path / "run.mcap"
    up = Up(str(grid_slice), "--tracker", "mcmcda", "--speed", "0", "--clock-period", "0.05", "--record",
            str(recording), "--exit-at-end", "--secure", "--certs", str(certs), scheme="tls")
    config = secure_client_config("sensor_agent", certs, [up.endpoint])
    with forged_tokens(up, config, "darpa-grid", ("sensor_agent",)):
        assert up.finish() == 0, up.log[-4000:]
    assert exported_tracks(recording, tmp_path) == offline_rows("mcmcda"), up.log[-4000:]
    assert "without --secure" not in up.log
    assert "ignoring" not in up.log, up.log[-4000:]  # denied at the router: nobody saw it
