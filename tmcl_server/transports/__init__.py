"""Transports: ways for hosts to reach the simulated modules, chosen by name.

Each transport turns its wire format into calls on :class:`tmcl_server.simulation.Simulation`
and writes the replies back; none of them knows anything about the module's internals.
Like python-can's ``BACKENDS``, :data:`TRANSPORTS` names each transport's class as a string:
a transport (and the library it needs: pyserial, python-can, aiomqtt) is imported only when
a server is asked to open it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from tmcl_spec.registry import resolve

if TYPE_CHECKING:
    from tmcl_server.transports.base import Transport

#: Endpoint kind -> "module:class".  CAN kinds share the server's simulated bus (docs/can.md).
TRANSPORTS: dict[str, str] = {
    "tcp": "tmcl_server.transports.tcp:TcpTransport",
    "pty": "tmcl_server.transports.pty:PtyTransport",
    "serial": "tmcl_server.transports.serial_port:SerialPortTransport",
    "can": "tmcl_server.transports.can.python_can:PythonCanTransport",
    "slcan": "tmcl_server.transports.can.slcan:SlcanPtyTransport",
    "socketcand": "tmcl_server.transports.can.socketcand:SocketcandTransport",
    "mqtt": "tmcl_server.transports.mqtt.bridge:MqttBridge",
    # not a host's transport: the live dashboard in a browser (docs/dashboard.md)
    "http": "tmcl_server.dashboard.web:DashboardTransport",
}


def transport_class(kind: str) -> type[Transport]:
    return resolve(TRANSPORTS, kind, "transport")
