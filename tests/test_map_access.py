"""The map as a web application with a threat model (issue: no silent loss, row 9): a page of
another site is refused, so is a request naming another host (DNS rebinding), and beyond
loopback the map does not start without a token; with one, the printed URL carries it and the
page's later requests pass on its cookie. In a real browser, one whose DNS also says evil.example
is this machine."""

from __future__ import annotations

import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import pytest

from bintrack.deployment_model import Deployment
from bintrack.bus_payloads import Clock
from bintrack.message_codec import encode
from bintrack.live.recording import RecordingWriter

from support import DATASETS, bintrack, free_port
from test_view import LAUNCH_ARGS, Process, browser_path

DARPA3 = DATASETS / "darpa-grid-3"
EVIL = "evil.example"

@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("map-access") / "tiny.mcap"
    deployment = Deployment.model_validate_json((DARPA3 / "deployment.json").read_text())
    with RecordingWriter(path, deployment, "darpa-grid") as writer:
        writer.write("bintrack/darpa-grid/clock", 1.0, encode(Clock(t=1.0)))
    return path


@pytest.fixture(scope="module")
def served(recording):
    view = Process("view", str(recording), "--map-port", str(free_port()))
    view.url = view.wait_for("view: map on").split("map on ", 1)[1].split()[0]
    yield view
    assert view.stop() == 0, view.log


# what a page's WebSocket to URL gets: the first message, or how it failed
OUTCOME = """url => new Promise(done => {
  const ws = new WebSocket(url);
  ws.onmessage = event => done("message: " + event.data.slice(0, 40));
  ws.onerror = () => done("error");
  ws.onclose = () => done("closed");
})"""


@pytest.fixture(scope="module")
def rebinding():
    """A browser whose DNS says evil.example is this machine (as an attacker's DNS would)."""
    from playwright.sync_api import sync_playwright

    if browser_path() is None:
        pytest.skip("browser tests need Debian's chromium-headless-shell package")
    with sync_playwright() as playwright:
        instance = playwright.chromium.launch(executable_path=browser_path(),
                                              args=[*LAUNCH_ARGS, f"--host-resolver-rules=MAP {EVIL} 127.0.0.1"])
        try:
            yield instance
        finally:
            instance.close()


@pytest.fixture(scope="module")
def evil_site():
    """A page of another site (evil.example, on a port of its own): an empty HTML page."""
    class Page(BaseHTTPRequestHandler):
        def do_GET(self):
            body = b"<html><body>another site</body></html>"
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args):
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Page)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://{EVIL}:{server.server_address[1]}/"
    server.shutdown()


def test_a_page_of_another_site_gets_nothing_from_the_map(rebinding, served, evil_site):
    ws_url = served.url.replace("http://", "ws://") + "ws"
    page = rebinding.new_page()
    try:
        page.goto(served.url)  # the map's own page gets the snapshot
        assert page.evaluate(OUTCOME, ws_url).startswith("message: [{")
        page.goto(evil_site)  # a page of evil.example does not
        assert page.evaluate(OUTCOME, ws_url) in ("error", "closed")
    finally:
        page.close()
    served.wait_for(f"refused a request: a page of {evil_site.rstrip('/')} is not the map's own")


def test_a_request_that_names_another_host_is_refused_dns_rebinding(rebinding, served):
    port = urlsplit(served.url).port
    page = rebinding.new_page()
    try:
        assert page.goto(f"http://127.0.0.1:{port}/state.json").status == 200
        response = page.goto(f"http://{EVIL}:{port}/state.json")
        assert response.status == 403 and "DNS rebinding" in response.text()
        assert page.goto(f"http://{EVIL}:{port}/").status == 403
    finally:
        page.close()
    served.wait_for(f"Host '{EVIL}:{port}' does not name this machine")


def test_beyond_loopback_the_map_needs_a_token(rebinding, recording):
    # without a token: one line, exit 2, from view and from up (which starts nothing)
    refused = bintrack("view", str(recording), "--map-bind", "0.0.0.0", "--map-port", str(free_port()))
    assert refused.returncode == 2 and refused.stderr.count("\n") == 1
    assert "would be open to any machine" in refused.stderr and "--map-token" in refused.stderr
    up = bintrack("up", str(DARPA3), "--map-bind", "0.0.0.0", "--exit-at-end", "--listen",
                  f"tcp/127.0.0.1:{free_port()}")
    assert up.returncode == 2 and up.stderr.count("\n") == 1 and "would be open to any machine" in up.stderr
    # with one: the printed URL carries it; a page without it is refused, with it served
    view = Process("view", str(recording), "--map-bind", "0.0.0.0", "--map-port", str(free_port()),
                   "--map-token", "s3cret")
    try:
        line = view.wait_for("view: map on")
        url = urlsplit(line.split("map on ", 1)[1].split()[0])
        assert parse_qs(url.query) == {"token": ["s3cret"]} and "every interface" in line
        base = f"http://127.0.0.1:{url.port}/"
        context = rebinding.new_context()
        page = context.new_page()
        assert page.goto(base + "state.json").status == 401
        assert page.goto(f"{base}?token=s3cret").status == 200
        state = page.goto(base + "state.json")  # the cookie set by the first visit
        assert state.status == 200 and state.json()["deployment"]["name"] == "darpa-grid"
        assert page.goto(f"{base}?token=wrong").status == 401
        context.close()
    finally:
        assert view.stop() == 0, view.log
