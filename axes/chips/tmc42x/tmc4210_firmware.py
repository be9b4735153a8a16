"""The TMC4210 core: the chip-specific half of the TMCL firmware, and the axis built on it.

:class:`TMC4210Driver` is what the module's microcontroller does with its TMC4210, and only
that: it talks to the chip through :meth:`TMC4210.spi` datagrams.  The routines it shares with
the TMC429 core (units, PULSE_DIV/RAMP_DIV and PMUL/PDIV, V_MIN, the 32-bit position fed to
the chip's 24 bits in rolling pieces, switches, stops) are :class:`axes.chips.tmc42x.firmware.
TMC42xDriver`; this driver adds the TMC4210's set-up and its switch register.  Everything a
TMCL axis does whatever its chip (reference search, stallGuard, encoder, current, events,
time) is in :class:`axes.firmware.AxisFirmware`; :class:`TMC4210Axis` joins the two.
The modelling choices are explained in docs/motion.md.
"""

from __future__ import annotations

from collections.abc import Mapping

from axes.board import AxisBoard
from axes.chips.tmc42x.firmware import ROLLING_REFRESH, ROLLING_SPAN, TMC42xDriver
from axes.chips.tmc42x.tmc4210 import (
    DEFAULT_CLOCK_HZ,
    EN_SD,
    MOT1R,
    SMGP_POWER_ON,
    TMC4210,
    Reg,
)
from axes.firmware import AxisFirmware
from axes.world import AxisWorld
from tmcl_spec.parameters import ParamSpec

__all__ = ["ROLLING_REFRESH", "ROLLING_SPAN", "SMGP_FIRMWARE", "TMC4210Axis", "TMC4210Driver"]

#: STEP pulse length 4 µs at 16 MHz and mot1r = 1 (the right switch belongs to the axis).
SMGP_FIRMWARE = MOT1R | (SMGP_POWER_ON & ~0xF00) | 3 << 8


class TMC4210Driver(TMC42xDriver):
    """The firmware's TMC4210 routines for one axis (an :class:`axes.core.ChipDriver`)."""

    chip_name = "TMC4210"

    def __init__(self, index: int, params: Mapping[int, int], board: AxisBoard,
                 clock_hz: int = DEFAULT_CLOCK_HZ) -> None:
        super().__init__(index, params, board, TMC4210(clock_hz, board))

    def setup_chip(self) -> None:
        """What the firmware does at power-up (spec §8.2): outputs on, right switch wired."""
        self._write_global(Reg.IF_CONFIGURATION, EN_SD)
        self._write_global(Reg.SMGP, SMGP_FIRMWARE)

    def levels(self) -> tuple[bool, bool, bool]:
        """Logical (left, right, home) switch levels as the chip reports them."""
        switches = self._read_global(Reg.REFERENCE_SWITCHES)
        return bool(switches & 2), bool(switches & 1), bool(switches & 8)


class TMC4210Axis(AxisFirmware):
    """One TMCM-6212 axis on a TMC4210: the TMCL firmware layer over the TMC4210 driver."""

    def __init__(self, index: int, parameters: Mapping[int, ParamSpec],
                 world: AxisWorld | None = None, clock_hz: int | None = None) -> None:
        clock = DEFAULT_CLOCK_HZ if clock_hz is None else clock_hz
        super().__init__(index, parameters, world,
                         lambda params, board: TMC4210Driver(index, params, board, clock))
