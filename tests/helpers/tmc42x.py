"""Setting up a TMC42x motor's ramp as the TMCL firmware does, for the chip tests of the TMC4210
and the TMC429 (both motors take the same register writes)."""

from __future__ import annotations

from typing import Protocol

from axes.chips.tmc42x.registers import RampMode, Reg
from axes.chips.tmc42x.units import pmul_pdiv, stop_speed


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
