"""The TMC4361A ramp generator's registers in exact *fine units*, and the vocabulary of its law.

The law (``docs/tmc4361a.md``, "The motion law") works on exact integers: one microstep is
``S`` fine units, where ``S`` is chosen so that every register value, at the programmed
CLK_FREQ, is a whole number of fine units per clock (per clock squared, per clock cubed)
(:func:`fine_scale`).  :class:`Params` is a register set in those units; :class:`Stage`,
:class:`Variant` and the actions ``A_*`` name what the law
(:class:`axes.chips.tmc4361a.law.RampLaw`) and its fast shortcut
(:class:`axes.chips.tmc4361a.ramp.Ramp`) talk about.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from math import lcm

#: Clocks per bow quantum (datasheet §6.3.10: AACTUAL alters every 64 clock cycles).
BOW_QUANTUM = 64
#: A braking distance for a ramp that never comes to an end (a bow or deceleration of 0).
NEVER = 1 << 400


class Stage(IntEnum):
    """Where a slope stands; the datasheet's B1..B4 / A1..A3 phases map onto these."""

    IDLE = 0  # at rest
    CRUISE = 1  # |v| constant, no slope in progress
    REC = 2  # the acceleration of the other slope is being taken back to 0
    UP = 3  # |a| rising (B1 on the rising slope, B3 on the falling slope)
    HOLD = 4  # |a| constant (B12 / B34)
    DOWN = 5  # |a| falling (B2 / B4)
    END = 6  # the DFINAL tail of a stop in velocity mode
    CRAWL = 7  # the VSTOP crawl to the target in positioning


RISE, FALL = 1, -1


class Variant(IntEnum):
    """What a falling slope is for."""

    TO_SPEED = 0  # down to a lower target speed (velocity mode, or VMAX lowered)
    TO_ZERO = 1  # to standstill: VMAX = 0, a direction reversal, a stop in velocity mode
    TO_TARGET = 2  # the final approach of a positioning move


def sign(value: int) -> int:
    return (value > 0) - (value < 0)


def signed32(value: int) -> int:
    value &= 0xFFFF_FFFF
    return value - (1 << 32) if value & 0x8000_0000 else value


def fine_scale(clk_freq: int) -> int:
    """Fine units per microstep: every register unit at ``clk_freq`` is a whole number of them.

    Velocity registers count 1/256 pps (1/(256 f) steps per clock), accelerations 1/4 pps²
    (1/(4 f²) per clock²) or, in direct mode, 2^-37 steps per clock²; bows 1 pps³ (1/f³ per
    clock³) or 2^-53 in direct mode.
    """
    f = max(clk_freq, 1)
    return lcm(f ** 3, 1 << 53, 4 * f * f, 256 * f)


@dataclass(frozen=True, slots=True)
class RampRegisters:
    """The raw register values the ramp generator reads."""

    rampmode: int = 0
    vmax: int = 0
    vstart: int = 0
    vstop: int = 0
    vbreak: int = 0
    amax: int = 0
    dmax: int = 0
    astart: int = 0
    dfinal: int = 0
    dstop: int = 0
    bow1: int = 0
    bow2: int = 0
    bow3: int = 0
    bow4: int = 0
    clk_freq: int = 16_000_000
    tzerowait: int = 0
    general_conf: int = 0


