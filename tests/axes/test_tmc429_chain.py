"""The TMC429's SPI driver chain (en_sd = 0): datagram assembly from the RAM configuration and
the microstep sequencer, cover datagrams, the read-back registers and their CDGW handshake,
and TMC262 drivers configured and read through the chain.
"""

from __future__ import annotations

from axes.chips.tmc42x.registers import RampMode, Reg
from axes.chips.tmc42x.tmc262 import TMC262, DrvReg, ReadSelect, drv_datagram
from axes.chips.tmc42x.tmc429 import (
    CONTINUOUS_UPDATE,
    EN_SD,
    NXM,
    POLARITY_DAC_AB,
    POLARITY_PH_AB,
    POR_SINE_TABLE,
    RAM_ADDRESS,
    TMC429,
    Signal,
    motor_address,
)

CDGW = 0x40

#: One TMC262 in SPI mode: a 20-bit DRVCTRL  0 0 PHA CA7..CA0 PHB CB7..CB0, with the six
#: DAC bits as CA7..CA2 / CB7..CB2.
TMC262_WORDS = [Signal.ZERO, Signal.ZERO, Signal.PH_A,
                *[Signal.DAC_A0 + k for k in range(5, -1, -1)], Signal.ZERO, Signal.ZERO,
                Signal.PH_B, *[Signal.DAC_B0 + k for k in range(5, -1, -1)], Signal.ZERO,
                Signal.ZERO | NXM]


def status(chip: TMC429) -> int:
    return chip.spi(0x73000000) >> 24  # a TYPE_VERSION read


