"""tmcl-sim: a simulator of the TRINAMIC TMCM-6212 six-axis TMCL module.

Layers, each importing only the ones below it:

* transports (tmcl_server/transports/): TCP, pty, serial port ... -> bytes in, bytes out
* simulation and module (tmcl_server/simulation.py, module.py): the TMCM-6212 itself
* interpreter/ (TMCL programs) and axes/ (motion), which know nothing of the layers above
"""

from tmcl_server.clock import RealClock, VirtualClock
from tmcl_server.embed import SimulatorThread
from tmcl_server.module import TMCM6212
from tmcl_server.server import Server, ServerConfig
from tmcl_server.simulation import Simulation

__all__ = ["TMCM6212", "RealClock", "Server", "ServerConfig", "Simulation", "SimulatorThread",
           "VirtualClock"]
__version__ = "0.1.0"
