"""A foreign web page in a real headless Chromium tries to drive the dashboard (issue 27,
item 1): a page from another origin opens the WebSocket and sends SAP/STAP, reads
/api/frame; a page whose name was pointed at 127.0.0.1 (DNS rebinding, simulated with
Chromium's host resolver rules) does the same from "its own" origin.  Both are refused and
the module is untouched; the same page from an origin allowed with ``--http-allow-origin``
gets through (the harness's positive control).  Skipped without Chromium."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import pytest

from tests.conftest import RawClient
from tests.helpers.browser import HeadlessChromium, missing_reason
from tmcl_server.embed import SimulatorThread
from tmcl_spec.commands import Opcode
from tmcl_spec.parameters import AP

pytest.importorskip("aiohttp")
pytestmark = pytest.mark.skipif(missing_reason() is not None, reason=missing_reason() or "")

#: A name the browser resolves to 127.0.0.1, as an attacker's DNS would after the page loaded.
REBOUND = "rebound.attacker.test"

ATTACK = """<!doctype html><title>elsewhere</title><script>
window.outcome = {ws: "pending", fetched: "pending"};
const target = "127.0.0.1:%(port)d";
const ws = new WebSocket("ws://" + target + "/ws");
ws.onopen = () => {
  window.outcome.ws = "open";
  ws.send(JSON.stringify({op: "command", id: 1, cmd: "SAP", type: 4, motor: 0, value: 1000}));
  ws.send(JSON.stringify({op: "command", id: 2, cmd: "STAP", type: 4, motor: 0}));
};
ws.onmessage = (event) => {
  const message = JSON.parse(event.data);
  if (message.type === "reply" && message.id === 2) window.outcome.ws = "replied " + message.status;
};
ws.onclose = (event) => {
  if (!window.outcome.ws.startsWith("replied")) window.outcome.ws = "closed " + event.code;
};
fetch("http://" + target + "/api/frame")
  .then((response) => response.text())
  .then((text) => { window.outcome.fetched = "read " + text.length + " bytes"; })
  .catch(() => { window.outcome.fetched = "blocked"; });
</script>"""


class _ForeignSite:
    """Another origin: a plain HTTP server on its own port that serves the attacking page."""

    def __init__(self, attack: str = ATTACK) -> None:
        #: The dashboard the page attacks (set once it runs).
        self.dashboard_port = 0
        site = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                page = (attack % {"port": site.dashboard_port}).encode()
                self.send_response(200)
                self.send_header("Content-Type", "text/html")
                self.send_header("Content-Length", str(len(page)))
                self.end_headers()
                self.wfile.write(page)

            def log_message(self, *args: Any) -> None:
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.origin = f"http://127.0.0.1:{self.server.server_address[1]}"
        self.url = f"{self.origin}/"
        self._thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self._thread.start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    chromium = HeadlessChromium(800, 600, flags=(f"--host-resolver-rules=MAP {REBOUND} 127.0.0.1",))
    try:
        yield chromium.driver
    finally:
        chromium.quit()


def until(condition: Callable[[], Any], timeout: float = 15.0) -> Any:
    deadline = time.monotonic() + timeout
    while not (value := condition()):
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {condition}")
        time.sleep(0.05)
    return value


def port_of(url: str) -> int:
    return int(url.split("?")[0].rstrip("/").rsplit(":", 1)[1])


def settled(page: Any) -> dict[str, str]:
    """The page's outcome once both attempts ended (an open socket still awaits its reply)."""
    outcome = page.execute_script("return window.outcome")
    return outcome if "pending" not in outcome.values() and outcome["ws"] != "open" else {}


def stored_max_speed(sim: SimulatorThread) -> tuple[int, int]:
    """AP 4 now, and as stored (RSAP restores the stored value)."""
    client = RawClient(sim.tcp)
    try:
        now = client.request(1, Opcode.GAP, AP.MAX_SPEED, 0).value
        client.request(1, Opcode.RSAP, AP.MAX_SPEED, 0)
        return now, client.request(1, Opcode.GAP, AP.MAX_SPEED, 0).value
    finally:
        client.close()


def attack(browser: Any, allow_the_site: bool) -> tuple[dict[str, str], tuple[int, int]]:
    """The foreign page against a fresh server: what it saw, and AP 4 (now, stored) after."""
    site = _ForeignSite()
    try:
        with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"], http=["127.0.0.1:0"],
                             http_allow_origins=[site.origin] if allow_the_site else []) as sim:
            site.dashboard_port = port_of(sim.endpoints["http"][0])
            browser.get(site.url)
            outcome = until(lambda: settled(browser))
            return outcome, stored_max_speed(sim)
    finally:
        site.close()


def test_a_page_from_another_origin_cannot_drive_the_dashboard(browser: Any) -> None:
    outcome, (now, stored) = attack(browser, allow_the_site=False)
    assert outcome["ws"].startswith("closed"), outcome  # the upgrade was refused (403)
    assert outcome["fetched"] == "blocked", outcome
    assert now == 51200 and stored == 51200  # neither set nor stored


def test_the_same_page_from_an_allowed_origin_gets_through(browser: Any) -> None:
    """The positive control: the harness does reach the dashboard when the origin is allowed
    (the fetch stays blocked: the dashboard sends no CORS headers, so no page reads it)."""
    outcome, (now, stored) = attack(browser, allow_the_site=True)
    assert outcome["ws"] == "replied 100", outcome
    assert now == 1000 and stored == 1000


def test_a_rebound_name_is_refused_even_from_its_own_origin(browser: Any) -> None:
    """DNS rebinding: the attacker's name now resolves to 127.0.0.1, so its page and the
    dashboard share an origin; the Host header gives it away."""
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"], http=["127.0.0.1:0"]) as sim:
        port = port_of(sim.endpoints["http"][0])
        browser.get(f"http://{REBOUND}:{port}/")
        assert "DNS rebinding" in browser.find_element("tag name", "body").text
        browser.execute_script(f"""
            window.outcome = {{ws: "pending", fetched: "pending"}};
            const ws = new WebSocket("ws://{REBOUND}:{port}/ws");
            ws.onopen = () => {{
              window.outcome.ws = "open";
              ws.send(JSON.stringify({{op: "command", id: 2, cmd: "SAP", type: 4, motor: 0, value: 1000}}));
            }};
            ws.onmessage = (e) => {{ const m = JSON.parse(e.data);
              if (m.type === "reply") window.outcome.ws = "replied " + m.status; }};
            ws.onclose = (e) => {{ if (!window.outcome.ws.startsWith("replied"))
              window.outcome.ws = "closed " + e.code; }};
            fetch("/api/frame").then((r) => window.outcome.fetched = "status " + r.status)
              .catch(() => window.outcome.fetched = "blocked");
        """)
        outcome = until(lambda: settled(browser))
        now, _ = stored_max_speed(sim)
    assert outcome["ws"].startswith("closed"), outcome
    assert outcome["fetched"] == "status 403", outcome
    assert now == 51200
