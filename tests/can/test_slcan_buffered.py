"""BufferedSlcanBus: python-can's SLCAN bus reading every waiting byte at once, losing no line.

A real pty stands in for the adapter: the test writes Lawicel lines to the master side in one
burst (frames, adapter responses ``z``/``\\r`` between them, an error bell) and reads them through
the bus on the slave side.
"""

from __future__ import annotations

import os
import pty
import tty

from host.link.transports.slcan_rx import BufferedSlcanBus


def test_a_burst_of_lines_comes_out_frame_by_frame_in_order() -> None:
    master, slave = pty.openpty()
    tty.setraw(master)
    bus = BufferedSlcanBus(os.ttyname(slave), sleep_after_open=0)
    try:
        frames = [f"t081{8}{k:02X}00000000000000".encode() for k in range(200)]
        burst = b"z\r".join(f + b"\r" for f in frames) + b"\a" + b"t0812ABCD\r"
        os.write(master, burst)
        got = []
        while len(got) < 201:
            msg = bus.recv(timeout=1.0)
            assert msg is not None, f"stopped after {len(got)} frames"
            got.append(msg)
        assert [m.data[0] for m in got[:200]] == list(range(200))
        assert all(m.arbitration_id == 0x081 and m.dlc == 8 for m in got[:200])
        assert bytes(got[200].data) == b"\xab\xcd"
        assert not bus.has_buffered_line()
        # a line split across two writes is kept until its end arrives
        os.write(master, b"t0811")
        assert bus.recv(timeout=0) is None
        os.write(master, b"7F\r")
        last = bus.recv(timeout=1.0)
        assert last is not None and bytes(last.data) == b"\x7f"
    finally:
        bus.shutdown()
        os.close(master)
        os.close(slave)
