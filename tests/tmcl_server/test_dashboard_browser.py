"""The dashboard end to end: a real headless Chromium on the page, a pytrinamic host on TCP,
the simulator on a virtual clock that the test moves.  Skipped when Chromium, chromedriver or
selenium are missing (scripts/test.py installs them)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from tests.helpers.browser import HeadlessChromium, missing_reason
from tests.helpers.requirements import needs
from tmcl_server.embed import SimulatorThread
from tmcl_server.upload import StreamClient, upload
from tmcl_spec.commands import ApplicationStatus, Opcode
from tmcl_spec.parameters import AP, GP

pytest.importorskip("aiohttp")
Keys = pytest.importorskip("selenium.webdriver.common.keys").Keys
pytrinamic = pytest.importorskip("pytrinamic.connections")
pytestmark = needs(missing_reason())

COUNTING_PROGRAM = """
    CALC LOAD, 0
Loop:
    CALC ADD, 1
    AGP 0, 2
    WAIT TICKS, 0, 1
    JA Loop
"""


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    chromium = HeadlessChromium(1400, 1000)
    try:
        yield chromium.driver
    finally:
        chromium.quit()


@pytest.fixture
def sim() -> Iterator[SimulatorThread]:
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"], http=["127.0.0.1:0"]) as sim:
        yield sim


@pytest.fixture
def host(sim: SimulatorThread) -> Iterator[Any]:
    iface = pytrinamic.ConnectionManager(f"--interface socket_serial_tmcl --port {sim.tcp}").connect()
    try:
        yield iface
    finally:
        iface.close()


@pytest.fixture
def page(browser: Any, sim: SimulatorThread) -> Any:
    browser.get(sim.endpoints["http"][0])
    until(lambda: browser.execute_script("return window.tmclDashboard && window.tmclDashboard.frames()"))
    return browser


def until(condition: Callable[[], Any], timeout: float = 10.0) -> Any:
    """Poll ``condition`` (the page is live: frames come at wall-clock pace) until truthy."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {condition}")
        time.sleep(0.02)


def line_classes(page: Any, address: int) -> str | None:
    """The classes of the listing's line at ``address`` as the page shows it now (None if
    there is no such line)."""
    return page.execute_script(
        "const line = document.querySelector(`#listing li[data-address=\"${arguments[0]}\"]`);"
        "return line ? line.className : null;", address)


def edit(cell: Any, text: str) -> None:
    """Type into a table cell as a person does: select what is there, type, Enter (the cell
    keeps the focus throughout, so live updates leave it alone)."""
    cell.click()
    cell.send_keys(Keys.CONTROL, "a")
    cell.send_keys(text, Keys.ENTER)


def plotted(page: Any, axis: int) -> dict[str, Any] | None:
    return page.execute_script(f"return window.tmclDashboard.plotted({axis})")


def test_the_page_loads_with_every_section(page: Any) -> None:
    assert page.title == "tmcl-sim dashboard"
    for section in ("axes", "io", "parameters", "program", "wire"):
        assert page.find_element("id", section).is_displayed()
    assert len(page.find_elements("css selector", "#axis-grid .axis")) == 6
    assert page.find_element("id", "clock-kind").text == "(virtual clock)"
    errors = [e for e in page.get_log("browser") if e["level"] == "SEVERE"]
    assert not errors, errors


def test_a_move_by_a_host_shows_on_the_plot_up_to_its_target(page: Any, sim: SimulatorThread,
                                                               host: Any) -> None:
    host.move_to(0, 51200)
    seen = []
    for step in range(1, 13):  # 3 simulated seconds, a sample after each quarter second
        sim.advance(0.25)
        point = until(lambda step=step: (p := plotted(page, 0)) and p["t"] >= step * 0.25 - 1e-9 and p)
        seen.append(point["position"])
    assert seen == sorted(seen) and 0 < seen[0] < 51200
    assert seen[-1] == 51200 and point["target"] == 51200 and point["velocity"] == 0
    assert point["maxSpeed"] == host.get_axis_parameter(AP.MAX_SPEED, 0) == 51200
    assert until(lambda: page.find_element("css selector", "#axis-0 .position").text == "51200")


