"""Frame-log file writer for the host's serial transport: JSON lines via :mod:`protocol.framelog`, host monotonic time."""

from __future__ import annotations

import time
from pathlib import Path
from typing import IO

from protocol import framelog
from protocol.framing import DecodeError, Frame

__all__ = ["FrameLogFile"]


class FrameLogFile:
    """Write one record per frame (``tx`` sent, ``rx`` received or discarded) to ``path``.

    ``t`` is ``time.monotonic()`` on the host, in seconds. Line-buffered, so a crash
    loses at most the line being written. The file is created with the first record, so a link
    that never opened leaves no empty log behind.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._f: IO[str] | None = None
        self._closed = False
        self.records = 0

    def write(self, direction: str, raw: bytes, item: Frame | DecodeError | None = None, t: float | None = None) -> None:
        if self._f is None:
            if self._closed:
                return
            self._f = open(self.path, "w", buffering=1, encoding="utf-8")
        rec = framelog.record(direction, time.monotonic() if t is None else t, raw, item)
        self._f.write(framelog.to_line(rec) + "\n")
        self.records += 1

    def close(self) -> None:
        self._closed = True
        if self._f is not None:
            self._f.close()
            self._f = None
