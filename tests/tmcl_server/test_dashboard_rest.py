"""The dashboard's REST face (issue 37, deliver 5): POST /api/command, POST/GET/DELETE
/api/fault, behind the page's Host/Origin/token rules.  A real HTTP client on loopback is
served (urllib, and curl running docs/dashboard.md's examples as written); a page of another
origin in a real headless Chromium is refused, and nothing changes."""

from __future__ import annotations

import json
import logging
import re
import shutil
import subprocess
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

import pytest

from tests.conftest import RawClient
from tests.helpers.browser import missing_reason as chromium_missing
from tmcl_server.embed import SimulatorThread
from tmcl_spec.commands import Opcode
from tmcl_spec.parameters import AP

pytest.importorskip("aiohttp")

ROOT = Path(__file__).resolve().parents[2]
WAIT_S = 30.0  # a fail-safe for what is due


def call(url: str, body: str | bytes | None = None, method: str | None = None,
         headers: dict[str, str] | None = None) -> tuple[int, Any]:
    """(HTTP status, the JSON answer or the text) from urllib, a real client."""
    data = body.encode() if isinstance(body, str) else body
    request = urllib.request.Request(url, data=data, method=method, headers=headers or {})
    try:
        with urllib.request.urlopen(request, timeout=WAIT_S) as response:
            status, text = response.status, response.read().decode()
    except urllib.error.HTTPError as error:
        status, text = error.code, error.read().decode()
    try:
        return status, json.loads(text)
    except ValueError:
        return status, text


@pytest.fixture
def sim() -> Any:
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"], http=["127.0.0.1:0"]) as simulator:
        yield simulator


def test_a_command_as_tmcl_send_writes_it_or_by_its_fields(sim: SimulatorThread) -> None:
    base = sim.endpoints["http"][0]
    status, answer = call(base + "api/command", "SAP MaxPositioningSpeed, 2, 1000")
    assert status == 200 and answer == {
        "module": 1, "request": "SAP 4 MaxPositioningSpeed m2 = 1000", "status": 100,
        "status_name": "OK", "value": 1000, "text": "SAP 4 MaxPositioningSpeed m2 = 1000 → 100 OK"}
    status, answer = call(base + "api/command", json.dumps({"opcode": 6, "type": 4, "motor": 2}),
                          headers={"Content-Type": "application/json"})
    assert (status, answer["value"], answer["request"]) == (200, 1000, "GAP 4 MaxPositioningSpeed m2")
    status, answer = call(base + "api/command", json.dumps({"command": "GAP MaxVelocity 2", "module": 1}))
    assert (status, answer["value"]) == (200, 1000)
    status, answer = call(base + "api/command", "SAP 6, 0, 300")  # out of range: the module says so
    assert (status, answer["status"], answer["status_name"]) == (200, 4, "INVALID_VALUE")
    client = RawClient(sim.tcp)  # a host sees what REST set
    try:
        assert client.request(1, Opcode.GAP, AP.MAX_SPEED, 2).value == 1000
    finally:
        client.close()


@pytest.mark.parametrize(("route", "body", "error"), [
    ("api/command", "FLY 1", "unknown command 'FLY'"),
    ("api/command", "SAP 4, 0", "SAP takes 3 operand(s), got 2"),
    ("api/command", '{"opcode": 6, "typ": 4}', "unknown field(s) typ"),
    ("api/command?module=9", "GAP 4, 0", "no module 9"),
    ("api/command", "", "the body is empty"),
    ("api/command", '{"command": ' + "[" * 2000, "nested"),
    ("api/fault", "bogus:x=1", "unknown fault 'bogus'"),
    ("api/fault", '{"fault": 7}', '"fault" must be a fault spec'),
])
def test_what_cannot_be_done_is_400_with_one_line(sim: SimulatorThread, route: str, body: str,
                                                 error: str) -> None:
    status, answer = call(sim.endpoints["http"][0] + route, body)
    assert status == 400 and error in answer["error"] and "\n" not in answer["error"], answer


def test_a_fault_by_rest_acts_on_a_host_and_is_removed_again(sim: SimulatorThread) -> None:
    """The fault language through the one injector: a TCP host's GAP goes unanswered, the
    Python API lists the same fault, DELETE removes it."""
    base = sim.endpoints["http"][0]
    status, answer = call(base + "api/fault", "noreply:opcode=GAP,endpoint=tcp")
    assert status == 200 and answer["installed"]["spec"] == "noreply:opcode=GAP,endpoint=tcp"
    number = answer["installed"]["id"]
    assert [f["id"] for f in sim.faults()] == [number]
    client = RawClient(sim.tcp)
    try:
        client.send_raw(b"\x01\x06\x04\x00\x00\x00\x00\x00\x0b")  # GAP 4: no reply
        client.expect_silence(0.3)
        status, answer = call(base + "api/fault", json.dumps({"kind": "delay", "ms": 1}))
        assert status == 200 and len(answer["faults"]) == 2
        status, answer = call(f"{base}api/fault?id={number}", method="DELETE")
        assert status == 200 and [f["kind"] for f in answer["faults"]] == ["delay"]
        assert client.request(1, Opcode.GAP, AP.MAX_SPEED, 0).value == 51200  # answered again
        status, answer = call(base + "api/fault", method="DELETE")
        assert (status, answer, sim.faults()) == (200, {"faults": []}, [])
        assert call(base + "api/fault?id=99", method="DELETE")[0] == 400
    finally:
        client.close()


