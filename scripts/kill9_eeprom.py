#!/usr/bin/env python3
"""Kill -9 during EEPROM writes: the state file stays valid, every value old or new.

Each run starts ``tmcl-server`` on a state directory that the previous runs left behind,
stores user variables (SGP + STGP, bank 2) and axis parameters (SAP + STAP) with ever
increasing values over TCP as fast as the module answers, and kills the process with
SIGKILL at a random instant (seeded).  Then it checks the file as the next start-up reads it:

* it is a valid EEPROM file (the simulator's own loader accepts it, nothing to repair);
* every stored value is one the host wrote (or the value before the run: "old or new");
* no acknowledged store is lost: a value is at least the last one whose STGP/STAP was
  answered before the kill (a real module answers a store when the EEPROM write is done);
* the restarted server answers those values on the wire;
* no temporary file of an interrupted write is left once the server has started again.

Prints one line per run and a JSON summary; exit status 1 if any run failed.

    .venv/bin/python scripts/kill9_eeprom.py [--runs 100] [--seed 1] [--max-delay 0.3]
"""

from __future__ import annotations

import argparse
import json
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from local_server import UploadError, tcp_host, wait_for_ready

from tmcl_server.eeprom import FILE_NAME, JOURNAL_NAMES, Eeprom
from tmcl_spec.commands import Opcode

#: Values stored on each pass: (set opcode, store opcode, type, motor/bank, read opcode).
USER_VARIABLES = [(Opcode.SGP, Opcode.STGP, n, 2, Opcode.GGP) for n in (0, 17, 55)]
AXIS_PARAMETERS = [(Opcode.SAP, Opcode.STAP, 4, m, Opcode.GAP) for m in (0, 5)]
SLOTS = USER_VARIABLES + AXIS_PARAMETERS
STATUS_OK = 100


@dataclass
class Trial:
    """What the host knows about one slot: every value written, the last one acknowledged."""

    written: dict[tuple[int, int], set[int]] = field(default_factory=dict)
    acknowledged: dict[tuple[int, int], int] = field(default_factory=dict)


class Server:
    def __init__(self, state: Path, work: Path) -> None:
        self.ready = work / f"ready-{time.monotonic_ns()}.json"
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tmcl_server", "--tcp", "127.0.0.1:0", "--state-dir",
             str(state), "--ready-file", str(self.ready)],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        endpoints = wait_for_ready(self.proc, self.ready, what="server", poll_s=0.005,
                                   details=lambda: repr(self.proc.communicate()[1]))
        self.host = tcp_host(endpoints["tcp"][0], timeout=10)

    def request(self, opcode: int, type_: int, motor: int, value: int = 0) -> tuple[int, int]:
        _, status, _, result = self.host.send(opcode, type_, motor, value)
        return status, result

    def kill(self) -> None:
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(10)
        self.host.close()
        self.ready.unlink(missing_ok=True)

    def stop(self) -> None:
        self.host.close()
        self.proc.terminate()
        self.proc.wait(10)
        self.ready.unlink(missing_ok=True)


def store_until_killed(server: Server, trial: Trial, counter: int, kill_after: float) -> int:
    """Store ever larger values until another thread kills the server; return the counter."""
    timer = threading.Timer(kill_after, server.kill)
    timer.start()
    try:
        while True:
            for set_op, store_op, type_, motor, _ in SLOTS:
                counter += 1
                key = (type_, motor)
                trial.written.setdefault(key, set()).add(counter)
                status, _ = server.request(set_op, type_, motor, counter)
                if status != STATUS_OK:
                    raise RuntimeError(f"set {key} answered status {status}")
                status, _ = server.request(store_op, type_, motor)
                if status != STATUS_OK:
                    raise RuntimeError(f"store {key} answered status {status}")
                trial.acknowledged[key] = counter
    except (OSError, UploadError):  # UploadError: the killed server closed the connection
        return counter  # the kill
    finally:
        timer.join()


def check(state: Path, work: Path, trial: Trial, before: dict[tuple[int, int], int]) -> list[str]:
    """Problems with the state the kill left behind (empty: the run passed)."""
    problems = []
    path = state / "module-1" / FILE_NAME
    journals = [path.parent / name for name in JOURNAL_NAMES]
    if not path.exists() and not any(j.exists() for j in journals):  # a server keeps a
        return [f"{path} is missing"]  # journal between snapshots (docs/eeprom.md)
    eeprom = Eeprom(path.parent)
    if eeprom.problem:
        return [f"the loader rejects the file: {eeprom.problem}"]
    server = Server(state, work)
    try:
        for _, _, type_, motor, read_op in SLOTS:
            key = (type_, motor)
            status, value = server.request(read_op, type_, motor)
            allowed = trial.written.get(key, set()) | {before[key]}
            if status != STATUS_OK or value not in allowed:
                problems.append(f"{key}: read {value} (status {status}), neither old nor new")
            elif value < trial.acknowledged.get(key, before[key]):
                problems.append(f"{key}: read {value}, but {trial.acknowledged[key]} was "
                                f"acknowledged before the kill")
            before[key] = value
    finally:
        server.stop()
    return problems


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--max-delay", type=float, default=0.3,
                        help="kill at a random instant up to this many seconds into the stores")
    args = parser.parse_args()
    rng = random.Random(args.seed)
    failures, stores, leftovers, torn = 0, 0, 0, 0
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        state = work / "state"
        server = Server(state, work)  # the factory values: the "old" of the first run
        before = {(t, m): server.request(read_op, t, m)[1] for _, _, t, m, read_op in SLOTS}
        server.stop()
        counter = max(before.values())
        for run in range(1, args.runs + 1):
            trial = Trial()
            server = Server(state, work)
            start = counter
            counter = store_until_killed(server, trial, counter, rng.uniform(0.0, args.max_delay))
            stores += counter - start
            torn += len(list((state / "module-1").glob(".eeprom-*")))  # before any restart
            problems = check(state, work, trial, before)
            leftovers = len(list((state / "module-1").glob(".eeprom-*")))  # after a restart
            if leftovers:
                problems.append(f"{leftovers} temporary files left after a restart")
            failures += bool(problems)
            print(f"run {run}/{args.runs}: {counter - start} stores, "
                  f"{'valid' if not problems else '; '.join(problems)}", flush=True)
    summary = {"runs": args.runs, "valid": args.runs - failures, "stores": stores,
               "torn_writes_found": torn,
               "temporary_files_left": leftovers}
    print(json.dumps(summary))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
