"""The runtime's view of a :class:`host.link.BoardClient`: frames, flushes, peripherals, board time."""

from __future__ import annotations

from host.motion.board_link import BoardFrameLink
from protocol.messages import ScreenCommand, SpeakerCommand


class ClientLink(BoardFrameLink):
    """Adapts :class:`BoardClient` to :class:`host.runtime.robot_runtime.RobotLink`: the streamer's frame link
    plus peripheral commands and camera captures."""

    async def send_peripheral(self, msg: ScreenCommand | SpeakerCommand) -> None:
        await self.client.request(msg)

    async def capture(self, width: int, height: int) -> bytes:
        return await self.client.capture(width, height)