def test_clicking_the_left_switch_stops_a_motor_moving_left(page: Any, sim: SimulatorThread,
                                                           host: Any) -> None:
    host.send(Opcode.ROL, 0, 1, 20000)
    sim.advance(0.5)
    assert host.get_axis_parameter(AP.ACTUAL_SPEED, 1, signed=True) < 0
    button = page.find_element("css selector", '#axis-1 button[data-switch="left"]')
    button.click()
    until(lambda: "held" in button.get_attribute("class"))  # the server holds it pressed
    sim.advance(0.5)
    assert host.get_axis_parameter(AP.LEFT_SWITCH, 1) == 1
    assert host.get_axis_parameter(AP.ACTUAL_SPEED, 1) == 0
    stopped_at = host.get_axis_parameter(AP.ACTUAL_POSITION, 1, signed=True)
    sim.advance(0.5)
    assert host.get_axis_parameter(AP.ACTUAL_POSITION, 1, signed=True) == stopped_at < 0
    until(lambda: "active" in button.get_attribute("class"))
    button.click()  # let go: the world has no switch there again
    until(lambda: "held" not in button.get_attribute("class"))
    assert host.get_axis_parameter(AP.LEFT_SWITCH, 1) == 0


def test_a_parameter_edited_in_the_table_is_read_back_by_the_host(page: Any, sim: SimulatorThread,
                                                                 host: Any) -> None:
    page.find_element("css selector", "#parameters-panel > summary").click()
    cell = page.find_element("css selector", '#axis-parameters tr[data-number="4"] td:nth-child(5) input')
    until(lambda: cell.get_attribute("value") == "51200")  # live values arrived
    edit(cell, "12345")
    status = page.find_element("id", "parameter-status")
    until(lambda: "→ 100 OK" in status.text)
    assert status.text == "SAP 4 MaxPositioningSpeed m2 = 12345 → 100 OK"
    assert host.get_axis_parameter(AP.MAX_SPEED, 2) == 12345
    # validated like a host's: out of range is refused, and nothing changes
    current = page.find_element("css selector", '#axis-parameters tr[data-number="6"] td:nth-child(5) input')
    edit(current, "300")
    until(lambda: "INVALID_VALUE" in status.text)
    assert host.get_axis_parameter(AP.MAX_CURRENT, 2) == 128
    # and traced like a host's: the wire shows the page as an http endpoint
    rows = until(lambda: page.execute_script(
        "return [...document.querySelectorAll('#wire-table tbody tr')]"
        ".map(row => [...row.cells].map(cell => cell.textContent))"
        ".filter(cells => cells[4].startsWith(arguments[0]))", "SAP 4 MaxPositioningSpeed m2 = 12345"))
    (_, endpoint, module, kind, text), = rows
    assert endpoint.startswith("http 127.0.0.1:") and (module, kind) == ("1", "cmd")
    assert text == "SAP 4 MaxPositioningSpeed m2 = 12345 → 100 OK"


def test_a_breakpoint_set_in_the_page_stops_the_program_and_step_advances_one_instruction(
        page: Any, sim: SimulatorThread, host: Any) -> None:
    from interpreter.assembler import assemble

    client = StreamClient.tcp(sim.tcp, 1, timeout=5)
    try:
        upload(client, assemble(COUNTING_PROGRAM).instructions)
    finally:
        client.close()
    host.send(Opcode.RUN_APPLICATION, 1, 0, 0)
    sim.advance(0.1)  # ten rounds
    # The page renders the listing anew for each change of program memory it hears of, and
    # the upload's frames reach it at wall-clock pace: wait for the whole program, and find
    # the line afresh at each look (an element from an earlier rendering is stale).
    until(lambda: len(page.find_elements("css selector", "#listing li[data-address]")) == 5)
    assert line_classes(page, 2) is not None
    assert page.find_element("css selector", '#listing li[data-address="2"]').text.split() == [
        "2", "AGP", "0,", "2"]
    until(lambda: page.execute_script(
        "const line = document.querySelector('#listing li[data-address=\"2\"]');"
        "if (line) line.click(); return Boolean(line);"))
    until(lambda: "breakpoint" in (line_classes(page, 2) or ""))
    sim.advance(0.05)
    assert host.get_global_parameter(GP.APPLICATION_STATUS, 0) == ApplicationStatus.STEP
    assert host.send(Opcode.GET_APPLICATION_STATUS, 1, 0, 0).value & 0xFFFF == 2
    rounds = host.get_global_parameter(0, 2)
    until(lambda: "current" in (line_classes(page, 2) or ""))
    assert page.find_element("id", "reg-state").text == "STEP"
    assert page.find_element("id", "reg-pc").text == "2"
    sim.advance(0.5)  # stopped: time passes, the program does not
    assert host.get_global_parameter(0, 2) == rounds
    page.find_element("id", "step").click()
    until(lambda: page.find_element("id", "reg-pc").text == "3")
    assert host.send(Opcode.GET_APPLICATION_STATUS, 1, 0, 0).value & 0xFFFF == 3
    assert host.get_global_parameter(0, 2) == rounds + 1  # exactly the AGP ran
    assert page.find_element("id", "program-status").text == "STEP_APPLICATION → 100 OK"
