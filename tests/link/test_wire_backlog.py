"""The host's model of its own line (``BoardClient.tx_wire``) and what the streamer plans with.

Over a UART of known baud (the emulated board's ``--baud``), a message sent now waits behind the
bytes sent before it; the host knows those bytes, so :meth:`BoardFrameLink.latency_us` adds the
line's present backlog instead of a p99 of past queues, and the TIME_SYNC samples count only the
latency beyond the line. Real pty, real serial transport; the board end is the pty's master fd.
"""

from __future__ import annotations

import os
import time

import anyio
import pytest

from host.link.client import BoardClient
from host.link.timesync import ClockSync
from host.link.transports.serial import SerialLinkTransport
from host.motion.board_link import BoardFrameLink
from protocol.framing import FRAME_DELIMITER, encode_frame
from protocol.messages import Flush, ServoFrame
from protocol.wiremodel import WireModel

BAUD = 115_200


def test_a_sync_sample_counts_only_the_latency_beyond_the_modelled_line() -> None:
    """Exchanges whose uplink was 1 ms beyond the line plus 0..4 ms on it (and say so): host_to_board
    + uplink p99 is when a message sent on an idle line arrives, 1 ms on, not 4 ms later."""
    true_offset = 5_000_000
    sync = ClockSync()
    for k in range(64):
        t1 = 1_000_000 + k * 50_000
        wire = (k % 5) * 1_000
        t2 = t1 + true_offset + 1_000 + wire
        sync.add(t1, t2, t2 + 20, t2 + 20 - true_offset + 1_000, wire_us=float(wire))
    est, up = sync.estimate, sync.uplink_quantile(0.99)
    assert est is not None and up is not None
    send = 5_000_000
    assert abs(est.host_to_board(send) + up - (send + true_offset + 1_000)) < 100


def test_the_board_clock_estimate_takes_each_legs_wire_time_out() -> None:
    """Over a modelled 115 200-baud line a TIME_SYNC request (17 bytes, 1.48 ms) is shorter on the wire
    than its reply (34 bytes, 2.95 ms). NTP's offset assumes equal legs and put the estimate half the
    difference (0.74 ms) behind the board clock; with each leg's wire time taken out it is within 20 µs,
    and host_to_board + uplink p99 is still when a message sent on an idle line arrives."""
    true_offset, beyond = 5_000_000, 120
    up_wire, down_wire = 17 * 10e6 / BAUD, 34 * 10e6 / BAUD

    def exchanges(sync: ClockSync, with_down: bool) -> ClockSync:
        for k in range(64):
            t1 = 1_000_000 + k * 50_000
            t2 = t1 + true_offset + beyond + round(up_wire)
            t4 = t2 + 20 - true_offset + beyond + round(down_wire)
            sync.add(t1, t2, t2 + 20, t4, wire_us=up_wire, wire_down_us=down_wire if with_down else 0.0)
        return sync

    send = 5_000_000
    for with_down, error in ((True, 20), (False, 700)):
        sync = exchanges(ClockSync(), with_down)
        est, up = sync.estimate, sync.uplink_quantile(0.99)
        assert est is not None and up is not None
        off = est.host_to_board(send) - (send + true_offset)
        assert (abs(off) < error) if with_down else (off < -error)  # the old estimate: behind the board
        assert abs(est.host_to_board(send) + up - (send + true_offset + beyond)) < 100


def test_the_line_model_occupies_and_frees_like_the_wire() -> None:
    line = WireModel(BAUD)
    end = line.occupy(10.0, 39)  # a 12-servo SERVO_FRAME at 115200 8N1: 3.39 ms
    assert end == pytest.approx(10.0 + 39 * 10 / BAUD)
    assert line.busy_s(10.001) == pytest.approx(end - 10.001)
    assert line.occupy(10.002, 17) == pytest.approx(end + 17 * 10 / BAUD)  # queued behind the frame
    assert line.busy_s(11.0) == 0.0  # idle: never negative
    assert WireModel(None).busy_s(10.0) == 0.0


