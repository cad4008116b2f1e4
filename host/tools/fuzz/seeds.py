"""Seed corpora for the fuzz targets from real runs' frame logs (and the paper tasks' programs).

``python -m host.tools.fuzz.seeds RUN_DIR... [--out tests/fuzz]`` reads each run folder's
``host_frames.jsonl`` (written by ``ghostshell run``; ``tx`` = host -> board, ``rx`` = board -> host)
and writes small seed files in each target's input layout:

* ``serial-decoder``: windows of consecutive wire frames (both directions) + 4 chunking-seed bytes;
* ``session``: windows of board -> host frames + 4 bytes;
* ``board``: the host -> board frames as RAW operations, each ADVANCE followed by a TICKS operation
  (a lockstep run's board also starts at time 0, so apply-at times line up);
* ``can-decoder``: the same messages re-encoded as node 5's fixed-layout CAN frames (classic and FD,
  both receivers), as raw-id frame records;
* ``shell``: every paper task's ground-truth program, strict (``0x00``) and lenient (``0x01``) + 4 bytes.
"""

from __future__ import annotations

import argparse
import hashlib
import struct
from collections.abc import Iterable, Iterator
from pathlib import Path

from cobs import cobs

from protocol.framelog import iter_records
from protocol.messages import MsgType

__all__ = ["board_ops", "main", "wire_windows", "write_seeds"]

_TAIL = b"\x2a\x00\x00\x00"  # chunking seed 42
_TICK_US = 2000


def _frames(path: Path) -> Iterator[tuple[str, bytes]]:
    with open(path, encoding="utf-8") as f:
        for rec in iter_records(f):
            yield rec["dir"], bytes.fromhex(rec["raw"])


def wire_windows(frames: Iterable[bytes], limit: int = 2000, count: int = 12) -> list[bytes]:
    """Up to ``count`` runs of consecutive frames, each at most ``limit`` bytes, spread over the log."""
    frames = list(frames)
    if not frames:
        return []
    out: list[bytes] = []
    step = max(1, len(frames) // count)
    for start in range(0, len(frames), step):
        buf = b""
        for raw in frames[start:]:
            if len(buf) + len(raw) > limit:
                break
            buf += raw
        if buf:
            out.append(buf + _TAIL)
        if len(out) >= count:
            break
    return out


def board_ops(frames: Iterable[bytes], limit: int = 1500) -> list[bytes]:
    """Host -> board wire frames as ``firmware_sim.fuzz`` operations, split into inputs of ``limit`` bytes."""
    out: list[bytes] = []
    cur = b""
    advanced = 0
    for raw in frames:
        body = cobs.decode(raw[:-1])
        mtype, seq, payload = body[1], struct.unpack_from("<H", body, 2)[0], body[5:-2]
        op = struct.pack("<BBHB", 0, mtype, seq, len(payload)) + payload
        if mtype == MsgType.ADVANCE:
            until = struct.unpack_from("<Q", payload)[0]
            n = max(0, min(255, (until - advanced) // _TICK_US))
            advanced = until
            op += struct.pack("<BB", 2, n)
        if len(cur) + len(op) > limit and cur:
            out.append(cur)
            cur = b""
        cur += op
    if cur:
        out.append(cur)
    return out


def can_records(frames: Iterable[tuple[str, bytes]], receiver: str, node: int = 5, fd: bool = False,
                limit: int = 1500) -> list[bytes]:
    """Serial frame-log frames re-encoded as this node's fixed-layout CAN frames, as ``can-decoder`` inputs.

    ``receiver`` ``board`` takes the host -> board (``tx``) frames, ``host`` the board -> host ones;
    messages without a fixed layout (they travel as ISO-TP bulk) are skipped.
    """
    from protocol.can.codec import Sender, encode_fixed
    from protocol.codec import PayloadError
    from protocol.framing import Frame, FrameDecoder

    want = "tx" if receiver == "board" else "rx"
    sender = Sender.HOST if receiver == "board" else Sender.BOARD
    out: list[bytes] = []
    cur = bytes([0 if receiver == "board" else 1])
    dec = FrameDecoder()
    for direction, raw in frames:
        if direction != want:
            continue
        for item in dec.feed(raw):
            if not isinstance(item, Frame):
                continue
            try:
                can_frames = encode_fixed(item.msg, item.seq, node, fd, sender)
            except (PayloadError, KeyError, ValueError):
                continue
            rec = b"".join(
                struct.pack("<BHB", int(f.is_fd), f.arbitration_id, len(f.data)) + f.data for f in can_frames
            )
            if len(cur) + len(rec) > limit:
                out.append(cur)
                cur = bytes([0 if receiver == "board" else 1])
            cur += rec
    if len(cur) > 1:
        out.append(cur)
    return out


def write_seeds(target_dir: Path, seeds: Iterable[bytes], max_files: int = 24) -> int:
    """Write seeds named by content hash into ``target_dir``; returns how many were written."""
    target_dir.mkdir(parents=True, exist_ok=True)
    n = 0
    for s in list(seeds)[:max_files]:
        (target_dir / f"seed-{hashlib.sha1(s).hexdigest()[:16]}").write_bytes(s)
        n += 1
    return n


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m host.tools.fuzz.seeds", description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path, help="run folders with host_frames.jsonl")
    ap.add_argument("--out", type=Path, default=Path("tests/fuzz"))
    a = ap.parse_args(argv)
    serial: list[bytes] = []
    session: list[bytes] = []
    board: list[bytes] = []
    can: list[bytes] = []
    for run in a.runs:
        frames = list(_frames(run / "host_frames.jsonl"))
        serial += wire_windows((raw for _, raw in frames), count=6)
        session += wire_windows((raw for d, raw in frames if d == "rx"), count=6)
        board += board_ops(raw for d, raw in frames if d == "tx")[:6]
        for receiver in ("board", "host"):
            for fd in (False, True):
                can += can_records(frames, receiver, fd=fd)[:2]
    from robots.registry import load_robot

    tasks = load_robot().tasks
    shell = [flag + t.ground_truth.encode() + _TAIL for t in tasks.values() if t.ground_truth for flag in (b"\0", b"\1")]
    for name, seeds in (("serial-decoder", serial), ("session", session), ("board", board), ("shell", shell),
                        ("can-decoder", can)):
        print(f"{name}: {write_seeds(a.out / name / 'corpus', seeds, 60 if name == 'shell' else 24)} seed(s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
