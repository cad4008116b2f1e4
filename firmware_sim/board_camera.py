"""A board's camera service: CAMERA_CAPTURE -> CAMERA_CHUNKs, CAMERA_RESEND, the images kept for it.

Held by :class:`firmware_sim.board.Board` (``board.cameras``), which routes the two messages here. In
lockstep a capture renders at once (its chunks are the reply); in realtime, after
:meth:`BoardCamera.start_worker`, it renders on a background thread and the chunks (or a NACK
NO_RENDERER) leave with the next tick's output (:meth:`BoardCamera.results`). The last
:data:`KEPT_IMAGES` images' chunks are kept by request id: the same request id again gets the same
image's chunks, CAMERA_RESEND the wanted ones (NACK BAD_VALUE once an image is no longer kept).
"""

from __future__ import annotations

from collections import OrderedDict

import mujoco

from firmware_sim.peripherals import MAX_IMAGE_SIDE, Camera, CameraUnavailable, CameraWorker
from protocol.codec import msg_type_of
from protocol.messages import CameraCapture, CameraChunk, CameraResend, Message, MsgType, Nack, NackReason

__all__ = ["KEPT_IMAGES", "BoardCamera", "nack"]

KEPT_IMAGES = 2  # camera images the board keeps for CAMERA_RESEND


def nack(msg: object, seq: int, reason: NackReason, detail: str) -> Nack:
    """NACK ``reason`` of ``msg`` (its type; HELLO when it is no message) with ``detail`` as ASCII, at most 64 chars."""
    try:
        mt = msg_type_of(msg)  # type: ignore[arg-type]
    except Exception:
        mt = MsgType.HELLO
    return Nack(seq, mt, reason, detail.encode("ascii", "replace").decode("ascii")[:64])


class BoardCamera:
    """The camera of one board's model (``spec``: the robot's MJCF camera name, None when it has none)."""

    def __init__(self, model: mujoco.MjModel, spec: str | None) -> None:
        self.model = model
        self.spec = spec
        self.camera = Camera(model, spec)
        #: renders off the control loop once started (realtime), else None: captures render at once
        self.worker: CameraWorker | None = None
        self._seqs: dict[int, int] = {}  # request id -> sequence number of a capture being rendered
        #: the last KEPT_IMAGES images' chunks by request id, for CAMERA_RESEND and a repeated CAMERA_CAPTURE
        self.kept: OrderedDict[int, list[CameraChunk]] = OrderedDict()

    def start_worker(self) -> str | None:
        """Render captures in a background thread from now on; returns why not, if it can't."""
        self.worker = CameraWorker(self.model, self.spec)
        return self.worker.error

    def capture(self, msg: CameraCapture, seq: int, data: mujoco.MjData) -> list[Message]:
        """The reply to CAMERA_CAPTURE ``msg`` of the world in ``data``: chunks, NACK, or nothing yet (worker)."""
        if not (1 <= msg.width <= MAX_IMAGE_SIDE and 1 <= msg.height <= MAX_IMAGE_SIDE):
            return [nack(msg, seq, NackReason.BAD_VALUE, f"image size must be 1..{MAX_IMAGE_SIDE} per side")]
        kept = self.kept.get(msg.request_id)
        if kept is not None:  # the host asks again (its request or every chunk was lost): same image
            return list(kept)
        if self.worker is not None:  # realtime: render off the control loop
            if msg.request_id in self._seqs:
                return []  # a repeated request for an image being rendered: it is on its way
            if self.worker.error is not None:
                return [nack(msg, seq, NackReason.NO_RENDERER, self.worker.error)]
            if not self.worker.submit(msg.request_id, int(msg.width), int(msg.height), data):
                return [nack(msg, seq, NackReason.BUSY, "camera busy: too many captures in flight")]
            self._seqs[msg.request_id] = seq
            return []
        try:
            png = self.camera.capture_png(data, int(msg.width), int(msg.height))
        except CameraUnavailable as e:
            return [nack(msg, seq, NackReason.NO_RENDERER, str(e))]
        return list(self._keep(msg.request_id, Camera.chunks(msg.request_id, png)))

    def _keep(self, request_id: int, chunks: list[CameraChunk]) -> list[CameraChunk]:
        """Remember an image's chunks (the last ``KEPT_IMAGES``) so the host can ask for lost ones."""
        self.kept[request_id] = chunks
        while len(self.kept) > KEPT_IMAGES:
            self.kept.popitem(last=False)
        return chunks

    def resend(self, msg: CameraResend, seq: int) -> list[Message]:
        """The reply to CAMERA_RESEND: the wanted chunks of a kept image (all when ``wanted`` is empty)."""
        kept = self.kept.get(msg.request_id)
        if kept is None:
            return [nack(msg, seq, NackReason.BAD_VALUE, f"no image {msg.request_id} kept")]
        if not msg.wanted:
            return list(kept)
        out: list[Message] = []
        for k in range(len(msg.wanted) * 8):
            if msg.wanted[k // 8] >> (k % 8) & 1 and msg.first + k < len(kept):
                out.append(kept[msg.first + k])
        return out

    def results(self) -> list[Message]:
        """The worker's finished captures: their chunks (kept), or NACK NO_RENDERER for a failed one."""
        out: list[Message] = []
        for request_id, result in self.worker.results() if self.worker else ():
            seq = self._seqs.pop(request_id, 0)
            if isinstance(result, str):
                out.append(Nack(seq, MsgType.CAMERA_CAPTURE, NackReason.NO_RENDERER, result[:64]))
            else:
                out.extend(self._keep(request_id, result))
        return out
