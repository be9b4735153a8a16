"""The TMC262 model: register decoding, the status word, stallGuard2 following the load, coolStep.

The register layout is the TMC26x datasheet's; the load model (docs/tmc429.md) is ours.
"""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from axes.chips.tmc42x.registers import Reg
from axes.chips.tmc42x.tmc262 import (
    SG_PER_SGT,
    STANDSTILL_CLOCKS,
    TMC262,
    UNLOADED,
    DriverFlag,
    DrvReg,
    ReadSelect,
    drv_datagram,
)
from axes.chips.tmc42x.tmc429 import EN_SD, TMC429
from axes.core import Stop
from axes.world import DEFAULT_LOAD


class Motor:
    """A hand-driven MotorSense: a step counter, a standstill flag and a load profile."""

    def __init__(self, loads: dict[int, int] | None = None, default: int = 700) -> None:
        self.steps = 0
        self.standstill = False
        self.loads = loads or {}
        self.default = default
        self.units = 4

    def sensed_steps(self) -> int:
        return self.steps

    def sensed_standstill(self) -> bool:
        return self.standstill

    def sensed_load(self, steps: int) -> int:
        return self.loads.get(steps, self.default)

    def sequencer_units(self) -> int:
        return self.units


def driver_on(motor: Motor | None = None, *, mres: int = 4, sgt: int = 0, sfilt: bool = False,
              cs: int = 20, rdsel: ReadSelect = ReadSelect.SG) -> TMC262:
    driver = TMC262()
    driver.attach(motor)
    driver.spi(drv_datagram(DrvReg.DRVCTRL, mres))
    driver.spi(drv_datagram(DrvReg.CHOPCONF, 0x901B4))  # TBL 2, HEND 2, HSTRT 3, TOFF 4 (typical)
    driver.spi(drv_datagram(DrvReg.SGCSCONF, sfilt << 16 | (sgt & 0x7F) << 8 | cs))
    driver.spi(drv_datagram(DrvReg.DRVCONF, rdsel << 4))
    return driver


def poll(driver: TMC262) -> int:
    """A datagram that changes nothing (DRVCONF again), for its answer, as firmware polls."""
    return driver.spi(drv_datagram(DrvReg.DRVCONF, driver.drvconf))


def test_power_on_bridges_off_and_256_microsteps() -> None:
    driver = TMC262()
    assert (driver.microsteps, driver.enabled, driver.current_scale, driver.cs) == (256, False, 0.0, 0)
    assert driver.spi(0) == int(DriverFlag.STST)  # no motor wired: it stands still, MSTEP 0
    assert UNLOADED == DEFAULT_LOAD


@pytest.mark.parametrize(("mres", "microsteps"), [(0, 256), (1, 128), (4, 16), (7, 2), (8, 1), (15, 1)])
def test_microstep_resolution(mres: int, microsteps: int) -> None:
    driver = TMC262()
    driver.write(drv_datagram(DrvReg.DRVCTRL, 1 << 9 | 1 << 8 | mres))
    assert (driver.microsteps, driver.intpol, driver.dedge) == (microsteps, True, True)


def test_register_fields() -> None:
    driver = TMC262()
    driver.write(0xD4115)  # SGCSCONF: SFILT 1, SGT -63 (0x41), CS 21
    assert (driver.sfilt, driver.sgt, driver.cs) == (True, -63, 21)
    driver.write(drv_datagram(DrvReg.SGCSCONF, 63 << 8 | 31))
    assert (driver.sfilt, driver.sgt, driver.cs) == (False, 63, 31)
    driver.write(drv_datagram(DrvReg.DRVCONF, 1 << 7 | 1 << 6 | 2 << 4))
    assert (driver.sdoff, driver.vsense, driver.full_scale_mv, driver.rdsel) == (True, True, 165, 2)
    driver.write(drv_datagram(DrvReg.SMARTEN, 1 << 15 | 2 << 13 | 9 << 8 | 1 << 5 | 3))
    assert (driver.seimin, driver.semax, driver.semin) == (True, 9, 3)
    driver.write(drv_datagram(DrvReg.CHOPCONF, 5))
    assert driver.enabled and driver.toff == 5
    driver.write(0x2A5C3)  # SPI mode DRVCTRL: PHA 1, CA 0x52, PHB 1, CB 0xC3
    assert driver.coil_currents == (-0x52, -0xC3)
    driver.faults = DriverFlag.OT
    assert not driver.enabled and driver.spi(0) & DriverFlag.OT


def test_current_scale_is_cs_plus_one_over_32() -> None:
    driver = driver_on(cs=15)
    assert driver.current_scale == 0.5
    assert driver_on(cs=31).current_scale == 1.0


def test_answer_is_the_status_from_before_the_write() -> None:
    motor = Motor(default=640)
    driver = driver_on(motor, rdsel=ReadSelect.MSTEP)
    motor.steps = 16  # MRES 4: one full step = 256 table units
    answer = driver.spi(drv_datagram(DrvReg.DRVCONF, ReadSelect.SG << 4))
    assert answer >> 10 == 256  # MSTEP, the select in force when the transfer began
    assert poll(driver) >> 10 == 640  # now SG


def test_sg_follows_the_load_at_the_last_full_step() -> None:
    motor = Motor({32: 300, 48: 100, 64: 0})
    driver = driver_on(motor)
    assert driver.stallguard() == 0 and not driver.measured  # nothing measured yet
    motor.steps = 20  # crosses the full step at 16 (load 700)
    assert driver.stallguard() == 700
    motor.steps = 47  # last full step crossed: 32
    assert driver.stallguard() == 300
    motor.steps = 48
    assert poll(driver) == 100 << 10  # moving, SG 100, no flags
    motor.steps = 70
    assert poll(driver) == DriverFlag.SG  # SG reached 0: the stall flag
    motor.steps = 60  # backwards: the full step at 64 is crossed again going down, at 60 none
    assert driver.stallguard() == 0
    motor.steps = 40  # full step 48 crossed last going down
    assert driver.stallguard() == 100
    motor.standstill = True  # at rest nothing is measured; the value stays, STST shows
    motor.loads.clear()
    assert poll(driver) == 100 << 10 | DriverFlag.STST


