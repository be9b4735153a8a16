"""The motion core of the TMC42x family (TMC4210, TMC429): one motor's registers and motion.

The TMC4210 is a one-motor cut of the TMC429 (``shared/spec/tmc429.md`` §1): both chips have,
per motor, the same sixteen axis registers (IDX 0..15) and the same ramp and pulse generator.
:class:`MotorEngine` is that motor: the axis registers (:mod:`axes.chips.tmc42x.registers`)
and its motion.  A chip (:class:`axes.chips.tmc42x.tmc4210.TMC4210`,
:class:`axes.chips.tmc42x.tmc429.TMC429`) owns the global registers and the SPI interface,
and tells each engine how it is wired (see "Wiring" on :class:`~axes.chips.tmc42x.law.MotorLaw`).

The motion is the law of ``shared/spec/tmc4210.md`` §4.8, one clk32 tick at a time, in
:mod:`axes.chips.tmc42x.law`; :meth:`MotorEngine.run` is its fast shortcut, which never walks
single clk32 ticks: stretches where the velocity cannot change are computed in closed form
(:mod:`axes.chips.tmc42x.fast_steady`), and ramps run one *ramp tick* per loop iteration or
whole batches of them at once, with the pulses in between counted arithmetically
(:mod:`axes.chips.tmc42x.fast_ramps`).  Either way the motor lands on exactly the states, at
exactly the clk32 ticks, that the law gives: ``tests/axes/test_tmc42x_law.py`` holds ``run``
to :meth:`~axes.chips.tmc42x.law.MotorLaw.step` on random states (the whole state, budgets
and stops included), and ``tests/axes/test_tmc4210.py`` / ``test_tmc429.py`` hold it to
``tests/axes/reference_tmc4210.py``, an independent transcription of the digest.

The engine knows nothing about seconds: time is a clk32 tick count.  Its pins (left and
right switch, home) are driven by a :class:`Board`, which also names the motor positions at
which the outside world changes so that the engine can stop there.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Callable
from typing import Self

from axes.chips.tmc42x.fast_ramps import RampBatches
from axes.chips.tmc42x.registers import (
    DEFAULT_CLOCK_HZ,
    MODE_HOLD,
    MOTOR_PLAIN_REGISTERS,
    RampMode,
    Reg,
    shallow_copy,
    signed,
)
from axes.core import Board, ChipModel, Stop

#: clk32 ticks per simulated second are clock_hz / 32; this is 32 s in ns.
_NS_PER_32_TICKS = 32_000_000_000


class MotorEngine(RampBatches, ChipModel):
    """One motor of a TMC42x chip: axis registers, switches, latch, interrupts and motion.

    The :class:`axes.core.ChipModel` of a TMC42x axis: a chip (the TMC4210) or a motor of
    one (:class:`axes.chips.tmc42x.tmc429.TMC429Motor`) adds SPI (:meth:`spi`,
    :meth:`spi_data`) and what a look-ahead copy is (:meth:`clone`, :meth:`adopt`).  The
    state, the wiring and the law are :class:`~axes.chips.tmc42x.law.MotorLaw`'s.
    """

    #: Bits of the IDX %1000 register that exist (the chip narrows or widens it).
    a_threshold_mask = 0x777FFF
    #: Steps that reached the motor, unwrapped (a plain attribute: the engine moves it).
    motor_position: int

    def __init__(self, clock_hz: int = DEFAULT_CLOCK_HZ, board: Board | None = None) -> None:
        super().__init__(clock_hz, board)

    def reset_motor(self) -> None:
        super().reset_motor()
        self._work = 1  # loop iterations the last _fast took (run's work budget)

    @abstractmethod
    def spi_data(self, frame: int) -> int:
        """``spi(frame) & MASK24``, the data bits of the answer: the firmware's reads ignore
        the status byte, so a chip may skip sampling it (the frame acts the same)."""

    def steps_reach_motor(self) -> bool:
        return self.steps_out

    def reads_are_quiet(self) -> bool:
        """A read of an axis register over SPI would change nothing now but what it answers
        (no chip woken from power-down, no status bit cleared, no datagram sent on): a
        reading computed without the read (:meth:`readings`) leaves the chip as the
        read would.  A chip that cannot tell says no."""
        return False

    def at_rest(self) -> bool:
        """Stopped, and no ramp tick will start the motor again."""
        return self.v == 0 and self._steady_steps() == -1

    def clone(self) -> Self:
        """An independent copy (for looking ahead without disturbing this motor)."""
        return shallow_copy(self)

    # == time ==================================================================================

    def ticks_at(self, t_ns: int) -> int:
        """clk32 ticks that have happened by simulated time ``t_ns``."""
        return t_ns * self.clock_hz // _NS_PER_32_TICKS

    def ns_at(self, ticks: int) -> int:
        """The simulated time (ns, rounded up) of clk32 tick ``ticks``."""
        return -(-ticks * _NS_PER_32_TICKS // self.clock_hz)

    # == axis registers ========================================================================

    def read_motor(self, idx: int) -> int:
        """The 24 data bits a read of axis register ``idx`` returns (zero-extended)."""
        plain = MOTOR_PLAIN_REGISTERS.get(idx)
        if plain is not None:
            return getattr(self, plain[0])
        read = _COMPUTED_READS.get(idx)
        return 0 if read is None else read(self)

    def write_motor(self, idx: int, data: int) -> None:
        """A write of ``data`` (24 bits) to axis register ``idx``, with its side effects."""
        plain = MOTOR_PLAIN_REGISTERS.get(idx)
        if plain is not None:
            setattr(self, plain[0], data & plain[1])
            return
        write = _SIDE_EFFECT_WRITES.get(idx)
        if write is not None:
            write(self, data)

    def _write_v_actual(self, data: int) -> None:
        if self.mode == MODE_HOLD:
            self.v = signed(data, 12) << 8

    def _write_pmul_pdiv(self, data: int) -> None:
        self.pmul = (data >> 8 & 0xFF) | 0x80
        self.pdiv = data & 0xF

    def _write_ref_conf(self, data: int) -> None:
        self.ref_conf = data & 0xF00
        self.mode = RampMode(data & 3)

    def _write_interrupt(self, data: int) -> None:
        """Sets the mask and clears the flags written 1 in one write (a cleared mask bit
        clears its flag too)."""
        self.int_mask = data >> 8 & 0xFF
        self.int_flags &= ~data & 0xFF
        self.int_flags &= self.int_mask

    def _write_dividers(self, data: int) -> None:
        self.pulse_div = data >> 12 & 0xF
        self.ramp_div = data >> 8 & 0xF
        self.usrs = data & 7
        ramp = 1 << self.ramp_div
        self.ramp_next = (self.t // ramp + 1) * ramp

    # == the engine ============================================================================

    def run(self, until: int, budget: int | None = None) -> Stop | None:
        """Advance to clk32 tick ``until``; return early (self.t < until) at a notable instant.

        The fast shortcut of :meth:`~axes.chips.tmc42x.law.MotorLaw.step`, and equal to it:
        wherever it returns, ``t`` and the whole motor state are what ``step`` reaches there,
        and it returns the same ``Stop`` at the same tick (None at ``until``).

        ``budget`` bounds the work: after that many loop iterations (a ramp tick taken the
        plain way, or a batch of them in closed form: each counts 1), it returns
        None short of ``until`` (the caller looks again from there).
        """
        while self.t < until:
            if self.powered_down:
                self._sleep(until)
                return None
            nr = self.ramp_next
            if nr > until:
                # No ramp tick on the way (a look at the position mid-move): the velocity
                # stays as it is, only pulses happen.
                return self._pulses(until)
            if nr + (1 << self.ramp_div) > until and budget is None:
                stop = self._only_ramp_tick(nr)
            else:
                steady = self._steady_steps()
                if steady is not None:
                    stop = self._steady_stretch(until, steady)
                elif budget is not None and budget <= 0:
                    return self._finish_tick()  # out of budget, short of until
                else:  # the pulses up to ramp tick nr, then ramp ticks (in line: every ramp)
                    stop = self._pulses(nr - 1) if self.t < nr - 1 else None
                    if stop is None:
                        self._work = 1
                        if self.mode != MODE_HOLD and nr + (1 << self.ramp_div) - 1 <= until:
                            stop = self._fast(until, budget)  # batches where they fit
                        else:
                            stop = self._slow_tick(nr)
                    if budget is not None:
                        budget -= self._work  # loop iterations, however many ticks they covered
            if stop is not None:
                return stop
        return None

    def _sleep(self, until: int) -> None:
        """Powered down: the clocks stand still until ``until`` (the ramp ticks keep their
        grid)."""
        self.t = until
        ramp = 1 << self.ramp_div
        self.ramp_next = (until // ramp + 1) * ramp

    def _only_ramp_tick(self, nr: int) -> Stop | None:
        """Exactly one ramp tick before ``until``: the pulses up to it, and the tick the plain
        way (the closed forms pay off over many ticks; one tick the plain way is the same
        tick)."""
        if self.t < nr - 1:
            stop = self._pulses(nr - 1)
            if stop is not None:
                return stop
        return self._slow_tick(nr)

    def _finish_tick(self) -> Stop | None:
        """Before returning short of ``until``: a ramp tick taken the plain way at ``t + 1``
        (``_slow_tick`` leaves ``t`` one short of it) gets its pulses too, so that the state
        is the law's at ``t`` wherever ``run`` returns."""
        if self.ramp_next - (1 << self.ramp_div) == self.t + 1:
            return self._pulses(self.t + 1)
        return None


