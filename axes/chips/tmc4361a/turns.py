"""The TMC4361A's promises to loop skipping: how far its speed moves one way from here.

The look-ahead (axes/forecast.py) skips the passes of a program's loop while a reading it
depends on cannot change; a ramp's speed that moves only one way for a stretch is such a
reading.  These tests answer that from the ramp's state alone, without running it: they
are a question asked about the chip, not part of its motion or its register file, so they
live apart from :mod:`axes.chips.tmc4361a.chip` (a base of its class, like ``recall.py``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from axes.chips.tmc4361a.params import A_FALL, A_SPEED, A_START, Context, Stage

if TYPE_CHECKING:
    from axes.chips.tmc4361a.ramp import Ramp

#: RAMPMODE(1:0) of an S-shaped ramp (Params.profile).
S_SHAPED_PROFILE = 2


def _turned_at_once(twin: TurnPromises) -> bool:
    """TMC4361A.speed_turns' test where no promise is made."""
    return True


def _never_turns(twin: TurnPromises) -> bool:
    """TMC4361A.positioning_turns' test where the speed only falls up to the target."""
    return False


def _final_approach_begun(twin: TurnPromises) -> bool:
    """TMC4361A.positioning_turns' test: the speed may fall from here on (the final approach,
    or the aim passed); it stays true up to the next rest, a STOPPED instant."""
    ramp = twin._ramp
    return ramp.braking or ramp.aim_rem(twin._context().target) * ramp.s <= 0


class TurnPromises:
    """The speed's turn tests of a TMC4361A (a base of the chip's class)."""

    t: int
    _ramp: Ramp

    if TYPE_CHECKING:
        def _context(self) -> Context: ...

    def speed_turns(self) -> Callable[[TurnPromises], bool] | None:
        """How far a rotation's VACTUAL moves one way from here, if nothing intervenes: a
        test of a later copy of this chip, true once the speed may have turned by its tick
        (false before, true from then on); None: it never turns.  Positioning ramps rise and
        fall: turned at once.  A rotation heads for the speed asked for, except:

        * a start from rest jumps to VSTART, which may lie beyond that speed (it comes
          back): turned at once, until the ramp has started (after TZEROWAIT's standstill),
          and, with a VSTART, turned at the standstill of a reversal (it starts again there);
        * an S-shaped slope first takes back the acceleration of the other slope (REC: a
          rotation asked for more speed while braking brakes on for a while, one asked for
          less while accelerating overshoots): turned where that acceleration reaches 0;
        * an S-shaped reversal with BOW2 = BOW4 passes through 0 without stopping and may
          then take back its acceleration again (the new direction's speed overshoots):
          turned at the zero crossing (or a standstill).

        Otherwise each slope lands on its goal (``Ramp._s_tick`` clamps there)."""
        ramp = self._ramp
        if ramp.P.positioning:
            return _turned_at_once
        if ramp.wait:  # TZEROWAIT: standing still until the start
            started = self.t + ramp.wait
            return lambda twin: twin.t > started
        if ramp.decide(self._context())[0] == A_START:
            return _turned_at_once
        s_shaped = ramp.P.profile == S_SHAPED_PROFILE
        if not s_shaped and not ramp.P.VSTART:
            return None
        if ramp.w == 0:  # at rest: the standstill the test looks for is a later one
            return _turned_at_once
        # a linear ramp turns only at a reversal's standstill, where it restarts at VSTART
        # (which may lie beyond the goal); an S-shaped one also where its REC stage ends
        direction, turning = ramp.s, s_shaped and self._takes_back_acceleration()

        def turned(twin: TurnPromises) -> bool:
            later = twin._ramp
            return (later.s != direction or later.w == 0
                    or (turning and not twin._takes_back_acceleration()))

        return turned

    def positioning_turns(self) -> tuple[Callable[[TurnPromises], bool], int] | None:
        """How far a trapezoid positioning move's VACTUAL moves one way from here, if nothing
        intervenes (axes/forecast.py F8): (a test of a later copy, false, then true once the
        speed may have turned; the microsteps to the target, where the stretch ends); None:
        no promise.  Towards the target, not braking, the speed heads for VMAX (it lands on
        it) and then falls on the final approach (``braking``) to VSTOP's crawl: it turns
        only where the final approach begins, or where the aim is passed (at or past the
        target step, where the stretch ends anyway); rest (a STOPPED instant, where a move
        may start again at VSTART) ends every run.  S-shaped ramps (a final approach that
        first takes back the acceleration), a start from rest, a stop switch in play and a
        move away from the target make no promise."""
        ramp = self._ramp
        P = ramp.P
        if not P.positioning or P.profile != 1 or not P.V:
            return None
        if ramp.wait or ramp.stopping or ramp.stage == Stage.IDLE or not ramp.w:
            return None
        ctx = self._context()
        if ctx.blocked_neg or ctx.blocked_pos:
            return None
        steps = ctx.target - ramp.x
        if steps * ramp.s <= 0 or ramp.aim_rem(ctx.target) * ramp.s <= 0:
            return None
        if ramp.braking or ramp.w >= P.V:
            return _never_turns, steps  # only falls (to VMAX, then to the crawl)
        return _final_approach_begun, steps

    def _takes_back_acceleration(self) -> bool:
        """Whether the next tick of an S-shaped rotation moves the speed against where its
        slope heads (the REC stage: the acceleration points the other way)."""
        ramp = self._ramp
        action = ramp.decide(self._context())
        if action[0] == A_SPEED:
            slope = (ramp.w < action[1]) - (ramp.w > action[1])
        elif action[0] == A_FALL:
            slope = -1
        else:  # at rest, waiting, a soft stop: no acceleration to take back
            return False
        return ramp.a * slope < 0
