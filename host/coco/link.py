"""The runtime's view of a :class:`host.link.BoardClient`: frames, flushes, peripherals, board time."""

from __future__ import annotations

from host.link.client import BoardClient
from protocol.messages import ScreenCommand, ServoFrame, SpeakerCommand


class ClientLink:
    """Adapts :class:`BoardClient` to :class:`host.coco.runtime.CocoLink`."""

    def __init__(self, client: BoardClient) -> None:
        self.client = client

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
        await self.client.request(msg)

    async def capture(self, width: int, height: int) -> bytes:
        return await self.client.capture(width, height)
