"""Searches the fast motion engines share: the first instant a monotone condition holds."""

from __future__ import annotations

from collections.abc import Callable


def first_true(pred: Callable[[int], bool], limit: int) -> int:
    """Smallest i in 1..limit with pred(i), for a predicate monotone in i; limit + 1 if none.

    Exponential probing from 1, then bisection: O(log answer) evaluations.
    """
    if limit < 1 or not pred(limit):
        return limit + 1
    low, high = 0, limit  # pred(low) false (0 is never asked), pred(high) true
    step = 1
    while low + step < high:
        probe = low + step
        if pred(probe):
            high = probe
            break
        low = probe
        step *= 2
    while high - low > 1:
        mid = (low + high) // 2
        if pred(mid):
            high = mid
        else:
            low = mid
    return high
