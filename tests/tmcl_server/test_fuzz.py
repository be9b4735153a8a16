"""The short fuzz run of issue 11: ~10,000 fuzzed, mutated, torn and bursty frames over TCP and
the pty against a real ``tmcl-server`` process, every reply checked (scripts/fuzz.py).

The full run (``scripts/fuzz.py --frames 1000000``) is not part of the test suite; this one uses
the same generator and checker with a fixed seed.  Stalls (replies later than 50 ms after they
were due) are counted and reported, but on a noisy 2-core CI machine a 50 ms bound would be
flaky: here no reply may come later than 1 s (docs/robustness.md, "The fuzzer").  For the same
reason a torn frame the server misjoined although nobody was measurably late is judged by rate.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "fuzz.py"
#: Nothing left out: issue 11's items 1-3 (low speed limits, a frame torn after a burst, EEPROM
#: stores in a program loop) are fixed and this run guards them too (``--avoid`` takes them out
#: again when a new problem needs to be seen past).
AVOID = ""
#: The CI bound on a reply's lateness (the fuzzer's own stall bound is 50 ms).
CI_LATENESS_MS = 1000.0


def test_ten_thousand_fuzzed_frames_get_exactly_the_replies_the_wire_rules_demand(tmp_path):
    report = tmp_path / "fuzz.json"
    result = subprocess.run(
        [sys.executable, str(SCRIPT), "--frames", "10000", "--seed", "7", "--transport", "both",
         "--avoid", AVOID, "--hang-s", "5", "--progress", "1000", "--report", str(report)],
        capture_output=True, text=True, timeout=110)
    assert result.returncode == 0, result.stderr[-3000:]
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    findings = json.loads(report.read_text())
    brief = result.stderr[-3000:]
    assert summary["frames"] >= 10_000
    # every frame checked: a reply, or a silence the rules demand (foreign addresses on TCP)
    assert summary["replies_checked"] + summary["silences_checked"] >= 9_000
    assert summary["torn_pieces"] > 0 and summary["dropped_partials"] > 0
    assert summary["violations"] == 0, findings["violations"][:3]
    # A frame torn on purpose (pieces < 2 ms apart) that the server misjoined although neither the
    # fuzzer nor the server's CPU was late: the kernel's own delivery of a pty's or socket's bytes
    # may be late on a loaded machine, so these are judged by their rate.  Before issue 11's
    # item 2 was fixed, a frame torn after a burst was misjoined every time.
    assert summary["torn_mismatches"] <= max(2, summary["torn_rounds"] // 50), \
        findings["torn_mismatches"][:3]
    assert summary["crashes"] == 0 and summary["tracebacks"] == 0, brief
    assert summary["hangs"] == 0, [h["reason"] for h in findings["hangs"]]
    assert summary["max_latency_ms"] < CI_LATENESS_MS, findings["stalls"][:3]
    assert summary["rss_kb_end"] - summary["rss_kb_start"] < 2048
    assert summary["fds_end"] == summary["fds_start"]
