#!/usr/bin/env python3
"""Fuzz a real ``tmcl-server`` process over TCP and a pty, checking every reply (issue 11).

    .venv/bin/python scripts/fuzz.py [--frames 1000000] [--seed 1] [--transport tcp|pty|both]
                                     [--duration S] [--avoid known|item1,item2,item3]
                                     [--report FILE] [--stall-ms 50] [--hang-s 10]

Starts ``python -m tmcl_server --tcp 127.0.0.1:0 --pty LINK --state-dir TMP`` and sends
rounds of frames: single commands and bursts of up to 2,000 frames, parameter combinations
(every ramp and reference-search mode with zero and extreme speeds and accelerations followed
by motion), raw register writes (146/147/148), random programs downloaded and run, control
commands, mutated frames (fields, checksums, foreign addresses), random bytes, frames torn
into pieces with pauses under 1 ms (the server must join them) and partial frames followed by
a 30 ms pause (the server must drop them, docs/protocol.md "Frames").

The checker models what the server must see: it cuts the bytes it sends into 9-byte frames
exactly as the server's 5 ms resynchronisation must (joining pieces sent less than 3 ms
apart, dropping a partial frame followed by a deliberate 30 ms pause, sent only once the
server has answered everything before it, so that its own backlog cannot hide the pause).
For every frame the server sees it knows the reply the wire rules demand:

* TCP is an RS-485 link: a frame for another address gets no reply at all, also with a wrong
  checksum; the pty is the module's USB port: every frame is answered.
* a wrong checksum (to the module's address, or any on USB): status 1, opcode 0, value 0;
* otherwise exactly one reply ``[2][1][status][opcode][value][checksum]`` with the request's
  opcode and a status the manual allows for it (tmcl_spec.commands.Status): 2 for an opcode
  the module does not know, 101 (or 9 past the end of memory) for a command stored in
  download mode, 6 for 129/130 in download mode; an error status echoes the value;
* 136 type 0 answers the version string, 134 the program word the checker knows it stored,
  137 with 1234 answers nothing; delayed 138 replies (status 128) may come at any time.

A reply that breaks a rule is a violation (reported with the rounds of frames that led to
it, then the link is resynchronised and the module reset with 137); a reply later than
``--stall-ms`` after it was due (the later of its request's last byte and the previous
reply) is a stall (``stalls_net_of_cpu_wait`` counts those still late once the reply's own
CPU wait is taken out: what the server's event-loop thread waited for a CPU between when the
reply was due and when it was read, from schedstat; ``stalls_net_of_both_cpu_waits`` also
takes out what the fuzzer itself waited meanwhile, and ``stalls_net_server_busy`` counts
those of ``stalls_net_of_cpu_wait`` during which the server's thread ran for more than half
of ``--stall-ms``: late by its own work rather than by the kernel's pty buffers or the
fuzzer's reading); no reply for ``--hang-s`` is a hang (the server is killed and restarted);
a server that exits, or a ``Traceback`` in its standard error, is a crash.  The seed fixes
every frame and pause sent; only the server's timing differs between runs.

The last line on standard output is a JSON summary; ``--report FILE`` writes every finding
with its repro.  Known open problems can be left out with ``--avoid`` (issue 11):
``item1`` (slow ramps: speed/acceleration limits and ROR/ROL speeds below 1,000, the dividers,
raw register writes), ``item2`` (a frame torn right after a big burst), ``item3`` (EEPROM
stores in a program loop), or ``known`` for all three.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import os
import random
import selectors
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import termios
import time
import tty
from collections import Counter, deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from local_server import rss_kb, wait_for_ready

from tmcl_spec.commands import FACTORY_RESET_KEY, Opcode, Status
from tmcl_spec.modules import module_type

PROFILE = module_type()
MODULE_ADDRESS = 1
HOST_ADDRESS = PROFILE.global_parameters[0][76].default
MEMORY = PROFILE.program_memory
KNOWN_OPCODES = frozenset(int(op) for op in PROFILE.commands)
#: Bank-0 globals whose change would alter the link itself (address, host address, secondary
#: address, reply suppression, telegram pause, code protection): the fuzzer never writes them.
PROTECTED_GLOBALS = frozenset({66, 75, 76, 81, 87, 255})
GLOBAL_WRITERS = frozenset({Opcode.SGP, Opcode.STGP, Opcode.RSGP, Opcode.AGP})
#: Opcodes whose 100-reply must echo the request's value (docs/protocol.md "Frames").
ECHOING = frozenset({Opcode.ROR, Opcode.ROL, Opcode.MST, Opcode.SAP, Opcode.SGP})
GENERAL_ERRORS = frozenset({Status.INVALID_COMMAND, Status.WRONG_TYPE, Status.INVALID_VALUE,
                            Status.EEPROM_LOCKED})
KNOWN_ITEMS = ("item1", "item2", "item3")
#: ``--avoid item1``: speed and acceleration limits (max speed, max acceleration, reference
#: search and switch speeds) and ROR/ROL speeds are never below this (0 and small values stall
#: the server: the look-ahead walks a slow ramp one chip tick at a time).
ITEM1_LIMITS = frozenset({4, 5, 194, 195})
ITEM1_FLOOR = 1000
#: ... nor are the pulse and ramp dividers (AP 153, 154) written, nor raw registers (146).
ITEM1_DIVIDERS = frozenset({153, 154})

JOIN_PAUSE_S = 0.0005  # pieces of one frame: well under the 5 ms rule
#: A reply this late makes the fuzzer ask the server for its stacks (SIGUSR1), once per wait.
STACK_SAMPLE_S = 0.2
JOIN_MAX_S = 0.002  # a planned join whose real gap exceeded this is ambiguous: not judged
DROP_PAUSE_S = 0.030  # a partial frame followed by this pause must be dropped
#: A reply outstanding this long while the server used less than IDLE_CPU_NS of CPU is lost.
IDLE_CHECK_S = 0.5
#: A round in which the server's thread waited this long for a CPU is not judged on framing.
STARVED_MS = 2.0
IDLE_CPU_NS = 5_000_000
INT32 = (-0x8000_0000, 0x7FFF_FFFF)


def i32(value: int) -> int:
    value &= 0xFFFF_FFFF
    return value - 0x1_0000_0000 if value & 0x8000_0000 else value


def encode(address: int, opcode: int, type_: int, motor: int, value: int) -> bytes:
    body = struct.pack(">BBBBi", address & 0xFF, opcode & 0xFF, type_ & 0xFF, motor & 0xFF,
                       i32(value))
    return body + bytes((sum(body) & 0xFF,))


def reply_bytes(status: int, opcode: int, value: int) -> bytes:
    body = struct.pack(">BBBBi", HOST_ADDRESS, MODULE_ADDRESS, status, opcode, i32(value))
    return body + bytes((sum(body) & 0xFF,))


# == the generator =============================================================================

EXTREMES = (0, 1, -1, 2, 3, 7, 100, 255, 256, 2047, 2048, 65535, 65536, 0x7FFFFF, 0x800000,
            1 << 24, 1 << 30, INT32[1], INT32[1] - 1, INT32[0], INT32[0] + 1)


@dataclass
class Write:
    """Bytes written in one call, after a pause: ``join`` (< 1 ms, must continue a partial
    frame) or ``drop`` (30 ms, after the server answered everything: a partial is dropped)."""

    data: bytes
    pause: str = "none"  # none | join | drop


@dataclass
class Round:
    kind: str
    stream: str
    writes: list[Write]
    #: What was sent: (pause kind, bytes as hex, real gap before it in ms) per write.
    log: list[tuple[str, str, float]] = field(default_factory=list)


class Generator:
    """Seeded rounds of frames: what is sent never depends on what comes back."""

    def __init__(self, seed: int, streams: list[str], avoid: set[str]) -> None:
        self.rng = random.Random(seed)
        self.streams = streams
        self.avoid = avoid
        self.axis_params = sorted(PROFILE.axis_parameters)
        self.globals = {bank: sorted(n for n in table if not (bank == 0 and n in PROTECTED_GLOBALS))
                        for bank, table in PROFILE.global_parameters.items()}
        kinds = {"single": 30, "burst": 25, "big_burst": 2, "torn": 12, "burst_torn": 1,
                 "resync": 5, "junk": 3, "program": 5, "combo": 12, "control": 2}
        self.kinds = list(kinds)
        self.weights = list(kinds.values())

    # -- values and fields ---------------------------------------------------------------------

    def value_for(self, spec: Any) -> int:
        rng = self.rng
        roll = rng.random()
        if spec is not None:
            if spec.allowed and roll < 0.35:
                return rng.choice(sorted(spec.allowed))
            if roll < 0.7:
                lo, hi = spec.minimum, spec.maximum
                return rng.choice((lo, hi, lo - 1, hi + 1, 0, rng.randint(lo, hi), rng.randint(lo, hi)))
        if roll < 0.9:
            return rng.choice(EXTREMES) * rng.choice((1, 1, -1))
        return rng.randint(*INT32)

    def motor(self) -> int:
        return self.rng.randrange(6) if self.rng.random() < 0.92 else self.rng.randrange(256)

    def axis_param(self) -> int:
        return self.rng.choice(self.axis_params) if self.rng.random() < 0.9 else self.rng.randrange(256)

    def sanitize(self, op: int, type_: int, motor: int, value: int,
                 in_program: bool = False) -> tuple[int, int, int, int]:
        """Keep the link usable (no address change, no reply suppression) and, on request,
        away from the known open problems."""
        if op in GLOBAL_WRITERS and type_ in PROTECTED_GLOBALS:
            type_ = self.rng.choice(self.globals[0])
        if "item1" in self.avoid:  # a low speed (not only 0) makes the look-ahead crawl
            if op == Opcode.SAP and type_ in ITEM1_LIMITS and 0 <= value < ITEM1_FLOOR:
                value = ITEM1_FLOOR + self.rng.randrange(2047)
            if op in (Opcode.ROR, Opcode.ROL) and 0 < abs(value) < ITEM1_FLOOR:
                value = ITEM1_FLOOR + self.rng.randrange(2047)
            if op == Opcode.SAP and type_ in ITEM1_DIVIDERS:
                op = Opcode.GAP
            if op == Opcode.AAP and type_ in ITEM1_LIMITS | ITEM1_DIVIDERS:
                type_ = 0
            if op == Opcode.WRITE_MC:  # a raw write can set any speed or divider
                op = Opcode.READ_MC
        if "item3" in self.avoid and in_program and op in (Opcode.STAP, Opcode.STGP, Opcode.SCO,
                                                           Opcode.SGP, Opcode.AGP):
            op = Opcode.GGP
        return op, type_, motor, value

    def command(self, address: int = MODULE_ADDRESS, in_program: bool = False) -> bytes:
        rng = self.rng
        pick = rng.random()
        if pick < 0.22:
            t = self.axis_param()
            f = (Opcode.SAP, t, self.motor(), self.value_for(PROFILE.axis_parameters.get(t)))
        elif pick < 0.32:
            f = (rng.choice((Opcode.GAP, Opcode.GAP, Opcode.STAP, Opcode.RSAP)), self.axis_param(),
                 self.motor(), 0)
        elif pick < 0.42:
            op = rng.choice((Opcode.ROR, Opcode.ROL, Opcode.MST, Opcode.MVP, Opcode.MVP))
            t = rng.choice((0, 0, 1, 2, rng.randrange(256))) if op == Opcode.MVP else 0
            m = self.motor() if rng.random() < 0.9 else rng.choice((0x80 | rng.randrange(64), 255))
            f = (op, t, m, self.value_for(None))
        elif pick < 0.47:
            f = (Opcode.RFS, rng.choice((0, 1, 2, 2, rng.randrange(256))), self.motor(), 0)
        elif pick < 0.58:
            bank = rng.choice((0, 2, 2, 3, rng.randrange(256)))
            numbers = self.globals.get(bank) or [rng.randrange(256)]
            t = rng.choice(numbers)
            spec = PROFILE.global_parameters.get(bank, {}).get(t)
            op = rng.choice((Opcode.SGP, Opcode.SGP, Opcode.GGP, Opcode.GGP, Opcode.STGP, Opcode.RSGP))
            f = (op, t, bank, self.value_for(spec) if op == Opcode.SGP else 0)
        elif pick < 0.63:
            op = rng.choice((Opcode.SIO, Opcode.GIO))
            f = (op, rng.randrange(10), rng.choice((0, 1, 2, 2, rng.randrange(256))),
                 rng.choice((0, 1, 2, -1)))
        elif pick < 0.69:
            op = rng.choice((Opcode.CALC, Opcode.CALCX, Opcode.COMP, Opcode.CLE, Opcode.EI, Opcode.DI,
                             Opcode.AAP, Opcode.AGP, Opcode.ACO, Opcode.JA, Opcode.JC, Opcode.WAIT,
                             Opcode.STOP, Opcode.RSUB, Opcode.RETI, Opcode.VECT, Opcode.CSUB))
            f = (op, rng.randrange(14) if rng.random() < 0.9 else rng.randrange(256), self.motor(),
                 self.value_for(None))
        elif pick < 0.74:
            op = rng.choice((Opcode.SCO, Opcode.GCO, Opcode.CCO))
            f = (op, rng.randrange(22) if rng.random() < 0.9 else rng.randrange(256),
                 rng.choice((0, 1, 5, 255, self.motor())), self.value_for(None))
        elif pick < 0.80:
            op = rng.choice((Opcode.WRITE_MC, Opcode.WRITE_MC, Opcode.READ_MC, Opcode.READ_MC_PYTRINAMIC))
            f = (op, rng.randrange(0x80) if rng.random() < 0.9 else rng.randrange(256), self.motor(),
                 self.value_for(None))
        elif pick < 0.86 and not in_program:
            op = rng.choice((128, 129, 130, 131, 134, 135, 135, 136, 136, 138, 138, 137))
            t = rng.choice((0, 1, rng.randrange(256)))
            value = self.value_for(None)
            if op == 137 and rng.random() < 0.01:
                value = FACTORY_RESET_KEY
            elif op == 138:
                value = rng.randrange(64)
            elif op == 134:
                value = rng.randrange(64) if rng.random() < 0.8 else value
            f = (op, t, self.motor(), value)
        elif pick < 0.89:
            f = (rng.randrange(64, 72), rng.randrange(256), rng.randrange(256), self.value_for(None))
        elif pick < 0.92:
            f = (rng.randrange(256), rng.randrange(256), rng.randrange(256), self.value_for(None))
        else:
            f = (Opcode.GAP, rng.choice((0, 1, 2, 3, 8, 206)), self.motor(), 0)
        op, t, m, v = self.sanitize(int(f[0]), int(f[1]), int(f[2]), int(f[3]), in_program)
        if not in_program and op in (132, 133) and rng.random() < 0.9:
            op = Opcode.GAP  # download mode belongs to program rounds (mostly)
        return encode(address, op, t, m, v)

    def mutated(self, stream: str) -> bytes:
        """A frame as a noisy line or a confused host sends it."""
        rng = self.rng
        frame = bytearray(self.command())
        roll = rng.random()
        if roll < 0.08:  # wrong checksum
            frame[8] = (frame[8] + rng.randrange(1, 256)) & 0xFF
        elif roll < 0.12:  # another address (silence on RS-485)
            others = [a for a in (0, 2, 3, 255, rng.randrange(256)) if a != MODULE_ADDRESS]
            frame[0] = rng.choice(others)
            if rng.random() < 0.3:
                frame[8] = (frame[8] + 1) & 0xFF
        elif roll < 0.16:  # one field changed, checksum right
            frame[rng.randrange(1, 8)] = rng.randrange(256)
            op, t, m, v = self.sanitize(frame[1], frame[2], frame[3], i32(int.from_bytes(frame[4:8], "big")))
            frame[:] = encode(frame[0], op, t, m, v)
        elif roll < 0.18:  # noise
            frame = bytearray(rng.randbytes(9))
        return bytes(frame)

    def frames(self, count: int, stream: str) -> bytes:
        return b"".join(self.mutated(stream) for _ in range(count))

    # -- rounds --------------------------------------------------------------------------------

    def round(self) -> Round:
        rng = self.rng
        stream = rng.choice(self.streams)
        kind = rng.choices(self.kinds, self.weights)[0]
        writes: list[Write]
        if kind == "single":
            writes = [Write(self.mutated(stream))]
        elif kind == "burst":
            data = self.frames(rng.randint(2, 40), stream)
            cut = sorted(rng.sample(range(1, len(data)), min(3, len(data) - 1))) if rng.random() < 0.3 else []
            pieces = [data[a:b] for a, b in zip([0, *cut], [*cut, len(data)], strict=True)]
            writes = [Write(p, "join" if i else "none") for i, p in enumerate(pieces)]
        elif kind == "big_burst":
            writes = [Write(self.frames(rng.randint(100, 2000), stream))]
        elif kind == "torn":
            head = self.frames(rng.randint(0, 5), stream)
            frame = self.mutated(stream)
            cuts = sorted(rng.sample(range(1, 9), rng.randint(1, 3)))
            pieces = [frame[a:b] for a, b in zip([0, *cuts], [*cuts, 9], strict=True)]
            pieces[0] = head + pieces[0]
            writes = [Write(p, "join" if i else "none") for i, p in enumerate(pieces)]
            if rng.random() < 0.5:
                writes.append(Write(self.frames(rng.randint(1, 5), stream), "join"))
        elif kind == "burst_torn":  # issue 11 item 2: a burst, the start of a frame, 1 ms, the rest
            burst = self.frames(rng.randint(500, 2000), stream)
            frame = self.mutated(stream)
            k = rng.randint(1, 8)
            if "item2" in self.avoid:
                writes = [Write(burst), Write(frame[:k], "drop"), Write(frame[k:], "join")]
            else:
                writes = [Write(burst + frame[:k]), Write(frame[k:], "join")]
        elif kind == "resync":
            junk = rng.randbytes(rng.randint(1, 8))
            head = self.frames(rng.randint(0, 4), stream)
            writes = [Write(head + junk), Write(self.frames(rng.randint(1, 6), stream), "drop")]
        elif kind == "junk":
            writes = [Write(rng.randbytes(rng.randint(5, 200)))]
            if rng.random() < 0.5:
                writes.append(Write(self.frames(rng.randint(1, 4), stream), "join"))
            writes.append(Write(self.frames(rng.randint(1, 4), stream), "drop"))
        elif kind == "program":
            writes = [Write(self.program(stream))]
        elif kind == "combo":
            writes = [Write(self.combo())]
        else:  # control
            op = rng.choice((128, 129, 130, 131, 135, 136, 137, 138))
            value = FACTORY_RESET_KEY if op == 137 and rng.random() < 0.3 else rng.randrange(64)
            writes = [Write(encode(MODULE_ADDRESS, op, rng.randrange(3), 0, value))]
        return Round(kind, stream, writes)

    def program(self, stream: str) -> bytes:
        """Download random bytecode (mostly real instructions), maybe run it."""
        rng = self.rng
        length = rng.randint(1, 60)
        start = 0 if rng.random() < 0.8 else rng.choice((rng.randrange(MEMORY), MEMORY - 2))
        parts = [encode(MODULE_ADDRESS, 132, 0, 0, start)]
        for _ in range(length):
            if rng.random() < 0.15:
                f = (Opcode.JA, 0, 0, start + rng.randrange(length))
            elif rng.random() < 0.1:
                f = (Opcode.WAIT, 0, 0, rng.randrange(20))
            elif rng.random() < 0.05:
                body = rng.randbytes(8)
                f = (body[1], body[2], body[3], i32(int.from_bytes(body[4:8], "big")))
            else:
                raw = self.command(in_program=True)
                f = (raw[1], raw[2], raw[3], i32(int.from_bytes(raw[4:8], "big")))
            op, t, m, v = self.sanitize(int(f[0]), int(f[1]), int(f[2]), int(f[3]), in_program=True)
            parts.append(encode(MODULE_ADDRESS, op, t, m, v))
        parts.append(encode(MODULE_ADDRESS, 133, 0, 0, 0))
        if rng.random() < 0.7:
            parts.append(encode(MODULE_ADDRESS, 129, rng.choice((0, 0, 1)), 0, start))
            parts += [encode(MODULE_ADDRESS, Opcode.GAP, 1, rng.randrange(6), 0)
                      for _ in range(rng.randint(0, 8))]
            parts.append(encode(MODULE_ADDRESS, 135, 0, 0, 0))
            if rng.random() < 0.6:
                parts.append(encode(MODULE_ADDRESS, 128, 0, 0, 0))
        return b"".join(parts)

    def combo(self) -> bytes:
        """Ramp / reference-search mode with zero and extreme limits, then a motion command."""
        rng = self.rng
        m = rng.randrange(6)
        ap = PROFILE.axis_parameters
        frames = []
        for number in (138, 193, 4, 5, 130, 194, 195, 153, 154, 140):
            if number in ap and rng.random() < 0.6:
                spec = ap[number]
                value = (rng.choice(sorted(spec.allowed)) if spec.allowed and rng.random() < 0.8
                         else rng.choice((0, 1, spec.minimum, spec.maximum, spec.maximum + 1,
                                          rng.randint(spec.minimum, spec.maximum))))
                op, t, mm, v = self.sanitize(Opcode.SAP, number, m, value)
                frames.append(encode(MODULE_ADDRESS, op, t, mm, v))
        move = rng.choice((
            (Opcode.ROL, 0, m, rng.choice((1, 2047, 2048, INT32[1], INT32[0]))),
            (Opcode.ROR, 0, m, rng.choice((1, 2047, 2048, INT32[1], -1))),
            (Opcode.MVP, 0, m, rng.choice((0, 1, -1, INT32[1], INT32[0], 1000))),
            (Opcode.MVP, 1, m, rng.choice((1, -1, 1000, INT32[1], INT32[0]))),
            (Opcode.RFS, 0, m, 0)))
        frames.append(encode(MODULE_ADDRESS, *move))
        for _ in range(rng.randint(0, 4)):
            frames.append(encode(MODULE_ADDRESS, Opcode.GAP, rng.choice((1, 3, 8, 206)), m, 0))
        if rng.random() < 0.3:
            frames.append(encode(MODULE_ADDRESS, Opcode.RFS, 2, m, 0))
        if rng.random() < 0.5:
            frames.append(encode(MODULE_ADDRESS, Opcode.MST, 0, m, 0))
        return b"".join(frames)


# == the checker's model of the module =========================================================

@dataclass
class ModuleModel:
    """What the checker must know to predict replies: download mode and program memory."""

    downloading: bool = False
    address: int = 0
    program_started: bool = False  # 129 or 130 was accepted since the last 128/131/137
    memory: dict[int, tuple[int, int, int, int]] = field(default_factory=dict)

    def reset(self) -> None:
        self.program_started = False
        self.downloading = False
        self.address = 0
        self.memory.clear()


@dataclass
class Expect:
    frame: bytes
    want: bytes | None  # exact reply, or None: judged by ``rule``
    rule: str = ""  # "status" (any allowed status), "lenient" (any well-formed reply)
    allowed: frozenset[int] = frozenset()
    echo: bool = False
    end: int = 0  # stream offset of the frame's last byte
    sent: float = 0.0
    #: (the server's, our own) time waited for a CPU so far, when the frame was sent
    waits_at_sent: tuple[int, int, int] = (0, 0, 0)


def expect_for(frame: bytes, rs485: bool, model: ModuleModel) -> tuple[Expect | None, bool]:
    """The reply a server-seen frame must get (None: silence), and whether the frame changes
    the link in ways the model does not follow (the module is then reset after the round)."""
    if rs485 and frame[0] != MODULE_ADDRESS:
        return None, False
    if sum(frame[:8]) & 0xFF != frame[8]:
        return Expect(frame, reply_bytes(Status.WRONG_CHECKSUM, 0, 0)), False
    op, t, m = frame[1], frame[2], frame[3]
    value = i32(int.from_bytes(frame[4:8], "big"))
    if op < 128 and model.downloading:
        if model.address >= MEMORY:
            return Expect(frame, reply_bytes(Status.MAX_EXCEEDED, op, value)), False
        model.memory[model.address] = (op, t, m, value)
        model.address += 1
        # a stored write of a protected global (only noise does that) may run later: reset
        return (Expect(frame, reply_bytes(Status.LOADED, op, value)),
                op in GLOBAL_WRITERS and t in PROTECTED_GLOBALS)
    if op in GLOBAL_WRITERS and t in PROTECTED_GLOBALS:
        return Expect(frame, None, "lenient"), True  # only from noise: reset afterwards
    if op not in KNOWN_OPCODES:
        return Expect(frame, reply_bytes(Status.INVALID_COMMAND, op, value)), False
    if op == Opcode.RESTORE_FACTORY_SETTINGS:
        if value == FACTORY_RESET_KEY:
            model.reset()
            return None, False
        return Expect(frame, reply_bytes(Status.INVALID_VALUE, op, value)), False
    if op == Opcode.GET_FIRMWARE_VERSION:
        if t == 0:
            return Expect(frame, bytes((HOST_ADDRESS,)) + PROFILE.version_string), False
        if t == 1:
            major, minor = PROFILE.firmware
            version = PROFILE.module_number << 16 | major << 8 | minor
            return Expect(frame, reply_bytes(100, op, version)), False
        return Expect(frame, reply_bytes(Status.WRONG_TYPE, op, value)), False
    if op == Opcode.ENTER_DOWNLOAD_MODE:
        if 0 <= value < MEMORY:
            model.downloading, model.address = True, value
            return Expect(frame, reply_bytes(100, op, value)), False
        return Expect(frame, reply_bytes(Status.INVALID_VALUE, op, value)), False
    if op == Opcode.EXIT_DOWNLOAD_MODE:
        model.downloading = False
        return Expect(frame, reply_bytes(100, op, value)), False
    if op == Opcode.READ_PROGRAM_MEMORY:
        if 0 <= value < MEMORY:
            word = model.memory.get(value, (0, 0, 0, 0))
            body = struct.pack(">BBBBi", HOST_ADDRESS, *word[:3], word[3])
            return Expect(frame, body[:8] + bytes((sum(body[:8]) & 0xFF,))), False
        return Expect(frame, reply_bytes(Status.INVALID_VALUE, op, value)), False
    if op in (Opcode.RUN_APPLICATION, Opcode.STEP_APPLICATION):
        if model.downloading:
            return Expect(frame, reply_bytes(Status.COMMAND_NOT_AVAILABLE, op, value)), False
        model.program_started = True
    if op in (Opcode.STOP_APPLICATION, Opcode.RESET_APPLICATION):
        model.program_started = False
    return Expect(frame, None, "status", GENERAL_ERRORS | {100}, op in ECHOING), False


def judge(exp: Expect, got: bytes) -> str | None:
    """Why ``got`` breaks the rules for ``exp`` (None: it is right)."""
    if exp.want is not None:
        return None if got == exp.want else f"expected {exp.want.hex(' ')}"
    if sum(got[:8]) & 0xFF != got[8]:
        return "reply checksum wrong"
    if exp.rule == "lenient":
        return None
    if got[0] != HOST_ADDRESS or got[1] != MODULE_ADDRESS:
        return f"reply addressed {got[0]}<-{got[1]}, expected {HOST_ADDRESS}<-{MODULE_ADDRESS}"
    if got[3] != exp.frame[1]:
        return f"reply opcode {got[3]} for request opcode {exp.frame[1]}"
    status = got[2]
    if status not in exp.allowed:
        return f"status {status} not allowed for opcode {exp.frame[1]}"
    if (status != 100 or exp.echo) and got[4:8] != exp.frame[4:8]:
        return f"status {status}: value {got[4:8].hex()} does not echo {exp.frame[4:8].hex()}"
    return None


def is_event(chunk: bytes) -> bool:
    return (len(chunk) == 9 and chunk[2] == Status.TARGET_REACHED_EVENT
            and chunk[3] == Opcode.TARGET_REACHED_EVENT and sum(chunk[:8]) & 0xFF == chunk[8]
            and chunk[0] == HOST_ADDRESS and chunk[1] == MODULE_ADDRESS)


# == the server process and its links ==========================================================

class Hang(Exception):
    pass


#: The module run as the server (``--server-module``: a wrapper that instruments it), and the
#: checkout it runs from (``--server-root``: e.g. a worktree of main, for a baseline).
SERVER_MODULE = ["tmcl_server"]
SERVER_ROOT = [Path(__file__).resolve().parent.parent]


class ServerProcess:
    def __init__(self, workdir: Path, index: int) -> None:
        self.dir = workdir / f"server-{index}"
        self.dir.mkdir()
        self.link = self.dir / "ttyFUZZ"
        ready = self.dir / "ready.json"
        self.stderr_path = self.dir / "stderr.log"
        self.stderr = open(self.stderr_path, "wb")  # noqa: SIM115 (closed in stop)
        self.proc = subprocess.Popen(
            # -X faulthandler: a hung server dumps its threads' stacks on SIGABRT (see stack())
            [sys.executable, "-X", "faulthandler", "-m", SERVER_MODULE[0], "--tcp", "127.0.0.1:0",
             "--pty", str(self.link),
             "--state-dir", str(self.dir / "state"), "--ready-file", str(ready)],
            stdout=subprocess.DEVNULL, stderr=self.stderr, cwd=str(SERVER_ROOT[0]),
            env={**os.environ, "PYTHONPATH": os.pathsep.join(
                [str(SERVER_ROOT[0]), *filter(None, [os.environ.get("PYTHONPATH")])])})
        endpoints = wait_for_ready(self.proc, ready, what="server",
                                   details=self.stderr_path.read_text)
        host, port = endpoints["tcp"][0].rsplit(":", 1)
        self.tcp = (host, int(port))

    def rss_kb(self) -> int:
        return rss_kb(self.proc.pid)

    def run_delay_ns(self) -> int:
        """How long the server's event-loop thread has waited for a CPU (schedstat), 0 if unknown.

        A partial frame the server reads while the machine starves it looks, to the server, like
        a pause on the line: the checker does not blame it for that."""
        try:
            return int(Path(f"/proc/{self.proc.pid}/task/{self.proc.pid}/schedstat").read_text().split()[1])
        except (OSError, IndexError, ValueError):
            return 0

    def cpu_ns(self) -> int:
        """CPU time the server's event-loop thread has used (schedstat), 0 if unknown."""
        try:
            return int(Path(f"/proc/{self.proc.pid}/task/{self.proc.pid}/schedstat").read_text().split()[0])
        except (OSError, IndexError, ValueError):
            return 0

    def fds(self) -> int:
        return len(os.listdir(f"/proc/{self.proc.pid}/fd"))

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, kill: bool = False) -> int | None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL if kill else signal.SIGTERM)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.stderr.close()
        return self.proc.returncode

    def stack(self) -> str:
        """Where a hung server is: its threads' Python stacks (faulthandler, on SIGABRT)."""
        if self.proc.poll() is not None:
            return ""
        self.proc.send_signal(signal.SIGABRT)
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            return ""
        text = self.stderr_text()
        at = text.rfind("Fatal Python error")
        return text[at:at + 4000] if at >= 0 else ""

    def stderr_text(self) -> str:
        return self.stderr_path.read_text(errors="replace")

    def sample_stack(self) -> None:
        """Ask a busy server where it is: tmcl-server prints its stacks on SIGUSR1."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGUSR1)


def own_run_delay_ns() -> int:
    """How long this thread has waited for a CPU (schedstat), 0 if unknown."""
    try:
        return int(Path("/proc/thread-self/schedstat").read_text().split()[1])
    except (OSError, IndexError, ValueError):
        return 0


def stall_stacks(text: str, depth: int = 8) -> list[str]:
    """The innermost frames of each stack a server printed on SIGUSR1, one string per dump."""
    stacks = []
    for block in text.split("Current thread ")[1:]:
        frames = [line.strip() for line in block.splitlines()[1:] if line.strip().startswith("File ")]
        stacks.append(" <- ".join(f.split('"')[1].rsplit("/", 2)[-1] + ":" + f.split("line ")[1]
                                  for f in frames[:depth] if '"' in f and "line " in f))
    return stacks


class Link:
    """One byte stream to the server (a TCP connection or the pty), non-blocking."""

    def __init__(self, name: str, fd: int, rs485: bool, closer: Any) -> None:
        self.name = name
        self.fd = fd
        self.rs485 = rs485
        self._closer = closer
        os.set_blocking(fd, False)
        self.inbox = bytearray()
        self.partial = b""  # bytes of a partial frame the server holds (the model's view)
        self.pending = 0
        self.broken = False  # a violation: stop, resynchronise
        self.joined = False  # this round continued a partial frame
        self.needs_drop = False  # a partial was left: the next round starts after a pause
        self.ambiguous = False  # a planned join took too long: mismatches are not judged
        self.offset = 0  # bytes written so far
        self.last_write = 0.0

    @classmethod
    def tcp(cls, address: tuple[str, int]) -> Link:
        sock = socket.create_connection(address)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return cls("tcp", sock.fileno(), True, sock.close)

    @classmethod
    def pty(cls, path: Path) -> Link:
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(fd)
        termios.tcflush(fd, termios.TCIOFLUSH)
        return cls("pty", fd, False, lambda: os.close(fd))

    def close(self) -> None:
        self._closer()


# == the run ===================================================================================

@dataclass
class Stats:
    frames: int = 0  # complete frames the server saw (the model's view)
    bytes_sent: int = 0
    replies_checked: int = 0
    silent_checked: int = 0  # frames that must get no reply
    events: int = 0  # delayed 138 replies
    rounds: int = 0
    torn: int = 0
    dropped_partials: int = 0
    ambiguous_rounds: int = 0
    ambiguous_mismatches: int = 0
    starved_mismatches: int = 0  # a torn frame misread while the OS kept the server off the CPU
    torn_mismatches: int = 0  # a mismatch in a round that joined a torn frame (nobody late)
    torn_rounds: int = 0  # rounds that joined a torn frame
    stalls: int = 0
    stalls_with_program: int = 0  # while a program the fuzzer started may be running
    stalls_starved: int = 0  # the server waited for a CPU for over half the stall
    #: late by more than --stall-ms once the reply's own CPU wait (what the server's
    #: event-loop thread waited for a CPU between when it was due and when we read it) is
    #: taken out
    stalls_net: int = 0
    #: ... and also once what the fuzzer waited for a CPU meanwhile is taken out (the two
    #: waits may overlap, so this count errs towards excusing)
    stalls_net_both: int = 0
    #: ... of stalls_net, those during which the server's loop thread ran more than half of
    #: --stall-ms (its own work made them late, not the kernel's pty buffers or our reading)
    stalls_net_busy: int = 0
    max_net_latency_ms: float = 0.0
    max_latency_ms: float = 0.0
    latencies: list[float] = field(default_factory=list)  # a sample for percentiles
    by_kind: dict[str, int] = field(default_factory=dict)


class Fuzzer:
    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.avoid: set[str] = set()
        for item in (args.avoid or "").split(","):
            item = item.strip()
            if item == "known":
                self.avoid |= set(KNOWN_ITEMS)
            elif item:
                self.avoid.add(item)
        streams = ["tcp", "pty"] if args.transport == "both" else [args.transport]
        self.gen = Generator(args.seed, streams, self.avoid)
        self.stats = Stats()
        self.model = ModuleModel()
        self.violations: list[dict[str, Any]] = []
        self.excused: list[dict[str, Any]] = []  # mismatches while the server was starved
        self.starved_ms = 0.0  # how long the server waited for a CPU between our last two reads
        self.delay_at_read = 0
        #: cpu_waits() at our last read and at the one before it
        self.waits_at_read: tuple[int, int, int] = (0, 0, 0)
        self.waits_prev_read: tuple[int, int, int] = (0, 0, 0)
        self.torn_mismatches: list[dict[str, Any]] = []
        self.round_delay_start = 0
        self.stall_list: list[dict[str, Any]] = []
        #: Where the server was when a reply was late by STACK_SAMPLE_S (stack -> times seen).
        self.stall_stacks: Counter[str] = Counter()
        self.hangs: list[dict[str, Any]] = []
        self.crashes: list[dict[str, Any]] = []
        self.history: deque[Round] = deque(maxlen=args.history)
        self.tmp = tempfile.TemporaryDirectory(prefix="tmcl-fuzz-")
        self.workdir = Path(self.tmp.name)
        self.servers = 0
        self.server: ServerProcess | None = None
        self.links: dict[str, Link] = {}
        self.sel = selectors.DefaultSelector()
        self.stderr_bytes = 0
        self.tracebacks = 0
        self.rss_start = self.fds_start = 0
        self.last_start = (0, 0, 0)  # RSS, descriptors and frames when the last server started
        self.rss_peak = 0
        self.needs_reset = False
        #: Frames the module executed since it started or was last reset (for reductions).
        self.journal: list[tuple[float, bytes]] = []

    # -- server lifecycle ----------------------------------------------------------------------

    def start_server(self) -> None:
        self.servers += 1
        self.server = ServerProcess(self.workdir, self.servers)
        self.links = {"tcp": Link.tcp(self.server.tcp), "pty": Link.pty(self.server.link)}
        self.model.reset()
        self.journal = []

    def stop_server(self, kill: bool = False) -> None:
        for link in self.links.values():
            link.close()
        self.links = {}
        if self.server is not None:
            self.server.stop(kill)
            text = self.server.stderr_text()
            self.stderr_bytes += len(text.encode())
            self.stall_stacks.update(stall_stacks(text.split("Fatal Python error")[0]))
            self.tracebacks += text.count("Traceback")  # (a faulthandler dump says "Stack")
            self.server = None

    def restart(self, reason: str) -> None:
        self.stop_server(kill=True)
        self.start_server()
        assert self.server is not None
        time.sleep(0.2)
        self.last_start = (self.server.rss_kb(), self.server.fds(), self.stats.frames)
        print(f"fuzz: server restarted ({reason})", file=sys.stderr)

    # -- one round -----------------------------------------------------------------------------

    def run_round(self, rnd: Round) -> None:
        link = self.links[rnd.stream]
        link.ambiguous = False
        link.joined = False
        assert self.server is not None
        self.round_delay_start = self.server.run_delay_ns()
        queue: deque[Expect] = deque()
        prev_arrival = 0.0
        log = rnd.log
        for w in rnd.writes:
            if link.broken:
                break
            if w.pause == "drop":
                self.wait_replies(link, queue, rnd, prev_arrival, log)  # the server is idle now
                prev_arrival = 0.0
                time.sleep(DROP_PAUSE_S)
                if link.pending:
                    self.stats.dropped_partials += 1
                    link.partial, link.pending = b"", 0
            elif w.pause == "join":
                time.sleep(JOIN_PAUSE_S)
            gap = time.monotonic() - link.last_write
            continues_frame = bool(link.pending)
            if link.pending:
                self.stats.torn += 1
                link.joined = True
                if gap > JOIN_MAX_S:
                    link.ambiguous = True
            log.append((w.pause, w.data.hex(), round(gap * 1000, 2)))
            # the model: which frames does the server see, and what must each get?
            start = link.offset - link.pending
            stream_bytes = link.partial + w.data
            n = len(stream_bytes) // 9
            for i in range(n):
                frame = stream_bytes[i * 9:(i + 1) * 9]
                exp, dangerous = expect_for(frame, link.rs485, self.model)
                self.needs_reset |= dangerous
                self.stats.frames += 1
                if exp is None:
                    self.stats.silent_checked += 1
                    if frame[1] == Opcode.RESTORE_FACTORY_SETTINGS and (
                            not link.rs485 or frame[0] == MODULE_ADDRESS):
                        self.journal.clear()  # a factory reset: what came before no longer matters
                    continue
                exp.end = start + (i + 1) * 9
                queue.append(exp)
                if exp.want is None or exp.want[2] != Status.WRONG_CHECKSUM:
                    self.journal.append((time.monotonic(), frame))
            link.partial = stream_bytes[n * 9:]
            link.pending = len(link.partial)
            self.send(link, w.data, queue, start, continues_frame)
            prev_arrival = self.read_available(link, queue, rnd, prev_arrival, log)
        if link.pending:
            link.needs_drop = True
        self.wait_replies(link, queue, rnd, prev_arrival, log)
        if link.ambiguous:
            self.stats.ambiguous_rounds += 1
        elif link.joined:
            self.stats.torn_rounds += 1
        self.history.append(rnd)

    def send(self, link: Link, data: bytes, queue: deque[Expect], start: int,
             continues_frame: bool = False) -> None:
        """Write all of ``data``, reading replies meanwhile; ``start``: where the frame the data
        begins in starts in the stream (a full link may cut a write inside a frame);
        ``continues_frame``: the data goes on with a frame an earlier write began."""
        view = memoryview(data)
        base = link.offset
        written = 0
        last = time.monotonic()
        while written < len(data):
            try:
                before = time.monotonic()
                if written and (base + written - start) % 9 and before - last > JOIN_MAX_S:
                    link.ambiguous = True  # we paused inside a frame (a full link, a busy CPU)
                if not written and continues_frame and before - link.last_write > JOIN_MAX_S:
                    # the join was planned short, but this process got the CPU back too late
                    # (the gap the round logs is taken before the model's work): the server
                    # may rightly have dropped the piece before (seen: 5.5 ms, seed 9)
                    link.ambiguous = True
                written += os.write(link.fd, view[written:])
                last = time.monotonic()
            except BlockingIOError:
                if time.monotonic() - last > self.args.hang_s:  # the server stopped reading
                    raise Hang(f"the server read nothing for {self.args.hang_s:g} s") from None
                self.sel_wait(link, writable=True)
                self.read_available(link, queue, None, None, None)
                continue
            except OSError as exc:
                raise Hang(f"write failed: {exc}") from exc
            now = time.monotonic()
            waits: tuple[int, int, int] | None = None
            for exp in queue:
                if not exp.sent and exp.end <= base + written:
                    exp.sent = now
                    exp.waits_at_sent = waits = waits or self.cpu_waits()
        link.offset += len(data)
        link.last_write = time.monotonic()
        self.stats.bytes_sent += len(data)

    def sel_wait(self, link: Link, writable: bool = False, timeout: float = 0.05) -> None:
        events = selectors.EVENT_READ | (selectors.EVENT_WRITE if writable else 0)
        key = self.sel.register(link.fd, events)
        try:
            self.sel.select(timeout)
        finally:
            self.sel.unregister(key.fd)

    def read_available(self, link: Link, queue: deque[Expect], rnd: Round | None,
                       prev_arrival: float | None, log: Any) -> float:
        prev = prev_arrival or 0.0
        try:
            data = os.read(link.fd, 65536)
        except (BlockingIOError, InterruptedError):
            return prev
        except OSError as exc:
            raise Hang(f"read failed: {exc}") from exc
        if not data:
            raise Hang("connection closed by the server")
        now = time.monotonic()
        link.inbox += data
        waits = self.cpu_waits()
        delay = waits[0]
        self.starved_ms = (delay - self.delay_at_read) / 1e6  # since the previous read
        self.delay_at_read = delay
        self.waits_prev_read, self.waits_at_read = self.waits_at_read, waits
        return self.consume(link, queue, now, prev, rnd, log)

    def cpu_waits(self) -> tuple[int, int, int]:
        """How long the server's event-loop thread and our own thread have waited for a CPU
        so far, and how long the server's thread has run (schedstat, ns): a reply's share of
        the waits is no lateness of the server's, and what the server ran says whether it was
        busy meanwhile or had nothing to do (the kernel's pty buffers, our own reading)."""
        if self.server is None:
            return 0, own_run_delay_ns(), 0
        return self.server.run_delay_ns(), own_run_delay_ns(), self.server.cpu_ns()

    def consume(self, link: Link, queue: deque[Expect], now: float, prev: float,
                rnd: Round | None, log: Any) -> float:
        inbox = link.inbox
        while len(inbox) >= 9:
            chunk = bytes(inbox[:9])
            if is_event(chunk) and (not queue or queue[0].want != chunk):
                del inbox[:9]
                self.stats.events += 1
                continue
            if not queue:
                self.violation(link, rnd, None, chunk, "a reply nobody asked for", log)
                return now
            exp = queue.popleft()
            del inbox[:9]
            problem = judge(exp, chunk)
            if problem is not None:
                queue.clear()
                self.violation(link, rnd, exp, chunk, problem, log)
                return now
            self.stats.replies_checked += 1
            prev_in = prev
            due = max(exp.sent or now, prev)
            latency = now - due
            prev = now
            if latency > self.stats.max_latency_ms / 1000:
                self.stats.max_latency_ms = latency * 1000
            if self.stats.replies_checked % 50 == 0:
                self.stats.latencies.append(latency)
            # the reply's own CPU wait: the server's and ours between when it was due and now
            base = exp.waits_at_sent if exp.sent and exp.sent >= prev_in else self.waits_prev_read
            server_wait = max(0, self.waits_at_read[0] - base[0]) / 1e9
            own_wait = max(0, self.waits_at_read[1] - base[1]) / 1e9
            server_ran = max(0, self.waits_at_read[2] - base[2]) / 1e9
            net = latency - server_wait  # the fuzzer's own wait is reported, not taken out
            if net > self.stats.max_net_latency_ms / 1000:
                self.stats.max_net_latency_ms = net * 1000
            if net * 1000 > self.args.stall_ms:
                self.stats.stalls_net += 1
                if server_ran * 1000 > self.args.stall_ms / 2:  # it was busy for most of it
                    self.stats.stalls_net_busy += 1
                if (net - own_wait) * 1000 > self.args.stall_ms:  # nor were we late to read it
                    self.stats.stalls_net_both += 1
            if latency * 1000 > self.args.stall_ms:
                self.stats.stalls += 1
                if self.starved_ms > latency * 1000 / 2:  # the OS kept the server off the CPU
                    self.stats.stalls_starved += 1
                if self.model.program_started:
                    self.stats.stalls_with_program += 1
                if len(self.stall_list) < 200:
                    self.stall_list.append({
                        "latency_ms": round(latency * 1000, 1), "stream": link.name,
                        "at_monotonic_s": round(now, 4),  # to match a server-side log
                        "server_waited_for_cpu_ms": round(self.starved_ms, 1),
                        "reply_cpu_wait_ms": {"server": round(server_wait * 1000, 1),
                                              "fuzzer": round(own_wait * 1000, 1)},
                        "server_ran_ms": round(server_ran * 1000, 1),
                        "net_latency_ms": round(net * 1000, 1),
                        "frame": exp.frame.hex(" "), "round": self.stats.rounds,
                        "program": self.model.program_started,
                        "program_words": ([[a, *w] for a, w in sorted(self.model.memory.items())]
                                          if self.model.program_started else []),
                        "repro": self.repro(rnd, log)})
        return prev

    def wait_replies(self, link: Link, queue: deque[Expect], rnd: Round, prev: float,
                     log: Any = None) -> None:
        last_progress = time.monotonic()
        count = len(queue)
        assert self.server is not None
        cpu, waited = self.server.cpu_ns(), self.server.run_delay_ns()
        sampled = False
        while queue and not link.broken:
            self.sel_wait(link, timeout=0.05)
            prev = self.read_available(link, queue, rnd, prev, log)
            now = time.monotonic()
            if len(queue) != count:
                count, last_progress = len(queue), now
                cpu, waited = self.server.cpu_ns(), self.server.run_delay_ns()
            elif not sampled and now - last_progress > STACK_SAMPLE_S:
                self.server.sample_stack()  # a long stall in the making: where is the server?
                sampled = True
            elif now - last_progress > IDLE_CHECK_S:
                if link.ambiguous:
                    # we paused longer than a join inside a frame: the server may rightly have
                    # dropped the fragment, so no reply is owed (counted as ambiguous, not a hang)
                    self.violation(link, rnd, queue[0], b"", "no reply after a late piece", log)
                    queue.clear()
                    return
                used = self.server.cpu_ns() - cpu
                kept_off = self.server.run_delay_ns() - waited
                if 0 <= used < IDLE_CPU_NS and kept_off < IDLE_CPU_NS:
                    # neither running nor waiting for a CPU, and it owes us a reply: lost
                    self.violation(link, rnd, queue[0], b"", "no reply, the server is idle", log)
                    queue.clear()
                    return
                cpu, waited = cpu + used, waited + kept_off
                if now - last_progress > self.args.hang_s:
                    raise Hang(f"no reply for {self.args.hang_s:g} s, {len(queue)} outstanding "
                               f"(next: {queue[0].frame.hex(' ')})")

    def repro(self, rnd: Round | None, log: Any) -> list[dict[str, Any]]:
        rounds = list(self.history)[-self.args.repro_rounds:]
        out = [{"stream": r.stream, "kind": r.kind, "writes": r.log} for r in rounds]
        if rnd is not None:
            out.append({"stream": rnd.stream, "kind": rnd.kind, "writes": log or [], "current": True})
        return out

    def violation(self, link: Link, rnd: Round | None, exp: Expect | None, got: bytes,
                  problem: str, log: Any) -> None:
        link.broken = True
        if link.ambiguous:  # the pieces of a frame were sent too far apart: not the server's fault
            self.stats.ambiguous_mismatches += 1
            return
        starved_ms = 0.0
        if self.server is not None:
            starved_ms = (self.server.run_delay_ns() - self.round_delay_start) / 1e6
        # The server waited for a CPU during the round: its reads may have split a frame anywhere
        # (a pty hands over what it has) and it saw the wait as a pause on the line.
        if starved_ms > STARVED_MS:
            self.stats.starved_mismatches += 1
            if len(self.excused) < 50:
                self.excused.append({"problem": problem, "stream": link.name, "got": got.hex(" "),
                                     "frame": exp.frame.hex(" ") if exp else None,
                                     "server_waited_for_cpu_ms": round(starved_ms, 1),
                                     "repro": self.repro(rnd, log)})
            return
        if link.joined:
            # A frame of this round was torn on purpose and neither we nor the server (CPU) were
            # measurably late, but the kernel may still deliver a pty's or socket's bytes late
            # on a loaded machine: counted and reported apart, judged by their rate.
            self.stats.torn_mismatches += 1
            if len(self.torn_mismatches) < 100:
                self.torn_mismatches.append({
                    "problem": problem, "stream": link.name, "got": got.hex(" "),
                    "server_waited_for_cpu_ms": round(starved_ms, 1),
                    "program": self.model.program_started,
                    "frame": exp.frame.hex(" ") if exp else None, "round": self.stats.rounds,
                    "repro": self.repro(rnd, log)})
            return
        if len(self.violations) < 200:
            self.violations.append({
                "problem": problem, "stream": link.name, "got": got.hex(" "),
                "server_waited_for_cpu_ms": round(starved_ms, 1),
                "program": self.model.program_started,
                "frame": exp.frame.hex(" ") if exp else None, "round": self.stats.rounds,
                "repro": self.repro(rnd, log)})

    # -- recovery ------------------------------------------------------------------------------

    def resync(self, link: Link) -> bool:
        """After a violation: let the server drop any partial, drain, reset the module (137)
        and check that a plain request is answered."""
        time.sleep(DROP_PAUSE_S)
        self.drain(link)
        for lk in self.links.values():
            os.write(lk.fd, encode(MODULE_ADDRESS, 137, 0, 0, FACTORY_RESET_KEY))
            time.sleep(DROP_PAUSE_S)
            self.drain(lk)
            lk.pending, lk.partial, lk.broken, lk.needs_drop = 0, b"", False, False
        self.model.reset()
        self.journal = []
        for lk in self.links.values():
            os.write(lk.fd, encode(MODULE_ADDRESS, Opcode.GGP, 66, 0, 0))
            deadline = time.monotonic() + 2
            while len(lk.inbox) < 9 and time.monotonic() < deadline:
                self.sel_wait(lk, timeout=0.05)
                with contextlib.suppress(BlockingIOError):
                    lk.inbox += os.read(lk.fd, 4096)
            got = bytes(lk.inbox[:9])
            lk.inbox.clear()
            if got != reply_bytes(100, Opcode.GGP, MODULE_ADDRESS):
                return False
        return True

    def drain(self, link: Link, quiet: float = 0.1) -> None:
        last = time.monotonic()
        while time.monotonic() - last < quiet:
            self.sel_wait(link, timeout=0.02)
            try:
                if os.read(link.fd, 65536):
                    last = time.monotonic()
            except BlockingIOError:
                pass
        link.inbox.clear()

    # -- main loop -----------------------------------------------------------------------------

    def run(self) -> dict[str, Any]:
        args = self.args
        self.start_server()
        assert self.server is not None
        time.sleep(0.2)
        self.rss_start, self.fds_start = self.server.rss_kb(), self.server.fds()
        self.last_start = (self.rss_start, self.fds_start, 0)
        started = time.monotonic()
        last_progress = started
        deadline = started + args.duration if args.duration else None
        while self.stats.frames < args.frames and (deadline is None or time.monotonic() < deadline):
            rnd = self.gen.round()
            self.stats.rounds += 1
            self.stats.by_kind[rnd.kind] = self.stats.by_kind.get(rnd.kind, 0) + 1
            link = self.links[rnd.stream]
            if link.needs_drop:
                time.sleep(DROP_PAUSE_S)
                self.stats.dropped_partials += 1
                link.pending, link.partial, link.needs_drop = 0, b"", False
            try:
                self.run_round(rnd)
            except Hang as exc:
                self.record_hang(rnd, str(exc))
                continue
            if link.broken or self.needs_reset:
                self.needs_reset = False
                if not self.resync(link):
                    self.record_hang(rnd, "no sane reply after a reset (137)")
            if not self.server.alive():
                self.record_crash(rnd)
            now = time.monotonic()
            if now - last_progress >= args.progress:
                last_progress = now
                self.progress(now - started)
        elapsed = time.monotonic() - started
        self.progress(elapsed)
        rss_end, fds_end = self.server.rss_kb(), self.server.fds()
        settle = time.monotonic() + 2.0  # a descriptor held for a moment (the EEPROM's sync
        while fds_end > self.fds_start and time.monotonic() < settle:  # thread) is no leak:
            time.sleep(0.05)  # a leaked one stays
            fds_end = self.server.fds()
        self.stop_server()
        return self.summary(elapsed, rss_end, fds_end)

    def record_hang(self, rnd: Round, reason: str) -> None:
        assert self.server is not None
        alive = self.server.alive()
        self.hangs.append({"reason": reason, "stream": rnd.stream, "round": self.stats.rounds,
                           "program": self.model.program_started,
                           "stack": self.server.stack() if alive else "",
                           "repro": self.repro(rnd, rnd.log),
                           "journal": [[round(t, 4), f.hex()] for t, f in self.journal]})
        if not alive:
            self.record_crash(rnd)
            return
        self.restart("hang")

    def record_crash(self, rnd: Round) -> None:
        assert self.server is not None
        code = self.server.proc.poll()
        self.crashes.append({"exit": code, "round": self.stats.rounds,
                             "stderr_tail": self.server.stderr_text()[-2000:],
                             "repro": self.repro(rnd, rnd.log)})
        self.restart(f"exited with {code}")

    def progress(self, elapsed: float) -> None:
        s = self.stats
        rss = self.server.rss_kb() if self.server else 0
        self.rss_peak = max(self.rss_peak, rss)
        print(f"fuzz: {elapsed:7.1f} s  frames {s.frames:>9,}  ({s.frames / max(elapsed, 1e-9):,.0f}/s)"
              f"  replies {s.replies_checked:,}  violations {len(self.violations)}  stalls {s.stalls}"
              f"  hangs {len(self.hangs)}  crashes {len(self.crashes)}  max {s.max_latency_ms:.1f} ms"
              f"  rss {rss} kB", file=sys.stderr, flush=True)

    def summary(self, elapsed: float, rss_end: int, fds_end: int) -> dict[str, Any]:
        s = self.stats
        lat = sorted(s.latencies)

        def pct(p: float) -> float:
            return round(lat[min(len(lat) - 1, int(p * len(lat)))] * 1000, 3) if lat else 0.0

        return {
            "seed": self.args.seed, "transport": self.args.transport, "avoid": sorted(self.avoid),
            "frames": s.frames, "bytes": s.bytes_sent, "rounds": s.rounds,
            "replies_checked": s.replies_checked, "silences_checked": s.silent_checked,
            "events_138": s.events, "torn_pieces": s.torn, "dropped_partials": s.dropped_partials,
            "ambiguous_rounds": s.ambiguous_rounds, "ambiguous_mismatches": s.ambiguous_mismatches,
            "starved_mismatches": s.starved_mismatches,
            "torn_rounds": s.torn_rounds, "torn_mismatches": s.torn_mismatches,
            "violations": len(self.violations),
            "stalls": s.stalls, "stalls_with_program": s.stalls_with_program,
            "stalls_starved": s.stalls_starved,
            "stalls_net_of_cpu_wait": s.stalls_net,
            "stalls_net_of_both_cpu_waits": s.stalls_net_both,
            "stalls_net_server_busy": s.stalls_net_busy,
            "max_latency_net_of_cpu_wait_ms": round(s.max_net_latency_ms, 1),
            "stall_ms": self.args.stall_ms, "max_latency_ms": round(s.max_latency_ms, 1),
            "latency_ms_p50": pct(0.5), "latency_ms_p99": pct(0.99), "hangs": len(self.hangs),
            "crashes": len(self.crashes), "tracebacks": self.tracebacks,
            "server_stderr_bytes": self.stderr_bytes, "servers_started": self.servers,
            "rss_kb_start": self.rss_start, "rss_kb_end": rss_end, "rss_kb_peak": max(self.rss_peak, rss_end),
            "fds_start": self.fds_start, "fds_end": fds_end,
            # after a hang the server is restarted: the last one's own start and frames served
            "last_server": {"rss_kb_start": self.last_start[0], "fds_start": self.last_start[1],
                            "frames": s.frames - self.last_start[2]},
            "seconds": round(elapsed, 1),
            "rounds_by_kind": s.by_kind,
        }


# == reducing a hang or stall to a minimal sequence =============================================

def describe(frame: bytes) -> str:
    """A frame as ``SAP 5, 0, 0`` (mnemonic, type, motor, value)."""
    try:
        name = Opcode(frame[1]).name
    except ValueError:
        name = f"op{frame[1]}"
    return f"{name} {frame[2]}, {frame[3]}, {i32(int.from_bytes(frame[4:8], 'big'))}"


_REPLAYS = itertools.count(10_000)


class Replayer:
    """Replays executed frames one at a time on a fresh server over TCP (each frame readdressed
    to the module) and reports the longest wait for a reply."""

    def __init__(self, workdir: Path, timeout: float) -> None:
        self.workdir = workdir
        self.timeout = timeout
        self.count = 0

    def slowest(self, frames: list[bytes], gaps: list[float] | None = None) -> float:
        self.count += 1
        server = ServerProcess(self.workdir, next(_REPLAYS))
        sock = socket.create_connection(server.tcp)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        worst = 0.0
        try:
            for i, raw in enumerate(frames):
                frame = encode(MODULE_ADDRESS, raw[1], raw[2], raw[3],
                               i32(int.from_bytes(raw[4:8], "big")))
                if gaps:
                    time.sleep(min(gaps[i], 0.5))
                sent = time.monotonic()
                sock.sendall(frame)
                if (frame[1] == Opcode.RESTORE_FACTORY_SETTINGS
                        and frame[4:8] == FACTORY_RESET_KEY.to_bytes(4, "big")):
                    time.sleep(0.05)
                    continue
                got = b""
                while True:
                    sock.settimeout(max(0.001, sent + self.timeout - time.monotonic()))
                    try:
                        data = sock.recv(9 - len(got))
                    except TimeoutError:
                        return float("inf")
                    if not data:
                        return float("inf")
                    got += data
                    if len(got) == 9:
                        if is_event(got):
                            got = b""
                            continue
                        break
                worst = max(worst, time.monotonic() - sent)
            return worst
        finally:
            sock.close()
            server.stop(kill=True)
            shutil.rmtree(server.dir, ignore_errors=True)


def ddmin(items: list[Any], test: Any, budget: float) -> list[Any]:
    """Zeller's delta debugging: a 1-minimal sublist for which ``test`` holds (within a time
    budget: then the smallest found so far)."""
    deadline = time.monotonic() + budget
    n = 2
    while len(items) >= 2 and time.monotonic() < deadline:
        size = len(items) // n
        chunks = [items[i:i + size] for i in range(0, len(items), size)] if size else [items]
        reduced = False
        for i in range(len(chunks)):
            complement = [x for j, c in enumerate(chunks) if j != i for x in c]
            if complement and test(complement):
                items, n, reduced = complement, max(n - 1, 2), True
                break
            if time.monotonic() > deadline:
                break
        if not reduced:
            if n >= len(items):
                break
            n = min(len(items), n * 2)
    return items


def reduce_journal(journal: list[tuple[float, bytes]], workdir: Path, threshold: float,
                   budget: float) -> dict[str, Any]:
    """The fewest executed frames that still make one reply later than ``threshold``."""
    replayer = Replayer(workdir, timeout=max(2 * threshold, threshold + 1.0))
    frames = [f for _, f in journal]
    times = [t for t, _ in journal]
    gaps = [0.0] + [b - a for a, b in itertools.pairwise(times)]
    timed = False
    if replayer.slowest(frames) < threshold:
        timed = True
        if replayer.slowest(frames, gaps) < threshold:
            return {"reproduced": False, "frames": len(frames), "replays": replayer.count}
    indexed = list(range(len(frames)))

    def test(sub: list[int]) -> bool:
        return replayer.slowest([frames[i] for i in sub],
                                [gaps[i] for i in sub] if timed else None) >= threshold

    reads = {Opcode.GAP, Opcode.GGP, Opcode.GIO, Opcode.GCO, 134, 135, 136, 147, 148}
    writes_only = [i for i in indexed if frames[i][1] not in reads]
    if writes_only != indexed and writes_only and test(writes_only):
        indexed = writes_only
    minimal = ddmin(indexed, test, budget)
    again = test(minimal)
    return {"reproduced": True, "confirmed": again, "timed": timed, "from_frames": len(frames),
            "replays": replayer.count, "minimal": [describe(frames[i]) for i in minimal],
            "minimal_hex": [frames[i].hex(" ") for i in minimal]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=1_000_000, help="stop after this many frames")
    parser.add_argument("--duration", type=float, default=None, help="or after this many seconds")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--transport", choices=("tcp", "pty", "both"), default="both")
    parser.add_argument("--avoid", default="", help="known,item1,item2,item3: leave known problems out")
    parser.add_argument("--stall-ms", type=float, default=50.0, help="a reply later than this is a stall")
    parser.add_argument("--hang-s", type=float, default=10.0, help="no reply for this long is a hang")
    parser.add_argument("--progress", type=float, default=5.0, help="seconds between progress lines")
    parser.add_argument("--report", type=Path, help="write every finding with its repro (JSON)")
    parser.add_argument("--history", type=int, default=50, help="rounds kept for repros")
    parser.add_argument("--repro-rounds", type=int, default=3, help="earlier rounds in a repro")
    parser.add_argument("--reduce", type=int, default=0, metavar="N",
                        help="after the run, reduce the first N hangs to a minimal frame sequence")
    parser.add_argument("--reduce-report", type=Path, metavar="FILE",
                        help="only reduce the hangs of an earlier --report FILE")
    parser.add_argument("--reduce-budget", type=float, default=300.0, metavar="S",
                        help="seconds of replays per reduction")
    parser.add_argument("--server-module", default="tmcl_server", metavar="MODULE",
                        help="run the server as python -m MODULE (default tmcl_server; a wrapper "
                             "on PYTHONPATH can instrument it, e.g. log slow loop callbacks)")
    parser.add_argument("--server-root", type=Path, metavar="DIR",
                        help="run the server from this checkout (e.g. a worktree of main, as a "
                             "baseline checked by the same fuzzer)")
    args = parser.parse_args(argv)
    SERVER_MODULE[0] = args.server_module
    if args.server_root is not None:
        SERVER_ROOT[0] = args.server_root.resolve()
    if args.reduce_report:
        report = json.loads(args.reduce_report.read_text())
        return reduce_hangs(report["hangs"][:args.reduce or None], args)
    bad = {a for a in args.avoid.split(",") if a.strip()} - {"known", *KNOWN_ITEMS}
    if bad:
        parser.error(f"--avoid: unknown item(s) {', '.join(sorted(bad))}")
    fuzzer = Fuzzer(args)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # so that the server is stopped too
    try:
        summary = fuzzer.run()
    finally:
        fuzzer.stop_server(kill=True)
        fuzzer.tmp.cleanup()
    def write_report() -> None:
        if args.report:
            args.report.write_text(json.dumps({
                "summary": summary, "violations": fuzzer.violations, "excused": fuzzer.excused,
                "torn_mismatches": fuzzer.torn_mismatches,
                "stalls": fuzzer.stall_list,
                "stall_stacks": [{"count": n, "stack": k}
                                 for k, n in fuzzer.stall_stacks.most_common(30)],
                "hangs": fuzzer.hangs, "crashes": fuzzer.crashes}, indent=1))

    write_report()
    if args.reduce and fuzzer.hangs:
        reduce_hangs(fuzzer.hangs[:args.reduce], args)
        write_report()
    for kind, items in (("violation", fuzzer.violations), ("torn mismatch", fuzzer.torn_mismatches),
                        ("hang", fuzzer.hangs),
                        ("stall", fuzzer.stall_list[:10]), ("crash", fuzzer.crashes)):
        for item in items[:10]:
            brief = {k: v for k, v in item.items() if k not in ("repro", "journal")}
            print(f"fuzz: {kind}: {json.dumps(brief)[:400]}", file=sys.stderr)
    print(json.dumps(summary), flush=True)
    return 0


def reduce_hangs(hangs: list[dict[str, Any]], args: argparse.Namespace) -> int:
    """Reduce each hang's journal to the fewest frames that still hang (> 1 s); print them."""
    with tempfile.TemporaryDirectory(prefix="tmcl-fuzz-reduce-") as tmp:
        for i, hang in enumerate(hangs):
            journal = [(t, bytes.fromhex(h)) for t, h in hang.get("journal", [])]
            if not journal:
                continue
            result = reduce_journal(journal, Path(tmp), threshold=1.0, budget=args.reduce_budget)
            hang["reduced"] = result
            print(f"fuzz: hang {i} ({hang['reason'][:60]}): {json.dumps(result)}", file=sys.stderr,
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
