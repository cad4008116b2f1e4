"""python-can's own ``socketcan`` driver on a real kernel's vcan: classic CAN, CAN FD, candump.

These pin down the ground the CAN transports stand on (and validate the UML harness): frames go
through the kernel's CAN stack, not through an in-process fake.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import can

from support.candump import CandumpCapture

CHANNEL = "vcan0"



def _frames(n: int, fd: bool = False) -> list[can.Message]:
    size = 64 if fd else 8
    return [
        can.Message(
            arbitration_id=0x100 + i,
            data=bytes((i + k) % 256 for k in range(size)),
            is_extended_id=False,
            is_fd=fd,
            bitrate_switch=fd,
        )
        for i in range(n)
    ]


def test_classic_frames_round_trip_in_order(open_bus: Any) -> None:
    rx, tx = open_bus(), open_bus()
    sent = _frames(32)
    for msg in sent:
        tx.send(msg)
    got = [rx.recv(timeout=5) for _ in sent]
    assert all(m is not None for m in got)
    assert [(m.arbitration_id, bytes(m.data), m.dlc, m.is_fd) for m in got] == [
        (m.arbitration_id, bytes(m.data), 8, False) for m in sent
    ]
    assert all(m.channel == CHANNEL for m in got)
    assert rx.recv(timeout=0) is None  # nothing more on the bus


def test_fd_frames_carry_64_bytes_and_brs(open_bus: Any) -> None:
    rx, tx = open_bus(fd=True), open_bus(fd=True)
    sent = _frames(8, fd=True)
    for msg in sent:
        tx.send(msg)
    got = [rx.recv(timeout=5) for _ in sent]
    assert all(m is not None and m.is_fd and m.bitrate_switch and m.dlc == 64 for m in got)
    assert [bytes(m.data) for m in got] == [bytes(m.data) for m in sent]


def test_classic_socket_never_sees_fd_frames(open_bus: Any) -> None:
    """A socket opened without ``fd=True`` gets classic frames only (kernel CAN_RAW_FD_FRAMES off)."""
    classic, tx = open_bus(fd=False), open_bus(fd=True)
    tx.send(_frames(1, fd=True)[0])
    tx.send(_frames(1)[0])
    got = classic.recv(timeout=5)
    assert got is not None and not got.is_fd and got.dlc == 8
    assert classic.recv(timeout=0) is None


def test_candump_log_of_the_traffic_reads_back_identically(open_bus: Any, tmp_path: Path) -> None:
    tx = open_bus(fd=True)
    sent = _frames(5) + _frames(3, fd=True)
    log = tmp_path / "capture.log"
    with CandumpCapture(CHANNEL, log) as capture:
        for msg in sent:
            tx.send(msg)
    lines = log.read_text().splitlines()
    assert len(lines) == len(sent) and all(f" {CHANNEL} " in line for line in lines)
    got = capture.messages()
    assert [(m.arbitration_id, bytes(m.data), m.is_fd, m.bitrate_switch) for m in got] == [
        (m.arbitration_id, bytes(m.data), m.is_fd, m.bitrate_switch) for m in sent
    ]
    stamps = [m.timestamp for m in got]
    assert stamps == sorted(stamps) and stamps[0] > 0
