"""Setting up a TMC42x motor's ramp as the TMCL firmware does, for the chip tests of the TMC4210
and the TMC429 (both motors take the same register writes)."""

from __future__ import annotations

from typing import Any, Protocol

from axes.chips.tmc42x.registers import MASK24, RampMode, Reg
from axes.chips.tmc42x.units import pmul_pdiv, stop_speed
from axes.core import Stop


class RegisterFile(Protocol):
    def write(self, reg: int, data: int) -> None: ...


def configure(motor: RegisterFile, *, v_max: int, a_max: int, pulse_div: int, ramp_div: int,
              v_min: int | None = None, mode: int = RampMode.RAMP) -> None:
    """V_MIN (the firmware's stop speed unless given), V_MAX, A_MAX, PMUL/PDIV for A_MAX, the
    dividers, and last the ramp mode word (``mode``: RAMP_MODE with any REF_CONF bits)."""
    pmul, pdiv = pmul_pdiv(a_max, ramp_div, pulse_div) or (128, 0)
    motor.write(Reg.V_MIN, stop_speed(a_max, pmul, pdiv, v_max, ramp_div, pulse_div)
                if v_min is None else v_min)
    motor.write(Reg.V_MAX, v_max)
    motor.write(Reg.A_MAX, a_max)
    motor.write(Reg.PMUL_PDIV, pmul << 8 | pdiv)
    motor.write(Reg.DIVIDERS, pulse_div << 12 | ramp_div << 8)
    motor.write(Reg.REF_CONF_RAMP_MODE, mode)


def apply_change(motor: RegisterFile, ref: Any, what: str, value: int, conf: int = 0) -> None:
    """One random change of a law-against-reference test, written to the motor's registers and
    set on the reference model alike (``conf``: REF_CONF bits kept when the mode is written)."""
    if what == "x_target":
        motor.write(Reg.X_TARGET, value & MASK24)
        ref.x_target = value & MASK24
    elif what == "v_target":
        motor.write(Reg.V_TARGET, value & 0xFFF)
        ref.v_target = value
    elif what == "mode":
        motor.write(Reg.REF_CONF_RAMP_MODE, conf | value)
        ref.mode = RampMode(value)
    else:
        motor.write(Reg[what.upper()], value)
        setattr(ref, what, value)


def run_alongside(motor: Any, ref: Any, until: int, arrivals: list[int], where: str) -> None:
    """The reference ticked and the motor run to clk32 tick ``until`` (each arrival's tick
    noted), then both at the same position, speed and target speed."""
    while ref.t < until:
        ref.tick()
    while motor.t < until:
        if motor.run(until) is Stop.ARRIVED:
            arrivals.append(motor.t)
    assert (motor.x_actual, motor.v, motor.v_target) == (ref.x_actual, ref.v, ref.v_target), where
