"""Motion-controller cores by name: an axis is a TMCL firmware layer over a chip core.

A module type names its core (``tmc4210`` on the TMCM-6212, ``tmc429`` on the TMCM-1110/3110/
6110); :func:`make_axes` builds a module's axes on it, :func:`make_axis` one axis.  Like
python-can's ``BACKENDS``, the table holds import paths as strings, so a core is only imported
when a module asks for it.  A new core is one entry here plus its files (docs/architecture.md,
"Adding a chip core").

A chip that drives several motors (the TMC429: three) serves several axes: its axis class
has a ``build_axes(count, parameters, clock_hz)`` class method that builds them in groups
sharing a chip.  A core without one gets one chip per axis.
"""

from __future__ import annotations

from collections.abc import Mapping

from axes.interface import Axis
from axes.world import AxisWorld
from tmcl_spec.parameters import ParamSpec
from tmcl_spec.registry import resolve

#: Core name -> "module:class" of its firmware layer (an :class:`axes.interface.Axis`).
CHIP_CORES: dict[str, str] = {
    "tmc4210": "axes.chips.tmc42x.tmc4210_firmware:TMC4210Axis",
    "tmc429": "axes.chips.tmc42x.tmc429_firmware:TMC429Axis",
    "tmc4361a": "axes.chips.tmc4361a.firmware:TMC4361AAxis",
    "tmc4361a-eval": "axes.chips.tmc4361a.eval_board:TMC4361AEvalAxis",
}
DEFAULT_CORE = "tmc4210"


def axis_class(core: str) -> type[Axis]:
    return resolve(CHIP_CORES, core, "chip core")


def make_axis(core: str, index: int, parameters: Mapping[int, ParamSpec],
              clock_hz: int | None = None, world: AxisWorld | None = None) -> Axis:
    """Axis ``index`` on core ``core``, with the module's axis-parameter table."""
    options = {} if clock_hz is None else {"clock_hz": clock_hz}
    return axis_class(core)(index, parameters=parameters, world=world, **options)


def make_axes(core: str, count: int, parameters: Mapping[int, ParamSpec],
              clock_hz: int | None = None) -> list[Axis]:
    """A module's ``count`` axes on core ``core``: in groups sharing a chip where the core's
    axis class builds them so (``build_axes``), else one chip per axis."""
    build = getattr(axis_class(core), "build_axes", None)
    if build is not None:
        return build(count, parameters, clock_hz)
    return [make_axis(core, index, parameters, clock_hz) for index in range(count)]
