"""tmcl-sim: simulated TRINAMIC TMCL modules (a TMCM-6212 by default), byte for byte on the wire.

Layers, each importing only the ones below it (docs/architecture.md):

* transports (tmcl_server/transports/): TCP, pty, serial port, CAN, MQTT -> bytes in, bytes out
* server, simulation and module (server.py, simulation.py, module.py): the modules themselves
* interpreter/ (TMCL programs) and axes/ (motion), which know nothing of the layers above
* tmcl_spec/: the firmware manual's vocabulary as data, imported by all

Importing this package loads nothing else: the names below are imported on first use, so a
host that only wants the codec (``tmcl_server.protocol``) pays for nothing more.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from tmcl_server.clock import LockstepClock, RealClock, VirtualClock
    from tmcl_server.embed import SimulatorThread
    from tmcl_server.module import TMCM6212, TMCLModule
    from tmcl_server.server import Server, ServerConfig
    from tmcl_server.simulation import Simulation

#: Public name -> the module that defines it.
_EXPORTS = {
    "LockstepClock": "tmcl_server.clock",
    "RealClock": "tmcl_server.clock",
    "VirtualClock": "tmcl_server.clock",
    "SimulatorThread": "tmcl_server.embed",
    "TMCLModule": "tmcl_server.module",
    "TMCM6212": "tmcl_server.module",
    "Server": "tmcl_server.server",
    "ServerConfig": "tmcl_server.server",
    "Simulation": "tmcl_server.simulation",
}

__all__ = [
    "TMCM6212",
    "LockstepClock",
    "RealClock",
    "Server",
    "ServerConfig",
    "Simulation",
    "SimulatorThread",
    "TMCLModule",
    "VirtualClock",
]


def __getattr__(name: str) -> Any:
    if name == "__version__":  # the installed distribution's (tmcl_spec.package)
        from tmcl_spec.package import package_version

        return package_version()
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'tmcl_server' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
