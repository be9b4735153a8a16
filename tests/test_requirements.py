"""A program the tests need (mosquitto, Chromium) and is missing: its tests skip on a laptop,
and fail under TMCL_SIM_REQUIRE_ALL=1 (.ci/run), so CI cannot pass by skipping them."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers.requirements import REQUIRE_ALL

ROOT = Path(__file__).resolve().parents[1]

NEEDY_TEST = '''
from tests.helpers.requirements import needs

pytestmark = needs("frobnicator is not installed (apt-get install frobnicator)")


def test_uses_the_frobnicator():
    pass
'''


@pytest.mark.parametrize(("flag", "outcome"), [("", "1 skipped"), ("1", "1 error")])
def test_missing_program_skips_or_fails_under_the_flag(tmp_path: Path, flag: str,
                                                        outcome: str) -> None:
    test_file = tmp_path / "test_needy.py"
    test_file.write_text(NEEDY_TEST)
    env = {**os.environ, REQUIRE_ALL: flag}
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           "-p", "no:xdist", "-p", "tests.conftest", "-c",
                           str(ROOT / "pyproject.toml"), "--rootdir", str(ROOT), "-rfEs",
                           str(test_file)],
                          capture_output=True, text=True, cwd=ROOT, env=env, timeout=60)
    assert outcome in done.stdout, done.stdout
    assert done.returncode == (1 if flag else 0), done.stdout
    assert "frobnicator is not installed" in done.stdout, done.stdout
