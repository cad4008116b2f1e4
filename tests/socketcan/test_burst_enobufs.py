"""A burst larger than the transmit queue (python-can issue #2004: ``ENOBUFS``), on a real kernel.

vcan itself never pushes back: its qdisc is ``noqueue`` and a frame is looped back synchronously,
so a burst of any size "succeeds" at the sender (and a receiver that is not reading loses what
does not fit its socket receive buffer, silently). A real controller (``can0``) has a queue of 10
frames in front of a 1 Mbit/s wire; when it is full the kernel's ``can_send()`` gets
``NET_XMIT_DROP`` from the qdisc and returns ``-ENOBUFS`` — python-can #2004. Here that is
reproduced on ``vcan1`` with a token-bucket qdisc (``tc qdisc ... tbf``) shaped like a 1 Mbit/s bus
with a 10-frame queue. What the tests pin down:

* every ``send()`` either succeeds or raises ``can.CanOperationError`` with ``errno.ENOBUFS``
  (nothing else, no crash) — also with a blocking ``timeout=None``, because ENOBUFS is a drop
  at the qdisc, not a full socket buffer, so ``select()`` does not wait for room;
* the frames whose ``send()`` succeeded are exactly the ones on the wire, in order (no frame is
  sent twice or reordered), and the qdisc's drop counter equals the number of ENOBUFS errors;
* a sender that retries a refused frame until the queue takes it delivers the whole burst in
  order — what a CAN transport must do instead of dropping or crashing.
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
#: A 16-byte classic CAN skb every ~135 bit times at 1 Mbit/s ~= 947 kbit/s of skb bytes.
TBF = ("tbf", "rate", "947kbit", "burst", "256", "limit", "160")  # limit 160 B = 10 frames
N = 2000


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
    for i in range(N):
        while True:
            try:
                tx.send(_msg(i))
                break
            except can.CanOperationError as exc:
                assert exc.error_code == errno.ENOBUFS, exc
                retries += 1  # retried at once: the qdisc drains a frame every ~135 us
    got = []
    for _ in range(N):
        msg = rx.recv(timeout=5)
        assert msg is not None
        got.append(int.from_bytes(msg.data[:4], "little"))
    assert got == list(range(N))
    assert retries > 0
