"""TMC4361A register map, power-on values, bit fields and unit conversions, as data.

Sources: ``shared/spec/tmc4361a.md`` §2-§4 and §8, and the register chapter (19) of the
datasheet.  Names follow the datasheet (and pytrinamic's ``TMC4361.REG`` where a name is
shared); addresses whose read and write meanings differ get one name per view.
"""

from __future__ import annotations

from enum import IntEnum

MASK32 = 0xFFFF_FFFF
DEFAULT_CLK_FREQ = 16_000_000
VERSION = 0x0002
#: RESET_REG (0x4F bits 31..8) value that triggers a software reset.
RESET_KEY = 0x525354


class Reg(IntEnum):
    """Register addresses (7 bits).  Aliases name the other view of a shared address."""

    GENERAL_CONF = 0x00
    REFERENCE_CONF = 0x01
    START_CONF = 0x02
    INPUT_FILT_CONF = 0x03
    SPI_OUT_CONF = 0x04
    CURRENT_CONF = 0x05
    SCALE_VALUES = 0x06
    ENC_IN_CONF = 0x07
    ENC_IN_DATA = 0x08
    ENC_OUT_DATA = 0x09
    STEP_CONF = 0x0A
    SPI_STATUS_SELECTION = 0x0B
    EVENT_CLEAR_CONF = 0x0C
    INTR_CONF = 0x0D
    EVENTS = 0x0E
    STATUS = 0x0F
    STP_LENGTH_ADD = 0x10  # 15..0, DIR_SETUP_TIME 31..16
    START_OUT_ADD = 0x11
    GEAR_RATIO = 0x12
    START_DELAY = 0x13
    CLK_GATING_DELAY = 0x14
    STDBY_DELAY = 0x15
    FREEWHEEL_DELAY = 0x16
    VDRV_SCALE_LIMIT = 0x17
    UP_SCALE_DELAY = 0x18
    HOLD_SCALE_DELAY = 0x19
    DRV_SCALE_DELAY = 0x1A
    BOOST_TIME = 0x1B
    CL_ANGLES = 0x1C  # CL_BETA 8..0, CL_GAMMA 23..16
    SPI_SWITCH_VEL = 0x1D
    HOME_SAFETY_MARGIN = 0x1E
    CHOPSYNC_DIV = 0x1F
    RAMPMODE = 0x20
    XACTUAL = 0x21
    VACTUAL = 0x22
    AACTUAL = 0x23
    VMAX = 0x24
    VSTART = 0x25
    VSTOP = 0x26
    VBREAK = 0x27
    AMAX = 0x28
    DMAX = 0x29
    ASTART = 0x2A
    DFINAL = 0x2B
    DSTOP = 0x2C
    BOW1 = 0x2D
    BOW2 = 0x2E
    BOW3 = 0x2F
    BOW4 = 0x30
    CLK_FREQ = 0x31
    POS_COMP = 0x32
    VIRT_STOP_LEFT = 0x33
    VIRT_STOP_RIGHT = 0x34
    X_HOME = 0x35
    X_LATCH = 0x36  # read (REV_CNT with circular_cnt_as_xlatch)
    X_RANGE = 0x36  # write
    XTARGET = 0x37
    X_PIPE0 = 0x38
    SH_REG0 = 0x40
    FREEZE = 0x4E  # DFREEZE 23..0, IFREEZE 31..24
    RESET_CLK_GATING = 0x4F  # CLK_GATING_REG 2..0, RESET_REG 31..8
    ENC_POS = 0x50
    ENC_LATCH = 0x51  # read
    ENC_RESET_VAL = 0x51  # write
    ENC_POS_DEV = 0x52  # read
    CL_TR_TOLERANCE = 0x52  # write
    ENC_POS_DEV_TOL = 0x53  # write only
    ENC_CONST = 0x54  # read
    ENC_IN_RES = 0x54  # write (bit 31: manual_enc_const)
    V_ENC = 0x65
    V_ENC_MEAN = 0x66
    VSTALL_LIMIT = 0x67
    COVER_LOW = 0x6C
    COVER_HIGH = 0x6D
    COVER_DRV_LOW = 0x6E
    COVER_DRV_HIGH = 0x6F
    MSLUT0 = 0x70
    MSLUTSEL = 0x78
    MSCNT = 0x79  # read; MS_OFFSET on write
    CURRENTA_B = 0x7A
    TZEROWAIT = 0x7B  # write; CURRENTA/B_SPI on read
    CIRCULAR_DEC = 0x7C  # write; SCALE_PARAM on read
    ENC_COMP = 0x7D
    START_SIN = 0x7E
    VERSION_NO = 0x7F


