"""The TMC4361A motion controller: register file, SPI, events, and its ramp generator.

:class:`TMC4361A` is the chip (it implements :class:`axes.core.ChipModel`); the register map
and unit helpers are in :mod:`axes.tmc4361a.registers`, the motion law and the fast engine in
:mod:`axes.tmc4361a.ramp`.  ``docs/tmc4361a.md`` has every modelling choice.
"""

from axes.tmc4361a.chip import DEFAULT_CLOCK_HZ, TMC4361A, EncoderBoard
from axes.tmc4361a.registers import (
    WAKE_ALWAYS,
    Event,
    GeneralConf,
    RefConf,
    Reg,
    Status,
    acceleration_pps2,
    acceleration_register,
    bow_register,
    datagram,
    velocity_pps,
    velocity_register,
)

__all__ = ["DEFAULT_CLOCK_HZ", "TMC4361A", "WAKE_ALWAYS", "EncoderBoard", "Event", "GeneralConf",
           "RefConf", "Reg", "Status", "acceleration_pps2", "acceleration_register",
           "bow_register", "datagram", "velocity_pps", "velocity_register"]
