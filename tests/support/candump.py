"""Capture a SocketCAN interface with can-utils' ``candump -L`` into a candump log file.

The capture is synchronised without sleeps: after starting ``candump`` the capture sends probe
frames (id ``PROBE_ID``) until candump prints one — from then on, every frame on the bus is in
the capture. On exit it sends an end probe and waits until candump has printed it, so every frame
sent before ``__exit__`` is in the file. Probe frames are left out of the file, which then holds
exactly the bus traffic of the ``with`` block, in ``candump -L`` format (``(ts) vcan0 123#..``,
read back with ``can.CanutilsLogReader``).
"""

from __future__ import annotations

import shutil
import subprocess
import threading
from pathlib import Path
from types import TracebackType

import can

#: 11-bit id of the synchronisation probes (the highest standard id; keep it out of the protocol).
PROBE_ID = 0x7FF
_PROBE_HEX = f"{PROBE_ID:03X}#"


class CandumpError(RuntimeError):
    """candump is missing, exited early, or did not see a probe in time."""


class CandumpCapture:
    """``with CandumpCapture("vcan0", path): ...`` — the bus traffic of the block in ``path``.

    channel: SocketCAN interface; path: the candump log written (text, one frame a line);
    sync_timeout: seconds to wait for candump to see a probe (raises CandumpError after it).
    """

    def __init__(self, channel: str, path: Path, *, sync_timeout: float = 10.0) -> None:
        self.channel = channel
        self.path = Path(path)
        self.sync_timeout = sync_timeout
        self._proc: subprocess.Popen[str] | None = None
        self._bus: can.BusABC | None = None
        self._thread: threading.Thread | None = None
        self._seen = (threading.Event(), threading.Event())  # start probe, end probe
        self.lines = 0

    def __enter__(self) -> CandumpCapture:
        exe = shutil.which("candump")
        if exe is None:
            raise CandumpError("candump not found (apt-get install can-utils)")
        self._bus = can.Bus(interface="socketcan", channel=self.channel)
        self._proc = subprocess.Popen([exe, "-L", self.channel], stdout=subprocess.PIPE, text=True, bufsize=1)
        self._thread = threading.Thread(target=self._pump, name="candump-pump", daemon=True)
        self._thread.start()
        self._probe(0)
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        try:
            if exc_type is None:
                self._probe(1)
        finally:
            if self._proc is not None:
                self._proc.terminate()
                self._proc.wait(timeout=10)
            if self._thread is not None:
                self._thread.join(timeout=10)
            if self._bus is not None:
                self._bus.shutdown()

    def messages(self) -> list[can.Message]:
        """The captured frames, parsed by python-can's candump log reader."""
        return list(can.CanutilsLogReader(self.path))

    def _probe(self, marker: int) -> None:
        assert self._bus is not None and self._proc is not None
        event = self._seen[marker]
        waited = 0.0
        while not event.wait(0.02):  # re-send until candump has printed it (it may not be bound yet)
            if self._proc.poll() is not None:
                raise CandumpError(f"candump exited with {self._proc.returncode} on {self.channel}")
            waited += 0.02
            if waited > self.sync_timeout:
                raise CandumpError(f"candump did not see a probe frame on {self.channel} in {self.sync_timeout} s")
            self._bus.send(can.Message(arbitration_id=PROBE_ID, data=[marker], is_extended_id=False))

    def _pump(self) -> None:
        assert self._proc is not None and self._proc.stdout is not None
        started, ended = self._seen
        with open(self.path, "w") as out:
            for line in self._proc.stdout:
                fields = line.split()
                if not fields:
                    continue
                if fields[-1].startswith(_PROBE_HEX):
                    (ended if started.is_set() and fields[-1][len(_PROBE_HEX):] == "01" else started).set()
                    continue
                if started.is_set() and not ended.is_set():
                    out.write(line)
                    out.flush()
                    self.lines += 1
