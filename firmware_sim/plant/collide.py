"""Two devices answering at once on a half-duplex UART line: what the controller's UART receives.

Both transmitters drive the one wire; the line is low while either sends a 0 (wired-AND: the idle
and stop level is 1). Each byte is a frame of 10 bits (start 0, 8 data bits LSB first, stop 1).
The second device starts ``lag_bits`` bit times after the first (servos' return delays and clocks
never match exactly), so the frames overlap misaligned; the result is decoded as a UART would:
wait for a falling edge, sample 8 data bits, drop frames without their stop bit (a framing error).
"""

from __future__ import annotations

__all__ = ["collide"]


def _bits(data: bytes) -> list[int]:
    out: list[int] = []
    for b in data:
        out.append(0)
        out.extend((b >> k) & 1 for k in range(8))
        out.append(1)
    return out


def collide(a: bytes, b: bytes, lag_bits: int = 3) -> bytes:
    """The bytes a UART decodes when ``b`` is sent ``lag_bits`` bit times after ``a`` on the same line."""
    la, lb = _bits(a), _bits(b)
    n = max(len(la), len(lb) + lag_bits) + 10
    line = [1] * n
    for i, v in enumerate(la):
        line[i] &= v
    for i, v in enumerate(lb):
        line[i + lag_bits] &= v
    out = bytearray()
    i = 0
    while i + 10 <= n:
        if line[i] == 0:  # start bit
            frame = line[i:i + 10]
            i += 10
            if frame[9] == 1:  # stop bit present
                out.append(sum(bit << k for k, bit in enumerate(frame[1:9])))
            else:  # a framing error: the byte is dropped and the UART waits for the line to go idle
                while i < n and line[i] == 0:
                    i += 1
        else:
            i += 1
    return bytes(out)
