"""The host's SLCAN output on a full port: sending never blocks the event loop and never splits a line.

A real pty stands between the host's CAN transport and an SLCAN adapter that the test drives by
hand (``SlcanDevice``, the board's adapter side), so the adapter can stop reading, as a busy
board or a stalled USB adapter does. python-can's own ``slcanBus.send`` spins in pyserial's
write while the port is full (pyserial #280), which froze the host's event loop -- the run's
silence watchdog included -- and lost the rest of a line the port took in part; with that send
this test does not return (pytest-timeout fails it).
"""

from __future__ import annotations

import asyncio
import os
import tty
from collections.abc import Iterator

import can
import pytest

from protocol.can.slcan import SlcanDevice
from host.link.transports.can import CanLinkTransport
from host.link.transports.slcan_tx import slcan_line
from protocol.can import CanDecoder, CanItem
from protocol.linkspec import parse_link_spec
from protocol.messages import ServoFrame

pytestmark = pytest.mark.timeout(30)


@pytest.fixture
def pty() -> Iterator[tuple[int, str]]:
    """(master fd, slave path): the adapter's end and the port the host opens."""
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    try:
        yield master, os.ttyname(slave)
    finally:
        for fd in (master, slave):
            os.close(fd)


def _read_all(master: int) -> bytes:
    out = bytearray()
    while True:
        try:
            chunk = os.read(master, 65536)
        except BlockingIOError:
            return bytes(out)
        if not chunk:
            return bytes(out)
        out += chunk


def test_a_full_port_queues_instead_of_blocking_and_loses_no_line(pty: tuple[int, str]) -> None:
    master, port = pty
    n_frames = 600  # 3 600 CAN frames, ~110 kB of SLCAN text: far more than the pty holds
    device = SlcanDevice()
    decoder = CanDecoder(1, "board")
    items: list[CanItem] = []

    async def main() -> None:
        loop = asyncio.get_running_loop()
        host = CanLinkTransport(parse_link_spec(f"can:slcan:{port}"))
        await host.connect(lambda _items: None, lambda reason: pytest.fail(f"link lost: {reason}"))
        device.feed(_read_all(master))  # python-can's open sequence (... O): the channel is open
        assert device.is_open
        try:
            # nobody reads the adapter's end: every send returns at once, the excess waits in order
            for i in range(n_frames):
                host.send(ServoFrame(i * 10_000, 0xFFF, tuple([0.01 * (i % 50)] * 12)), i)
            assert host.backlog > 0 and host.tx_retries > 0  # the port was full and the host waited

            # the adapter reads again: the loop's writer callback finishes the rest as room appears
            drained = asyncio.Event()

            def adapter() -> None:
                events, _ = device.feed(_read_all(master))
                for ev in events:
                    if ev.frame is not None:
                        items.extend(i for i in decoder.feed(ev.frame) if isinstance(i, CanItem))
                if host.backlog == 0 and len(items) == n_frames:
                    drained.set()

            loop.add_reader(master, adapter)
            try:
                await drained.wait()
            finally:
                loop.remove_reader(master)
        finally:
            _read_all(master)  # room for python-can's closing "C" (it writes it blocking)
            host.close()

    asyncio.run(main())
    assert device.errors == 0 and decoder.error_count == 0  # every line whole: nothing glued or cut
    assert [i.seq for i in items] == list(range(n_frames))
    assert [i.msg.apply_at_us for i in items] == [k * 10_000 for k in range(n_frames)]  # type: ignore[attr-defined]


@pytest.mark.parametrize("msg", [
    can.Message(arbitration_id=0x181, data=bytes(range(8)), is_extended_id=False),
    can.Message(arbitration_id=0x701, data=b"", is_extended_id=False),
    can.Message(arbitration_id=0x581, data=bytes(range(48)), is_fd=True, is_extended_id=False),
    can.Message(arbitration_id=0x581, data=bytes(12), is_fd=True, bitrate_switch=True, is_extended_id=False),
])
def test_lines_are_the_ones_python_can_writes(msg: can.Message) -> None:
    bus = can.Bus(interface="slcan", channel="loop://", sleep_after_open=0)  # pyserial's loopback port
    try:
        port = bus.serialPortOrig  # type: ignore[attr-defined]
        port.read(port.in_waiting)  # the open sequence
        bus.send(msg)
        assert port.read(port.in_waiting) == slcan_line(msg)
    finally:
        bus.shutdown()
