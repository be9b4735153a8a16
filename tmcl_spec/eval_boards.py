"""The boards of Trinamic's evaluation system, as a module profile names them.

Part of a profile (:attr:`tmcl_spec.modules.ModuleType.eval_boards`) and defined apart from the
Landungsbruecke's profile so that ``modules`` needs no import of a profile file.
"""

from __future__ import annotations

import dataclasses
from enum import IntEnum


class BoardId(IntEnum):
    """Board ids of the evaluation system (``tmc/BoardAssignment.h``)."""

    NONE = 0
    TMC4361A = 11


class IdState(IntEnum):
    """The detection state of a channel (``tmc/IdDetection.h``)."""

    DONE = 2  # detected, and supported by this firmware
    NO_ANSWER = 4  # no board answered
    NOT_IN_FW = 6  # an id this firmware does not support (also: id 0, no board)


@dataclasses.dataclass(frozen=True)
class EvalBoards:
    """What sits on the Landungsbruecke's two channels, as its firmware reports it."""

    #: Channel 1 (motion controller) and channel 2 (driver) board ids.
    mc_id: int
    drv_id: int
    #: ID EEPROM contents per channel (1, 2); a channel without an entry has no EEPROM.
    id_eeproms: dict[int, bytes]
    #: GP 5: the Landungsbruecke's hardware id (1: hardware 1.x, 2: 2.0 and later).
    hardware_id: int

    def word(self, mc_state: int, drv_state: int) -> int:
        """The 32-bit id word: driver state, driver id, controller state, controller id."""
        return drv_state << 24 | self.drv_id << 16 | mc_state << 8 | self.mc_id

    @property
    def detected(self) -> int:
        """The reply to ASSIGNMENT type 0: what the detection found (no answer on an empty
        channel)."""
        return self.word(IdState.DONE if self.mc_id else IdState.NO_ANSWER,
                         IdState.DONE if self.drv_id else IdState.NO_ANSWER)

    @property
    def supported(self) -> int:
        """GP 4 (``Board_supported``): whether this firmware supports the assigned ids (an
        empty channel, id 0, is "not in firmware")."""
        return self.word(IdState.DONE if self.mc_id else IdState.NOT_IN_FW,
                         IdState.DONE if self.drv_id else IdState.NOT_IN_FW)


#: The ID EEPROM layout pytrinamic's IDEEPROM reads: description (16 bytes), board id (16
#: bit), hardware version major and minor, magic number 0x3412 (all little endian).
ID_EEPROM_SIZE = 256
ID_EEPROM_MAGIC = 0x3412


def id_eeprom(description: str, board_id: int, hardware: tuple[int, int]) -> bytes:
    image = bytearray(b"\xff" * ID_EEPROM_SIZE)  # an erased EEPROM reads all ones
    image[0:16] = description.encode("ascii").ljust(16, b"\0")
    image[16:18] = board_id.to_bytes(2, "little")
    image[18], image[19] = hardware
    image[20:22] = ID_EEPROM_MAGIC.to_bytes(2, "little")
    return bytes(image)