#: Power-on values of the write views that are not 0 (register chapter; digest §2, §16.10).
POWER_ON: dict[int, int] = {
    Reg.GENERAL_CONF: 0x0000_6020,
    Reg.SCALE_VALUES: 0xFFFF_FFFF,
    Reg.ENC_IN_CONF: 0x0000_0400,
    Reg.STEP_CONF: 0x00FB_0C80,
    Reg.SPI_STATUS_SELECTION: 0x8202_9805,
    Reg.GEAR_RATIO: 0x0100_0000,
    Reg.CL_ANGLES: 0x00FF_00FF,
    Reg.CHOPSYNC_DIV: 0x0000_0280,
    Reg.CLK_FREQ: DEFAULT_CLK_FREQ,
    Reg.ENC_POS_DEV_TOL: 0xFFFF_FFFF,
    0x56: 0x00A0_00A0,  # SER_CLK_IN_HIGH / _LOW
    0x57: 0x00F0_0000,  # SSI_IN_CLK_DELAY / SSI_IN_WTIME
    0x58: 0x0000_0190,  # SER_PTIME
    0x62: 0x00FF_FFFF,  # ENC_VEL_ZERO / DC_LSPTM
    0x70: 0xAAAA_B554, 0x71: 0x4A95_54AA, 0x72: 0x2449_2929, 0x73: 0x1010_4222,
    0x74: 0xFBFF_FFFF, 0x75: 0xB5BB_777D, 0x76: 0x4929_5556, 0x77: 0x0040_4222,
    Reg.MSLUTSEL: 0xFFFF_8056,
    Reg.START_SIN: 0x00F7_0000,  # START_SIN90_120 = 247
}

#: Bits that exist in a write view (others read back as 0).  Unlisted: all 32 bits.
WRITE_MASKS: dict[int, int] = {
    Reg.RAMPMODE: 0x7,
    Reg.VSTART: 0x7FFF_FFFF,
    Reg.VSTOP: 0x7FFF_FFFF,
    Reg.VBREAK: 0x7FFF_FFFF,
    Reg.AMAX: 0xFF_FFFF,
    Reg.DMAX: 0xFF_FFFF,
    Reg.ASTART: 0x80FF_FFFF,
    Reg.DFINAL: 0xFF_FFFF,
    Reg.DSTOP: 0xFF_FFFF,
    Reg.BOW1: 0xFF_FFFF,
    Reg.BOW2: 0xFF_FFFF,
    Reg.BOW3: 0xFF_FFFF,
    Reg.BOW4: 0xFF_FFFF,
    Reg.CLK_FREQ: 0x1FF_FFFF,
    Reg.HOME_SAFETY_MARGIN: 0xFFFF,
    Reg.X_RANGE: 0x7FFF_FFFF,
    Reg.CHOPSYNC_DIV: 0xFFF,
    Reg.CL_ANGLES: 0xFF_01FF,
    Reg.VSTALL_LIMIT: 0xFF_FFFF,
    Reg.RESET_CLK_GATING: 0xFFFF_FF07,
}

#: Addresses whose read view is not simply the last value written.
READ_COMPUTED = frozenset({
    Reg.EVENTS, Reg.STATUS, Reg.XACTUAL, Reg.VACTUAL, Reg.AACTUAL, Reg.X_LATCH, Reg.ENC_POS,
    Reg.ENC_LATCH, Reg.ENC_POS_DEV, Reg.ENC_CONST, Reg.V_ENC, Reg.V_ENC_MEAN, Reg.MSCNT,
    Reg.CURRENTA_B, Reg.TZEROWAIT, Reg.CIRCULAR_DEC, Reg.VERSION_NO, Reg.RESET_CLK_GATING,
    Reg.ENC_POS_DEV_TOL, 0x5A, 0x5B, 0x5C, 0x5D, 0x5E, 0x5F, 0x60, 0x61, 0x62, 0x63, 0x64,
    0x68, 0x69, 0x6A, 0x6B, Reg.COVER_DRV_LOW, Reg.COVER_DRV_HIGH, 0x55, 0x56, 0x57, 0x58,
    0x70, 0x71, 0x72, 0x73, 0x74, 0x75, 0x76, 0x77, Reg.MSLUTSEL, Reg.ENC_COMP,
})
#: Read-only addresses: writes are ignored.
READ_ONLY = frozenset({Reg.STATUS, Reg.VACTUAL, Reg.AACTUAL, Reg.V_ENC, Reg.V_ENC_MEAN,
                       Reg.CURRENTA_B, Reg.VERSION_NO, 0x6A, 0x6B})
