"""A raw-wire client for board tests: start a board subprocess, send frames, read what comes back.

Speaks pyserial + protocol.framing directly (no BoardClient), so a test controls every byte and
every sequence number (garbage, replays, reordering). Lockstep boards: nothing advances unless the
test sends frames or ADVANCE, so waits are on the board clock, not on sleeps.
"""

from __future__ import annotations

import select
import time
from pathlib import Path

import serial

from host.link.board_process import BoardProcess, start_board
from protocol.framing import DecodeError, Frame, FrameDecoder, encode_frame
from protocol.messages import Message


class Wire:
    def __init__(self, args: list[str], stderr: Path) -> None:
        self.board: BoardProcess = start_board(args, stderr, timeout=120)
        self.ser = serial.Serial(self.board.port, 115200, timeout=0)
        self.dec = FrameDecoder()
        self.seq = 0
        self.got: list[Frame | DecodeError] = []
        self.stderr = stderr

    def send(self, msg: Message, seq: int | None = None) -> int:
        s = self.seq if seq is None else seq
        if seq is None:
            self.seq = (self.seq + 1) & 0xFFFF
        self.ser.write(encode_frame(msg, s))
        return s

    def raw(self, data: bytes) -> None:
        self.ser.write(data)

    def frames(self) -> list[Frame]:
        return [f for f in self.got if isinstance(f, Frame)]

    def of(self, cls: type) -> list:
        return [f.msg for f in self.frames() if isinstance(f.msg, cls)]

    def wait(self, pred, timeout: float = 30.0, what: str = "") -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if pred():
                return
            select.select([self.ser.fileno()], [], [], 0.2)
            self.got += self.dec.feed(self.ser.read(65536))
            if self.board.proc.poll() is not None:
                raise AssertionError(f"the board exited ({self.board.proc.returncode}): {self.stderr.read_text()[-2000:]}")
        raise AssertionError(f"timed out waiting for {what}; last frames: "
                             f"{[type(f.msg).__name__ for f in self.frames()[-6:]]}")

    def close(self) -> int:
        self.ser.close()
        return self.board.stop()