def program_chain(chip: TMC429, words: list[int]) -> None:
    """Write driver-chain configuration words from word 0 on, two per RAM address."""
    words = [*words, 0] if len(words) % 2 else list(words)
    for pair in range(len(words) // 2):
        chip.write(RAM_ADDRESS + pair, words[2 * pair + 1] << 8 | words[2 * pair])


def bits(value: int, width: int) -> list[int]:
    return [value >> (width - 1 - k) & 1 for k in range(width)]


def chain_of_tmc262(count: int) -> tuple[TMC429, list[TMC262]]:
    drivers = [TMC262() for _ in range(count)]
    chip = TMC429(drivers=drivers)
    program_chain(chip, TMC262_WORDS * count)
    chip.write(Reg.SMGP, 0x000700 | (count - 1))  # CLK2_DIV 7, LSMD = count - 1
    return chip, drivers


def cover(chip: TMC429, position: int, frame: int, length: int = 20) -> None:
    chip.write(Reg.COVER_POS_LEN, position << 8 | length)
    chip.write(Reg.COVER_DATAGRAM, frame)


def test_power_on_datagram_is_one_12_bit_tmc24x_word() -> None:
    chip = TMC429()
    motor = chip.motor(0)
    motor.write(Reg.DIVIDERS, 6)  # USRS 6: 64 microsteps, all six DAC bits
    motor.write(Reg.USTEP_COUNT, 80)  # quadrant 1, r = 16
    sin, cos = POR_SINE_TABLE[64 - 16], POR_SINE_TABLE[16]
    # MDA CA3 CA2 CA1 CA0 PHA MDB CB3 CB2 CB1 CB0 PHB, CAn = DAC bits 5..2; quadrant 1: PH_A 1, PH_B 0
    expected = [1, *bits(sin >> 2, 4), 1, 1, *bits(cos >> 2, 4), 0]
    assert chip.chain_datagram() == expected
    chip.write(Reg.SMGP, 0x000F00 | POLARITY_PH_AB | POLARITY_DAC_AB)
    expected = [1, *bits(~sin >> 2 & 15, 4), 0, 1, *bits(~cos >> 2 & 15, 4), 1]
    assert chip.chain_datagram() == expected
    chip.write(Reg.SMGP, 0x000F02)  # LSMD = 2: three drivers, 36 bits
    assert len(chip.chain_datagram()) == 36


def test_sequencer_resolution_and_current_scaling() -> None:
    chip = TMC429()
    program_chain(chip, [Signal.DAC_A0 + k for k in range(5, -1, -1)] + [Signal.ONE | NXM])
    motor = chip.motor(0)
    motor.write(Reg.USTEP_COUNT, 40)  # quadrant 0: coil A = LUT[40] = 53 = %110101
    motor.write(Reg.DIVIDERS, 6)
    assert chip.chain_datagram() == [*bits(53, 6), 1]
    motor.write(Reg.DIVIDERS, 2)  # 4 microsteps: DAC bits 5 and 4 only
    assert chip.chain_datagram() == [*bits(48, 6), 1]
    motor.write(Reg.DIVIDERS, 6)
    motor.write(Reg.A_THRESHOLD, 4 << 20 | 4 << 16 | 2 << 12)  # 50 % moving, 25 % at rest
    assert chip.chain_datagram() == [*bits(53 * 4 >> 3, 6), 1]  # at rest for < 255 ramp ticks: IS_ALEAT
    motor.run(255)  # 255 ramp ticks (RAMP_DIV 0) after coming to rest: IS_V0
    assert chip.chain_datagram() == [*bits(53 * 2 >> 3, 6), 1]


def test_steps_move_the_sequencer_pointer() -> None:
    chip = TMC429()
    motor = chip.motor(0)
    motor.write(Reg.DIVIDERS, 4)  # 16 microsteps: 4 table steps per microstep
    motor.write(Reg.V_MIN, 10)
    motor.write(Reg.V_MAX, 500)
    motor.write(Reg.A_MAX, 100)
    motor.write(Reg.X_TARGET, 21)
    motor.run(10**6)
    assert motor.read(Reg.USTEP_COUNT) == 84 and motor.motor_position == 21
    motor.write(Reg.X_TARGET, 0xFFFFFF)  # -1
    motor.run(10**7)
    assert motor.read(Reg.USTEP_COUNT) == 252


def test_cover_datagram_configures_a_tmc262_and_reads_its_status_back() -> None:
    chip, (driver,) = chain_of_tmc262(1)
    assert len(chip.chain_datagram()) == 20
    cover(chip, 0, drv_datagram(DrvReg.DRVCONF, 1 << 7 | ReadSelect.SG << 4))  # SDOFF, read SG
    assert driver.sdoff and driver.rdsel == ReadSelect.SG
    assert status(chip) & CDGW  # the frame after the write still shows it ...
    assert not status(chip) & CDGW  # ... then the chain is done
    # the answer shifted back while the cover datagram went out: the power-on status word
    # (MSTEP 0, no flags: STST needs 2**20 clocks without a step, and the chip just started)
    assert chip.read(Reg.DATAGRAM_LOW) == 0
    assert chip.read(Reg.DATAGRAM_HIGH) == 0
    assert chip.read(Reg.COVER_POS_LEN) == 1 << 8 | 20  # COVER_POS reads back + 1
    assert chip.read(Reg.COVER_DATAGRAM) == drv_datagram(DrvReg.DRVCONF, 0x90)
    cover(chip, 0, drv_datagram(DrvReg.SGCSCONF, 1 << 16 | 3 << 8 | 17))
    assert (driver.sfilt, driver.sgt, driver.cs) == (True, 3, 17)


def test_a_partial_cover_replaces_bits_in_transmission_order() -> None:
    chip, (driver,) = chain_of_tmc262(1)
    cover(chip, 0, drv_datagram(DrvReg.DRVCONF, 1 << 7))  # SPI mode
    chip.motor(0).write(Reg.DIVIDERS, 6)
    chip.motor(0).write(Reg.USTEP_COUNT, 16)  # quadrant 0: sin = LUT[16], cos = LUT[48]
    cover(chip, 11, 0b0110, length=4)  # CA1, CA0, PHB, CB7: positions 11..14
    sent = [0, 0, 1, *bits(POR_SINE_TABLE[16], 6), 0, 0, 1, *bits(POR_SINE_TABLE[48], 6), 0, 0]
    sent[11:15] = [0, 1, 1, 0]
    word = int("".join(map(str, sent)), 2)
    assert driver.drvctrl == word


def test_sequencer_datagrams_set_the_coil_currents_in_spi_mode() -> None:
    chip, (driver,) = chain_of_tmc262(1)
    cover(chip, 0, drv_datagram(DrvReg.DRVCONF, 1 << 7))
    motor = chip.motor(0)
    motor.write(Reg.DIVIDERS, 6)
    motor.write(Reg.REF_CONF_RAMP_MODE, RampMode.VELOCITY)
    motor.write(Reg.V_MAX, 300)
    motor.write(Reg.A_MAX, 300)
    motor.write(Reg.V_TARGET, 300)
    motor.run(100_000)
    chip.write(Reg.DATAGRAM_LOW, 0)  # re-arm: datagrams flow (the motor runs), done at once
    w = motor.ustep_count
    quadrant, r = w >> 6, w & 63
    lut = [*POR_SINE_TABLE, 63]
    sin, cos = (lut[r], lut[64 - r]) if quadrant % 2 == 0 else (lut[64 - r], lut[r])
    ph_a, ph_b = ((1, 1), (1, 0), (0, 0), (0, 1))[quadrant]
    assert driver.coil_currents == (-(sin << 2) if ph_a else sin << 2, -(cos << 2) if ph_b else cos << 2)
    assert driver.current_scale == 0.0  # TOFF = 0: the bridges are still off


def test_read_back_handshake() -> None:
    chip, _ = chain_of_tmc262(1)
    cover(chip, 0, drv_datagram(DrvReg.DRVCONF, 1 << 7 | ReadSelect.SG << 4))
    status(chip)
    chip.write(Reg.DATAGRAM_LOW, 0)  # re-arm with every motor at rest: nothing is sent
    for _ in range(3):
        assert status(chip) & CDGW
    chip.write(Reg.SMGP, 0x000700 | CONTINUOUS_UPDATE)
    assert status(chip) & CDGW  # sampled before this frame's datagram ...
    assert not status(chip) & CDGW  # ... which completed the capture
    assert chip.read(Reg.DATAGRAM_LOW) == 0  # SG 0 (nothing measured), no flags
    chip.motor(0).run(1 << 15)  # 2**20 clocks at rest
    chip.write(Reg.DATAGRAM_LOW, 0)
    assert chip.read(Reg.DATAGRAM_LOW) == 0x80  # STST


def test_three_tmc262_answer_in_chain_order() -> None:
    chip, drivers = chain_of_tmc262(3)
    for k in range(3):  # each driver's 20 bits sit at 20 k in transmission order
        cover(chip, 20 * k, drv_datagram(DrvReg.DRVCONF, 1 << 7 | ReadSelect.SG << 4))
        cover(chip, 20 * k, drv_datagram(DrvReg.SGCSCONF, 10 + k))
    assert [d.cs for d in drivers] == [10, 11, 12]
    assert all(d.sdoff and d.rdsel == ReadSelect.SG for d in drivers)
    drivers[0].faults = drivers[0].faults.OT
    drivers[1].faults = drivers[1].faults.OLA
    drivers[2].faults = drivers[2].faults.OLB
    chip.write(Reg.SMGP, 0x000702 | CONTINUOUS_UPDATE)
    chip.write(Reg.DATAGRAM_HIGH, 0)  # re-arm: continuous update sends at once
    # 60 bits came back, motor 1 first: the 48-bit register keeps motor 1's last 8 bits
    words = [0x02, 0x20, 0x40]  # OT / OLA / OLB, SG 0
    captured = (words[0] & 0xFF) << 40 | words[1] << 20 | words[2]
    assert chip.read(Reg.DATAGRAM_HIGH) << 24 | chip.read(Reg.DATAGRAM_LOW) == captured


def test_no_chain_in_step_dir_mode_until_it_comes_back() -> None:
    chip, (driver,) = chain_of_tmc262(1)
    chip.write(Reg.IF_CONFIGURATION, EN_SD)
    cover(chip, 0, drv_datagram(DrvReg.SGCSCONF, 9))
    assert status(chip) & CDGW and driver.cs == 0
    assert chip.read(Reg.COVER_POS_LEN) >> 23 == 1  # cw: not sent yet
    chip.write(Reg.IF_CONFIGURATION, 0)  # back to SPI mode: the chain starts with it
    assert driver.cs == 9
    assert status(chip) & CDGW
    assert not status(chip) & CDGW


def test_writes_to_a_motor_register_address_reach_only_that_motor() -> None:
    chip, _ = chain_of_tmc262(3)
    chip.write(motor_address(2, Reg.USTEP_COUNT), 64)
    assert [m.ustep_count for m in chip.motors] == [0, 0, 64]
