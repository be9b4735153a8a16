"""The TMC4361A core: the chip-specific half of the TMCL firmware, and the axis built on it.

:class:`TMC4361ADriver` is what the module's microcontroller does with a TMC4361A, and only
that: it talks to the chip through 40-bit :meth:`TMC4361A.spi` datagrams, writes the ramp
parameters the axis parameters describe (AP 4/5 and the six-point ramp of AP 15-21) in the
chip's real units (or the manual's internal units in unit mode 0), and reads positions (32
bit, so no rolling targets) and speeds back.  Everything a TMCL axis does whatever its chip
is in :class:`axes.firmware.AxisFirmware`; :class:`TMC4361AAxis` joins the two.  Every
mapping choice is explained in docs/motion.md ("The TMC4361A core") and docs/tmc4361a.md.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import cast

from axes.board import AxisBoard
from axes.chips.tmc4361a import TMC4361A, Event, GeneralConf, RefConf, Reg, Status, datagram
from axes.chips.tmc4361a.registers import MASK32, WRITE_MASKS, signed32
from axes.core import ChipDriver, ChipModel
from axes.firmware import AxisFirmware
from axes.interface import NotAvailable
from axes.world import AxisWorld
from tmcl_spec.numbers import NS_PER_S, to_int32
from tmcl_spec.parameters import AP, ParamSpec

DEFAULT_CLOCK_HZ = 16_000_000

#: RAMPMODE bits: positioning mode (bit 2) and the ramp profile (bits 1..0).
POSITIONING = 0b100
PROFILE_MASK = 0b011
TRAPEZOID = 0b01
S_SHAPED = 0b10
#: Real-unit accelerations are 22.2 fixed point in 24 bits: at most this many pps².
REAL_ACCELERATION_MAX = 0xFF_FFFF / 4
#: Direct acceleration values (GENERAL_CONF.1) may not exceed 2^20 (datasheet).
DIRECT_ACCELERATION_MAX = 1 << 20
#: The largest VMAX/VSTART/VSTOP/VBREAK register value (23.8 fixed point, positive).
VELOCITY_REGISTER_MAX = 0x7FFF_FFFF
#: Datasheet §6.7.2 and Table 18: |VMAX| <= f/2 in velocity mode and <= f/4 in positioning
#: mode ("INCORRECT step pulses ... and/or positioning is not executed properly" beyond).
VELOCITY_MODE_CEILING_DIVISOR = 2
POSITIONING_CEILING_DIVISOR = 4
#: AP 21 counts 32 µs (manual Table 14: "0.000032 s").
RAMP_WAIT_UNIT_S = 32e-6
#: Unit mode 0: the manual's internal units (the TMC5130's, "used directly", Table 14 AP 255):
#: a velocity unit is f/2^24 pps and an acceleration unit f^2/2^41 pps^2 at clock f.
INTERNAL_VELOCITY_SHIFT = 24
INTERNAL_ACCELERATION_SHIFT = 41

_VEL_STATE = Status.VEL_STATE_POS | Status.VEL_STATE_NEG
_SWITCH_EVENTS = Event.STOPL | Event.STOPR
#: The events that lock a direction: the stop switches' and the virtual stops'.
_STOP_EVENTS = _SWITCH_EVENTS | Event.VSTOPL_ACTIVE | Event.VSTOPR_ACTIVE
#: The REFERENCE_CONF bits the firmware owns (the rest is left as a host wrote it via 146).
_FIRMWARE_REF_BITS = (RefConf.STOP_LEFT_EN | RefConf.STOP_RIGHT_EN | RefConf.POL_STOP_LEFT
                      | RefConf.POL_STOP_RIGHT | RefConf.INVERT_STOP_DIRECTION
                      | RefConf.SOFT_STOP_EN)
#: Ramp registers the firmware writes through a shadow (a repeated value is not sent again).
_SHADOWED = frozenset({Reg.AMAX, Reg.DMAX, Reg.ASTART, Reg.DFINAL, Reg.DSTOP, Reg.VSTART,
                       Reg.VSTOP, Reg.VBREAK, Reg.TZEROWAIT, Reg.GENERAL_CONF, Reg.BOW1,
                       Reg.BOW2, Reg.BOW3, Reg.BOW4})
#: The TMC4361 modules' (TMCM-1111) bows, their own parameters (raw pps^3 register values).
_BOWS = ((Reg.BOW1, AP.BOW1), (Reg.BOW2, AP.BOW2), (Reg.BOW3, AP.BOW3), (Reg.BOW4, AP.BOW4))
#: REFERENCE_CONF's virtual stop bits, owned by the firmware where the module has the
#: TMC4361 modules' virtual stop parameters (AP 26..29 on the TMCM-1111).
_VIRTUAL_REF_BITS = (RefConf.VIRTUAL_LEFT_LIMIT_EN | RefConf.VIRTUAL_RIGHT_LIMIT_EN
                     | RefConf.VIRT_STOP_MODE)

#: The TMCM-1111's closed loop mode (its own number; the firmware layer keeps it as it is).
CLOSED_LOOP_MODE = 129

#: Registers only a datagram changes (the chip never does): the firmware remembers what it
#: wrote and answers its own questions from that instead of reading them back.
_REMEMBERED = frozenset({Reg.RAMPMODE, Reg.VMAX, Reg.XTARGET})

_READ_XACTUAL = datagram(Reg.XACTUAL)
_READ_STATUS = datagram(Reg.STATUS)


class TMC4361ADriver(ChipDriver):
    """The firmware's TMC4361A routines for one axis (an :class:`axes.core.ChipDriver`)."""

    #: XACTUAL is the whole 32-bit AP 1: the look-ahead need not stop every 4 s to read it.
    lookahead_ns = 60 * NS_PER_S
    #: Positioning speeds beyond the datasheet's f/4 (refused), and the TMCM-1111's encoder
    #: and motor resolution while its closed loop runs (status 6).
    checked_parameters = frozenset({AP.MAX_SPEED, AP.RFS_SWITCH_SPEED, AP.FULLSTEPS,
                                    AP.ENCODER_RESOLUTION})

    def __init__(self, index: int, params: Mapping[int, int], board: AxisBoard,
                 clock_hz: int = DEFAULT_CLOCK_HZ) -> None:
        self.index = index
        #: The axis parameters (the firmware's dict, read here, never written).
        self.params = params
        self.board = board
        self.chip = TMC4361A(clock_hz, board)
        #: AP 1, as of the last read of XACTUAL.
        self.position = 0
        self._searching = False
        #: Last value written to each shadowed register (None: unknown, send it).
        self._shadow: dict[int, int] = {}
        #: The value of each remembered register as the firmware last wrote it.
        self._known: dict[int, int] = {}
        #: The module numbers its parameters as the TMC4361 modules do (the TMCM-1111: a ramp
        #: type, bows and DSTOP of its own; TMCL-LITE-1111 ``SetAccelerationDeceleration``):
        #: every ramp register comes from its parameter, in both modes.
        self._own_ramp = AP.STOP_DECELERATION in params
        self._virtual_stops = AP.VIRTUAL_STOP_ENABLE in params

    # == chip access ===========================================================================

    def _write(self, reg: int, value: int) -> None:
        value &= MASK32
        if reg in _SHADOWED:
            if self._shadow.get(reg) == value:
                return
            self._shadow[reg] = value
        elif reg in _REMEMBERED:
            self._known[reg] = value & WRITE_MASKS.get(reg, MASK32)
        self.chip.spi(datagram(reg, value, write=True))

    def _forget(self) -> None:
        """A host wrote a register (command 146) or the chip was reset: send and read again."""
        self._shadow.clear()
        self._known.clear()

    def _read(self, reg: int) -> int:
        """The 32 data bits of a register: the read is answered one datagram later."""
        known = self._known.get(reg)
        if known is not None:
            return known
        frame = datagram(reg)
        self.chip.spi(frame)
        return self.chip.spi(frame) & MASK32

    def power_up(self) -> None:
        """What the firmware does at power-up: clock, switch inputs, an idle velocity ramp.

        CLK_FREQ is set to the module's clock (all real units depend on it); the switch inputs
        are high-active, because the module's input stage hands the chip logical levels
        (polarity AP 24/25 and swap AP 14 are applied before the chip, as on the TMC4210
        core); EVENTS is read once to clear the reset event.
        """
        self._forget()
        self.chip.spi(datagram(Reg.CLK_FREQ, self.chip.clock_hz, write=True))
        self._write_reference_conf()
        self._set_mode(positioning=False)
        self._write(Reg.VMAX, 0)
        self._write_ramp(positioning=False)
        self._read(Reg.EVENTS)

    def register_access(self, address: int, value: int | None = None) -> int:
        """Commands 146/147: one register, its 32 data bits as TMCL's 32-bit value.

        A write sends one datagram with the value as its data; a read sends the read datagram
        twice (the answer comes one datagram later) and returns the data, so the SPI status
        byte of the 40-bit answer is not part of the reply.  Writes bypass the firmware.
        The firmware's main loop has run before the request (stop events at standstill
        cleared, :meth:`_release_stop_events`).
        """
        self._release_stop_events()
        if value is None:
            answer = self._read(address)
        else:
            self.chip.spi(datagram(address, value, write=True))
            self._forget()  # the host may have changed what the firmware wrote
            answer = value & MASK32
        self.read_position()
        return to_int32(answer)

    # == readings ==============================================================================

    def read_position(self) -> int:
        self.chip.spi(_READ_XACTUAL)
        self.position = signed32(self.chip.spi(_READ_XACTUAL))
        return self.position

    def _status(self) -> int:
        self.chip.spi(_READ_STATUS)
        return self.chip.spi(_READ_STATUS) & MASK32

    def moving(self) -> bool:
        """In motion, or about to move by itself (the zero of a U-turn, TZEROWAIT, a restart
        toward the target): the standstill of a TMCL axis is a chip that stays at rest."""
        status = self._status()
        if status & _VEL_STATE:
            return True
        direction = self._direction_ahead()
        if direction > 0:
            return not status & (Status.STOPR_ACTIVE_F | Status.VSTOPR_ACTIVE_F)
        if direction < 0:
            return not status & (Status.STOPL_ACTIVE_F | Status.VSTOPL_ACTIVE_F)
        return False

    def actual_speed(self) -> int:
        """AP 3: VACTUAL (integer pps), or in unit mode 0 the manual's internal units."""
        return self._speed_from_pps(signed32(self._read(Reg.VACTUAL)))

    def speed_turns(self, start: ChipModel) -> Callable[[ChipModel], bool] | None:
        """S-shaped ramps bend: the chip says how far a rotation's speed moves one way."""
        assert isinstance(start, TMC4361A)
        test = start.speed_turns()
        if test is None:
            return None
        return lambda later: test(cast(TMC4361A, later))

    def positioning_speed(self, start: ChipModel) -> tuple[Callable[[ChipModel], bool],
                                                           int] | None:
        """A trapezoid move's VACTUAL rises to VMAX and falls on the final approach (F8)."""
        assert isinstance(start, TMC4361A)
        plan = start.positioning_turns()
        if plan is None:
            return None
        test, steps = plan
        return (lambda later: test(cast(TMC4361A, later))), steps

    def levels(self) -> tuple[bool, bool, bool]:
        """Logical (left, right, home) levels, read from the input stage.

        The TMC4361A has no register with the raw levels of its STOPL/STOPR/HOME_REF inputs
        (STATUS shows a stop switch only while it is enabled), so the firmware reads the
        module's input stage directly, as the microcontroller's inputs wired in parallel.
        """
        return self.board.pins(self.chip.motor_position)

    def take_switch_stop(self) -> bool:
        """Whether a stop switch latched its event since the last call (reading clears it)."""
        return bool(self._read(Reg.EVENTS) & _SWITCH_EVENTS)

    def mode_name(self) -> str:
        return "position" if self._read(Reg.RAMPMODE) & POSITIONING else "velocity"

    def heading(self) -> int:
        """Direction of travel, or of the travel about to start (-1, 0, +1)."""
        status = self._status()
        if status & Status.VEL_STATE_POS:
            return 1
        if status & Status.VEL_STATE_NEG:
            return -1
        return self._direction_ahead()

    def _direction_ahead(self) -> int:
        """At rest: where the ramp heads (sign of VMAX, or toward XTARGET), 0 if nowhere."""
        if self._read(Reg.RAMPMODE) & POSITIONING:
            if not self._read(Reg.VMAX):
                return 0
            ahead = signed32(self._read(Reg.XTARGET) - self._read(Reg.XACTUAL))
        else:
            ahead = signed32(self._read(Reg.VMAX))
        return (ahead > 0) - (ahead < 0)

    # == units =================================================================================

    @property
    def _pps_units(self) -> bool:
        return self.params[AP.UNIT_MODE] == 1

    def check_write(self, number: int, value: int) -> None:
        """AP 4 and AP 195 (the reference search's last move) are positioning speeds: beyond
        f/4 the chip does not position (datasheet §6.7.2, Table 18), so the module refuses
        them rather than run slower than it says (the TMCM-1111's own firmware writes what
        it is given, and runs it).  The TMCM-1111 refuses a new AP 202/210 while its closed
        loop runs (TMCL-LITE-1111 Commands.c lines 993-1008, 1023-1037: status 6)."""
        if self._own_ramp:
            if (number in (AP.FULLSTEPS, AP.ENCODER_RESOLUTION)
                    and self.params.get(CLOSED_LOOP_MODE) and value != self.params[number]):
                raise NotAvailable("not while the closed loop runs (AP 129 = 1)")
        elif number in (AP.MAX_SPEED, AP.RFS_SWITCH_SPEED):
            ceiling = self.chip.clock_hz / POSITIONING_CEILING_DIVISOR
            if self._pps(abs(value)) > ceiling:
                raise ValueError(f"{value} is beyond the {ceiling:.0f} pps the TMC4361A "
                                 f"positions at {self.chip.clock_hz} Hz (f/4)")

    def _pps(self, speed: int) -> float:
        """A speed parameter in pps (unit mode 0: internal units of f/2^24 pps; on the
        TMCM-1111 VMAX's own, 1/256 pps: TMCL-LITE-1111 ``ConvertInternalToInternal``)."""
        if self._pps_units:
            return float(speed)
        if self._own_ramp:
            return speed / (1 << 8)
        return speed * self.chip.clock_hz / (1 << INTERNAL_VELOCITY_SHIFT)

    def _speed_from_pps(self, pps: int) -> int:
        if self._pps_units:
            return pps
        if self._own_ramp:
            return pps << 8  # GAP 3: VACTUAL << 8 (TMCL-LITE-1111 Commands.c line 1242)
        return round(pps * (1 << INTERNAL_VELOCITY_SHIFT) / self.chip.clock_hz)

    def _velocity_register(self, speed: int) -> int:
        """VMAX/VSTART/VSTOP/VBREAK register (24.8 pps) for a speed parameter, sign kept."""
        if self._pps_units:
            magnitude = abs(speed) << 8  # exact: whole pps
        elif self._own_ramp:
            magnitude = abs(speed)  # the TMCM-1111's unit mode 0: VMAX itself
        else:
            magnitude = round(abs(speed) * self.chip.clock_hz / (1 << (INTERNAL_VELOCITY_SHIFT - 8)))
        magnitude = min(magnitude, VELOCITY_REGISTER_MAX)
        return -magnitude if speed < 0 else magnitude

    def _vmax_register(self, speed: int, positioning: bool) -> int:
        """VMAX for a speed parameter, within the datasheet's ceiling for the mode (f/4 pps
        in positioning, f/2 pps in velocity mode; docs/tmc4361a.md, "Speed ceiling").

        The TMC4361 modules' own firmware (TMCL-LITE-1111: VMAX = pps << 8) does not clamp,
        so a module with their numbering (the TMCM-1111) writes what it is given.
        """
        if self._own_ramp:
            return self._velocity_register(speed)
        divisor = POSITIONING_CEILING_DIVISOR if positioning else VELOCITY_MODE_CEILING_DIVISOR
        ceiling = (self.chip.clock_hz << 8) // divisor
        return max(-ceiling, min(self._velocity_register(speed), ceiling))

    def _pps2(self, acceleration: int) -> float:
        """An acceleration parameter in pps² (unit mode 0: internal units of f²/2^41 pps²)."""
        if self._pps_units:
            return float(acceleration)
        if self._own_ramp:
            return acceleration / 4  # the TMCM-1111's unit mode 0: the 22.2 registers' own
        f = self.chip.clock_hz
        return acceleration * f * f / (1 << INTERNAL_ACCELERATION_SHIFT)

    def _acceleration_registers(self, accelerations: dict[int, int]) -> tuple[bool, dict[int, int]]:
        """(direct mode?, register -> value) for accelerations given as parameters.

        Real units (22.2 pps²) reach 4 194 303 pps²; the manual allows up to 7 629 278, so when
        any acceleration of the ramp is beyond the real-unit range the firmware switches the
        chip to direct values (GENERAL_CONF.1, f²/2^37 pps² per LSB, ~1862.6 pps² at 16 MHz)
        for all of them.
        """
        pps2 = {reg: self._pps2(value) for reg, value in accelerations.items()}
        direct = any(value > REAL_ACCELERATION_MAX for value in pps2.values())
        f = self.chip.clock_hz
        out = {}
        for reg, value in pps2.items():
            if direct:
                out[reg] = min(round(value * (1 << 37) / (f * f)), DIRECT_ACCELERATION_MAX)
            else:
                out[reg] = round(value * 4)
        return direct, out

    def _ramp_wait_clocks(self) -> int:
        """TZEROWAIT for AP 21 (units of 32 µs; 512 clocks at 16 MHz)."""
        return round(self.params[AP.RAMP_WAIT] * RAMP_WAIT_UNIT_S * self.chip.clock_hz)

    # == the ramp ==============================================================================

    def _set_mode(self, positioning: bool) -> None:
        """RAMPMODE: the operation mode; the profile bits stay as they are (trapezoid after
        power-up, S-shaped if a host chose it through command 146), or, on a module with a
        ramp type parameter (the TMCM-1111's AP 14), as that says."""
        if AP.RAMP_TYPE in self.params:
            profile = S_SHAPED if self.params[AP.RAMP_TYPE] else TRAPEZOID
        else:
            profile = self._read(Reg.RAMPMODE) & PROFILE_MASK or TRAPEZOID
        self._write(Reg.RAMPMODE, profile | (POSITIONING if positioning else 0))

    def _write_ramp(self, positioning: bool) -> None:
        """The ramp registers for a move (AP 5, 15-21) or a rotation (AP 5 both ways).

        Positioning uses the six-point ramp of Table 14: AMAX = AP 5, DMAX = AP 17, and with
        V1 (AP 16) > 0: VBREAK = V1, ASTART = A1 (AP 15), DFINAL = D1 (AP 18); VSTART = AP 19,
        VSTOP = AP 20.  Velocity mode ("in position mode only" for the rest) accelerates and
        decelerates with AP 5 and starts and stops from 0.  A soft stop (AP 26) brakes with
        DSTOP = the deceleration in force.  AP 21 is TZEROWAIT (direction reversals).

        A module numbering its parameters as the TMC4361 modules do (the TMCM-1111) has a
        parameter for every register: AMAX, DMAX, ASTART, DFINAL, DSTOP, VBREAK, VSTART,
        VSTOP and BOW1..4 are written as they are, for moves and rotations alike (as
        TMCL-LITE-1111 does); ramp wait stays 0 (it has none).
        """
        p = self.params
        accelerations: dict[int, int] = {Reg.AMAX: p[AP.MAX_ACCELERATION]}
        if self._own_ramp:  # the TMC4361 modules: each register its parameter, both modes
            accelerations.update({Reg.DMAX: p[AP.MAX_DECELERATION], Reg.ASTART: p[AP.A1],
                                  Reg.DFINAL: p[AP.D1], Reg.DSTOP: p[AP.STOP_DECELERATION]})
            vbreak = self._velocity_register(p[AP.V1])
            vstart = self._velocity_register(p[AP.VSTART])
            vstop = self._velocity_register(p[AP.VSTOP])
            for bow, number in _BOWS:
                self._write(bow, p[number])
        elif positioning:
            accelerations[Reg.DMAX] = p[AP.MAX_DECELERATION]
            six_point = p[AP.V1] > 0
            accelerations[Reg.ASTART] = p[AP.A1] if six_point else 0
            accelerations[Reg.DFINAL] = p[AP.D1] if six_point else 0
            vbreak = self._velocity_register(p[AP.V1]) if six_point else 0
            vstart = self._velocity_register(p[AP.VSTART])
            vstop = self._velocity_register(p[AP.VSTOP])
        else:
            accelerations[Reg.DMAX] = p[AP.MAX_ACCELERATION]
            accelerations[Reg.ASTART] = accelerations[Reg.DFINAL] = 0
            vbreak = vstart = vstop = 0
        direct, registers = self._acceleration_registers(accelerations)
        general = self._shadow.get(Reg.GENERAL_CONF)
        if general is None:
            general = self._read(Reg.GENERAL_CONF)
        general = (general | GeneralConf.DIRECT_ACC_VAL_EN if direct
                   else general & ~GeneralConf.DIRECT_ACC_VAL_EN)
        self._write(Reg.GENERAL_CONF, general)
        for reg, value in registers.items():
            self._write(reg, value)
        if not self._own_ramp:
            self._write(Reg.DSTOP, registers[Reg.DMAX])
        self._write(Reg.VBREAK, vbreak)
        self._write(Reg.VSTART, vstart)
        self._write(Reg.VSTOP, vstop)
        self._write(Reg.TZEROWAIT, self._ramp_wait_clocks())

    def limits_changed(self, positioning: bool, velocity_command: int) -> None:
        """A speed, acceleration, ramp or unit parameter changed: the ramp in flight follows."""
        in_positioning_mode = bool(self._read(Reg.RAMPMODE) & POSITIONING)
        if positioning and in_positioning_mode:
            self._write_ramp(positioning=True)
            self._write(Reg.VMAX, self._vmax_register(self.params[AP.MAX_SPEED], True))
        elif not in_positioning_mode:
            self._write_ramp(positioning=False)
            self._write(Reg.VMAX, self._vmax_register(velocity_command, False))

    # == switches ==============================================================================

    def _write_reference_conf(self) -> None:
        p = self.params
        conf = self._read(Reg.REFERENCE_CONF) & ~_FIRMWARE_REF_BITS
        conf |= RefConf.POL_STOP_LEFT | RefConf.POL_STOP_RIGHT
        if not (self._searching or p[AP.LEFT_DISABLE]):
            conf |= RefConf.STOP_LEFT_EN
        if not (self._searching or p[AP.RIGHT_DISABLE]):
            conf |= RefConf.STOP_RIGHT_EN
        if p[AP.SOFT_STOP]:
            conf |= RefConf.SOFT_STOP_EN
        if self._virtual_stops:  # the TMCM-1111's AP 26..29 (TMCL-LITE-1111's SAP 26..29)
            self._write(Reg.VIRT_STOP_LEFT, p[AP.VIRTUAL_STOP_LEFT])
            self._write(Reg.VIRT_STOP_RIGHT, p[AP.VIRTUAL_STOP_RIGHT])
            enable = p[AP.VIRTUAL_STOP_ENABLE]
            conf &= ~_VIRTUAL_REF_BITS
            if enable & 1:
                conf |= RefConf.VIRTUAL_LEFT_LIMIT_EN
            if enable & 2:
                conf |= RefConf.VIRTUAL_RIGHT_LIMIT_EN
            conf |= (p[AP.VIRTUAL_STOP_MODE] & 3) << 8
        self._write(Reg.REFERENCE_CONF, conf)

    def configure_stops(self, searching: bool) -> None:
        """Stop switches as AP 12/13/26 say (and the virtual stops where the module has them);
        a reference search drives through the switches."""
        self._searching = searching
        self._write_reference_conf()

    # == motion ================================================================================

    def _release_stop_events(self) -> None:
        """Clear latched stop events while the motor stands (datasheet §8.1.2), as Trinamic's
        TMC4361 TMCL firmware does in every pass of its main loop (TMCL-LITE-1111,
        ``SystemControl``: a STOPL, STOPR, VSTOPL or VSTOPR event with VACTUAL = 0 is read
        and cleared).

        The chip latches a stop event whenever an enabled switch becomes active, also at
        standstill (a polarity or swap change, a switch passing by), and locks that direction
        until the event is cleared, even after the switch is released; an active switch (or
        a virtual limit still passed) keeps it locked through its STATUS flag.  The main loop
        runs between any two host requests, so the firmware here clears the events before
        each motion command and each register access (writing 1 clears only those bits).
        """
        if not self._read(Reg.VACTUAL):
            self._write(Reg.EVENTS, _STOP_EVENTS)

    def start_velocity(self, speed: int) -> None:
        self._release_stop_events()
        self._write_ramp(positioning=False)
        self._set_mode(positioning=False)
        self._write(Reg.VMAX, self._vmax_register(speed, False))

    def start_positioning(self, target: int, top_speed: int) -> None:
        self._release_stop_events()
        self._write_ramp(positioning=True)
        self._write(Reg.VMAX, self._vmax_register(top_speed, True))
        self._set_mode(positioning=True)
        self._write(Reg.XTARGET, target)

    def continue_move(self, target: int) -> None:
        """Nothing to do: XTARGET holds the whole 32-bit target."""

    def refill_mark(self, target: int) -> int | None:
        return None

    def ramp_stop(self) -> None:
        """MST: velocity mode, VMAX = 0, decelerating with AP 5."""
        self._write_ramp(positioning=False)
        self._set_mode(positioning=False)
        self._write(Reg.VMAX, 0)

    def hard_stop(self) -> None:
        """Stop within the datagram: a hard virtual stop at the present position.

        The chip has no "stop now" command; a virtual stop switch in hard mode
        (VIRT_STOP_MODE 1) that becomes active in the direction of travel sets VACTUAL to 0
        at once.  The firmware sets the limit to XACTUAL on the side the motor heads for,
        enables it, then restores REFERENCE_CONF and the limit and clears the event it
        latched; the chip is left in velocity mode with VMAX = 0.
        """
        status = self._status()
        self._set_mode(positioning=False)
        self._write(Reg.VMAX, 0)
        if not status & _VEL_STATE:
            return
        if status & Status.VEL_STATE_POS:
            limit, enable, event = Reg.VIRT_STOP_RIGHT, RefConf.VIRTUAL_RIGHT_LIMIT_EN, Event.VSTOPR_ACTIVE
        else:
            limit, enable, event = Reg.VIRT_STOP_LEFT, RefConf.VIRTUAL_LEFT_LIMIT_EN, Event.VSTOPL_ACTIVE
        conf = self._read(Reg.REFERENCE_CONF)
        old_limit = self._read(limit)
        self._write(limit, self._read(Reg.XACTUAL))
        self._write(Reg.REFERENCE_CONF, (conf & ~RefConf.VIRT_STOP_MODE) | 1 << 8 | enable)
        self._write(Reg.REFERENCE_CONF, conf)
        self._write(limit, old_limit)
        self._write(Reg.EVENTS, event)

    def set_position(self, value: int) -> bool:
        """AP 1 write: XACTUAL and XTARGET := value (a move in flight ends with a ramped stop).

        Returns True if a move in flight was turned into a ramped stop.
        """
        in_flight = bool(self._read(Reg.RAMPMODE) & POSITIONING) and self.moving()
        if in_flight:
            self.ramp_stop()
        self._write(Reg.XACTUAL, value)
        self._write(Reg.XTARGET, value)
        self.position = to_int32(value)
        return in_flight


class TMC4361AAxis(AxisFirmware):
    """One TMCM-6212 axis on a TMC4361A: the TMCL firmware layer over the TMC4361A driver."""

    def __init__(self, index: int, parameters: Mapping[int, ParamSpec],
                 world: AxisWorld | None = None, clock_hz: int | None = None) -> None:
        if AP.PULSE_DIVISOR in parameters:
            raise ValueError("its speeds are TMC429 register values at the divisors of "
                             "AP 153/154, which only a TMC42x core has")
        clock = DEFAULT_CLOCK_HZ if clock_hz is None else clock_hz
        super().__init__(index, parameters, world,
                         lambda params, board: TMC4361ADriver(index, params, board, clock))
