"""CAN: the simulated bus the server owns, and the ways hosts reach it.

* :mod:`.bus` -- one simulated wire; the modules sit on it as one party
* :mod:`.python_can` -- ``--can IFACE:CHANNEL``: join a python-can bus (socketcan, virtual, ...)
* :mod:`.slcan` -- ``--slcan-pty PATH``: a virtual SLCAN (Lawicel) USB-CAN adapter
* :mod:`.socketcand` -- ``--socketcand [HOST:]PORT``: a socketcand server (raw mode)

The server creates the bus once (``Server.can_bus()``) and hands it to every CAN transport;
docs/can.md has the rules of the wire.  This file imports no CAN library.
"""

#: The simulated bus's name unless ``--can-bus`` names it (socketcand clients open it by name).
DEFAULT_BUS_NAME = "can0"
#: socketcand's well-known port.
DEFAULT_SOCKETCAND_PORT = 29536


def check_bus_name(name: str) -> str:
    """The bus name as socketcand's ``< open NAME >`` can carry it; ValueError otherwise."""
    if not name or any(c.isspace() or c in "<>" for c in name) or len(name) > 16:
        raise ValueError(f"bad CAN bus name {name!r} (1..16 characters, no blanks or <>)")
    return name
