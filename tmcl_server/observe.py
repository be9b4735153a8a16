"""What a server attaches to watch its simulation: the trace (``--trace``) and the recorder
(``--record``), opened from the server's configuration and closed with it."""

from __future__ import annotations

import asyncio
import contextlib
import sys
from typing import TYPE_CHECKING, Protocol, TextIO

if TYPE_CHECKING:
    from tmcl_server.record import Recorder
    from tmcl_server.simulation import Simulation
    from tmcl_server.trace import Tracer

#: On a real clock the recorder catches up at least this often (wall seconds), so that its
#: file grows while the host is quiet.
RECORD_WAKE_S = 0.1
#: ``--trace`` without a file name.
STDERR = "-"


class ObserverSettings(Protocol):
    """What the observers take from a server's configuration (``ServerConfig`` has it)."""

    #: Telegram trace: a file, "-" for stderr, None for none; "text" or "jsonl".
    trace: str | None
    trace_format: str
    #: Record the axes to a .csv or .jsonl file every record_resolution simulated seconds.
    record: str | None
    record_resolution: float
    record_axes: list[int] | None


class Observers:
    """The trace and the recorder of one server (each optional)."""

    def __init__(self, simulation: Simulation, config: ObserverSettings) -> None:
        self.simulation = simulation
        self.config = config
        self.tracer: Tracer | None = None
        self.recorder: Recorder | None = None
        self._files: list[TextIO] = []
        self._wake: asyncio.Task[None] | None = None

    def start(self, loop: asyncio.AbstractEventLoop | None = None) -> None:
        config = self.config
        try:
            if config.trace is not None:
                from tmcl_server.trace import Tracer

                stream = sys.stderr if config.trace == STDERR else self._open(config.trace)
                self.tracer = Tracer(stream, config.trace_format).attach(self.simulation, loop)
            if config.record is not None:
                self._start_recorder(config.record, loop)
        except BaseException:
            self.close()
            raise

    def _open(self, path: str) -> TextIO:
        stream = open(path, "w", encoding="utf-8", newline="")  # noqa: SIM115 (closed in close())
        self._files.append(stream)
        return stream

    def _start_recorder(self, path: str, loop: asyncio.AbstractEventLoop | None) -> None:
        from tmcl_server.record import Recorder, RecordWriter, file_format

        fmt = file_format(path)
        writer = RecordWriter(self._open(path), fmt)
        self.recorder = Recorder(self.simulation, self.config.record_resolution,
                                 axes=self.config.record_axes, on_sample=writer.sample,
                                 on_mark=writer.mark, keep=False).start()
        if loop is not None and not self.simulation.clock.virtual:
            self._wake = loop.create_task(self._keep_recording(writer.stream), name="recorder")

    async def _keep_recording(self, stream: TextIO) -> None:
        period = max(RECORD_WAKE_S, self.config.record_resolution)
        while True:
            await asyncio.sleep(period)
            while self.recorder is not None and self.simulation.run_due(0):
                await asyncio.sleep(0)  # the recorder is behind: catch up in turns
            stream.flush()

    def close(self) -> None:
        if self._wake is not None:
            self._wake.cancel()
            self._wake = None
        if self.recorder is not None:
            self.recorder.stop()
            self.recorder = None
        if self.tracer is not None:
            self.tracer.detach()
            self.tracer = None
        for stream in self._files:
            with contextlib.suppress(OSError):
                stream.close()
        self._files.clear()
