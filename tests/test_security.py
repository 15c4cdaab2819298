"""The secure profile (deploy/secure/) on a real router on loopback: certificates, mutual TLS,
per-role access control, and the whole stack under it giving the offline rows; and the policies
across a region router of ``up --regions`` (region routers that show each other the router
certificate; the whole secure mesh of ``up --regions --secure`` runs in test_regions_live.py)."""

from __future__ import annotations

import ipaddress
import json
import stat
import sys
import threading
from pathlib import Path

import pytest
import zenoh
from cryptography import x509

from bintrack.cli import certs_command
from bintrack.cli import main as cli
from bintrack.formats import TruthRow, open_dataset, read_tracks, write_dataset
from bintrack.keys import Keys
from bintrack.live.session_options import client_config as plain_client_config
from bintrack.live.secure_profile import (PROFILE, awaiting_token_holders, client_config, restrict_sensor_agents,
                                          role_of, router_config, router_options, secure_commands)
from bintrack.live.stack import region_stack_commands
from bintrack.bus_payloads import Clock, Track, TrackSet
from bintrack.message_codec import encode

from support import DATASETS, HUNG, REPO, bintrack, free_port, wait_until
from test_mesh import RouterProcess

DARPA3 = DATASETS / "darpa-grid-3"
NET = "bintrack/sec"


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("certs")
    assert cli.main(["certs", "--out", str(folder)]) == 0
    return folder


def test_certs_are_signed_by_the_ca_with_the_role_as_common_name_and_private_keys_0600(certs, tmp_path):
    ca = x509.load_pem_x509_certificate((certs / "ca.pem").read_bytes())
    for role in ("router", "sensor_agent", "peer_agent", "basestation", "replay", "recorder", "viewer", "merge"):
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


def test_the_router_certificate_names_the_hosts_of_a_mesh_on_several_machines(certs, tmp_path, capsys):
    """``certs --router-name HOST`` (repeatable): the router certificate also names where the
    routers of a multi-machine mesh listen, so that clients and routers reach them over TLS; a
    router on an address it does not name is refused. 127.0.0.252 stands for another machine."""
    site = tmp_path / "site"
    assert cli.main(["certs", "--out", str(site), "--roles", "router", "--ca", str(certs),
                     "--router-name", "127.0.0.252", "--router-name", "router-b.example"]) == 0
    names = x509.load_pem_x509_certificate((site / "router.pem").read_bytes()).extensions.get_extension_for_class(
        x509.SubjectAlternativeName).value
    assert "router-b.example" in names.get_values_for_type(x509.DNSName)
    assert ipaddress.ip_address("127.0.0.252") in names.get_values_for_type(x509.IPAddress)
    endpoint = f"tls/127.0.0.252:{free_port()}"
    for folder, reachable in ((site, True), (certs, False)):
        router = zenoh.open(router_config(folder, [endpoint]))
        try:
            if reachable:
                zenoh.open(client_config("viewer", certs, [endpoint])).close()
            else:
                with pytest.raises(zenoh.ZError):
                    zenoh.open(client_config("viewer", certs, [endpoint]))
        finally:
            router.close()
    assert cli.main(["certs", "--out", str(tmp_path / "bad"), "--router-name", "not a host!"]) == 2
    assert "--router-name 'not a host!': not a host name or an IP address" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


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
        assert [r.ok.payload.to_bytes() for r in viewer.get(f"{NET}/deployment", timeout=HUNG) if r.ok] == [b"d"]
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


def assert_only_genuine_clients_connect(certs: Path, endpoint: str, tmp_path: Path) -> None:
    """A client of the TLS router at ``endpoint`` gets in with a certificate of ``certs``' CA
    only: not without one, not with another CA's, not over plain TCP."""
    # TLS with the right CA but no certificate of its own
    config = client_config("viewer", certs, [endpoint])
    config.insert_json5("transport/link/tls/connect_certificate", "null")
    config.insert_json5("transport/link/tls/connect_private_key", "null")
    with pytest.raises(zenoh.ZError):
        zenoh.open(config)
    # a certificate of another CA
    other = tmp_path / "other"
    assert cli.main(["certs", "--out", str(other), "--roles", "viewer"]) == 0
    with pytest.raises(zenoh.ZError):
        zenoh.open(client_config("viewer", other, [endpoint]))
    # plain TCP to the TLS port
    with pytest.raises(zenoh.ZError):
        zenoh.open(plain_client_config(["tcp/" + endpoint.removeprefix("tls/")]))
    # and the genuine viewer can
    zenoh.open(client_config("viewer", certs, [endpoint])).close()


