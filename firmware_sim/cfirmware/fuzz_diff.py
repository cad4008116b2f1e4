"""Fuzz target ``c-diff``: the same bytes through the C and the Python frame decoders, the same frames out.

Input: 4 bytes seed the chunking of the Python feed (the ``serial-decoder`` layout, so the
frame-log corpora seed it), the rest is the byte stream. The C decoder (``gs_link`` +
the generated codec, built as a shared library, :mod:`firmware_sim.cfirmware.build` kind
``libdecode``) takes it whole, the Python :class:`protocol.framing.FrameDecoder` in pseudo-random
chunks; both print one line per frame (sequence number, wire bytes, the decoded fields in wire
units: :func:`protocol.cgen.wire_text` / C ``gs_dump_msg``) or error (its kind), and the lists must
be equal (float32 NaN payload bits, which Python's float does not keep, are compared as bytes
only). Coverage guidance comes from the instrumented Python side (atheris); the C side runs plain.
"""

from __future__ import annotations

import ctypes
import math
import random
import sys
from collections.abc import Callable

__all__ = ["load", "python_lines"]


def python_lines(data: bytes, seed: int) -> list[str]:
    from protocol import codec
    from protocol.cgen import wire_text
    from protocol.framing import Frame, FrameDecoder

    dec = FrameDecoder()
    rng = random.Random(seed)
    items = []
    i = 0
    while i < len(data):
        n = rng.randint(0, 300)
        items += dec.feed(data[i:i + n])
        i += n
    out = []
    for it in items:
        if isinstance(it, Frame):
            nan = any(isinstance(f, codec.F32Array) and any(math.isnan(v) for v in getattr(it.msg, name))
                      for name, f in codec.LAYOUTS[it.msg_type])
            out.append(f"F {it.seq} {it.raw.hex()}" + ("" if nan else f" {wire_text(it.msg)}"))
        else:
            out.append(f"E {it.kind.value}")
    return out


def load(instrument: bool = False) -> Callable[[bytes], None]:
    if instrument:
        import atheris  # type: ignore[import-not-found,unused-ignore]

        with atheris.instrument_imports(include=["protocol"]):
            from protocol import cgen, codec, framing  # noqa: F401
    from firmware_sim.cfirmware.build import build
    from robots.registry import DEFAULT_ROBOT, load_robot

    lib = ctypes.CDLL(str(build("libdecode", load_robot(DEFAULT_ROBOT))))
    lib.gs_diff_decode.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_char_p, ctypes.c_size_t]
    lib.gs_diff_decode.restype = ctypes.c_size_t
    out = ctypes.create_string_buffer(1 << 22)

    def one_input(data: bytes) -> None:
        if len(data) < 4:
            return
        seed, stream = int.from_bytes(data[:4], "little"), data[4:]
        n = lib.gs_diff_decode(stream, len(stream), out, len(out))
        c_lines = out.raw[:n].decode().splitlines()
        py = python_lines(stream, seed)
        assert len(c_lines) == len(py), f"C gave {len(c_lines)} frames/errors, Python {len(py)}:\n{c_lines}\n{py}"
        for a, b in zip(c_lines, py):
            if b.startswith("F ") and b.count(" ") == 2:  # float32 NaN: sequence and bytes only
                a = " ".join(a.split(" ")[:3])
            assert a == b, f"C and Python decoders differ:\n  C:      {a}\n  Python: {b}"

    return one_input


if __name__ == "__main__":
    import atheris  # type: ignore[import-not-found,unused-ignore]

    # argv[0] as a command line: libFuzzer's -fork, -jobs and -merge modes re-run it through the shell
    # (the module's .py path is not executable: -merge=1 merged nothing)
    atheris.Setup([f"{sys.executable} -m firmware_sim.cfirmware.fuzz_diff", *sys.argv[1:]], load(True))
    atheris.Fuzz()
