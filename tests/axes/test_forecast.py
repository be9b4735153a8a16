"""How each parameter moves is data (ParamSpec.motion), and the forecasts read it."""

from __future__ import annotations

import dataclasses

import pytest

from axes.chips.tmc42x.tmc4210_firmware import TMC4210Axis
from axes.interface import FOREVER
from tmcl_spec.modules import MODULE_TYPES, module_type
from tmcl_spec.parameters import AP, Motion
from tmcl_spec.tmcm6212 import AXIS_PARAMETERS, TMCM_6212


def test_a_row_that_says_nothing_of_how_it_moves_is_refused_when_the_module_type_is_built() -> None:
    table = dict(AXIS_PARAMETERS)
    table[AP.MAX_SPEED] = dataclasses.replace(table[AP.MAX_SPEED], motion=None)
    with pytest.raises(ValueError, match=r"axis parameters \[4\] say nothing of how"):
        dataclasses.replace(TMCM_6212, axis_parameters=table)
    banks = {bank: dict(rows) for bank, rows in TMCM_6212.global_parameters.items()}
    banks[2][7] = dataclasses.replace(banks[2][7], motion=None)
    with pytest.raises(ValueError, match=r"bank 2 parameters \[7\]"):
        dataclasses.replace(TMCM_6212, global_parameters=banks)


@pytest.mark.parametrize("kind", sorted(MODULE_TYPES))
def test_every_row_of_every_module_type_says_how_it_moves(kind: str) -> None:
    profile = module_type(kind)
    for rows in (profile.axis_parameters, *profile.global_parameters.values()):
        assert all(isinstance(spec.motion, Motion) for spec in rows.values())


@pytest.mark.parametrize(("number", "motion", "says"), [
    (AP.ACTUAL_POSITION, Motion.SETTING, "reads it from the chip"),
    (AP.MAX_SPEED, Motion.AXIS, "keeps it"),
])
def test_the_firmware_refuses_a_table_that_disagrees_with_what_it_does(
        number: int, motion: Motion, says: str) -> None:
    table = dict(AXIS_PARAMETERS)
    table[number] = dataclasses.replace(table[number], motion=motion)
    with pytest.raises(ValueError, match=f"axis parameter {number}: .* {says}"):
        TMC4210Axis(0, table)


def test_while_the_axis_moves_each_row_is_as_steady_as_its_column_says() -> None:
    axis = TMC4210Axis(0, AXIS_PARAMETERS)
    axis.move_to(200_000)
    axis.advance_to(50_000_000)
    assert axis.next_event_ns() is not None, "still moving"
    by_motion = {Motion.SETTING: AP.MAX_SPEED, Motion.EVENTS: AP.HOME_SWITCH,
                 Motion.ACCESS: AP.ERROR_FLAGS}
    for motion, number in by_motion.items():
        assert AXIS_PARAMETERS[number].motion is motion
        assert axis.steady_until(number) == FOREVER, motion
    for number in (AP.ACTUAL_POSITION, AP.ENCODER_POSITION, AP.LOAD):
        assert AXIS_PARAMETERS[number].motion is Motion.AXIS
        assert axis.steady_until(number) == 0, number
    # AP 8 (moves with the axis) holds until the position first meets the target
    assert 50_000_000 < axis.steady_until(AP.POSITION_REACHED) < FOREVER
