"""The TMC4361A's basic incremental encoder input and its microstep counter (MSCNT).

ENC_POS counts the encoder's A/B transitions scaled by ENC_CONST (from ENC_IN_RES and the
microsteps per revolution, or written directly), ENC_POS_DEV is its deviation from XACTUAL,
V_ENC the encoder's rate; a board with ``encoder_counts(motor_position)`` drives the inputs
(:class:`EncoderBoard`), else the encoder follows the motor exactly.  None of it moves the
motor: the chip (:class:`axes.chips.tmc4361a.chip.TMC4361A`) reads it for its registers,
the ENC_FAIL flag and the positions where the deviation crosses ENC_POS_DEV_TOL.  Choices
are in ``docs/tmc4361a.md``, "Encoder (basic incremental)".
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, runtime_checkable

from axes.chips.tmc4361a.registers import Event, GeneralConf, Reg, signed32
from axes.core import Board

if TYPE_CHECKING:
    from axes.chips.tmc4361a.ramp import Ramp

ENC_SEL_DECIMAL = 1 << 0
INVERT_ENC_DIR = 1 << 29
MANUAL_ENC_CONST = 1 << 31


@runtime_checkable
class EncoderBoard(Board, Protocol):
    """A board that also drives the encoder inputs (A/B transitions)."""

    def encoder_counts(self, motor_position: int) -> int:
        """Signed count of AB transitions the encoder has made with the motor at this position."""
        ...


class EncoderInputs:
    """The encoder and MSCNT state of a TMC4361A (a base of the chip's class)."""

    regs: dict[int, int]
    board: Board | None
    events: int
    _ramp: Ramp
    _enc_const: tuple[int, int, int]
    _enc_base: int
    _enc_counts_base: int
    _mscnt_base: int
    _mscnt_m: int

    if TYPE_CHECKING:
        @property
        def motor_position(self) -> int: ...

        @property
        def xactual(self) -> int: ...

    def _encoder_reset(self, motor_position: int) -> None:
        """Power-on: ENC_POS 0 with the constant of the power-on registers, MSCNT 0 here."""
        self._enc_const = (0, 65536, 0)  # (numerator, denominator, ENC_CONST register)
        self._enc_base = 0  # ENC_POS * denominator at the rebase point
        self._enc_counts_base = 0
        self._mscnt_base = 0
        self._mscnt_m = motor_position
        self._enc_rebase(0)

    def _encoder_counts(self, motor_position: int) -> int:
        g = self.regs.get
        if isinstance(self.board, EncoderBoard):
            counts = self.board.encoder_counts(motor_position)
        else:
            resolution = g(Reg.ENC_IN_RES, 0)
            if resolution & MANUAL_ENC_CONST or not resolution:
                return 0
            counts = motor_position * resolution // self._usteps_per_rev()
        return -counts if g(Reg.ENC_IN_CONF, 0) & INVERT_ENC_DIR else counts

    def _usteps_per_rev(self) -> int:
        step_conf = self.regs.get(Reg.STEP_CONF, 0)
        fs_per_rev = (step_conf >> 4) & 0xFFF
        return max(fs_per_rev * (256 >> min(step_conf & 0xF, 8)), 1)

    def _enc_const_now(self) -> tuple[int, int, int]:
        """(numerator, denominator, register) of ENC_CONST from ENC_IN_RES and STEP_CONF."""
        g = self.regs.get
        written = g(Reg.ENC_IN_RES, 0)
        decimal = bool(g(Reg.ENC_IN_CONF, 0) & ENC_SEL_DECIMAL)
        if written & MANUAL_ENC_CONST:
            raw = written & 0x7FFF_FFFF
            if decimal:
                return (raw >> 16) * 10000 + min(raw & 0xFFFF, 9999), 10000, raw
            return raw, 65536, raw
        resolution = written & 0x7FFF_FFFF
        if not resolution:
            return 0, 65536, 0
        whole, rest = divmod(self._usteps_per_rev(), resolution)
        if whole > 0x7FFF:
            whole = 0x7FFF
        if rest * 65536 % resolution == 0 or (rest * 10000 % resolution and not decimal):
            fraction = rest * 65536 // resolution
            return whole * 65536 + fraction, 65536, whole << 16 | fraction
        fraction = rest * 10000 // resolution
        return whole * 10000 + fraction, 10000, whole << 16 | fraction

    def _enc_fine(self, motor_position: int) -> int:
        """ENC_POS times the constant's denominator."""
        numerator, _, _ = self._enc_const
        return self._enc_base + (self._encoder_counts(motor_position)
                                 - self._enc_counts_base) * numerator

    def enc_pos(self, motor_position: int | None = None) -> int:
        m = self.motor_position if motor_position is None else motor_position
        return signed32(self._enc_fine(m) // self._enc_const[1])

    def _enc_rebase(self, value: int | None = None) -> None:
        """Freeze ENC_POS here (or set it to ``value``) before the constant or counting changes."""
        m = self.motor_position
        if value is None:
            value = self.enc_pos(m) if hasattr(self, "_enc_const") else 0
        self._enc_const = self._enc_const_now()
        self._enc_base = value * self._enc_const[1]
        self._enc_counts_base = self._encoder_counts(m)

    def _enc_dev(self, motor_position: int) -> int:
        x = signed32(self.xactual + motor_position - self.motor_position)
        return signed32(self.enc_pos(motor_position) - x)

    def _encoder_fail_position(self) -> int | None:
        """First motor position ahead where |ENC_POS_DEV| exceeds ENC_POS_DEV_TOL.

        Assumes the deviation grows steadily with the distance travelled (a slipping or lagging
        encoder); the search is exponential and then bisects, O(log distance) board queries.
        """
        tolerance = self.regs.get(Reg.ENC_POS_DEV_TOL, 0)
        if tolerance >= 0x8000_0000 or self.events & Event.ENC_FAIL or not self._ramp.w:
            return None
        m = self.motor_position
        s = self._ramp.s
        if abs(self._enc_dev(m)) > tolerance:
            return None
        low, step = 0, 1
        high = None
        while step < 1 << 34:
            if abs(self._enc_dev(m + s * (low + step))) > tolerance:
                high = low + step
                break
            low += step
            step *= 2
        if high is None:
            return None
        while high - low > 1:
            mid = (low + high) // 2
            if abs(self._enc_dev(m + s * mid)) > tolerance:
                high = mid
            else:
                low = mid
        return m + s * high

    def _v_enc(self) -> int:
        """Encoder velocity [pps]: the encoder's rate against the motor at the present speed."""
        ramp = self._ramp
        if not ramp.w:
            return 0
        m = self.motor_position
        span = 1024 * ramp.s
        ratio_num = self.enc_pos(m + span) - self.enc_pos(m)
        v = self._vactual_exact()
        return int(v * ratio_num / span)

    def _vactual_exact(self) -> float:
        r = self._ramp
        return r.s * r.w * r.P.f / r.P.S

    def _mscnt(self) -> int:
        step_conf = self.regs.get(Reg.STEP_CONF, 0)
        increment = 1 << min(step_conf & 0xF, 8)
        if self.regs.get(Reg.GENERAL_CONF, 0) & GeneralConf.REVERSE_MOTOR_DIR:
            increment = -increment
        return (self._mscnt_base + (self.motor_position - self._mscnt_m) * increment) & 0x3FF

    def _mscnt_rebase(self, old_step_conf: int) -> None:
        new = self.regs.get(Reg.STEP_CONF, 0)
        self.regs[Reg.STEP_CONF] = old_step_conf
        value = self._mscnt()
        self.regs[Reg.STEP_CONF] = new
        self._mscnt_base = value
        self._mscnt_m = self.motor_position
