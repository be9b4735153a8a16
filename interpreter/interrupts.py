"""The TMCL interrupt vectors (TMCM-6212 firmware manual §3.5.6, Table 12) as data.

Vector numbers double as priorities: a lower number wins (§5.4).  The bank-3 global
parameters that configure interrupts use the same numbers (timer periods 0..2, trigger
transitions from 27), which is why one table serves both.  The bases are the TMCL family's;
how many vectors follow each base is the module's: one per axis, one per input
(:func:`vector_table`; the TMCM-6110's inputs 4..7 are vectors 43..46, as its bank-3 rows).
The module-level tables are the TMCM-6212's (its include file).
"""

from __future__ import annotations

from enum import IntEnum

from tmcl_spec.tmcm6212 import TMCM_6212

NUMBER_OF_AXES = TMCM_6212.number_of_axes
NUMBER_OF_INPUTS = TMCM_6212.digital_inputs
NUMBER_OF_TIMERS = 3

TIMER_BASE = 0
TARGET_REACHED_BASE = 3
STALL_BASE = 15
DEVIATION_BASE = 21
STOP_SWITCH_BASE = 27  # left switch of axis n: 27 + 2n, right switch: 28 + 2n
INPUT_CHANGE_BASE = 39
GLOBAL = 255  # EI/DI 255 switch interrupt processing as a whole


class Trigger(IntEnum):
    """Bank 3 trigger transition of a switch or input interrupt."""

    OFF = 0
    LOW_HIGH = 1
    HIGH_LOW = 2
    BOTH = 3

    def fires(self, level: bool) -> bool:
        """Whether a change to ``level`` (True = high) raises the interrupt."""
        return bool(self & (Trigger.LOW_HIGH if level else Trigger.HIGH_LOW))


def timer(n: int) -> int:
    return TIMER_BASE + n


def target_reached(axis: int) -> int:
    return TARGET_REACHED_BASE + axis


def stall(axis: int) -> int:
    return STALL_BASE + axis


def deviation(axis: int) -> int:
    return DEVIATION_BASE + axis


def left_switch(axis: int) -> int:
    return STOP_SWITCH_BASE + 2 * axis


def right_switch(axis: int) -> int:
    return STOP_SWITCH_BASE + 2 * axis + 1


def input_change(port: int) -> int:
    return INPUT_CHANGE_BASE + port


def vector_table(number_of_axes: int = NUMBER_OF_AXES,
                 number_of_inputs: int = NUMBER_OF_INPUTS) -> dict[int, tuple[str, str]]:
    """vector -> (include-file symbol, description) for a module's axes and inputs."""
    table: dict[int, tuple[str, str]] = {}
    for n in range(NUMBER_OF_TIMERS):
        table[timer(n)] = (f"TI_TIMER{n}", f"Timer {n}")
    for a in range(number_of_axes):
        table[target_reached(a)] = (f"TI_TARGET{a}", f"Target position reached {a}")
    for a in range(number_of_axes):
        table[stall(a)] = (f"TI_STALL{a}", f"stallGuard axis {a}")
    for a in range(number_of_axes):
        table[deviation(a)] = (f"TI_DEVIATION{a}", f"Deviation axis {a}")
    for a in range(number_of_axes):
        table[left_switch(a)] = (f"TI_STOPL{a}", f"Left stop switch {a}")
        table[right_switch(a)] = (f"TI_STOPR{a}", f"Right stop switch {a}")
    for p in range(number_of_inputs):
        table[input_change(p)] = (f"TI_INPUT{p}", f"Input change {p}")
    table[GLOBAL] = ("TI_GLOBAL", "Global interrupts")
    return table


def triggered(number_of_axes: int = NUMBER_OF_AXES,
              number_of_inputs: int = NUMBER_OF_INPUTS) -> frozenset[int]:
    """Vectors whose bank-3 parameter of the same number is a trigger transition."""
    return frozenset([left_switch(a) for a in range(number_of_axes)]
                     + [right_switch(a) for a in range(number_of_axes)]
                     + [input_change(p) for p in range(number_of_inputs)])


#: Table 12: vector number -> (symbol in Interrupts.inc, the manual's description).
INTERRUPT_VECTORS: dict[int, tuple[str, str]] = vector_table()

#: The TMCM-6212's vectors whose bank-3 parameter of the same number is a trigger transition.
TRIGGERED: frozenset[int] = triggered()
