"""Axis parameters of the TMCM-6212 (firmware manual §4.1, Table 14) as data.

Each entry gives number, name, access, the valid range and the factory default.  The manual
gives ranges but no defaults; the defaults chosen here are documented in docs/parameters.md.
The module validates SAP/GAP requests against this table before an axis sees them.
"""

from __future__ import annotations

from dataclasses import dataclass

INT32_MIN = -(2**31)
INT32_MAX = 2**31 - 1
UINT32_MAX = 2**32 - 1

MAX_VELOCITY_PPS = 7_999_774
MAX_ACCELERATION_PPS2 = 7_629_278


@dataclass(frozen=True, slots=True)
class ParamSpec:
    """One row of a parameter table.

    ``access`` uses the manual's letters: R readable, W writable, E storable with
    STGP/RSGP (or STAP/RSAP), A automatically stored in EEPROM when written.
    ``allowed`` restricts the value to a set when the range is not contiguous.
    ``unsigned`` means the 32-bit wire value is read as unsigned before the range check.
    """

    number: int
    name: str
    access: str
    minimum: int = INT32_MIN
    maximum: int = INT32_MAX
    default: int = 0
    allowed: frozenset[int] | None = None
    unsigned: bool = False

    @property
    def readable(self) -> bool:
        return "R" in self.access

    @property
    def writable(self) -> bool:
        return "W" in self.access

    @property
    def storable(self) -> bool:
        return "E" in self.access

    @property
    def auto_stored(self) -> bool:
        return "A" in self.access

    def accepts(self, value: int) -> bool:
        """True if a (signed 32-bit wire) value is valid for this parameter."""
        if self.unsigned:
            value &= UINT32_MAX
        if self.allowed is not None:
            return value in self.allowed
        return self.minimum <= value <= self.maximum

    def normalise(self, value: int) -> int:
        """Wire value as stored (unsigned parameters keep their unsigned meaning)."""
        return value & UINT32_MAX if self.unsigned else value


def _p(number: int, name: str, access: str, lo: int = INT32_MIN, hi: int = INT32_MAX,
       default: int = 0, allowed: frozenset[int] | None = None) -> ParamSpec:
    return ParamSpec(number, name, access, lo, hi, default, allowed)


_V = MAX_VELOCITY_PPS
_A = MAX_ACCELERATION_PPS2
_BOOL = (0, 1)

#: Reference search modes: 1..8, +64 for modes 1..4 (right switch), +128 for modes 5..8
#: (inverted home switch).  The manual's examples also quote 129..132 for "mode 5..8 + 128";
#: both spellings are accepted (docs/parameters.md).
REFERENCE_SEARCH_MODES = frozenset(
    list(range(1, 9)) + [m + 64 for m in range(1, 5)] + [m + 128 for m in range(5, 9)]
    + [129, 130, 131, 132]
)