def test_beyond_loopback_rest_needs_the_token() -> None:
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"], http=["0.0.0.0:0"]) as sim:
        url, token = sim.endpoints["http"][0].split("?token=")
        port = url.rstrip("/").rsplit(":", 1)[1]
        base = f"http://127.0.0.1:{port}/"
        status, answer = call(base + "api/command", "SAP 4, 0, 1000")
        assert status == 403 and "needs its token" in answer
        status, answer = call(base + "api/command", "SAP 4, 0, 1000",
                              headers={"Authorization": f"token {token}"})
        assert (status, answer["status"]) == (200, 100)


def test_another_origin_and_a_rebound_host_are_refused(sim: SimulatorThread) -> None:
    """The guard's rules, asked by a client that sends what a browser would send."""
    base = sim.endpoints["http"][0]
    port = base.rstrip("/").rsplit(":", 1)[1]
    for headers in ({"Origin": "http://evil.example"}, {"Host": f"rebound.attacker.test:{port}"}):
        status, answer = call(base + "api/fault", "stuck:axis=0", headers=headers)
        assert status == 403, answer
    assert sim.faults() == []


# -- curl, running docs/dashboard.md's examples as written -----------------------------------------

def documented_session() -> list[tuple[str, str]]:
    """(command, output) of each ``$`` line of docs/dashboard.md's REST console block."""
    text = (ROOT / "docs" / "dashboard.md").read_text(encoding="utf-8")
    section = text[text.index("## REST API"):]
    block = re.search(r"```console\n(.*?)```", section, re.S)
    assert block is not None
    session: list[tuple[str, str]] = []
    for line in block.group(1).splitlines():
        if line.startswith("$ "):
            session.append((line[2:], ""))
        else:
            command, output = session[-1]
            session[-1] = (command, output + line + "\n")
    return session


@pytest.mark.skipif(shutil.which("curl") is None, reason="curl is not installed")
def test_the_documented_curl_session_runs_as_written(sim: SimulatorThread) -> None:
    """Each example as pasted, against a server of the test's own: the one substitution is
    its URL for the documented ``http://127.0.0.1:8080``; every answer is the documented one."""
    base = sim.endpoints["http"][0].rstrip("/")
    session = documented_session()
    assert len(session) >= 6
    for command, documented in session:
        done = subprocess.run(["bash", "-c", command.replace("http://127.0.0.1:8080", base)],
                              capture_output=True, text=True, timeout=WAIT_S)
        assert (done.returncode, done.stdout) == (0, documented), command


# -- a page of another origin, in a real browser --------------------------------------------------

REST_ATTACK = """<!doctype html><title>elsewhere</title><script>
window.outcome = {command: "pending", fault: "pending", json: "pending", clear: "pending"};
const base = "http://127.0.0.1:%(port)d";
function note(key, promise) {
  promise.then((r) => { window.outcome[key] = "status " + r.status; })
         .catch(() => { window.outcome[key] = "blocked"; });
}
// "simple" requests: a browser sends them without asking first (no preflight)
note("command", fetch(base + "/api/command", {method: "POST", body: "SAP 4, 0, 1000"}));
note("fault", fetch(base + "/api/fault", {method: "POST", body: "stuck:axis=0"}));
// these need a preflight (JSON, DELETE), which the dashboard never grants
const json = {opcode: 5, type: 4, motor: 0, value: 1000};
note("json", fetch(base + "/api/command", {method: "POST", body: JSON.stringify(json),
                                           headers: {"Content-Type": "application/json"}}));
note("clear", fetch(base + "/api/fault", {method: "DELETE"}));
</script>"""


@pytest.mark.skipif(chromium_missing() is not None, reason=chromium_missing() or "")
@pytest.mark.parametrize("allowed", [False, True], ids=["foreign", "allowed (the control)"])
def test_a_page_of_another_origin_cannot_use_rest(allowed: bool, caplog: pytest.LogCaptureFixture) -> None:
    """The page's simple POSTs reach the server (its log shows the refusal: one line, the
    repeats held back) and change nothing; with its origin allowed (--http-allow-origin),
    the same page's POSTs act: the harness does reach the dashboard."""
    from tests.helpers.browser import HeadlessChromium
    from tests.tmcl_server.test_dashboard_browser_security import _ForeignSite, port_of, until
    from tmcl_server.lograte import REPEATS

    caplog.set_level(logging.WARNING, logger="tmcl_server.dashboard.web")
    REPEATS.reset()  # the refusals' log lines are rate-limited per call site
    site = _ForeignSite(REST_ATTACK)
    chromium = HeadlessChromium(800, 600)
    try:
        with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"], http=["127.0.0.1:0"],
                             http_allow_origins=[site.origin] if allowed else []) as sim:
            site.dashboard_port = port_of(sim.endpoints["http"][0])
            chromium.driver.get(site.url)
            outcome = until(lambda: (lambda o: o if "pending" not in o.values() else None)(
                chromium.driver.execute_script("return window.outcome")))
            client = RawClient(sim.tcp)
            try:
                max_speed = client.request(1, Opcode.GAP, AP.MAX_SPEED, 0).value
            finally:
                client.close()
            faults = sim.faults()
    finally:
        chromium.quit()
        site.close()
    refused = [r.getMessage() for r in caplog.records if "refused POST /api/" in r.getMessage()]
    # no CORS headers ever: the page reads no answer, allowed or not
    assert outcome == dict.fromkeys(("command", "fault", "json", "clear"), "blocked"), outcome
    if allowed:
        assert max_speed == 1000 and [f["spec"] for f in faults] == ["stuck:axis=0"]
        assert not refused
    else:
        assert max_speed == 51200 and faults == []
        assert refused and all("Origin" in line for line in refused), refused
