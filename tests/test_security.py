"""The secure profile (deploy/secure/) on a real router on loopback: certificates, mutual TLS,
per-role access control, and the whole stack under it giving the offline rows."""

from __future__ import annotations

import stat
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import zenoh
from cryptography import x509

from bintrack.cli import main as cli
from bintrack.formats import TruthRow, open_dataset, read_tracks, write_dataset
from bintrack.live.bus import client_config as plain_client_config
from bintrack.live.secure_profile import awaiting_token_holders, client_config, restrict_sensor_agents, role_of, router_config
from bintrack.messages import Clock, Track, TrackSet, encode

from conftest import REPO, free_port

DARPA3 = REPO / "datasets" / "darpa-grid-3"
NET = "bintrack/sec"


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("certs")
    assert cli.main(["certs", "--out", str(folder)]) == 0
    return folder


def bintrack(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bintrack.cli", *args], capture_output=True, text=True,
                          timeout=300, cwd=REPO)


def test_certs_are_signed_by_the_ca_with_the_role_as_common_name_and_private_keys_0600(certs, tmp_path):
    ca = x509.load_pem_x509_certificate((certs / "ca.pem").read_bytes())
    for role in ("router", "sensor_agent", "peer_agent", "basestation", "replay", "recorder", "viewer"):
        cert = x509.load_pem_x509_certificate((certs / f"{role}.pem").read_bytes())
        cert.verify_directly_issued_by(ca)
        assert cert.subject.get_attributes_for_oid(x509.NameOID.COMMON_NAME)[0].value == role
        assert stat.S_IMODE((certs / f"{role}-key.pem").stat().st_mode) == 0o600
    assert stat.S_IMODE((certs / "ca-key.pem").stat().st_mode) == 0o600
    # rotation: a new certificate for one role from the same CA; the key never printed
    result = bintrack("certs", "--out", str(tmp_path), "--roles", "viewer", "--ca", str(certs))
    assert result.returncode == 0, result.stderr
    assert "PRIVATE KEY" not in result.stdout + result.stderr
    new = x509.load_pem_x509_certificate((tmp_path / "viewer.pem").read_bytes())
    new.verify_directly_issued_by(ca)
    assert stat.S_IMODE((tmp_path / "viewer-key.pem").stat().st_mode) == 0o600


@pytest.fixture
def secure_router(certs):
    endpoint = f"tls/127.0.0.1:{free_port()}"
    router = zenoh.open(router_config(certs, [endpoint]))
    try:
        yield endpoint
    finally:
        router.close()