def test_a_client_without_a_certificate_or_from_another_ca_cannot_connect(certs, secure_router, tmp_path):
    assert_only_genuine_clients_connect(certs, secure_router, tmp_path)


def test_the_secure_stack_gives_the_offline_rows(certs, tmp_path):
    ds = open_dataset(DARPA3)
    folder = write_dataset(tmp_path / "slice", ds.deployment, [e for e in ds.events() if 10.0 <= e.t < 40.0],
                           [TruthRow(*r) for r in ds.truth() if 10.0 <= r.t < 40.0])
    recording = tmp_path / "secure.mcap"
    up = bintrack("up", str(folder), "--speed", "0", "--tracker", "equal-weight", "--record", str(recording),
                  "--exit-at-end", "--secure", "--certs", str(certs), "--listen", f"tls/127.0.0.1:{free_port()}",
                  "--map-port", str(free_port()))  # the map runs as the viewer role
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
    # each role may declare the tokens of the instances the base file runs, no other
    instances = [f"{name}={s['command'][s['command'].index('--id') + 1]}" for name, s in base.items()
                 if "--id" in s["command"]]
    assert secure["router"]["command"] == ["bintrack.services.router", "-c", "/secure/router.json5", "-l", "tls/[::]:7447",
                                           "--pin-tokens", f"darpa-grid:{','.join(instances)}"]
    for name, service in secure.items():
        assert {"./deploy/secure:/secure:ro", "./certs:/certs:ro"} <= set(service["volumes"]), name
        if name == "router":
            continue
        role = ["-c", f"/secure/{role_of(name)}.json5"]
        tls = [{"tcp/router:7447": "tls/router:7447"}.get(a, a) for a in base[name]["command"]]
        assert service["command"] == list(awaiting_token_holders(tls)) + role, name
        health = [{"tcp/router:7447": "tls/router:7447"}.get(a, a) for a in base[name]["healthcheck"]["test"]]
        if role_of(name) == "viewer":  # no liveliness token to probe: the page (or the WebSocket port) answers
            probe = " ".join(service["healthcheck"]["test"])
            assert "state.json" in probe or "create_connection(('127.0.0.1', 8765)" in probe, name
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


# --------------------------------------------------------------------------- regions: a router mesh

REGIONS = ["r0c0", "r0c1", "r1c0", "r1c1"]


def test_every_role_has_a_client_config_a_subject_and_a_policy():
    """Each role `bintrack certs` makes (the merge's too) has deploy/secure/<role>.json5 naming its own
    certificate, and router.json5 a subject of that common name with a policy; every service of
    ``up --regions`` runs under one of them."""
    router = zenoh.Config.from_file(str(PROFILE / "router.json5"))
    subjects = {s["id"]: s["cert_common_names"] for s in json.loads(router.get_json("access_control/subjects"))}
    policies = {p["id"]: p for p in json.loads(router.get_json("access_control/policies"))}
    for role in certs_command.ROLES:
        assert subjects.get(role) == [role], role
        assert role in policies and policies[role]["subjects"] == [role], role
        if role == "router":
            continue
        config = zenoh.Config.from_file(str(PROFILE / f"{role}.json5"))
        assert json.loads(config.get_json("transport/link/tls/connect_certificate")) == f"/certs/{role}.pem", role
        assert json.loads(config.get_json("mode")) == "client", role
    services = region_stack_commands(regions=REGIONS, endpoint="tls/127.0.0.1:7447", net="sec", source="d",
                                     record="r.mcap", view_port=8080)
    assert {role_of(c.name) for c in services} <= set(certs_command.ROLES)


