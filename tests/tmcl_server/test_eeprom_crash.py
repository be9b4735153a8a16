"""Kill -9 in the middle of EEPROM writes, from outside (scripts/kill9_eeprom.py, 100 runs by hand)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "kill9_eeprom.py"


def test_kills_during_stores_leave_valid_state_with_nothing_acknowledged_lost():
    result = subprocess.run([sys.executable, str(SCRIPT), "--runs", "6", "--seed", "11"],
                            capture_output=True, text=True, timeout=240)
    summary = json.loads(result.stdout.splitlines()[-1])
    assert result.returncode == 0, result.stdout + result.stderr
    assert summary["valid"] == summary["runs"] == 6
    assert summary["stores"] > 0  # the kills did land in the middle of storing
    assert summary["temporary_files_left"] == 0
