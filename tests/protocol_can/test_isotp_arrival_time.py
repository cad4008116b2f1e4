"""ISO-TP's N_Bs and N_Cr are judged at a frame's arrival, not at the time the loop read it (protocol/can/isotp_link.py).

A loop that stalls (a collection, a long lockstep batch, a starved process in User-Mode Linux) with the peer's
frames already waiting must not lose the transfer; a frame that really came late still times out. The clock is
virtual (``clock=``), so nothing here sleeps. The C link (gs_isotp.c) is held to the same rule in
tests/cfirmware/test_can_equivalence.py.
"""

from __future__ import annotations

import time

import isotp

from protocol.can.frame import CanFrame
from protocol.can.isotp_link import ISOTP_BACKSTOP_MS, ISOTP_TIMEOUT_MS, MAX_FRAME_AGE_S, IsoTpLink
from protocol.can.pycan import from_can_message, to_can_message

MS = 1_000_000  # ns
SDU = bytes(range(40))  # a First Frame and five consecutive frames (classic CAN)


class Clock:
    def __init__(self) -> None:
        self.ns = 10_000 * MS

    def __call__(self) -> int:
        return self.ns


def _pair(clock: Clock) -> tuple[IsoTpLink, IsoTpLink, list[CanFrame], list[CanFrame]]:
    to_rx: list[CanFrame] = []
    to_tx: list[CanFrame] = []
    tx = IsoTpLink(rxid=0x681, txid=0x601, fd=False, send=to_rx.append, clock=clock)
    rx = IsoTpLink(rxid=0x601, txid=0x681, fd=False, send=to_tx.append, clock=clock)
    return tx, rx, to_rx, to_tx


def _answered_first_frame(clock: Clock) -> tuple[IsoTpLink, IsoTpLink, list[CanFrame], list[CanFrame]]:
    """A pair whose receiver has taken the First Frame and put its flow control in ``to_tx``."""
    tx, rx, to_rx, to_tx = _pair(clock)
    tx.send(SDU)
    tx.poll()
    rx.feed(to_rx.pop(0))
    rx.poll()
    return tx, rx, to_rx, to_tx


def test_the_timers_are_the_links_own() -> None:
    """can-isotp's private timer hooks are overridden (a can-isotp release that renamed them would fail here)."""
    clock = Clock()
    tx, rx, to_rx, to_tx = _pair(clock)
    tx.send(SDU)
    tx.poll()
    assert type(tx.layer.timer_rx_fc).__name__ == "_LinkTimer" and tx.layer.timer_rx_fc.start_time == clock.ns
    rx.feed(to_rx.pop(0))
    rx.poll()
    assert type(rx.layer.timer_rx_cf).__name__ == "_LinkTimer" and rx.layer.timer_rx_cf.start_time == clock.ns


def test_consecutive_frames_that_came_in_time_are_taken_however_late_the_loop_reads_them() -> None:
    clock = Clock()
    tx, rx, to_rx, to_tx = _pair(clock)
    tx.send(SDU)
    tx.poll()
    rx.feed(to_rx.pop(0))  # the First Frame
    assert rx.poll() == [] and len(to_tx) == 1  # the flow control goes out at once
    clock.ns += 2 * MS
    tx.feed(to_tx.pop())
    tx.poll()
    assert len(to_rx) == 5
    for f in to_rx:
        rx.feed(f)  # all five arrive 2 ms after the flow control ...
    clock.ns += 3 * ISOTP_TIMEOUT_MS * MS  # ... and the receiver's loop gets to them 600 ms later
    assert rx.poll() == [SDU]
    assert rx.errors == 0 and tx.errors == 0


def test_a_flow_control_that_came_in_time_is_taken_however_late_the_sender_reads_it() -> None:
    clock = Clock()
    tx, rx, to_rx, to_tx = _pair(clock)
    tx.send(SDU)
    tx.poll()
    clock.ns += 1 * MS
    rx.feed(to_rx.pop(0))
    rx.poll()
    tx.feed(to_tx.pop(), at_ns=clock.ns)  # arrived 1 ms after the First Frame
    clock.ns += 2 * ISOTP_TIMEOUT_MS * MS  # read 400 ms later
    tx.poll()
    assert tx.flow_control_timeouts == 0 and tx.errors == 0
    assert [f.data[0] >> 4 for f in to_rx] == [2] * 5  # the five consecutive frames went out (they are late now:
    # the receiver's N_Cr, from its flow control, is the stalled sender's to answer for, as ISO 15765-2 has it)


