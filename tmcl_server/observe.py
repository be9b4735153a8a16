"""What a server attaches to watch its simulation: the trace (``--trace``) and the recorder
(``--record``), opened from the server's configuration and closed with it.

Each writes through a :class:`~tmcl_server.sidechannel.RotatingFile`: past ``--trace-max`` /
``--record-max`` bytes the file becomes ``FILE.1`` and a new one starts; a write that fails
(a full disk) stops that observer with one warning, and the modules go on answering."""

from __future__ import annotations

import asyncio
import contextlib
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

from tmcl_server.sidechannel import RotatingFile, SideChannel

if TYPE_CHECKING:
    from tmcl_server.record import Recorder
    from tmcl_server.simulation import Simulation
    from tmcl_server.trace import Tracer

#: On a real clock the recorder catches up at least this often (wall seconds), so that its
#: file grows while the host is quiet.
RECORD_WAKE_S = 0.1
#: ``--trace`` without a file name.
STDERR = "-"
#: A trace or record file is rotated past this many bytes (``--trace-max``, ``--record-max``):
#: a flooded trace writes up to about 60 MB a minute, a recording about 5 MB; with the one
#: rotated file kept, each takes at most twice this on disk.
DEFAULT_TRACE_MAX = 100 * 1024 * 1024
DEFAULT_RECORD_MAX = 100 * 1024 * 1024


class ObserverSettings(Protocol):
    """What the observers take from a server's configuration (``ServerConfig`` has it)."""

    #: Telegram trace: a file, "-" for stderr, None for none; "text" or "jsonl".
    trace: str | None
    trace_format: str
    #: Record the axes to a .csv or .jsonl file every record_resolution simulated seconds.
    record: str | None
    record_resolution: float
    record_axes: list[int] | None
    #: Rotate the trace or record file past this many bytes (0: never).
    trace_max: int
    record_max: int


class Observers:
    """The trace and the recorder of one server (each optional)."""

    def __init__(self, simulation: Simulation, config: ObserverSettings) -> None:
        self.simulation = simulation
        self.config = config
        self.tracer: Tracer | None = None
        self.recorder: Recorder | None = None
        #: The trace's and the recorder's channels: stopped by their first failed write.
        self.trace_channel = SideChannel("the trace (--trace)", self._stop_tracer)
        self.record_channel = SideChannel("the recorder (--record)", self._stop_recorder)
        self._files: list[RotatingFile] = []
        self._wake: asyncio.Task[None] | None = None
        self._loop: asyncio.AbstractEventLoop | None = None

    def start(self, loop: asyncio.AbstractEventLoop | None = None) -> None:
        config = self.config
        self._loop = loop
        try:
            if config.trace is not None:
                from tmcl_server.trace import Tracer

                if config.trace == STDERR:
                    stream = RotatingFile(None, self.trace_channel, stream=sys.stderr)
                else:
                    stream = self._open(config.trace, self.trace_channel, config.trace_max)
                self.tracer = Tracer(stream, config.trace_format).attach(self.simulation, loop)  # type: ignore[arg-type]
            if config.record is not None:
                self._start_recorder(config.record, loop)
        except BaseException:
            self.close()
            raise

    def _open(self, path: str, channel: SideChannel, max_bytes: int) -> RotatingFile:
        stream = RotatingFile(path, channel, max_bytes)
        self._files.append(stream)
        return stream

    def _start_recorder(self, path: str, loop: asyncio.AbstractEventLoop | None) -> None:
        from tmcl_server.record import Recorder, RecordWriter, file_format

        fmt = file_format(path)
        stream = self._open(path, self.record_channel, self.config.record_max)
        writer = RecordWriter(stream, fmt)  # type: ignore[arg-type]
        stream.header = writer.header
        channel = self.record_channel
        self.recorder = Recorder(self.simulation, self.config.record_resolution,
                                 axes=self.config.record_axes,
                                 on_sample=channel.guard(writer.sample, f"writing {path}"),
                                 on_mark=channel.guard(writer.mark, f"writing {path}"),
                                 keep=False).start()
        if loop is not None and not self.simulation.clock.virtual:
            self._wake = loop.create_task(self._keep_recording(stream), name="recorder")

    async def _keep_recording(self, stream: RotatingFile) -> None:
        period = max(RECORD_WAKE_S, self.config.record_resolution)
        while self.recorder is not None:
            await asyncio.sleep(period)
            while self.recorder is not None and self.simulation.run_due(0):
                await asyncio.sleep(0)  # the recorder is behind: catch up in turns
            stream.flush()

    # -- a channel that failed stops (after the request in progress: not from inside it) ------

    def _stop_recorder(self) -> None:
        self._later(self._detach_recorder)

    def _stop_tracer(self) -> None:
        self._later(self._detach_tracer)

    def _later(self, action: Callable[[], None]) -> None:
        if self._loop is not None and not self._loop.is_closed():
            self._loop.call_soon(action)
        else:
            action()

    def _detach_recorder(self) -> None:
        if self._wake is not None:
            self._wake.cancel()
            self._wake = None
        recorder, self.recorder = self.recorder, None
        if recorder is not None:
            with contextlib.suppress(Exception):  # its last samples go nowhere now
                recorder.stop()

    def _detach_tracer(self) -> None:
        tracer, self.tracer = self.tracer, None
        if tracer is None:
            return
        if tracer.listeners:  # the dashboard still reads it: keep it, without a file
            tracer.stream = None
            return
        with contextlib.suppress(Exception):
            tracer.detach()

    def close(self) -> None:
        if self._wake is not None:
            self._wake.cancel()
            self._wake = None
        if self.recorder is not None:
            with contextlib.suppress(Exception):
                self.recorder.stop()
            self.recorder = None
        if self.tracer is not None:
            with contextlib.suppress(Exception):
                self.tracer.detach()
            self.tracer = None
        for stream in self._files:
            stream.flush()
            stream.close()
        self._files.clear()
