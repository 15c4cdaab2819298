"""``python -m bintrack.services.health``, the compose healthcheck, against a real router."""

from __future__ import annotations

import subprocess

import pytest
import zenoh

from bintrack.live.session_options import client_config
from bintrack.keys import Keys
from support import free_port, python_module


def health(*args: str) -> subprocess.CompletedProcess:
    return python_module("bintrack.services.health", *args)


@pytest.fixture
def token(zenoh_router):
    """A session holding the liveliness token of a ``recorder`` instance on net ``health``."""
    session = zenoh.open(client_config([zenoh_router]))
    token = session.liveliness().declare_token(Keys("health").alive("recorder", "box-1"))
    yield zenoh_router
    token.undeclare()
    session.close()


def test_a_live_instance_is_healthy(token):
    result = health("recorder", "-e", token, "--net", "health")
    assert result.returncode == 0, result.stderr
    assert result.stdout == "health: recorder: alive (1 instance: box-1)\n"


@pytest.mark.parametrize("service, net", [("basestation", "health"), ("recorder", "other")])
def test_no_token_is_unhealthy_with_one_line(token, service, net):
    result = health(service, "-e", token, "--net", net)
    assert result.returncode == 1
    assert result.stderr == (f"health: {service}: no live instance "
                             f"(no liveliness token on bintrack/{net}/alive/{service}/*)\n")


def test_no_router_is_unhealthy_with_one_line():
    result = health("recorder", "-e", f"tcp/127.0.0.1:{free_port()}", "--wait", "0.2")
    assert result.returncode == 1
    assert result.stderr.count("\n") == 1 and "no Zenoh router reachable" in result.stderr


def test_bad_names_are_refused():
    assert health("sensor/agent").returncode == 2
    result = health("recorder", "--net", "a*b", "--wait", "0")
    assert result.returncode == 1 and "network name 'a*b'" in result.stderr
