"""One real board subprocess on a real pty: it announces the pty, answers HELLO, renders the camera, exits on SIGTERM."""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import serial

from protocol.codec import SCHEMA_HASH
from protocol.framing import DecodeError, Frame, FrameDecoder, encode_frame
from protocol.messages import PROTOCOL_VERSION, CameraCapture, CameraChunk, Caps, Hello, Nack

ROOT = Path(__file__).resolve().parents[2]


def _read_until(ser: serial.Serial, dec: FrameDecoder, pred, timeout: float = 10.0) -> list[Frame | DecodeError]:
    got: list[Frame | DecodeError] = []
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        select.select([ser.fileno()], [], [], 0.2)
        got += dec.feed(ser.read(65536))
        if pred(got):
            return got
    raise AssertionError(f"timed out; got {[type(g.msg).__name__ if isinstance(g, Frame) else g for g in got][-5:]}")


def test_board_on_pty_answers_hello(tmp_path: Path) -> None:
    log = tmp_path / "board.jsonl"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--link", "pty", "--lockstep", "--log", str(log)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline().strip()
        assert first.startswith("board: listening on /dev/pts/"), first
        port = first.removeprefix("board: listening on ")
        with serial.Serial(port, 115200, timeout=0) as ser:
            ser.reset_input_buffer()
            dec = FrameDecoder()
            ser.write(b"\x00garbage\x00" + encode_frame(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 123), 7))
            got = _read_until(ser, dec, lambda g: any(isinstance(f, Frame) and isinstance(f.msg, Caps) for f in g))
            caps = next(f.msg for f in got if isinstance(f, Frame) and isinstance(f.msg, Caps))
            assert caps.servo_count == 12 and caps.lockstep and caps.schema_hash == SCHEMA_HASH
            # wrong schema -> NACK with a clear detail
            ser.write(encode_frame(Hello(PROTOCOL_VERSION, SCHEMA_HASH ^ 1, 0), 8))
            got = _read_until(ser, dec, lambda g: any(isinstance(f, Frame) and isinstance(f.msg, Nack) for f in g))
            nack = next(f.msg for f in got if isinstance(f, Frame) and isinstance(f.msg, Nack))
            assert nack.ack_seq == 8 and "schema" in nack.detail
            # head camera: PNG in chunks (or a clear NO_RENDERER where no GL backend exists)
            ser.write(encode_frame(CameraCapture(5, 64, 48), 9))
            def done(g: list) -> bool:
                chunks = [f.msg for f in g if isinstance(f, Frame) and isinstance(f.msg, CameraChunk)]
                nacks = [f.msg for f in g if isinstance(f, Frame) and isinstance(f.msg, Nack) and f.msg.ack_seq == 9]
                return bool(nacks) or (bool(chunks) and len(chunks) == chunks[0].total)
            got = _read_until(ser, dec, done)
            chunks = [f.msg for f in got if isinstance(f, Frame) and isinstance(f.msg, CameraChunk)]
            if chunks:
                png = b"".join(c.data for c in sorted(chunks, key=lambda c: c.index))
                assert png.startswith(b"\x89PNG\r\n\x1a\n")
            else:
                nack = next(f.msg for f in got if isinstance(f, Frame) and isinstance(f.msg, Nack))
                assert nack.reason.name == "NO_RENDERER" and nack.detail
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 130  # SIGTERM: "interrupted", after a clean shutdown
        err = proc.stderr.read() if proc.stderr else ""
        assert "link error" in err  # the garbage was counted and reported, not fatal
        recs = [json.loads(line) for line in log.read_text().splitlines()]
        assert any(r["dir"] == "rx" and r.get("type") == "HELLO" for r in recs)
        assert any(r["dir"] == "tx" and r.get("type") == "CAPS" for r in recs)
        assert any(r["dir"] == "rx" and r.get("error") for r in recs)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def _lockstep_run(chunk: int) -> list[bytes]:
    """Send HELLO + 60 frames to a fresh lockstep board in chunks of ``chunk`` frames; collect telemetry bytes."""
    import math

    from protocol.messages import MsgType, ServoFrame
    from robots.coco import load_servo_table

    neutral = load_servo_table().neutral
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--link", "pty", "--lockstep"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )
    try:
        assert proc.stdout is not None
        port = proc.stdout.readline().strip().removeprefix("board: listening on ")
        with serial.Serial(port, 115200, timeout=0) as ser:
            dec = FrameDecoder()
            wire = [encode_frame(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), 0)]
            for k in range(1, 61):
                q = list(neutral)
                q[8] += 0.5 * math.sin(k / 10)
                q[0] += 0.2 * math.sin(k / 10)
                wire.append(encode_frame(ServoFrame(k * 10_000, 0x0FFF, tuple(q)), k))
            for i in range(0, len(wire), chunk):
                ser.write(b"".join(wire[i : i + chunk]))
                ser.flush()
            got = _read_until(
                ser, dec, lambda g: sum(isinstance(f, Frame) and f.msg_type is MsgType.TELEMETRY for f in g) >= 30
            )
            return [f.raw for f in got if isinstance(f, Frame) and f.msg_type is MsgType.TELEMETRY][:30]
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=10)


def test_lockstep_over_pty_is_deterministic_however_chunked() -> None:
    assert _lockstep_run(chunk=1) == _lockstep_run(chunk=61)