@dataclass(frozen=True, slots=True)
class Params:
    """The ramp registers in fine units (see :func:`fine_scale`)."""

    S: int
    f: int
    positioning: bool
    profile: int  # RAMPMODE(1:0): 0 no ramp, 1 trapezoid / SixPoint, 2 S-shaped
    V: int  # |VMAX|
    sv: int  # sign of VMAX
    VSTART: int
    VSTOP: int
    VBREAK: int
    AMAX: int
    DMAX: int
    ASTART: int
    DFINAL: int
    DSTOP: int
    J1: int  # bow quanta (acceleration change per quantum)
    J2: int
    J3: int
    J4: int
    tzerowait: int
    use_astart: bool
    bows_equal: bool  # BOW2 == BOW4: S-ramps pass through v = 0 without stopping
    quantum: int
    margin: int  # how far past the entry of the target step a positioning move aims

    @classmethod
    def from_registers(cls, regs: RampRegisters, quantum: int = BOW_QUANTUM) -> Params:
        f = max(regs.clk_freq, 1)
        S = fine_scale(f)
        direct_a = bool(regs.general_conf & 2)
        direct_j = bool(regs.general_conf & 4)

        def vel(reg: int) -> int:
            return min(reg * S // (256 * f), S)

        def acc(reg: int) -> int:
            return (reg * S) >> 37 if direct_a else reg * S // (4 * f * f)

        def jerk(reg: int) -> int:
            return quantum * ((reg * S) >> 53 if direct_j else reg * S // f ** 3)

        vmax = signed32(regs.vmax)
        V, AMAX, ASTART = vel(abs(vmax)), acc(regs.amax), acc(regs.astart)
        DMAX, DFINAL, VBREAK = acc(regs.dmax), acc(regs.dfinal), vel(regs.vbreak)
        J3, J4 = jerk(regs.bow3), jerk(regs.bow4)
        margin = landing_margin(S, regs.rampmode & 3, V, AMAX, ASTART, DMAX, DFINAL, VBREAK, J3,
                                J4, quantum)
        return cls(S=S, f=f, margin=margin, positioning=bool(regs.rampmode & 4), profile=regs.rampmode & 3,
                   V=vel(abs(vmax)), sv=sign(vmax), VSTART=vel(regs.vstart),
                   VSTOP=vel(regs.vstop), VBREAK=vel(regs.vbreak), AMAX=acc(regs.amax),
                   DMAX=acc(regs.dmax), ASTART=acc(regs.astart), DFINAL=acc(regs.dfinal),
                   DSTOP=acc(regs.dstop), J1=jerk(regs.bow1), J2=jerk(regs.bow2),
                   J3=jerk(regs.bow3), J4=jerk(regs.bow4), tzerowait=regs.tzerowait,
                   use_astart=bool(regs.general_conf & 1),
                   bows_equal=regs.bow2 == regs.bow4, quantum=quantum)


def landing_margin(S: int, profile: int, V: int, AMAX: int, ASTART: int, DMAX: int,
                   DFINAL: int, VBREAK: int, J3: int, J4: int, quantum: int) -> int:
    """How far past the entry of the target step a positioning move aims (fine units).

    The braking decision, taken once per clock, can leave the final approach short of its aim
    by at most one clock of travel plus one clock of acceleration carried through the whole
    braking ramp; aiming that far into the target step lands every normal move inside it.
    Capped at half a step.
    """
    if profile == 2:
        if not (DMAX and J3 and J4):
            return S // 2
        brake_ticks = V // DMAX + 1 + quantum * (DMAX // J3 + DMAX // J4 + 2)
    else:
        decel = min([DMAX] + ([DFINAL] if VBREAK else []))
        if decel == 0:
            return S // 2
        brake_ticks = V // decel + 1
    a = max(AMAX, ASTART)
    return min(S // 2, V + a + a * brake_ticks)


@dataclass(slots=True)
class Context:
    """What the ramp needs from the rest of the chip for one decision."""

    target: int = 0  # XTARGET as an unwrapped microstep position
    blocked_neg: bool = False  # motion in - direction locked by a (virtual) stop switch
    blocked_pos: bool = False

    def blocks(self, direction: int) -> bool:
        """Motion in ``direction`` (-1, 0, 1) is locked by a (virtual) stop switch."""
        return self.blocked_neg if direction < 0 else direction > 0 and self.blocked_pos


# Actions (what a tick does), chosen by Ramp.decide.
A_IDLE, A_WAIT, A_STOP, A_NORAMP, A_START, A_SPEED, A_FALL, A_POSITION = range(8)


def ceil_div(a: int, b: int) -> int:
    return -(-a // b)
