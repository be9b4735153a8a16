#!/usr/bin/env python3
"""Drive a simulated TMCM-6212 with the unchanged pytrinamic client.

Start the simulator first (``python3 scripts/serve.py``), then:

    .venv/bin/python scripts/example_pytrinamic.py --tcp 127.0.0.1:2323
    .venv/bin/python scripts/example_pytrinamic.py --pty /tmp/ttyTMCL0

With ``--self-contained`` the script starts its own simulator in-process (virtual clock) and
shows that simulated time need not pass in real time.
"""

from __future__ import annotations

import argparse
import sys
import time

try:
    from pytrinamic.connections import ConnectionManager
    from pytrinamic.modules import TMCM6212
except ImportError:  # the server alone does not need it
    sys.exit("this example needs pytrinamic: python3 scripts/serve.py installs it, or run "
             ".venv/bin/pip install -e '.[examples]'")


def demo(interface_args: str, advance=None) -> None:
    with ConnectionManager(interface_args).connect() as iface:
        module = TMCM6212(iface)
        motor = module.motors[0]
        print("firmware:", iface.get_version_string())
        motor.linear_ramp.max_velocity = 51200
        motor.linear_ramp.max_acceleration = 51200
        print("moving axis 0 to 102400 ...")
        module.move_to(0, 102400)
        while not motor.get_position_reached():
            print(f"  position {motor.actual_position:7d}  velocity {motor.actual_velocity:6d}")
            if advance:
                advance(0.25)
            else:
                time.sleep(0.25)
        print(f"  reached {motor.actual_position}")
        print("rotating left at 25600 pps for one second, then stopping")
        module.rotate(0, -25600)
        advance(1.0) if advance else time.sleep(1.0)
        module.stop(0)
        print(f"  position {motor.actual_position}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--tcp", metavar="HOST:PORT")
    where.add_argument("--pty", metavar="PATH")
    where.add_argument("--self-contained", action="store_true")
    args = parser.parse_args()
    if args.tcp:
        demo(f"--interface socket_serial_tmcl --port {args.tcp}")
    elif args.pty:
        demo(f"--interface serial_tmcl --port {args.pty} --data-rate 115200")
    else:
        from tmcl_server import SimulatorThread

        with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"]) as sim:
            demo(f"--interface socket_serial_tmcl --port {sim.tcp}", advance=sim.advance)


if __name__ == "__main__":
    main()
