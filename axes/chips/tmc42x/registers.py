"""The TMC42x family's register map, bits and number helpers (TMC4210, TMC429).

The TMC4210 is a one-motor cut of the TMC429 (``shared/spec/tmc429.md`` §1): both chips have,
per motor, the same sixteen axis registers (IDX 0..15) and the same global registers
(SMDA = %11).  :class:`Reg` names them at the TMC4210's addresses, which are the TMC429's
motor 0 (a TMC429 motor's axis register is at ``motor << 4 | IDX``).  Nothing here moves: the
motion law is :mod:`axes.chips.tmc42x.law`, its fast shortcut :mod:`axes.chips.tmc42x.engine`.
"""

from __future__ import annotations

from enum import IntEnum
from typing import TypeVar

_T = TypeVar("_T")

MASK24 = 0xFFFFFF
HALF24 = 1 << 23
#: The deceleration ramp is internally limited to 2**19 steps (datasheet).
DISTANCE_LIMIT = 1 << 19
DEFAULT_CLOCK_HZ = 16_000_000
#: Speeds a velocity register can hold (11 bits).
V_RANGE = 2048


class RampMode(IntEnum):
    RAMP = 0
    SOFT = 1
    VELOCITY = 2
    HOLD = 3


class Reg(IntEnum):
    """Register addresses (the 7-bit ``RRS|SMDA|IDX`` field, datagram bits 31..25): the axis
    registers IDX 0..15 (the TMC429's motor 0) and the global registers ``%011 JDX``."""

    X_TARGET = 0x0
    X_ACTUAL = 0x1
    V_MIN = 0x2
    V_MAX = 0x3
    V_TARGET = 0x4
    V_ACTUAL = 0x5
    A_MAX = 0x6
    A_ACTUAL = 0x7
    A_THRESHOLD = 0x8  # TMC429: IS_AGTAT / IS_ALEAT / IS_V0 / A_THRESHOLD (current scaling)
    PMUL_PDIV = 0x9
    REF_CONF_RAMP_MODE = 0xA
    INTERRUPT = 0xB
    DIVIDERS = 0xC
    DX_REF_TOLERANCE = 0xD
    X_LATCHED = 0xE
    USTEP_COUNT = 0xF
    DATAGRAM_LOW = 0x30
    DATAGRAM_HIGH = 0x31
    COVER_POS_LEN = 0x32
    COVER_DATAGRAM = 0x33
    IF_CONFIGURATION = 0x34
    POS_COMP = 0x35
    POS_COMP_INT = 0x36
    POWER_DOWN = 0x38
    TYPE_VERSION = 0x39
    REFERENCE_SWITCHES = 0x3E
    SMGP = 0x3F


#: The first global register address (below it: axis registers, on the TMC429 of motors 0..2).
GLOBAL_REGISTERS = 0x30
#: The axis registers (IDX, the low four bits of a motor's address).
AXIS_REGISTERS = tuple(reg for reg in Reg if reg < 0x10)

#: Axis registers that are plain storage: attribute and the bits that exist (tmc4210.md §3.2).
#: The A_THRESHOLD slot's mask is the chip's (``MotorEngine.a_threshold_mask``).
MOTOR_PLAIN_REGISTERS: dict[int, tuple[str, int]] = {
    Reg.X_TARGET: ("x_target", MASK24),
    Reg.X_ACTUAL: ("x_actual", MASK24),
    Reg.V_MIN: ("v_min", 0x7FF),
    Reg.V_MAX: ("v_max", 0x7FF),
    Reg.A_MAX: ("a_max", 0x7FF),
    Reg.DX_REF_TOLERANCE: ("dx_ref_tolerance", 0xFFF),
    Reg.USTEP_COUNT: ("ustep_count", 0xFF),
}

#: The modes as plain ints, for the hot paths: an IntEnum member looked up through its class
#: costs about 0.1 us in CPython 3.11, ten times a global int (the two compare equal).
MODE_RAMP = int(RampMode.RAMP)
MODE_SOFT = int(RampMode.SOFT)
MODE_VELOCITY = int(RampMode.VELOCITY)  # modes below it position (ramp, soft)
MODE_HOLD = int(RampMode.HOLD)


class Irq(IntEnum):
    """Interrupt flag bits (INTERRUPT register bits 7..0; the mask is the same, shifted by 8)."""

    POS_END = 0
    REF_WRONG = 1
    REF_MISS = 2
    STOP = 3
    STOP_LEFT_LOW = 4
    STOP_RIGHT_LOW = 5
    STOP_LEFT_HIGH = 6
    STOP_RIGHT_HIGH = 7


IRQ_REF_MISS = int(Irq.REF_MISS)  # a plain int for the hot path (see MODE_RAMP)

# Bits of the REF_CONF / RAMP_MODE register.
DISABLE_STOP_L = 1 << 8
DISABLE_STOP_R = 1 << 9
SOFT_STOP = 1 << 10
REF_RNL = 1 << 11
LATCH_PENDING = 1 << 16


def sdiff24(a: int, b: int) -> int:
    """``a - b`` as a signed 24-bit difference (the chip's direction rule)."""
    return ((a - b + HALF24) & MASK24) - HALF24


def signed(value: int, bits: int) -> int:
    sign = 1 << (bits - 1)
    value &= (1 << bits) - 1
    return value - (sign << 1) if value & sign else value


def datagram(address: int, data: int = 0, read: bool = False) -> int:
    """Build a 32-bit host datagram for a 7-bit register (or RAM) address."""
    return (address & 0x7F) << 25 | int(read) << 24 | (data & MASK24)


def shallow_copy(obj: _T) -> _T:
    """``copy.copy`` for a plain object with a ``__dict__``, without the pickle protocol
    (several times faster: the firmware copies a chip at every look-ahead)."""
    twin = object.__new__(type(obj))
    twin.__dict__.update(obj.__dict__)
    return twin
