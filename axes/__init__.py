"""Motion axes of the simulated TMCM-6212.

The module talks to an axis only through :class:`axes.interface.Axis`; everything behind that
interface (motion-controller emulation, switches, encoder, load) belongs to this package.
"""

from axes.interface import Axis, AxisEvent, AxisEventKind
from axes.parameters import AXIS_PARAMETERS, NUMBER_OF_AXES, ParamSpec

__all__ = ["AXIS_PARAMETERS", "NUMBER_OF_AXES", "Axis", "AxisEvent", "AxisEventKind", "ParamSpec"]
