"""The boards of Trinamic's evaluation system, as a module profile names them.

Part of a profile (:attr:`tmcl_spec.modules.ModuleType.eval_boards`) and defined apart from the
Landungsbruecke's profile so that ``modules`` needs no import of a profile file.
"""

from __future__ import annotations

import dataclasses
from enum import IntEnum, IntFlag

from tmcl_spec.commands import Status


class BoardId(IntEnum):
    """Board ids of the evaluation system (``tmc/BoardAssignment.h``)."""

    NONE = 0
    TMC4361A = 11


class DetectedBy(IntEnum):
    """How a channel's board was found (``tmc/BoardAssignment.h``): command 136 type 4."""

    NONE = 0
    MONOFLOP = 1
    EEPROM = 2


class EvalError(IntFlag):
    """What a board function of the evaluation firmware returns (TMC-API's ``TMCError`` and
    the EvalSystem's ``EvalboardErrorBit``); :func:`reply_status` turns it into a status."""

    NONE = 0
    GENERIC = 0x01
    FUNCTION = 0x02  # the channel has no such function (a dummy)
    TYPE = 0x04
    MOTOR = 0x08
    VALUE = 0x10
    NOT_DONE = 0x20
    CHIP = 0x40
    NOT_AVAILABLE = 0x80


#: ``setTMCLStatus`` (``tmc/TMCL.c``): the first bit present decides, in this order.  A
#: motor error answers 3, as a type error does (the source's own "todo").
_STATUS_OF_ERROR = ((EvalError.FUNCTION, Status.INVALID_COMMAND), (EvalError.TYPE, Status.WRONG_TYPE),
                    (EvalError.MOTOR, Status.WRONG_TYPE), (EvalError.VALUE, Status.INVALID_VALUE),
                    (EvalError.NOT_DONE, Status.DELAYED), (EvalError.CHIP, Status.EEPROM_LOCKED),
                    (EvalError.NOT_AVAILABLE, Status.COMMAND_NOT_AVAILABLE))


def reply_status(errors: int) -> Status:
    """The reply status of a board function's error bits (GENERIC alone leaves it OK)."""
    for bit, status in _STATUS_OF_ERROR:
        if errors & bit:
            return status
    return Status.OK


@dataclasses.dataclass(frozen=True)
class EvalFirmware:
    """Facts of one TMC-EvalSystem release that commands 136, 157 and GIO report."""

    #: VERSION_PATCH and BUILD_VERSION (the version's digits, ``version.txt`` 3.11.7 -> 3117).
    patch: int
    build: int
    #: GetInfo 30: the short git hash of the release (& 0x0FFFFFFF) | dirty << 28.
    git_info: int
    #: GetInfo 3: GETINFO_RELEASE_TYPE (0 public, 1 internal, 2 custom, 3 local build).
    release_type: int
    #: GetInfo 2: capability bits (2: TMCL).
    capabilities: int = 0x2
    #: The ADC's full scale (16 bit on the Landungsbruecke; 12 bit on the LandungsbrueckeV3).
    adc_full_scale: int = 65535
    #: VM (0.1 V) at the ADC's full scale: VM = ADC * vm_factor / full scale, truncated.
    vm_factor: int = 713


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
    #: The firmware release's own facts (136, 157, GIO 5/6).
    firmware: EvalFirmware

    def detected_by(self, channel: int) -> DetectedBy:
        """How the firmware found the board on ``channel`` (1, 2): by its ID EEPROM, else by
        the older boards' monoflop pulse, or not at all."""
        if channel in self.id_eeproms:
            return DetectedBy.EEPROM
        board = self.mc_id if channel == 1 else self.drv_id
        return DetectedBy.MONOFLOP if board else DetectedBy.NONE

    def hardware_version(self, channel: int) -> tuple[int, int]:
        """(major, minor) from the channel's ID EEPROM; 0xFF each when it has none."""
        image = self.id_eeproms.get(channel)
        return (image[18], image[19]) if image is not None else (0xFF, 0xFF)

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
