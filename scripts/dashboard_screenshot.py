#!/usr/bin/env python3
"""Make docs/dashboard.png: the dashboard (``tmcl-server --http``) with six moving axes, as a
headless Chromium shows it.

A simulator (real clock) runs docs/examples/dashboard-demo.tmc on axes 0..2, uploaded over TCP
like the TMCL-IDE does it, while a pytrinamic host drives axes 3..5 (a rotation that turns
round, a reference search against the left switch of docs/examples/dashboard-world.toml, steps
over a home switch) and polls the positions, so the Wire section fills.  The page gets a
breakpoint on a line the program never reaches, by a click, and the screenshot is taken after
``--seconds``.  Needs the test extra and Debian's chromium + chromium-driver (scripts/test.py).

    .venv/bin/python scripts/dashboard_screenshot.py [-o docs/dashboard.png] [--seconds 9]
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tests.helpers.browser import HeadlessChromium  # noqa: E402
from tmcl_server.embed import SimulatorThread  # noqa: E402
from tmcl_server.upload import StreamClient, load_program, upload  # noqa: E402
from tmcl_spec.commands import Opcode  # noqa: E402
from tmcl_spec.parameters import AP  # noqa: E402

PROGRAM = ROOT / "docs/examples/dashboard-demo.tmc"
WORLD = ROOT / "docs/examples/dashboard-world.toml"
#: The demo program's "Done: STOP", never reached: the page shows a breakpoint there.
UNREACHED_LINE = 22


def drive_host(tcp: str, stop: threading.Event) -> None:
    """A pytrinamic host on axes 3..5 that also polls every position (wire traffic)."""
    from pytrinamic.connections import ConnectionManager

    with ConnectionManager(f"--interface socket_serial_tmcl --port {tcp}").connect() as iface:
        for axis, speed, acceleration in ((3, 90000, 60000), (4, 60000, 80000), (5, 50000, 50000)):
            iface.set_axis_parameter(AP.MAX_SPEED, axis, speed)
            iface.set_axis_parameter(AP.MAX_ACCELERATION, axis, acceleration)
        iface.set_axis_parameter(AP.RFS_MODE, 4, 1)  # the left end switch
        iface.set_axis_parameter(AP.RFS_SPEED, 4, 3500)  # still seeking when the picture is taken
        iface.set_axis_parameter(AP.RFS_SWITCH_SPEED, 4, 2000)
        iface.send(Opcode.SIO, 1, 2, 1)  # OUT1 lamp on
        iface.send(Opcode.RFS, 0, 4, 0)
        iface.send(Opcode.ROR, 0, 3, 70000)
        turn, step, direction, targets = time.monotonic() + 2.5, time.monotonic(), 1, [80000, -20000]
        while not stop.is_set():
            now = time.monotonic()
            if now >= turn:
                direction = -direction
                iface.send(Opcode.ROR if direction > 0 else Opcode.ROL, 0, 3, 70000)
                turn = now + 3.0
            if now >= step and iface.get_axis_parameter(AP.POSITION_REACHED, 5):
                iface.send(Opcode.MVP, 0, 5, targets[0])
                targets.reverse()
                step = now + 0.6
            for axis in range(6):
                iface.get_axis_parameter(AP.ACTUAL_POSITION, axis)
            time.sleep(0.05)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-o", "--output", default=str(ROOT / "docs/dashboard.png"))
    parser.add_argument("--seconds", type=float, default=9.0, help="motion before the picture")
    parser.add_argument("--width", type=int, default=1400)
    args = parser.parse_args()

    with SimulatorThread(clock="real", tcp=["127.0.0.1:0"], http=["127.0.0.1:0"],
                         world=str(WORLD)) as sim:
        client = StreamClient.tcp(sim.tcp, 1, timeout=5)
        try:
            upload(client, load_program(PROGRAM))
            client.send(Opcode.RUN_APPLICATION, 1, 0, 0)
        finally:
            client.close()
        sim.call(lambda: (sim.module(1).set_digital_input(2, True),
                          sim.module(1).set_analog_input(1, 41000)))
        stop = threading.Event()
        host = threading.Thread(target=drive_host, args=(sim.tcp, stop), daemon=True)
        host.start()
        browser = HeadlessChromium(args.width, 1000)
        try:
            page = browser.driver
            page.get(sim.endpoints["http"][0])
            deadline = time.monotonic() + 10
            while not page.execute_script("return window.tmclDashboard.state.listing.length"):
                if time.monotonic() > deadline:
                    raise RuntimeError("the page shows no program")
                time.sleep(0.05)
            page.find_element("css selector", f'#listing li[data-address="{UNREACHED_LINE}"]').click()
            time.sleep(args.seconds)
            page.execute_script("window.scrollTo(0, 0)")
            height = page.execute_script("return document.documentElement.scrollHeight")
            page.execute_cdp_cmd("Emulation.setDeviceMetricsOverride", {
                "width": args.width, "height": height, "deviceScaleFactor": 1, "mobile": False})
            time.sleep(0.3)  # a frame or two at the full size
            page.save_screenshot(args.output)
        finally:
            browser.quit()
            stop.set()
            host.join(5)
    print(f"{args.output}: {args.width}x{height}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
