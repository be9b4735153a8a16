"""Motion-controller cores by name: an axis is a TMCL firmware layer over a chip core.

A module type names its core (``tmc4210`` on the TMCM-6212, ``tmc429`` on the TMCM-1110/3110/
6110); :func:`make_axes` builds a module's axes on it, :func:`make_axis` one axis.  Like
python-can's ``BACKENDS``, the table holds import paths as strings, so a core is only imported
when a module asks for it.  A new core is its folder under ``axes/chips/`` plus one entry here
(docs/architecture.md, "Adding a chip core").

An entry names a subclass of :class:`axes.interface.Axis`.  Its ``build_axes(count,
parameters, clock_hz)`` builds a module's axes: one chip per axis by default; a chip that
drives several motors (the TMC429: three) builds them in groups sharing a chip.
"""

from __future__ import annotations

from collections.abc import Mapping

from axes.interface import Axis
from axes.world import AxisWorld
from tmcl_spec.parameters import ParamSpec
from tmcl_spec.registry import resolve

#: Core name -> "module:class" of its axis (an :class:`axes.interface.Axis` subclass).
CHIP_CORES: dict[str, str] = {
    "tmc4210": "axes.chips.tmc42x.tmc4210_firmware:TMC4210Axis",
    "tmc429": "axes.chips.tmc42x.tmc429_firmware:TMC429Axis",
    "tmc4361a": "axes.chips.tmc4361a.firmware:TMC4361AAxis",
    "tmc4361a-eval": "axes.chips.tmc4361a.eval_board:TMC4361AEvalAxis",
}
DEFAULT_CORE = "tmc4210"


def axis_class(core: str) -> type[Axis]:
    """The axis class of core ``core`` (ValueError naming the known cores if there is none)."""
    cls = resolve(CHIP_CORES, core, "chip core")
    if not (isinstance(cls, type) and issubclass(cls, Axis)):
        raise TypeError(f"chip core {core!r}: {CHIP_CORES[core.lower()]} is not an axes.interface.Axis")
    return cls


def make_axis(core: str, index: int, parameters: Mapping[int, ParamSpec],
              clock_hz: int | None = None, world: AxisWorld | None = None) -> Axis:
    """Axis ``index`` on core ``core``, with the module's axis-parameter table (a chip of its
    own, at ``clock_hz``; None: the chip's default clock)."""
    return axis_class(core)(index, parameters, world=world, clock_hz=clock_hz)


def make_axes(core: str, count: int, parameters: Mapping[int, ParamSpec],
              clock_hz: int | None = None) -> list[Axis]:
    """A module's ``count`` axes on core ``core``: in groups sharing a chip where the core's
    chip drives several motors, else one chip per axis (:meth:`Axis.build_axes`)."""
    return axis_class(core).build_axes(count, parameters, clock_hz)


def refusal(core: str, parameters: Mapping[int, ParamSpec]) -> str | None:
    """Why axes with this parameter table cannot run on core ``core`` (None: they can): the
    reason the core's axis class gives when it is built with it."""
    try:
        make_axis(core, 0, parameters)
    except ValueError as exc:
        return str(exc)
    return None
