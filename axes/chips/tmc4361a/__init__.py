"""The TMC4361A motion controller: register file, SPI, events, and its ramp generator.

:class:`TMC4361A` is the chip (it implements :class:`axes.core.ChipModel`); the register map
and unit helpers are in :mod:`axes.chips.tmc4361a.registers`, the ramp registers in fine
units in :mod:`axes.chips.tmc4361a.params`, the motion law (one clock) in
:mod:`axes.chips.tmc4361a.law` and its fast shortcut (the segment jumper) in
:mod:`axes.chips.tmc4361a.ramp`; the chip's encoder, home tracking and remembered runs in
:mod:`~axes.chips.tmc4361a.encoder`, :mod:`~axes.chips.tmc4361a.home` and
:mod:`~axes.chips.tmc4361a.recall`.  Two cores drive it: the TMCL firmware's
(:mod:`axes.chips.tmc4361a.firmware`, core ``tmc4361a``) and the evaluation board's
(:mod:`axes.chips.tmc4361a.eval_board`, core ``tmc4361a-eval``).  ``docs/tmc4361a.md`` has
every modelling choice.
"""

from axes.chips.tmc4361a.chip import DEFAULT_CLOCK_HZ, TMC4361A
from axes.chips.tmc4361a.encoder import EncoderBoard
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