@settings(max_examples=40, deadline=None)
@given(load=st.integers(0, 1023), sgt=st.integers(-64, 63))
def test_sgt_shifts_the_reading(load: int, sgt: int) -> None:
    motor = Motor(default=load)
    driver = driver_on(motor, sgt=sgt)
    motor.steps = 16
    assert driver.stallguard() == max(0, min(1023, load + SG_PER_SGT * sgt))


def test_filter_averages_the_four_full_steps_of_an_electrical_period() -> None:
    motor = Motor({16: 100, 32: 200, 48: 300, 64: 400, 80: 0})
    driver = driver_on(motor, sfilt=True)
    motor.steps = 63  # three full steps of the period: no new value yet
    assert not driver.measured
    motor.steps = 65  # the period ends at step 64: mean of the loads at 16, 32, 48 and 64
    assert driver.stallguard() == 250
    motor.steps = 100  # one more full step (80, load 0): filtered, nothing yet
    assert driver.stallguard() == 250


def test_cool_step_current_follows_the_shared_law() -> None:
    """SEUP/SEDN rates and the SEIMIN floor are axes.stallguard.regulate's (the firmware's)."""
    motor = Motor(default=50)
    driver = driver_on(motor, cs=20)  # 16 microsteps: a full step every 16 steps
    assert driver.se == 20  # coolStep off (SEMIN = 0): SE = CS
    # SEMIN 4 (SG < 128: up), SEMAX 2 (SG >= 224: down), SEDN 3 (every measurement), SEUP 1 (+2)
    driver.write(drv_datagram(DrvReg.SMARTEN, 3 << 13 | 2 << 8 | 1 << 5 | 4))
    motor.steps = 16
    assert driver.se == 20  # SG 50 < 128, but already at CS
    motor.default = 600
    motor.steps = 16 * 4  # three more full steps read 600 >= 224: three decrements
    assert driver.se == 17
    motor.steps = 16 * 20  # many more: down to half the current, (20 + 1) // 2 - 1
    assert driver.se == 9
    motor.default = 50
    motor.steps = 16 * 22  # two measurements below SEMIN * 32: +2 each
    assert driver.se == 13
    driver.write(drv_datagram(DrvReg.SMARTEN, 1 << 15 | 3 << 13 | 2 << 8 | 1 << 5 | 4))
    motor.default = 150
    motor.steps = 16 * 23
    assert driver.se == 13  # between the thresholds: unchanged
    motor.default = 1000
    motor.steps = 16 * 40
    assert driver.se == 4  # SEIMIN: a quarter, (20 + 1) // 4 - 1
    driver.write(drv_datagram(DrvReg.DRVCONF, ReadSelect.SG_SE << 4))
    assert poll(driver) >> 10 == (1000 >> 5) << 5 | 4
    motor.steps = 16 * 36  # backwards: four measurements at 1000 change nothing at the floor
    assert driver.se == 4


def test_spi_mode_steps_use_the_sequencers_step_size() -> None:
    motor = Motor()
    driver = driver_on(motor)
    driver.write(drv_datagram(DrvReg.DRVCONF, 1 << 7))  # SDOFF: the TMC429's sequencer drives it
    motor.units = 64  # USRS 2: 4 steps per full step
    motor.steps = 5
    assert driver.mscnt == 320 and driver.measured


# == wired to a TMC429 motor ===================================================================


class LoadedBoard:
    """Switches open; the load drops to 0 from position 2000 on."""

    def pins(self, motor_position: int) -> tuple[bool, bool, bool]:
        return False, False, False

    def next_mark(self, motor_position: int, direction: int) -> int | None:
        return None

    def load(self, motor_position: int) -> int:
        return 0 if motor_position >= 2000 else 800


def test_a_tmc262_on_a_tmc429_motor_in_step_dir_mode() -> None:
    driver = TMC262()
    chip = TMC429(boards=[None, LoadedBoard()], drivers=[None, driver])
    chip.write(Reg.IF_CONFIGURATION, EN_SD)
    driver.spi(drv_datagram(DrvReg.DRVCONF, ReadSelect.SG << 4))  # the MCU's own SPI to the driver
    driver.spi(drv_datagram(DrvReg.DRVCTRL, 8))  # full step: every step is a full step
    motor = chip.motor(1)
    motor.write(Reg.V_MIN, 10)
    motor.write(Reg.V_MAX, 1000)
    motor.write(Reg.A_MAX, 500)
    motor.write(Reg.X_TARGET, 1500)
    motor.run(2_000)
    assert 0 < motor.motor_position < 1500 and driver.spi(0) == 800 << 10
    assert motor.run(10**7) is Stop.ARRIVED
    assert not driver.spi(0) & DriverFlag.STST  # just stopped
    motor.run(motor.t + STANDSTILL_CLOCKS // 32)
    assert driver.spi(0) == 800 << 10 | DriverFlag.STST
    motor.write(Reg.X_TARGET, 3000)
    assert motor.run(10**8) is Stop.ARRIVED
    motor.run(motor.t + STANDSTILL_CLOCKS // 32)
    assert driver.spi(0) == DriverFlag.SG | DriverFlag.STST  # stalled zone, and at rest again
    twin = motor.clone()  # a lookahead carries its own copy of the driver
    assert twin.driver is not driver and twin.driver.sense is twin