#: Registers the ramp generator reads (a write rebuilds its parameters).
RAMP_REGISTERS = frozenset({
    Reg.GENERAL_CONF, Reg.RAMPMODE, Reg.VMAX, Reg.VSTART, Reg.VSTOP, Reg.VBREAK, Reg.AMAX,
    Reg.DMAX, Reg.ASTART, Reg.DFINAL, Reg.DSTOP, Reg.BOW1, Reg.BOW2, Reg.BOW3, Reg.BOW4,
    Reg.CLK_FREQ, Reg.TZEROWAIT,
})


class BitNames:
    """A namespace of plain int bit masks (plain ints: the chip tests them on every tick)."""

    @classmethod
    def names(cls, value: int) -> list[str]:
        """The names of the masks set in ``value`` (for messages and debugging)."""
        return [name for name, mask in vars(cls).items()
                if not name.startswith("_") and isinstance(mask, int) and mask
                and value & mask == mask]


class GeneralConf(BitNames):
    USE_ASTART_AND_VSTART = 1 << 0
    DIRECT_ACC_VAL_EN = 1 << 1
    DIRECT_BOW_VAL_EN = 1 << 2
    INTR_POL = 1 << 15
    INVERT_POL_TARGET_REACHED = 1 << 16
    CIRCULAR_CNT_AS_XLATCH = 1 << 27
    REVERSE_MOTOR_DIR = 1 << 28


class RefConf(BitNames):
    """REFERENCE_CONF (0x01) bits."""

    STOP_LEFT_EN = 1 << 0
    STOP_RIGHT_EN = 1 << 1
    POL_STOP_LEFT = 1 << 2  # 0: the input is active low
    POL_STOP_RIGHT = 1 << 3
    INVERT_STOP_DIRECTION = 1 << 4
    SOFT_STOP_EN = 1 << 5
    VIRTUAL_LEFT_LIMIT_EN = 1 << 6
    VIRTUAL_RIGHT_LIMIT_EN = 1 << 7
    VIRT_STOP_MODE = 3 << 8  # 1 hard, 2 soft (DSTOP)
    LATCH_X_ON_INACTIVE_L = 1 << 10
    LATCH_X_ON_ACTIVE_L = 1 << 11
    LATCH_X_ON_INACTIVE_R = 1 << 12
    LATCH_X_ON_ACTIVE_R = 1 << 13
    STOP_LEFT_IS_HOME = 1 << 14
    STOP_RIGHT_IS_HOME = 1 << 15
    HOME_EVENT = 0xF << 16
    START_HOME_TRACKING = 1 << 20
    CLR_POS_AT_TARGET = 1 << 21
    CIRCULAR_MOVEMENT_EN = 1 << 22
    POS_COMP_OUTPUT = 3 << 23
    POS_COMP_SOURCE = 1 << 25
    MODIFIED_POS_COMPARE = 3 << 28


class Event(BitNames):
    """EVENTS (0x0E) bits; the STATUS flags they follow are in :class:`Status`."""

    TARGET_REACHED = 1 << 0
    POS_COMP_REACHED = 1 << 1
    VEL_REACHED = 1 << 2
    VEL_STATE_ZERO = 1 << 3
    VEL_STATE_POS = 1 << 4
    VEL_STATE_NEG = 1 << 5
    RAMP_STATE_CONST = 1 << 6
    RAMP_STATE_ACC = 1 << 7
    RAMP_STATE_DEC = 1 << 8
    MAX_PHASE_TRAP = 1 << 9
    FROZEN = 1 << 10
    STOPL = 1 << 11
    STOPR = 1 << 12
    VSTOPL_ACTIVE = 1 << 13
    VSTOPR_ACTIVE = 1 << 14
    HOME_ERROR = 1 << 15
    XLATCH_DONE = 1 << 16
    FS_ACTIVE = 1 << 17
    ENC_FAIL = 1 << 18
    N_ACTIVE = 1 << 19
    ENC_DONE = 1 << 20
    SER_ENC_DATA_FAIL = 1 << 21
    SER_DATA_DONE = 1 << 23
    SERIAL_ENC_FLAGS = 1 << 24
    COVER_DONE = 1 << 25
    ENC_VEL0 = 1 << 26
    CL_MAX = 1 << 27
    CL_FIT = 1 << 28
    STOP_ON_STALL = 1 << 29
    MOTOR_EV = 1 << 30
    RST_EV = 1 << 31


