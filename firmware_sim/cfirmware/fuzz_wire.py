"""Fuzz target ``c-wire``: the C firmware's link decoder and board session under libFuzzer.

``python -m firmware_sim.cfirmware.fuzz_wire [libFuzzer args]`` builds the target with Debian's
clang (``-fsanitize=fuzzer,address,undefined``, :mod:`firmware_sim.cfirmware.build` kind
``fuzz-c-wire``, cached) and replaces itself with it, so ``ghostshell fuzz c-wire`` drives it like
the atheris targets. The input layout is the ``serial-decoder`` target's (4 chunking-seed bytes +
wire bytes), so the frame-log corpora seed it; invariants in firmware_sim/c/tests/fuzz_c_wire.c.
:func:`load` runs one input through the binary, :func:`replay` a whole corpus in one process (the replay tests).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from firmware_sim.cfirmware import libfuzzer

__all__ = ["binary", "load", "replay"]

KIND = "fuzz-c-wire"


def binary() -> Path:
    return libfuzzer.binary(KIND)


def replay(paths: Sequence[Path]) -> None:
    """Every input in ``paths`` through the binary, one process for all (the corpus replay test)."""
    libfuzzer.replay_files(KIND, "c-wire", paths)


def load(instrument: bool = False) -> Callable[[bytes], None]:
    return libfuzzer.one_input_runner(KIND, "c-wire")


if __name__ == "__main__":
    libfuzzer.exec_target(KIND)
