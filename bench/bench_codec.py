"""Codec throughput: encode and decode frames/s for SERVO_FRAME and TELEMETRY.

Run: ``.venv/bin/python bench/bench_codec.py [--seconds S]``. Prints numbers only;
nothing is asserted. Encode = ``encode_frame`` (payload + header + CRC + COBS);
decode = ``FrameDecoder.feed`` on a 100-frame byte stream (COBS + CRC + payload).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

from protocol.framing import FrameDecoder, encode_frame, frame_size
from protocol.testing.samples import servo_frame_12, telemetry_12


def rate(fn: Callable[[], int], seconds: float) -> float:
    """Calls ``fn`` (which returns the frames it handled) for ~``seconds``; frames per second."""
    n = 0
    t0 = time.perf_counter()
    deadline = t0 + seconds
    while True:
        n += fn()
        now = time.perf_counter()
        if now >= deadline:
            return n / (now - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=1.0, help="time per measurement (default 1)")
    args = ap.parse_args()
    print(f"{'message':<12} {'bytes':>5} {'encode frames/s':>16} {'decode frames/s':>16}")
    for name, msg in (("SERVO_FRAME", servo_frame_12()), ("TELEMETRY", telemetry_12())):
        stream = b"".join(encode_frame(msg, i) for i in range(100))

        def enc(msg=msg) -> int:
            for i in range(100):
                encode_frame(msg, i)
            return 100

        def dec(stream=stream) -> int:
            return len(FrameDecoder().feed(stream))

        print(f"{name:<12} {frame_size(msg):>5} {rate(enc, args.seconds):>16,.0f} {rate(dec, args.seconds):>16,.0f}")


if __name__ == "__main__":
    main()