class Status(BitNames):
    """STATUS (0x0F) flags (live)."""

    TARGET_REACHED_F = 1 << 0
    POS_COMP_REACHED_F = 1 << 1
    VEL_REACHED_F = 1 << 2
    VEL_STATE_POS = 1 << 3  # VEL_STATE_F = 01
    VEL_STATE_NEG = 1 << 4  # VEL_STATE_F = 10
    RAMP_STATE_ACC = 1 << 5  # RAMP_STATE_F = 01
    RAMP_STATE_DEC = 1 << 6  # RAMP_STATE_F = 10
    STOPL_ACTIVE_F = 1 << 7
    STOPR_ACTIVE_F = 1 << 8
    VSTOPL_ACTIVE_F = 1 << 9
    VSTOPR_ACTIVE_F = 1 << 10
    ACTIVE_STALL_F = 1 << 11
    HOME_ERROR_F = 1 << 12
    FS_ACTIVE_F = 1 << 13
    ENC_FAIL_F = 1 << 14
    N_ACTIVE_F = 1 << 15
    ENC_LATCH_F = 1 << 16


#: Events run() always returns Stop.EVENT for (besides those selected in INTR_CONF).
WAKE_ALWAYS = (Event.STOPL | Event.STOPR | Event.VSTOPL_ACTIVE | Event.VSTOPR_ACTIVE
               | Event.XLATCH_DONE | Event.ENC_FAIL)

#: Flags whose rising edge latches the event of the same meaning.
FLAG_EVENTS: tuple[tuple[int, int], ...] = (
    (Status.TARGET_REACHED_F, Event.TARGET_REACHED),
    (Status.POS_COMP_REACHED_F, Event.POS_COMP_REACHED),
    (Status.VEL_REACHED_F, Event.VEL_REACHED),
    (Status.STOPL_ACTIVE_F, Event.STOPL),
    (Status.STOPR_ACTIVE_F, Event.STOPR),
    (Status.VSTOPL_ACTIVE_F, Event.VSTOPL_ACTIVE),
    (Status.VSTOPR_ACTIVE_F, Event.VSTOPR_ACTIVE),
    (Status.HOME_ERROR_F, Event.HOME_ERROR),
    (Status.ENC_FAIL_F, Event.ENC_FAIL),
)


# == units =======================================================================================
# Real-unit ("frequency") mode, digest §4.1: velocities 24.8 / 23.8 fixed point [pps],
# accelerations 22.2 [pps²], bows integer [pps³].  The chip converts with CLK_FREQ itself.


def velocity_register(pps: float) -> int:
    """VMAX/VSTART/VSTOP/VBREAK register value for a velocity in pps (VMAX: two's complement)."""
    return round(pps * 256) & MASK32


def velocity_pps(register: int, signed: bool = True) -> float:
    """The velocity a VMAX (signed) or VSTART/VSTOP/VBREAK register value stands for."""
    if signed and register & 0x8000_0000:
        register -= 1 << 32
    return register / 256


def acceleration_register(pps2: float) -> int:
    """AMAX/DMAX/ASTART/DFINAL/DSTOP register value for an acceleration in pps²."""
    return min(round(pps2 * 4), 0xFF_FFFF)


def acceleration_pps2(register: int) -> float:
    return (register & 0xFF_FFFF) / 4


def bow_register(pps3: float) -> int:
    """BOW1..BOW4 register value for a jerk in pps³."""
    return min(round(pps3), 0xFF_FFFF)


def direct_acceleration_pps2(register: int, clk_freq: int) -> float:
    """Direct mode (GENERAL_CONF.1): an acceleration register as pps² (LSB 2^-37 per clock²)."""
    return register * clk_freq * clk_freq / 2 ** 37


def direct_bow_pps3(register: int, clk_freq: int) -> float:
    """Direct mode (GENERAL_CONF.2): a bow register as pps³ (LSB 2^-53 per clock³)."""
    return register * clk_freq ** 3 / 2 ** 53


def signed32(value: int) -> int:
    value &= MASK32
    return value - (1 << 32) if value & 0x8000_0000 else value


def datagram(address: int, data: int = 0, write: bool = False) -> int:
    """A 40-bit host frame: W bit, 7-bit address, 32 data bits."""
    return (int(write) << 39) | (address & 0x7F) << 32 | (data & MASK32)