@pytest.fixture
def region_mesh(certs, tmp_path):
    """The hub router (in this process) and region r0c0's router on 127.0.0.2 as ``up --secure
    --regions`` starts it (a ``bintrack.services.router`` process with the router certificate, meshed
    with the hub); yields (hub endpoint, region endpoint) once the two routers are linked."""
    port = free_port()
    hub_endpoint = f"tls/127.0.0.1:{port}"
    hub = zenoh.open(router_config(certs, [hub_endpoint]))
    stack = secure_commands(region_stack_commands(regions=["r0c0"], endpoint=hub_endpoint, net="sec"), certs)
    command = next(c for c in stack if c.name == "router")
    assert "tls/127.0.0.2:" + str(port) in command.args
    region = f"tls/127.0.0.2:{port}"
    router = RouterProcess("r0c0", region, [hub_endpoint], tmp_path, argv=command.argv(sys.executable))
    try:
        router.wait_logged("router r0c0: router ", "the hub, over mutual TLS")
        yield hub_endpoint, region
    finally:
        assert router.stop() == 0
        hub.close()


class Heard:
    """The keys a session's subscriber (or liveliness subscriber) got, waited on by event."""

    def __init__(self):
        self.keys: list[str] = []
        self.changed = threading.Condition()

    def __call__(self, sample: zenoh.Sample) -> None:
        with self.changed:
            self.keys.append(str(sample.key_expr))
            self.changed.notify_all()

    def wait_for(self, *keys: str) -> list[str]:
        with self.changed:
            assert self.changed.wait_for(lambda: all(k in self.keys for k in keys), HUNG), self.keys
            return list(self.keys)


def test_across_a_region_router_the_merge_and_a_region_base_station_may_do_only_what_their_policies_say(
        certs, region_mesh):
    hub, region = region_mesh
    observer = Observer(certs, hub)  # a recorder on the hub: reads everything
    merge = zenoh.open(client_config("merge", certs, [hub]))
    base = zenoh.open(client_config("basestation", certs, [region]))  # the region router's name is checked
    heard, tokens, observed_tokens = Heard(), Heard(), Heard()
    scan = encode(TrackSet(t=1.0, tracker="mcmcda", tracks=[Track(track=1, x=1.0, y=2.0)]))
    entities = [merge.declare_subscriber(f"{NET}/**", heard),
                merge.liveliness().declare_subscriber(f"{NET}/region/*/alive", tokens, history=True),
                observer.session.liveliness().declare_subscriber(f"{NET}/**", observed_tokens, history=True)]
    try:
        # the region's base station serves its scans and holds its region's token, seen on the hub
        entities.append(base.declare_queryable(f"{NET}/region/r0c0/tracks",
                                               lambda q: q.reply(f"{NET}/region/r0c0/tracks", scan)))
        entities.append(base.liveliness().declare_token(f"{NET}/region/r0c0/alive"))
        tokens.wait_for(f"{NET}/region/r0c0/alive")
        # a restarted merge asks the region for the scans it missed
        replies = [r.ok.payload.to_bytes() for r in merge.get(f"{NET}/region/r0c0/tracks?after=0.5", timeout=HUNG) if r.ok]
        assert replies == [scan]
        # the station's region keys cross the router link; the merge reads tracks and progress only
        base.put(f"{NET}/region/r0c0/fusion/reports", b"r")
        base.put(f"{NET}/region/r0c0/tracks", scan)
        base.put(f"{NET}/region/r0c0/progress", encode(Clock(t=1.0)))
        observer.wait_for(f"{NET}/region/r0c0/fusion/reports", f"{NET}/region/r0c0/tracks",
                          f"{NET}/region/r0c0/progress")
        seen = heard.wait_for(f"{NET}/region/r0c0/tracks", f"{NET}/region/r0c0/progress")
        assert f"{NET}/region/r0c0/fusion/reports" not in seen, seen
        # the merge may publish the network's tracks and its own progress, not pose as a region,
        # the replay or a sensor
        merge.put(f"{NET}/region/r1c1/tracks", scan)
        merge.put(f"{NET}/clock", encode(Clock(t=2.0)))
        merge.put(f"{NET}/sensor/n001/transition", b"t")
        entities.append(merge.liveliness().declare_token(f"{NET}/region/r1c1/alive"))
        merge.put(f"{NET}/tracks", scan)  # the markers
        merge.put(f"{NET}/control/progress/merge/m1", encode(Clock(t=2.0)))
        entities.append(merge.liveliness().declare_token(f"{NET}/alive/merge/m1"))
        seen = observer.wait_for(f"{NET}/tracks", f"{NET}/control/progress/merge/m1")
        assert not [k for k in seen if "r1c1" in k or k.endswith(("/clock", "/transition"))], seen
        assert f"{NET}/region/r1c1/alive" not in observed_tokens.wait_for(f"{NET}/alive/merge/m1",
                                                                           f"{NET}/region/r0c0/alive")
        # and the base station may not hold the merge's token nor publish its progress
        base.put(f"{NET}/control/progress/merge/m2", encode(Clock(t=3.0)))
        entities.append(base.liveliness().declare_token(f"{NET}/alive/merge/m2"))
        base.put(f"{NET}/control/progress/basestation/b1", encode(Clock(t=3.0)))  # the markers
        entities.append(base.liveliness().declare_token(f"{NET}/alive/basestation/b1"))
        assert f"{NET}/control/progress/merge/m2" not in observer.wait_for(f"{NET}/control/progress/basestation/b1")
        assert f"{NET}/alive/merge/m2" not in observed_tokens.wait_for(f"{NET}/alive/basestation/b1")
    finally:
        for entity in entities:
            entity.undeclare()
        for session in (merge, base):
            session.close()
        observer.close()


