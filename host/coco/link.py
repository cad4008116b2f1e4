"""The runtime's view of a :class:`host.link.BoardClient`: frames, flushes, peripherals, board time."""

from __future__ import annotations

from host.link.client import BoardClient
from protocol.messages import ScreenCommand, ServoFrame, SpeakerCommand

#: how long (wall seconds) to wait for the board clock to reach a time before giving up
BOARD_TIME_TIMEOUT_S = 120.0


class ClientLink:
    """Adapts :class:`BoardClient` to :class:`host.coco.runtime.CocoLink`."""

    def __init__(self, client: BoardClient, *, timeout_s: float = BOARD_TIME_TIMEOUT_S) -> None:
        self.client = client
        self.timeout_s = timeout_s

    @property
    def lockstep(self) -> bool:
        return self.client.lockstep

    def board_now_us(self) -> int:
        return self.client.board_now_estimate()

    async def send_frame(self, frame: ServoFrame) -> int:
        return self.client.send_frame(frame)

    async def flush(self, from_us: int, mask: int) -> None:
        await self.client.flush(from_us, mask)

    async def send_peripheral(self, msg: ScreenCommand | SpeakerCommand) -> None:
        if isinstance(msg, ScreenCommand):
            await self.client.screen(msg.target, msg.name, msg.start_at_us, msg.duration_ms)
        else:
            await self.client.speaker(msg.action, msg.kind, start_at_us=msg.start_at_us,
                                      duration_ms=msg.duration_ms, volume=msg.volume, name=msg.name, text=msg.text)

    async def wait_board_time(self, t_us: int) -> None:
        """Return once telemetry reports board time ``t_us`` (or later)."""
        await self.client.wait_for(lambda t: t.board_time_us >= t_us, timeout=self.timeout_s)

    async def capture(self, width: int, height: int) -> bytes:
        return await self.client.capture(width, height)
