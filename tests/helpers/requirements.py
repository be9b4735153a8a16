"""Tests that need a program from the distribution (mosquitto, Chromium): skipped where it is
missing, so that ``python3 scripts/test.py`` on a laptop runs the rest; failed instead when
``TMCL_SIM_REQUIRE_ALL=1`` (``.ci/run`` installs them and sets it: CI must not pass by
skipping what it was meant to run).

    pytestmark = needs(missing_reason())      # None: present, the tests run
"""

from __future__ import annotations

import os

import pytest

#: The environment variable under which a missing program fails its tests.
REQUIRE_ALL = "TMCL_SIM_REQUIRE_ALL"
#: The mark conftest.py fails a test for (its argument says what is missing).
MISSING_MARK = "missing_requirement"


def required() -> bool:
    return os.environ.get(REQUIRE_ALL, "") not in ("", "0")


def needs(reason: str | None) -> pytest.MarkDecorator:
    """A mark for a test or module: nothing when ``reason`` is None, else a skip, or under
    :data:`REQUIRE_ALL` a failure naming ``reason``."""
    if reason is None:
        return pytest.mark.skipif(False, reason="")
    if required():
        return getattr(pytest.mark, MISSING_MARK)(f"{reason} ({REQUIRE_ALL}=1: it must be here)")
    return pytest.mark.skip(reason=reason)
