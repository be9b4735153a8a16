"""Fixtures the transport tests share."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.helpers.mosquitto import Broker


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Broker]:
    """A throwaway mosquitto of the test's own (only where mosquitto is installed: the MQTT
    tests are marked ``needs(missing_reason())``)."""
    b = Broker(tmp_path)
    yield b
    b.stop()