class Observer:
    """A recorder-role session (reads everything): the keys it has seen, waited on by event."""

    def __init__(self, certs: Path, endpoint: str):
        self.session = zenoh.open(client_config("recorder", certs, [endpoint]))
        self.seen: list[str] = []
        self.changed = threading.Condition()
        self.subscriber = self.session.declare_subscriber(f"{NET}/**", self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        with self.changed:
            self.seen.append(str(sample.key_expr))
            self.changed.notify_all()

    def wait_for(self, *keys: str) -> list[str]:
        with self.changed:
            assert self.changed.wait_for(lambda: all(k in self.seen for k in keys), 20), self.seen
            return list(self.seen)

    def close(self) -> None:
        self.subscriber.undeclare()
        self.session.close()


def test_each_role_may_do_only_what_its_policy_says(certs, secure_router):
    observer = Observer(certs, secure_router)
    sessions = {role: zenoh.open(client_config(role, certs, [secure_router]))
                for role in ("sensor_agent", "replay", "viewer", "basestation")}
    tracks = encode(TrackSet(t=1.0, tracker="mcmcda", tracks=[Track(track=1, x=1.0, y=2.0)]))
    try:
        sensor, replay, viewer, base = (sessions[r] for r in ("sensor_agent", "replay", "viewer", "basestation"))
        deployment = replay.declare_queryable(f"{NET}/deployment", lambda q: q.reply(f"{NET}/deployment", b"d"))
        # a sensor certificate may put transitions, not tracks nor the clock
        sensor.put(f"{NET}/tracks", tracks)
        sensor.put(f"{NET}/clock", encode(Clock(t=1e6)))
        sensor.put(f"{NET}/raw/n001", b"x")
        sensor.put(f"{NET}/sensor/n001/transition", b"t")  # allowed: the marker
        seen = observer.wait_for(f"{NET}/sensor/n001/transition")
        assert f"{NET}/tracks" not in seen and f"{NET}/clock" not in seen and f"{NET}/raw/n001" not in seen
        # the viewer may put nothing, but may ask
        for key in ("tracks", "clock", "control/eos", "sensor/n002/transition", "peer/n001/estimate"):
            viewer.put(f"{NET}/{key}", b"x")
        assert [r.ok.payload.to_bytes() for r in viewer.get(f"{NET}/deployment", timeout=5) if r.ok] == [b"d"]
        replay.put(f"{NET}/clock", encode(Clock(t=1.0)))  # allowed: the replay's clock
        base.put(f"{NET}/tracks", tracks)  # allowed: the base station's tracks
        seen = observer.wait_for(f"{NET}/clock", f"{NET}/tracks")
        assert seen.count(f"{NET}/clock") == 1 and seen.count(f"{NET}/tracks") == 1, seen
        assert not [k for k in seen if "eos" in k or "n002" in k or "estimate" in k], seen
        # and the replay may not publish tracks, the base station no clock
        replay.put(f"{NET}/tracks", tracks)
        base.put(f"{NET}/clock", encode(Clock(t=2.0)))
        base.put(f"{NET}/fusion/reports", b"r")  # the markers
        replay.put(f"{NET}/raw/n001", b"x")
        seen = observer.wait_for(f"{NET}/fusion/reports", f"{NET}/raw/n001")
        assert seen.count(f"{NET}/clock") == 1 and seen.count(f"{NET}/tracks") == 1, seen
        deployment.undeclare()
    finally:
        for session in sessions.values():
            session.close()
        observer.close()


def test_a_client_without_a_certificate_or_from_another_ca_cannot_connect(certs, secure_router, tmp_path):
    # TLS with the right CA but no certificate of its own
    config = client_config("viewer", certs, [secure_router])
    config.insert_json5("transport/link/tls/connect_certificate", "null")
    config.insert_json5("transport/link/tls/connect_private_key", "null")
    with pytest.raises(zenoh.ZError):
        zenoh.open(config)
    # a certificate of another CA
    other = tmp_path / "other"
    assert cli.main(["certs", "--out", str(other), "--roles", "viewer"]) == 0
    with pytest.raises(zenoh.ZError):
        zenoh.open(client_config("viewer", other, [secure_router]))
    # plain TCP to the TLS port
    with pytest.raises(zenoh.ZError):
        zenoh.open(plain_client_config(["tcp/" + secure_router.removeprefix("tls/")]))
    # and the genuine viewer can
    zenoh.open(client_config("viewer", certs, [secure_router])).close()


def test_the_secure_stack_gives_the_offline_rows(certs, tmp_path):
    ds = open_dataset(DARPA3)
    folder = write_dataset(tmp_path / "slice", ds.deployment, [e for e in ds.events() if 10.0 <= e.t < 40.0],
                           [TruthRow(*r) for r in ds.truth() if 10.0 <= r.t < 40.0])
    recording = tmp_path / "secure.mcap"
    up = bintrack("up", str(folder), "--speed", "0", "--tracker", "equal-weight", "--record", str(recording),
                  "--exit-at-end", "--secure", "--certs", str(certs), "--listen", f"tls/127.0.0.1:{free_port()}",
                  "--view-port", str(free_port()))  # the map runs as the viewer role
    assert up.returncode == 0, up.stderr[-3000:]
    assert "bad payloads" not in up.stderr and "PRIVATE KEY" not in up.stderr
    offline = tmp_path / "offline.csv"
    assert bintrack("track", str(folder), "--tracker", "equal-weight", "--out", str(offline)).returncode == 0
    expected = read_tracks(offline)
    assert len(expected) > 20
    for what in ("estimates", "tracks"):
        exported = tmp_path / f"{what}.csv"
        assert bintrack("export", str(recording), "--what", what, "--out", str(exported)).returncode == 0
        assert read_tracks(exported) == expected, what
    assert b"PRIVATE KEY" not in recording.read_bytes()


def test_up_secure_needs_a_tls_endpoint_and_the_certificates(certs, tmp_path, capsys):
    assert cli.main(["up", str(DARPA3), "--secure", "--certs", str(certs), "--listen", "tcp/127.0.0.1:1"]) == 2
    assert "--secure needs a tls/ endpoint" in capsys.readouterr().err
    assert cli.main(["up", str(DARPA3), "--secure", "--certs", str(tmp_path), "--listen", "tls/127.0.0.1:1"]) == 2
    assert "make the certificates with `bintrack certs" in capsys.readouterr().err


def test_the_compose_override_runs_every_service_of_the_base_file_under_its_role():
    import yaml

    base = yaml.safe_load((REPO / "docker-compose.yml").read_text())["services"]
    secure = yaml.safe_load((REPO / "docker-compose.secure.yml").read_text())["services"]
    assert set(secure) == set(base)
    assert secure["router"]["command"] == ["-c", "/secure/router.json5"]
    for name, service in secure.items():
        assert {"./deploy/secure:/secure:ro", "./certs:/certs:ro"} <= set(service["volumes"]), name
        if name == "router":
            continue
        role = ["-c", f"/secure/{role_of(name)}.json5"]
        tls = [{"tcp/router:7447": "tls/router:7447"}.get(a, a) for a in base[name]["command"]]
        assert service["command"] == list(awaiting_token_holders(tls)) + role, name
        health = [{"tcp/router:7447": "tls/router:7447"}.get(a, a) for a in base[name]["healthcheck"]["test"]]
        if role_of(name) == "viewer":  # no liveliness token to probe: the page answers instead
            assert "state.json" in " ".join(service["healthcheck"]["test"]), name
        else:
            assert service["healthcheck"]["test"] == health + role, name
        config = zenoh.Config.from_file(str(REPO / "deploy" / "secure" / f"{role_of(name)}.json5"))
        assert "/certs/" in str(config.get_json("transport/link/tls/connect_certificate"))
    zenoh.Config.from_file(str(REPO / "deploy" / "secure" / "router.json5"))


def test_a_sensor_agent_restricted_to_its_sensors_cannot_put_another_sensors_transitions(certs, tmp_path):
    assert cli.main(["certs", "--out", str(certs), "--ca", str(certs), "--roles", "sensor_agent-north"]) == 0
    endpoint = f"tls/127.0.0.1:{free_port()}"
    config = router_config(certs, [endpoint])
    restrict_sensor_agents(config, {"sensor_agent-north": ["n001", "n002"]})
    router = zenoh.open(config)
    observer = Observer(certs, endpoint)
    north = _client("sensor_agent-north", certs, endpoint)
    try:
        north.put(f"{NET}/sensor/n003/transition", b"t")  # another agent's sensor
        north.put(f"{NET}/tracks", b"t")
        north.put(f"{NET}/sensor/n001/transition", b"t")
        north.put(f"{NET}/control/progress/sensor_agent/north", encode(Clock(t=1.0)))
        north.put(f"{NET}/sensor/n002/transition", b"t")
        seen = observer.wait_for(f"{NET}/sensor/n001/transition", f"{NET}/sensor/n002/transition",
                                 f"{NET}/control/progress/sensor_agent/north")
        assert f"{NET}/sensor/n003/transition" not in seen and f"{NET}/tracks" not in seen, seen
    finally:
        north.close()
        observer.close()
        router.close()


def _client(common_name: str, certs: Path, endpoint: str) -> zenoh.Session:
    """A sensor-agent client whose certificate is ``common_name``'s."""
    config = client_config("sensor_agent", certs, [endpoint])
    config.insert_json5("transport/link/tls/connect_certificate", f'"{certs / (common_name + ".pem")}"')
    config.insert_json5("transport/link/tls/connect_private_key", f'"{certs / (common_name + "-key.pem")}"')
    return zenoh.open(config)
