"""Motion axes of the simulated TMCM-6212.

The module talks to an axis only through :class:`axes.interface.Axis`; everything behind that
interface (motion-controller emulation, switches, encoder, load) belongs to this package:
:class:`axes.firmware.TMC4210Axis` (the TMCL firmware layer, the module's default axis) over
:class:`axes.tmc4210.TMC4210` (the emulated chip), in the world of :mod:`axes.world`.
"""

from axes.firmware import TMC4210Axis
from axes.interface import Axis, AxisEvent, AxisEventKind
from axes.parameters import AXIS_PARAMETERS, NUMBER_OF_AXES, ParamSpec
from axes.tmc4210 import TMC4210
from axes.world import AxisWorld, World, load_world

__all__ = ["AXIS_PARAMETERS", "NUMBER_OF_AXES", "TMC4210", "Axis", "AxisEvent", "AxisEventKind",
           "AxisWorld", "ParamSpec", "TMC4210Axis", "World", "load_world"]