def test_frames_that_really_came_late_still_time_out() -> None:
    clock = Clock()
    tx, rx, to_rx, to_tx = _answered_first_frame(clock)
    fc = to_tx.pop()
    clock.ns += (ISOTP_TIMEOUT_MS + 1) * MS
    tx.feed(fc)  # the flow control arrives 201 ms after the First Frame went out: N_Bs ran out
    tx.poll()
    assert tx.flow_control_timeouts == 1 and to_rx == []
    clock.ns += (ISOTP_TIMEOUT_MS + 1) * MS  # and the receiver waited 201 ms more for a consecutive frame: N_Cr
    rx.poll()
    assert rx.errors == 1 and "ConsecutiveFrameTimeout" in rx.last_error


def test_a_frame_is_stamped_with_the_drivers_arrival_time() -> None:
    """python-can's ``Message.timestamp`` (the kernel's on SocketCAN) travels in ``CanFrame.timestamp`` and sets the
    arrival on the link's clock; no stamp means now; a stamp from a clock that jumped is bounded."""
    clock = Clock()
    link = IsoTpLink(rxid=0x601, txid=0x681, fd=False, send=lambda f: None, clock=clock)
    frame = from_can_message(to_can_message(CanFrame(0x601, b"\x10\x28" + bytes(6)), timestamp=time.time() - 0.25))
    assert frame.timestamp is not None and frame == CanFrame(0x601, b"\x10\x28" + bytes(6))  # not part of equality
    age_ms = (clock.ns - link.arrival_ns(frame)) / MS
    assert 250 <= age_ms < 350
    assert link.arrival_ns(CanFrame(0x601, b"\x01\x00")) == clock.ns
    assert link.arrival_ns(CanFrame(0x601, b"\x01\x00", timestamp=1.0)) == clock.ns - int(MAX_FRAME_AGE_S * 1e9)
    assert link.arrival_ns(CanFrame(0x601, b"\x01\x00", timestamp=time.time() + 60)) == clock.ns


def test_can_isotp_alone_would_have_lost_the_late_read_transfer() -> None:
    """The failure this guards against, shown on can-isotp's own clock-reading timers: the same late read loses the
    transfer (so the tests above would fail without the arrival stamps)."""
    clock = Clock()
    tx, rx, to_rx, to_tx = _answered_first_frame(clock)
    tx.feed(to_tx.pop())
    tx.poll()
    plain = isotp.tools.Timer(ISOTP_TIMEOUT_MS / 1000)
    plain.start()
    plain.start_time -= (ISOTP_TIMEOUT_MS + 1) * MS  # as if started 201 ms ago by time.perf_counter_ns
    rx.layer.timer_rx_cf = plain
    for f in to_rx:
        rx.feed(f)
    assert rx.poll() == [] and rx.errors >= 1


def _board_sender(clock: Clock, board: Clock) -> tuple[IsoTpLink, list[CanFrame]]:
    out: list[CanFrame] = []
    tx = IsoTpLink(rxid=0x601, txid=0x681, fd=False, send=out.append, clock=clock, board_clock=board)
    tx.send(SDU)
    tx.poll()
    assert len(out) == 1  # the First Frame; N_Bs runs
    return tx, out


FC = CanFrame(0x601, bytes([0x30, 0, 0]) + b"\xcc" * 5)


def test_lockstep_counts_board_time_so_a_slow_host_loses_no_transfer() -> None:
    """With a board clock (lockstep), a flow control 600 ms late in wall time but 50 ms in board time is in time."""
    clock, board = Clock(), Clock()
    tx, out = _board_sender(clock, board)
    clock.ns += 600 * MS  # the host took 600 ms of wall time to answer ...
    board.ns += 50 * MS  # ... while the board ran 50 ms (it never runs past the frames the host sent)
    tx.feed(FC)
    tx.poll()
    assert tx.errors == 0 and len(out) == 6


def test_lockstep_times_out_on_board_time_and_on_the_wall_clock_backstop() -> None:
    clock, board = Clock(), Clock()
    tx, out = _board_sender(clock, board)
    board.ns += (ISOTP_TIMEOUT_MS + 1) * MS  # 201 ms of board time without a flow control: N_Bs
    tx.poll()
    assert tx.flow_control_timeouts == 1
    clock2, board2 = Clock(), Clock()
    tx2, _ = _board_sender(clock2, board2)
    clock2.ns += (ISOTP_BACKSTOP_MS - 1) * MS  # a host that went away: board time stands still
    tx2.poll()
    assert tx2.flow_control_timeouts == 0
    clock2.ns += 2 * MS  # ISO 15765-2's 1 000 ms of wall time: the backstop
    tx2.poll()
    assert tx2.flow_control_timeouts == 1
