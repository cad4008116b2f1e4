"""A burst larger than the transmit queue (python-can issue #2004: ``ENOBUFS``), on a real kernel.

vcan itself never pushes back: its qdisc is ``noqueue`` and a frame is looped back synchronously,
so a burst of any size "succeeds" at the sender (and a receiver that is not reading loses what
does not fit its socket receive buffer, silently). A real controller (``can0``) has a queue of 10
frames in front of a 1 Mbit/s wire; when it is full the kernel's ``can_send()`` gets
``NET_XMIT_DROP`` from the qdisc and returns ``-ENOBUFS`` — python-can #2004. Here that is
reproduced on ``vcan1`` with a token-bucket qdisc (``tc qdisc ... tbf``) shaped like a 1 Mbit/s bus
with a 10-frame queue, but a slower one (below). What the tests pin down:

* every ``send()`` either succeeds or raises ``can.CanOperationError`` with ``errno.ENOBUFS``
  (nothing else, no crash) — also with a blocking ``timeout=None``, because ENOBUFS is a drop
  at the qdisc, not a full socket buffer, so ``select()`` does not wait for room;
* the frames whose ``send()`` succeeded are exactly the ones on the wire, in order (no frame is
  sent twice or reordered), and the qdisc's drop counter equals the number of ENOBUFS errors;
* a sender that retries a refused frame until the queue takes it delivers the whole burst in
  order — what a CAN transport must do instead of dropping or crashing.

The queue drains at 16 kbit/s, not at a 1 Mbit/s wire's rate, so the test does not depend on
how fast this machine sends. A 16-byte classic CAN skb leaves a 1 Mbit/s bus every ~135 us, and
a Python ``send()`` inside User-Mode Linux takes about as long (measured: 134 us per send, 2 000
sends, quiet machine): at 947 kbit/s the sender never got ahead of the queue, so the burst
overflowed it on a fast CI machine and never on this one. At 16 kbit/s a frame leaves every 8 ms,
~60x slower than that sender: the 10-frame queue overflows however loaded the machine is, and
ENOBUFS comes from the queue being full, which is what python-can #2004 is about (the wire rate
behind the queue does not matter to it).
"""

from __future__ import annotations

import errno
import os
import re
import shutil
import socket
import subprocess
from typing import Any

import can
import pytest

from support.uml import native_vcan

CHANNEL = "vcan1"
#: 16 kbit/s of 16-byte skbs: one frame every 8 ms (see the module docstring); burst 32 B = two
#: frames' tokens, limit 160 B = 10 frames queued, as in front of a real can0.
TBF = ("tbf", "rate", "16kbit", "burst", "32", "limit", "160")
N = 2000  # the refused-burst test: 2 000 sends, ~0.3 s inside UML, of which ~10 + 0.3 s / 8 ms are accepted
N_RETRY = 200  # the retry test delivers every frame: 200 x 8 ms = 1.6 s of draining


@pytest.fixture
def shaped_channel() -> Any:
    if not native_vcan(CHANNEL):
        pytest.skip(f"{CHANNEL} is not up (the UML run creates it)")
    if shutil.which("tc") is None or os.geteuid() != 0:
        pytest.skip("shaping vcan1 needs `tc` (iproute2) and root (both hold inside UML)")
    subprocess.run(["tc", "qdisc", "replace", "dev", CHANNEL, "root", *TBF], check=True)
    yield CHANNEL
    subprocess.run(["tc", "qdisc", "del", "dev", CHANNEL, "root"], check=False)


def _qdisc_dropped(channel: str) -> int:
    out = subprocess.run(["tc", "-s", "qdisc", "show", "dev", channel], check=True, capture_output=True, text=True).stdout
    match = re.search(r"dropped (\d+)", out)
    assert match, out
    return int(match.group(1))


def _receiver(open_bus: Any, channel: str) -> can.BusABC:
    rx = open_bus(channel)
    # room for the whole burst: SO_RCVBUFFORCE (root may pass net.core.rmem_max)
    rx.socket.setsockopt(socket.SOL_SOCKET, getattr(socket, "SO_RCVBUFFORCE", 33), 8 << 20)
    return rx


def _msg(i: int) -> can.Message:
    return can.Message(arbitration_id=0x100 + (i % 16), data=i.to_bytes(4, "little") + bytes(4), is_extended_id=False)


@pytest.mark.parametrize("timeout", [0.0, None], ids=["nonblocking", "blocking"])
def test_burst_past_the_queue_gets_enobufs_and_loses_only_refused_frames(
    open_bus: Any, shaped_channel: str, timeout: float | None
) -> None:
    rx, tx = _receiver(open_bus, shaped_channel), open_bus(shaped_channel)
    dropped_before = _qdisc_dropped(shaped_channel)
    accepted: list[int] = []
    refused = 0
    for i in range(N):
        try:
            tx.send(_msg(i), timeout=timeout)
            accepted.append(i)
        except can.CanOperationError as exc:
            assert exc.error_code == errno.ENOBUFS, exc
            refused += 1
    assert refused > 0, "the shaped queue never overflowed: the test no longer reproduces #2004"
    assert _qdisc_dropped(shaped_channel) - dropped_before == refused
    got: list[int] = []
    while len(got) < len(accepted):
        msg = rx.recv(timeout=5)
        assert msg is not None, f"only {len(got)} of {len(accepted)} accepted frames arrived"
        got.append(int.from_bytes(msg.data[:4], "little"))
    assert got == accepted
    assert rx.recv(timeout=0) is None


def test_retrying_refused_frames_delivers_the_whole_burst_in_order(open_bus: Any, shaped_channel: str) -> None:
    rx, tx = _receiver(open_bus, shaped_channel), open_bus(shaped_channel)
    retries = 0
    for i in range(N_RETRY):
        while True:
            try:
                tx.send(_msg(i))
                break
            except can.CanOperationError as exc:
                assert exc.error_code == errno.ENOBUFS, exc
                retries += 1  # retried at once: the qdisc drains a frame every 8 ms
    got = []
    for _ in range(N_RETRY):
        msg = rx.recv(timeout=5)
        assert msg is not None
        got.append(int.from_bytes(msg.data[:4], "little"))
    assert got == list(range(N_RETRY))
    assert retries > 0