#: Axis registers whose read is computed (the others are plain storage or read 0).
_COMPUTED_READS: dict[int, Callable[[MotorEngine], int]] = {
    Reg.V_TARGET: lambda m: m.v_target & 0xFFF,
    Reg.V_ACTUAL: lambda m: m.v_actual & 0xFFF,
    Reg.A_ACTUAL: lambda m: m.a_actual & 0xFFF,
    Reg.A_THRESHOLD: lambda m: m.a_threshold,
    Reg.PMUL_PDIV: lambda m: m.pmul << 8 | m.pdiv,
    Reg.REF_CONF_RAMP_MODE: lambda m: m.latch_pending << 16 | m.ref_conf | m.mode,
    Reg.INTERRUPT: lambda m: m.int_mask << 8 | m.int_flags,
    Reg.DIVIDERS: lambda m: m.pulse_div << 12 | m.ramp_div << 8 | m.usrs,
    Reg.X_LATCHED: lambda m: m.x_latched,
}


def _arm_latch(motor: MotorEngine, data: int) -> None:
    motor.latch_pending = True


def _write_v_target(motor: MotorEngine, data: int) -> None:
    motor.v_target = signed(data, 12)


def _write_a_threshold(motor: MotorEngine, data: int) -> None:
    motor.a_threshold = data & motor.a_threshold_mask


#: Axis registers whose write does more than store bits (the others store or are read-only).
_SIDE_EFFECT_WRITES: dict[int, Callable[[MotorEngine, int], None]] = {
    Reg.V_TARGET: _write_v_target,
    Reg.V_ACTUAL: MotorEngine._write_v_actual,
    Reg.A_THRESHOLD: _write_a_threshold,
    Reg.PMUL_PDIV: MotorEngine._write_pmul_pdiv,
    Reg.REF_CONF_RAMP_MODE: MotorEngine._write_ref_conf,
    Reg.INTERRUPT: MotorEngine._write_interrupt,
    Reg.DIVIDERS: MotorEngine._write_dividers,
    Reg.X_LATCHED: _arm_latch,
}
