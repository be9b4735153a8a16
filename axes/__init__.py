"""Motion axes: a TMCL firmware layer over an emulated motion-controller chip, per axis.

The module talks to an axis only through :class:`axes.interface.Axis` and builds axes by core
name with :func:`axes.cores.make_axes`; everything behind that (chip emulation, switches,
encoder, load) belongs to this package.  The firmware layer reaches its chip only through SPI
datagrams (:mod:`axes.core` is that contract); the world around the axes is :mod:`axes.world`.
The chip cores live in :mod:`axes.chips`, one package per chip family; importing this
package loads none of them: a core is imported when a module asks for it.
"""

from axes.interface import Axis, AxisEvent, AxisEventKind, AxisStatus
from axes.world import AxisWorld, World, load_world

__all__ = ["Axis", "AxisEvent", "AxisEventKind", "AxisStatus", "AxisWorld", "World", "load_world"]
