"""The board's CAN transport in isolation (python-can virtual bus, no board loop)."""

from __future__ import annotations

import can

from firmware_sim.transports.can import BusBoardTransport
from protocol.can import CanFrame, encode_bulk
from protocol.can.ids import bulk_ids
from protocol.framing import Frame
from protocol.linkspec import parse_link_spec
from protocol.messages import SpeakerAction, SpeakerCommand, SoundKind


def _isotp_frames(sdu: bytes, rxid: int) -> list[CanFrame]:
    """ISO-TP segments of ``sdu`` as the host sends them (first frame + consecutive frames, padded)."""
    frames = [CanFrame(rxid, bytes([0x10 | (len(sdu) >> 8), len(sdu) & 0xFF]) + sdu[:6])]
    rest, sn = sdu[6:], 1
    while rest:
        chunk, rest = rest[:7], rest[7:]
        frames.append(CanFrame(rxid, (bytes([0x20 | sn]) + chunk).ljust(8, b"\xcc")))
        sn = (sn + 1) & 0xF
    return frames


def test_a_bulk_message_completed_during_flush_is_delivered(virtual_channel: str) -> None:
    spec = parse_link_spec(f"can:virtual:{virtual_channel}")
    bus = can.Bus(interface="virtual", channel=virtual_channel)
    t = BusBoardTransport(spec, bus=bus)
    try:
        msg = SpeakerCommand(SpeakerAction.PLAY, SoundKind.SPEECH, 100, 1500, 80, text="Hello, I am CoCo!")
        sdu = encode_bulk(msg, 35)
        for f in _isotp_frames(sdu, bulk_ids(1)[0]):
            t.isotp.feed(f)  # frames arrived; ISO-TP has not run yet
        t.flush(0.0)  # the transmit path advances ISO-TP, which completes the message here
        items = t.receive(0.0, read=False)
        assert [i.msg for i in items if isinstance(i, Frame)] == [msg]
        assert [i.seq for i in items if isinstance(i, Frame)] == [35]
    finally:
        t.close()
