"""How a reply leaves when a fault altered it (late, torn, spoilt, doubled): the transports
send a :class:`Delivery` each its own way.  Apart from the fault language (faults.py), so a
transport that never meets a fault imports nothing of it."""

from __future__ import annotations

from dataclasses import dataclass

from tmcl_server.protocol import AnyReply


@dataclass(slots=True)
class Delivery:
    """A reply the faults altered, and how it leaves: each transport sends it its own way."""

    reply: AnyReply
    delay_s: float = 0.0
    bad_checksum: bool = False
    garbage: bytes = b""
    pieces: int = 1
    pause_s: float = 0.0
    copies: int = 1

    def frame(self) -> bytes:
        """The reply's bytes on a serial link (its checksum byte spoilt if asked)."""
        data = self.reply.encode()
        if self.bad_checksum:
            data = data[:-1] + bytes((data[-1] ^ 0xFF,))
        return data

    def stream_pieces(self) -> list[tuple[float, bytes]]:
        """(pause before, bytes) for a byte stream: the first pause is the delay; pieces with
        no pause between them are joined into one write."""
        frame = self.frame()
        size, extra = divmod(len(frame), self.pieces)
        cuts = [0]
        for index in range(self.pieces):
            cuts.append(cuts[-1] + size + (index < extra))
        out: list[tuple[float, bytes]] = []
        for copy in range(self.copies):
            for index in range(self.pieces):
                data = frame[cuts[index]:cuts[index + 1]]
                if copy == 0 and index == 0:
                    out.append((self.delay_s, self.garbage + data))
                    continue
                pause = self.pause_s if index else 0.0
                if pause > 0:
                    out.append((pause, data))
                else:
                    out[-1] = (out[-1][0], out[-1][1] + data)
        return out

    @property
    def total_delay_s(self) -> float:
        """A link that sends whole messages (CAN, MQTT) cannot tear one: the pauses add up."""
        return self.delay_s + (self.pieces - 1) * self.pause_s
