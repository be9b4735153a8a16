"""Transports: ways for hosts to reach the simulated modules.

Each transport turns its wire format into calls on :class:`tmcl_server.simulation.Simulation`
and writes the replies back; none of them knows anything about the module's internals.
"""

from tmcl_server.transports.base import Transport

__all__ = ["Transport"]
