"""The session's command helpers: servo frames, FLUSH, ESTOP, ADVANCE, CONFIG, SCREEN, SPEAKER, camera capture.

:class:`BoardCommands` builds one protocol message (:mod:`protocol.messages`) per helper and hands it
to the session's ``send`` (no reply) or ``request`` (awaits the ACK, with retries;
:mod:`host.link.requests`); :class:`CameraCapturer` asks for a camera image and drives its selective
repeat (:class:`host.link.camera.CameraAssembler`). Both are parts of
:class:`host.link.client.BoardClient` and hold the session (:class:`host.link.core.LinkSession`)
only as the Protocols :class:`CommandLink` and :class:`CaptureLink`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

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

__all__ = ["BoardCommands", "CameraCapturer", "CaptureLink", "CommandLink"]


class CommandLink(Protocol):
    """What the command helpers need of the session."""

    @property
    def caps(self) -> Caps | None: ...
    def send(self, msg: Message) -> int: ...
    async def request(self, msg: Message, timeout: float | None = None, attempts: int | None = None) -> Ack: ...


class CaptureLink(Protocol):
    """What a camera capture needs of the session: its sends, the replies it awaits by sequence number,
    the chunks assembled so far, and its retry count."""

    @property
    def requests(self) -> RequestTable: ...
    @property
    def camera(self) -> CameraAssembler: ...
    def require_ready(self) -> None: ...
    def transmit(self, msg: Message) -> int: ...
    def count_retry(self) -> None: ...


class BoardCommands:
    """Command helpers over ``link``'s ``send``/``request`` (module docstring)."""

    def __init__(self, link: CommandLink) -> None:
        self.link = link

    def send_frame(self, frame: ServoFrame) -> int:
        """Queue a timed servo frame; returns its sequence number (a NACK is recorded, see ``frame_nack``)."""
        return self.link.send(frame)

    def all_mask(self) -> int:
        """The mask of every servo the board has (from CAPS; bits 0..N-1)."""
        caps = self.link.caps
        if caps is None:
            raise LinkDown("not connected: no CAPS yet")
        return (1 << caps.servo_count) - 1

    def send_targets(self, apply_at_us: int, targets: Sequence[float], mask: int | None = None) -> int:
        """Convenience: a :class:`ServoFrame` for ``targets`` (one per mask bit) at ``apply_at_us``."""
        mask = self.all_mask() if mask is None else mask
        return self.send_frame(ServoFrame(int(apply_at_us), mask, tuple(float(v) for v in targets)))

    async def flush(self, from_us: int, mask: int | None = None) -> Ack:
        """Drop buffered frames due at or after ``from_us`` (board time) for the masked servos."""
        return await self.link.request(Flush(int(from_us), self.all_mask() if mask is None else mask))

    async def estop(self) -> Ack:
        """Emergency stop: the board holds where it is and refuses frames until :meth:`estop_clear`.

        Re-sent until acknowledged, also under loss: the first re-send after the link's measured
        round-trip timeout, for ``20 × reply_timeout`` s in all (:meth:`host.link.core.LinkSession.request`).
        """
        return await self.link.request(Estop(), attempts=20)

    async def estop_clear(self) -> Ack:
        """Clear an estop or a latched watchdog fault."""
        return await self.link.request(EstopClear())

    async def advance(self, until_us: int) -> Ack:
        """Lockstep only: let the board clock run up to ``until_us``."""
        return await self.link.request(Advance(int(until_us)))

    async def configure(self, key: ConfigKey, value: int) -> Ack:
        """Change a board setting at run time (NACK BAD_VALUE when out of range)."""
        return await self.link.request(Config(ConfigKey(key), int(value)))

    async def screen(self, target: ScreenTarget, name: str, start_at_us: int = 0, duration_ms: int = 0) -> Ack:
        """Show an expression/animation on the face screen."""
        return await self.link.request(ScreenCommand(ScreenTarget(target), name, int(start_at_us), int(duration_ms)))

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
        return await self.link.request(
            SpeakerCommand(SpeakerAction(action), SoundKind(kind), int(start_at_us), int(duration_ms), int(volume), name, text)
        )


class CameraCapturer:
    """Camera captures over ``link`` (module docstring); request ids count from 1 and wrap past 0xFFFFFFFF."""

    def __init__(self, link: CaptureLink) -> None:
        self.link = link
        self._next_request_id = 1

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
        link = self.link
        link.require_ready()
        rid = self._next_request_id
        self._next_request_id = (rid + 1) & 0xFFFFFFFF or 1
        fut: Reply[bytes] = Reply()
        request = CameraCapture(rid, int(width), int(height))
        seqs = [link.transmit(request)]
        link.requests.expect(seqs[0], fut)
        parts = link.camera.start(rid, seqs[0])
        deadline = anyio.current_time() + timeout
        try:
            while True:
                left = deadline - anyio.current_time()
                if left <= 0:
                    raise LinkTimeout(f"camera image {rid} incomplete after {timeout} s ({link.camera.describe(rid)})")
                have = len(parts)
                stall = self.CAPTURE_STALL_S if have else self.CAPTURE_FIRST_S
                if await fut.wait(min(left, stall)):
                    return fut.result()
                if len(parts) != have:
                    continue  # chunks are still arriving
                gap = link.camera.missing(rid)
                if gap is None:  # nothing arrived: the request or every chunk was lost
                    seq = link.transmit(request)
                    seqs.append(seq)
                    link.requests.expect(seq, fut)
                else:
                    link.transmit(CameraResend(rid, *gap))
                link.count_retry()
        finally:
            link.requests.release(seqs, fut)
            fut.cancel()
            link.camera.drop(rid)