def test_a_region_router_refuses_a_client_without_a_certificate(certs, region_mesh, tmp_path):
    assert_only_genuine_clients_connect(certs, region_mesh[1], tmp_path)


def test_up_secure_with_regions_needs_a_router_certificate_that_names_the_region_routers(tmp_path, monkeypatch,
                                                                                          capsys):
    old = tmp_path / "old"  # as `bintrack certs` made them before --regions ran secure
    monkeypatch.setattr(certs_command, "ROUTER_ADDRESSES", ("127.0.0.1",))
    certs_command.make_certs(old, list(certs_command.ROLES))
    assert cli.main(["up", str(DARPA3), "--tracker", "mcmcda", "--regions", "4", "--secure", "--certs", str(old),
                     "--listen", "tls/127.0.0.1:1"]) == 2
    err = capsys.readouterr().err
    assert "router.pem does not name 127.0.0.2" in err and "--roles router --ca" in err


def test_a_router_given_pin_tokens_lets_a_role_declare_only_the_instances_named(certs, tmp_path):
    """``--pin-tokens`` (the compose secure profile's router): with the sensor-agent certificate,
    the token of instance ``sensor_agent`` is declared and one of ``evil`` is denied."""
    endpoint = f"tls/127.0.0.1:{free_port()}"
    router = RouterProcess("pinned", endpoint, [], tmp_path, argv=[
        sys.executable, "-m", "bintrack.services.router", "-l", endpoint, "--name", "pinned",
        *router_options(certs), "--pin-tokens", "darpa-grid:sensor_agent,replay"])
    agent = zenoh.open(client_config("sensor_agent", certs, [endpoint]))
    reader = zenoh.open(client_config("recorder", certs, [endpoint]))
    keys = Keys("darpa-grid")
    try:
        forged = agent.liveliness().declare_token(keys.alive("sensor_agent", "evil"))
        genuine = agent.liveliness().declare_token(keys.alive("sensor_agent", "sensor_agent"))

        def alive() -> set[str]:
            return {str(r.ok.key_expr) for r in reader.liveliness().get(keys.alive(), timeout=5) if r.ok}

        wait_until(lambda: keys.alive("sensor_agent", "sensor_agent") in alive(), "the genuine token")
        assert keys.alive("sensor_agent", "evil") not in alive()
        forged.undeclare()
        genuine.undeclare()
    finally:
        agent.close()
        reader.close()
        assert router.stop() == 0
