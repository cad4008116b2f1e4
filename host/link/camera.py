"""Camera image reassembly: CAMERA_CHUNKs in, whole images out (no I/O, no clock).

The session asks the board for an image with CAMERA_CAPTURE (request id ``rid``, sent with wire
sequence number ``seq``); the board answers with ``total`` CAMERA_CHUNKs of that request id. One
:class:`CameraAssembler` holds every capture in progress: the chunks received, the chunk count (the
first chunk's count holds; a chunk that disagrees is dropped) and the sequence number whose pending
future the image completes. An image is handed out only when every chunk ``0..total-1`` is there
(never a partial image). :meth:`CameraAssembler.missing` gives the CAMERA_RESEND bitmap for the
chunks still missing (selective repeat); :meth:`CameraAssembler.forget_seq` drops a capture whose
sequence number is reused (16-bit wrap).
"""

from __future__ import annotations

import logging

from protocol.codec import MAX_RESEND_BITMAP
from protocol.messages import CameraChunk

__all__ = ["CameraAssembler"]

log = logging.getLogger("host.link")


class CameraAssembler:
    """Captures in progress by request id: ``parts`` (chunk index -> bytes), ``totals`` (chunk count,
    from the first chunk), ``seqs`` (the CAMERA_CAPTURE's wire sequence number)."""

    def __init__(self) -> None:
        self.parts: dict[int, dict[int, bytes]] = {}
        self.totals: dict[int, int] = {}
        self.seqs: dict[int, int] = {}

    def start(self, rid: int, seq: int) -> dict[int, bytes]:
        """A capture ``rid`` was requested with sequence number ``seq``; its (empty) chunk map."""
        parts: dict[int, bytes] = {}
        self.parts[rid] = parts
        self.seqs[rid] = seq
        return parts

    def on_chunk(self, msg: CameraChunk) -> tuple[int, bytes] | None:
        """One chunk; ``(seq, image)`` when it completes its image, else None (unknown requests are ignored)."""
        parts = self.parts.get(msg.request_id)
        seq = self.seqs.get(msg.request_id)
        if parts is None or seq is None:
            return None
        total = self.totals.setdefault(msg.request_id, msg.total)
        if msg.total != total:  # chunks of one image disagree: the first count holds, this one is dropped
            log.debug("link: camera image %d: chunk %d says %d chunks, the first said %d (dropped)",
                      msg.request_id, msg.index, msg.total, total)
            return None
        parts[msg.index] = msg.data
        if len(parts) >= total and all(i in parts for i in range(total)):  # never a partial image
            return seq, b"".join(parts[i] for i in range(total))
        return None

    def missing(self, rid: int) -> tuple[int, bytes] | None:
        """``(first, bitmap)`` for CAMERA_RESEND (bit ``k`` = chunk ``first + k``, at most
        ``MAX_RESEND_BITMAP`` bytes), or None while the chunk count is unknown (no chunk came)."""
        total = self.totals.get(rid)
        if total is None:
            return None
        parts = self.parts.get(rid, {})
        missing = [i for i in range(total) if i not in parts]
        if not missing:
            return None
        first = missing[0]
        wanted = bytearray((min(missing[-1] - first, MAX_RESEND_BITMAP * 8 - 1) >> 3) + 1)
        for i in missing:
            if i - first < len(wanted) * 8:
                wanted[(i - first) >> 3] |= 1 << ((i - first) & 7)
        return first, bytes(wanted)

    def describe(self, rid: int) -> str:
        """``"3 of 9 chunks"`` or ``"no chunk"`` (for a timeout message)."""
        if rid in self.totals:
            return f"{len(self.parts.get(rid, {}))} of {self.totals[rid]} chunks"
        return "no chunk"

    def drop(self, rid: int) -> None:
        """Capture ``rid`` ended (done, failed or timed out)."""
        self.parts.pop(rid, None)
        self.seqs.pop(rid, None)
        self.totals.pop(rid, None)

    def forget_seq(self, seq: int) -> None:
        """``seq`` is sent again: a capture still waiting on its old use is dropped."""
        for rid, cseq in list(self.seqs.items()):
            if cseq == seq:
                del self.seqs[rid]
                self.parts.pop(rid, None)

    def clear(self) -> None:
        """The link went down: every capture in progress is dropped."""
        self.parts.clear()
        self.totals.clear()
        self.seqs.clear()
