"""The last frames a CAN frame log holds in each direction, to compare the two ends' logs of one run."""

from __future__ import annotations

from pathlib import Path

import can

__all__ = ["last_frames"]


def last_frames(path: str | Path, n: int, *, received: bool) -> list[str]:
    """The last ``n`` frames of a python-can log (any suffix) that this end received (``received``) or sent,
    as ``ID#DATA`` text, in file order."""
    rows = [f"{m.arbitration_id:03X}#{bytes(m.data).hex()}" for m in can.LogReader(str(path))  # type: ignore[no-untyped-call]
            if bool(m.is_rx) == received and not m.is_error_frame]
    return rows[-n:]