AXIS_PARAMETERS: dict[int, ParamSpec] = {
    spec.number: spec
    for spec in (
        _p(0, "Target position", "RW"),
        _p(1, "Actual position", "RW"),
        _p(2, "Target speed", "RW", -_V, _V),
        _p(3, "Actual speed", "R", -_V, _V),
        _p(4, "Maximum positioning speed", "RW", 0, _V, 51200),
        _p(5, "Maximum acceleration", "RW", 0, _A, 51200),
        _p(6, "Maximum current", "RW", 0, 255, 128),
        _p(7, "Standby current", "RW", 0, 255, 8),
        _p(8, "Position reached flag", "R", *_BOOL),
        _p(9, "Home switch state", "R", *_BOOL),
        _p(10, "Right limit switch state", "R", *_BOOL),
        _p(11, "Left limit switch state", "R", *_BOOL),
        _p(12, "Right limit switch disable", "RW", *_BOOL),
        _p(13, "Left limit switch disable", "RW", *_BOOL),
        _p(14, "Swap limit switches", "RW", *_BOOL),
        _p(15, "Acceleration A1", "RW", 0, _A, 51200),
        _p(16, "Velocity V1", "RW", 0, 1_000_000, 0),
        _p(17, "Maximum deceleration", "RW", 0, _A, 51200),
        _p(18, "Deceleration D1", "RW", 0, _A, 51200),
        _p(19, "Velocity VSTART", "RW", 0, 249_999, 0),
        _p(20, "Velocity VSTOP", "RW", 0, 249_999, 10),
        _p(21, "Ramp wait time", "RW", 0, 65535, 0),
        _p(22, "Speed threshold for coolStep / fullstep", "RW", 0, _V, 0),
        _p(23, "Minimum speed for dcStep", "RW", 0, _V, 0),
        _p(24, "Right limit switch polarity", "RW", *_BOOL),
        _p(25, "Left limit switch polarity", "RW", *_BOOL),
        _p(26, "Soft stop enable", "RW", *_BOOL),
        _p(27, "High speed chopper mode", "RW", *_BOOL),
        _p(28, "High speed fullstep mode", "RW", *_BOOL),
        _p(29, "Measured speed", "R", 0, _V),
        _p(31, "Power down ramp", "RW", 0, 15, 10),
        _p(32, "dcStep time", "RW", 0, 1023, 0),
        _p(33, "dcStep stallGuard", "RW", 0, 255, 0),
        _p(127, "Relative positioning option", "RW", 0, 2, 0),
        _p(140, "Microstep resolution", "RW", 0, 8, 8),
        _p(162, "Chopper blank time", "RW", 0, 3, 2),
        _p(163, "Constant TOFF mode", "RW", *_BOOL),
        _p(164, "Disable fast decay comparator", "RW", *_BOOL),
        _p(165, "Chopper hysteresis end / fast decay time", "RW", 0, 15, 0),
        _p(166, "Chopper hysteresis start / sine wave offset", "RW", 0, 8, 4),
        _p(167, "Chopper off time (TOff)", "RW", 0, 15, 3),
        _p(168, "smartEnergy current minimum (SEIMIN)", "RW", *_BOOL),
        _p(169, "smartEnergy current down step", "RW", 0, 3, 0),
        _p(170, "smartEnergy hysteresis", "RW", 0, 15, 0),
        _p(171, "smartEnergy current up step", "RW", 0, 3, 0),
        _p(172, "smartEnergy hysteresis start", "RW", 0, 15, 0),
        _p(173, "stallGuard2 filter enable", "RW", *_BOOL),
        _p(174, "stallGuard2 threshold", "RW", -64, 63, 0),
        _p(180, "smartEnergy actual current", "R", 0, 31),
        _p(181, "Stop on stall", "RW", 0, _V, 0),
        _p(182, "smartEnergy threshold speed", "RW", 0, _V, 0),
        _p(184, "Random TOff mode", "RW", *_BOOL),
        _p(185, "Chopper synchronization", "RW", 0, 15, 0),
        _p(186, "PWM threshold speed", "RW", 0, _V, 0),
        _p(187, "PWM gradient", "RW", 0, 15, 0),
        _p(188, "PWM amplitude", "RW", 0, 255, 128),
        _p(193, "Reference search mode", "RW", 1, 136, 1, REFERENCE_SEARCH_MODES),
        _p(194, "Reference search speed", "RW", 0, _V, 51200),
        _p(195, "Reference switch speed", "RW", 0, _V, 5120),
        _p(196, "End switch distance", "R"),
        _p(197, "Last reference position", "R"),
        _p(201, "Encoder mode", "RW", 0, 255, 0),
        _p(202, "Motor full step resolution", "RW", 0, 65535, 200),
        _p(204, "Freewheeling mode", "RW", 0, 3, 0),
        _p(206, "Actual load value", "R", 0, 1023),
        _p(207, "Extended error flags", "R", 0, 3),
        _p(208, "TMC5130 error flags", "R", 0, 255),
        _p(209, "Encoder position", "RW"),
        _p(210, "Encoder resolution", "RW", 0, 65535, 51200),
        _p(212, "Maximum encoder deviation", "RW", 0, 65535, 0),
        _p(214, "Power down delay", "RW", 0, 417, 200),
        _p(255, "Unit mode", "RW", *_BOOL, 1),
    )
}

#: Parameters whose RAM value is kept when STAP stores an axis's configuration.
STORABLE_AXIS_PARAMETERS: tuple[int, ...] = tuple(
    n for n, s in AXIS_PARAMETERS.items() if s.writable and n not in (0, 1, 2, 209)
)

NUMBER_OF_AXES = 6
