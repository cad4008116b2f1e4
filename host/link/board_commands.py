"""The session's command helpers: servo frames, FLUSH, ESTOP, ADVANCE, CONFIG, SCREEN, SPEAKER, camera capture.

:class:`BoardCommands` is a mixin of :class:`host.link.session.BoardClient`: each helper builds one
protocol message (:mod:`protocol.messages`) and hands it to the session's ``send`` (no reply) or
``request`` (awaits the ACK, with retries; :mod:`host.link.requests`). :meth:`BoardCommands.capture`
also drives the selective repeat of a camera image (:class:`host.link.camera.CameraAssembler`).
"""

from __future__ import annotations

from collections.abc import Sequence

import anyio

from host.link.camera import CameraAssembler
from host.link.errors import LinkDown, LinkTimeout
from host.link.requests import RequestTable
from host.link.waiting import Reply
from protocol.messages import (
    Ack,
    Advance,
    CameraCapture,
    CameraResend,
    Caps,
    Config,
    ConfigKey,
    Estop,
    EstopClear,
    Flush,
    Message,
    ScreenCommand,
    ScreenTarget,
    ServoFrame,
    SoundKind,
    SpeakerAction,
    SpeakerCommand,
)

__all__ = ["BoardCommands"]


class BoardCommands:
    """Command helpers over the session's ``send``/``request`` (the session provides what is annotated here)."""

    caps: Caps | None
    camera: CameraAssembler
    requests: RequestTable
    _next_request_id: int

    def send(self, msg: Message) -> int:  # the session's
        raise NotImplementedError

    def _send(self, msg: Message) -> int:  # the session's
        raise NotImplementedError

    def _require_ready(self) -> None:  # the session's
        raise NotImplementedError

    def _count_retry(self) -> None:  # the session's
        raise NotImplementedError

    async def request(self, msg: Message, timeout: float | None = None, attempts: int | None = None) -> Ack:
        raise NotImplementedError  # the session's

    def send_frame(self, frame: ServoFrame) -> int:
        """Queue a timed servo frame; returns its sequence number (a NACK is recorded, see ``frame_nack``)."""
        return self.send(frame)

    def all_mask(self) -> int:
        """The mask of every servo the board has (from CAPS; bits 0..N-1)."""
        if self.caps is None:
            raise LinkDown("not connected: no CAPS yet")
        return (1 << self.caps.servo_count) - 1

    def send_targets(self, apply_at_us: int, targets: Sequence[float], mask: int | None = None) -> int:
        """Convenience: a :class:`ServoFrame` for ``targets`` (one per mask bit) at ``apply_at_us``."""
        mask = self.all_mask() if mask is None else mask
        return self.send_frame(ServoFrame(int(apply_at_us), mask, tuple(float(v) for v in targets)))

    async def flush(self, from_us: int, mask: int | None = None) -> Ack:
        """Drop buffered frames due at or after ``from_us`` (board time) for the masked servos."""
        return await self.request(Flush(int(from_us), self.all_mask() if mask is None else mask))

    async def estop(self) -> Ack:
        """Emergency stop: the board holds where it is and refuses frames until :meth:`estop_clear`.

        Re-sent until acknowledged, also under loss: the first re-send after the link's measured
        round-trip timeout, for ``20 × reply_timeout`` s in all (:meth:`request`).
        """
        return await self.request(Estop(), attempts=20)

    async def estop_clear(self) -> Ack:
        """Clear an estop or a latched watchdog fault."""
        return await self.request(EstopClear())

    async def advance(self, until_us: int) -> Ack:
        """Lockstep only: let the board clock run up to ``until_us``."""
        return await self.request(Advance(int(until_us)))

    async def configure(self, key: ConfigKey, value: int) -> Ack:
        """Change a board setting at run time (NACK BAD_VALUE when out of range)."""
        return await self.request(Config(ConfigKey(key), int(value)))

    async def screen(self, target: ScreenTarget, name: str, start_at_us: int = 0, duration_ms: int = 0) -> Ack:
        """Show an expression/animation on the face screen."""
        return await self.request(ScreenCommand(ScreenTarget(target), name, int(start_at_us), int(duration_ms)))

    async def speaker(
        self,
        action: SpeakerAction,
        kind: SoundKind = SoundKind.SPEECH,
        *,
        start_at_us: int = 0,
        duration_ms: int = 0,
        volume: int = 80,
        name: str = "",
        text: str = "",
    ) -> Ack:
        """Play or stop speech or a clip on the board clock."""
        return await self.request(
            SpeakerCommand(SpeakerAction(action), SoundKind(kind), int(start_at_us), int(duration_ms), int(volume), name, text)
        )

    #: wall seconds without a new camera chunk before the host asks again (a render takes ~0.1 s)
    CAPTURE_STALL_S = 0.4
    #: the same before the capture's first chunk: a lockstep board makes its renderer (GL context, first
    #: render: ~0.35 s quiet, more under load) at its first capture, and a request asked again meanwhile
    #: would have it send the whole image twice
    CAPTURE_FIRST_S = 1.0

    async def capture(self, width: int, height: int, timeout: float = 10.0) -> bytes:
        """One head-camera image as PNG bytes (reassembled from CAMERA_CHUNKs).

        Selective repeat over a lossy link: when no new chunk came for :attr:`CAPTURE_STALL_S` s
        (:attr:`CAPTURE_FIRST_S` before the first), the host asks again, with CAMERA_RESEND for the
        chunks still missing once it knows how many there are, else with the same CAMERA_CAPTURE (the
        board answers a request id it already rendered with the same image). Raises :class:`LinkTimeout` after ``timeout`` s
        without the whole image, :class:`NackError` when the board refuses the capture
        (NO_RENDERER, BAD_VALUE, BUSY).
        """
        self._require_ready()
        rid = self._next_request_id
        self._next_request_id = (rid + 1) & 0xFFFFFFFF or 1
        fut: Reply[bytes] = Reply()
        request = CameraCapture(rid, int(width), int(height))
        seqs = [self._send(request)]
        self.requests.expect(seqs[0], fut)
        parts = self.camera.start(rid, seqs[0])
        deadline = anyio.current_time() + timeout
        try:
            while True:
                left = deadline - anyio.current_time()
                if left <= 0:
                    raise LinkTimeout(f"camera image {rid} incomplete after {timeout} s ({self.camera.describe(rid)})")
                have = len(parts)
                stall = self.CAPTURE_STALL_S if have else self.CAPTURE_FIRST_S
                if await fut.wait(min(left, stall)):
                    return fut.result()
                if len(parts) != have:
                    continue  # chunks are still arriving
                gap = self.camera.missing(rid)
                if gap is None:  # nothing arrived: the request or every chunk was lost
                    seq = self._send(request)
                    seqs.append(seq)
                    self.requests.expect(seq, fut)
                else:
                    self._send(CameraResend(rid, *gap))
                self._count_retry()
        finally:
            self.requests.release(seqs, fut)
            fut.cancel()
            self.camera.drop(rid)
