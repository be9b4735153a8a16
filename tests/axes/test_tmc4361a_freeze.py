"""The TMC4361A's NFREEZE input (datasheet §12): a falling edge stops the ramp (DFREEZE 0: at
once), latches FROZEN, which stays, and locks motion until a reset.  The evaluation board drives
the pin from its microcontroller (command 144 type 2, tests/tmcl_server/test_eval_firmware.py).
"""

from __future__ import annotations

from axes.chips.tmc4361a import TMC4361A, Event, Reg, velocity_register

MHZ16 = 16_000_000
RESET = 0x525354 << 8


def running_chip() -> TMC4361A:
    chip = TMC4361A(clock_hz=MHZ16)
    chip.write(Reg.CLK_FREQ, MHZ16)
    chip.write(Reg.RAMPMODE, 0)  # velocity mode without a ramp
    chip.write(Reg.VMAX, velocity_register(10_000))
    chip.read(Reg.EVENTS)
    chip.run(MHZ16 // 100)  # 10 ms
    return chip


def test_a_falling_nfreeze_stops_at_once_and_locks_motion_until_a_reset() -> None:
    chip = running_chip()
    assert chip.read(Reg.VACTUAL) == 10_000
    chip.set_freeze(True)  # high: nothing happens
    assert not chip.frozen and chip.read(Reg.VACTUAL) == 10_000
    chip.set_freeze(False)
    assert chip.frozen and chip.read(Reg.VACTUAL) == 0
    position = chip.motor_position
    assert chip.read(Reg.EVENTS) & Event.FROZEN
    assert chip.read(Reg.EVENTS) & Event.FROZEN  # it stays: reading does not clear it
    chip.write(Reg.EVENTS, 0xFFFF_FFFF)  # nor does writing
    assert chip.read(Reg.EVENTS) & Event.FROZEN
    chip.set_freeze(True)  # released: still frozen
    chip.write(Reg.VMAX, velocity_register(-5_000))
    chip.run(chip.t + MHZ16 // 100)
    assert chip.motor_position == position and chip.read(Reg.VACTUAL) == 0
    chip.write(Reg.RESET_CLK_GATING, RESET)  # a reset ends it
    assert not chip.frozen and not chip.read(Reg.EVENTS) & Event.FROZEN
    chip.write(Reg.CLK_FREQ, MHZ16)
    chip.write(Reg.RAMPMODE, 0)
    chip.write(Reg.VMAX, velocity_register(5_000))
    chip.run(chip.t + MHZ16 // 100)
    assert chip.motor_position > position


def test_a_freeze_survives_a_clone() -> None:
    chip = running_chip()
    chip.set_freeze(False)
    twin = chip.clone()
    twin.write(Reg.VMAX, velocity_register(3_000))
    twin.run(twin.t + MHZ16 // 100)
    assert twin.frozen and twin.motor_position == chip.motor_position
