"""The TMC4361A motion controller: register file, SPI, events, and its ramp generator.

:class:`TMC4361A` is the chip (it implements :class:`axes.core.ChipModel`); the register map
and unit helpers are in :mod:`axes.chips.tmc4361a.registers`, the motion law and the fast
engine in :mod:`axes.chips.tmc4361a.ramp`.  Two cores drive it: the TMCL firmware's
(:mod:`axes.chips.tmc4361a.firmware`, core ``tmc4361a``) and the evaluation board's
(:mod:`axes.chips.tmc4361a.eval_board`, core ``tmc4361a-eval``).  ``docs/tmc4361a.md`` has
every modelling choice.
"""

from axes.chips.tmc4361a.chip import DEFAULT_CLOCK_HZ, TMC4361A, EncoderBoard
from axes.chips.tmc4361a.registers import (
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
