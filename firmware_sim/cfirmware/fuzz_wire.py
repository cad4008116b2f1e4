"""Fuzz target ``c-wire``: the C firmware's link decoder and board session under libFuzzer.

``python -m firmware_sim.cfirmware.fuzz_wire [libFuzzer args]`` builds the target with Debian's
clang (``-fsanitize=fuzzer,address,undefined``, :mod:`firmware_sim.cfirmware.build` kind
``fuzz-c-wire``, cached) and replaces itself with it, so ``ghostshell fuzz c-wire`` drives it like
the atheris targets. The input layout is the ``serial-decoder`` target's (4 chunking-seed bytes +
wire bytes), so the frame-log corpora seed it; invariants in firmware_sim/c/tests/fuzz_c_wire.c.
:func:`load` runs one input through the binary (the replay tests).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

__all__ = ["binary", "load"]


def binary() -> Path:
    from firmware_sim.cfirmware.build import build
    from robots.registry import DEFAULT_ROBOT, load_robot

    return build("fuzz-c-wire", load_robot(DEFAULT_ROBOT))


def load(instrument: bool = False) -> Callable[[bytes], None]:
    exe = binary()

    def one_input(data: bytes) -> None:
        with tempfile.NamedTemporaryFile(prefix="c-wire-", delete=False) as f:
            f.write(data)
        try:
            r = subprocess.run([str(exe), f.name], capture_output=True, text=True, timeout=60)
        finally:
            os.unlink(f.name)
        if r.returncode != 0:
            raise AssertionError(f"c-wire: the C firmware broke an invariant or a sanitizer fired:\n{r.stderr[-3000:]}")

    return one_input


if __name__ == "__main__":
    exe = binary()
    sys.stdout.flush()
    os.execv(str(exe), [str(exe), *sys.argv[1:]])