def test_a_line_with_a_delimiter_releases_what_one_read_holds_frame_by_frame() -> None:
    """A start's first frame and FLUSH reach a pty in one write and are read at once: the board's model of
    its UART releases the frame when its own 39 bytes are through (3.39 ms), the FLUSH 19 bytes later,
    and an unfinished frame's bytes after them; without a delimiter the read is released whole."""
    first = encode_frame(ServoFrame(1_000_000, 0xFFF, tuple(0.1 * i for i in range(12))), 7)
    flush = encode_frame(Flush(1_000_001, 0xFFF), 8)
    assert (len(first), len(flush)) == (39, 19)
    line = WireModel(BAUD, FRAME_DELIMITER)
    line.push(10.0, first + flush + b"\x05\x01")
    assert line.pop_ready(10.0 + 38 * 10 / BAUD) == b""
    assert line.pop_ready(10.0 + 39 * 10 / BAUD + 1e-9) == first
    assert line.next_release() == pytest.approx(10.0 + 58 * 10 / BAUD)
    assert line.pop_ready(10.0 + 60 * 10 / BAUD + 1e-9) == flush + b"\x05\x01"
    assert line.bytes_queued == 0
    whole = WireModel(BAUD)
    whole.push(10.0, first + flush)
    assert whole.pop_ready(10.0 + 57 * 10 / BAUD) == b"" and whole.next_release() == pytest.approx(10.0 + 58 * 10 / BAUD)


def test_every_send_occupies_the_hosts_line_and_the_streamer_plans_behind_it() -> None:
    """Each send occupies the modelled line from the moment it was handed over (``_last_tx``), behind
    the bytes before it; ``latency_us`` then plans behind the whole backlog. Forty 12-servo frames sent
    faster than their wire time leave a backlog of up to ~135 ms, and the planned extra is compared with
    what is left of it (never below 0) at the clock readings just before and after it, so the check
    holds however long a loaded machine takes between two statements (a CI
    worker once took 3.9 ms inside one ``send``, which a fixed ± 2 ms had not allowed for)."""
    async def main() -> None:
        master, slave = os.openpty()
        try:
            transport = SerialLinkTransport(os.ttyname(slave))
            await transport.connect(lambda items: None, lambda reason: None)
            client = BoardClient(os.ttyname(slave), transport=transport, wire_baud=BAUD)
            link = BoardFrameLink(client, wire_baud=BAUD)
            line = client.tx_wire
            assert line is not None and link.client.tx_wire is line
            idle = link.latency_us(31)
            frame = ServoFrame(1_000_000, 0xFFF, tuple(0.1 * i for i in range(12)))
            for _ in range(40):
                before = line.free_at
                seq = client.session.transmit(frame)
                nbytes = len(encode_frame(frame, seq, client.schema))
                # the frame's wire time, from when it was handed over or behind the bytes before it
                assert line.free_at == pytest.approx(max(before, client.session.last_tx) + nbytes * 10 / BAUD, abs=1e-9)
            t0 = time.monotonic()
            extra = link.latency_us(31) - idle
            t1 = time.monotonic()
            # a message sent now waits behind the backlog: planned later by what is left of it
            assert max(0.0, line.free_at - t1) * 1e6 - 1 <= extra <= max(0.0, line.free_at - t0) * 1e6 + 1
            os.read(master, 4096)  # the bytes really went out
            transport.close()
        finally:
            os.close(master)
            os.close(slave)

    anyio.run(main)


def test_without_a_baud_nothing_is_modelled() -> None:
    client = BoardClient("/dev/null")
    link = BoardFrameLink(client)
    assert client.tx_wire is None
    assert link.latency_us(1_000) == link.latency_us(0)  # a pty: no wire time at all
